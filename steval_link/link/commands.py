"""Host → drone commands (protocol v2, frame type 8) and the drone's acknowledgements (type 5)."""

from __future__ import annotations

import math
import random
import shlex
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from steval_link.errors import UserError
from steval_link.link import protocol as P
from steval_link.link.frames import AckFrame

#: SET_PARAM parameter names (``steval param set NAME VALUE``) → ids
PARAMS = {
    "kp_ground": P.PARAM_KP_GROUND,
    "kp_flight": P.PARAM_KP_FLIGHT,
    "ki": P.PARAM_KI,
    "min_thr": P.PARAM_MIN_THR,
    "correction": P.PARAM_CORRECTION,
}
PARAM_NAMES = {v: k for k, v in PARAMS.items()}
#: what each parameter is, for help texts and errors
PARAM_HELP = {
    "kp_ground": "proportional gain while the throttle is below min_thr (AHRS_KP_BIG, 10)",
    "kp_flight": "proportional gain from min_thr on (AHRS_KP_NORM, 0.4)",
    "ki": "integral gain (AHRS_KI, 0.1; lab exercise 4: 1.0)",
    "min_thr": "the filter's throttle threshold for the gain switch (MIN_THR, 200)",
    "correction": "accelerometer correction on/off (lab exercise 5: off)",
}
#: largest gain the firmware accepts (stv_cmd.h STV_GAIN_MAX)
GAIN_MAX = 1000.0
MODES = {"binary": P.MODE_BINARY, "text": P.MODE_TEXT}

#: why the drone refused, by ack result
RESULTS = {
    P.ACK_ACCEPTED: "accepted",
    P.ACK_REFUSED_ARMED: "refused: the motors may spin (throttle at or above MIN_THR, or armed) and this firmware "
    "does not allow filter changes in flight",
    P.ACK_UNKNOWN: "refused: the firmware does not know this command or parameter",
    P.ACK_OUT_OF_RANGE: "refused: value out of range",
    P.ACK_NOT_IN_BUILD: "refused: not available in this firmware build",
}

_ON = {"on", "1", "true", "yes"}
_OFF = {"off", "0", "false", "no"}
_SYNTAX = (
    "commands: set NAME VALUE (NAME: " + ", ".join(PARAMS) + "), correction on|off, reset, status, mode text|binary"
)


@dataclass(frozen=True)
class Command:
    """One command: ``cmd`` (protocol ``CMD_*``), ``param`` (``PARAM_*`` or the mode), ``value`` (SET_PARAM)."""

    cmd: int
    param: int = 0
    value: float = 0.0

    def encode(self, cmd_seq: int) -> bytes:
        """The 20-byte command frame with sequence number ``cmd_seq``."""
        return P.encode_command(cmd_seq=cmd_seq, cmd=self.cmd, param=self.param, value=self.value)

    def describe(self) -> str:
        """The command as one would type it (``set ki 1``, ``correction off``, ``reset-filter``, ...)."""
        if self.cmd == P.CMD_SET_PARAM:
            name = PARAM_NAMES.get(self.param, f"param {self.param}")
            if name == "correction":
                return "correction " + ("on" if self.value else "off")
            return f"set {name} {_fmt(name, self.value)}"
        if self.cmd == P.CMD_SET_MODE:
            return "mode " + ("text" if self.param == P.MODE_TEXT else "binary")
        return {P.CMD_RESET_FILTER: "reset-filter", P.CMD_REQUEST_STATUS: "status"}.get(self.cmd, f"command {self.cmd}")


def _fmt(name: str, value: float) -> str:
    """As typed: whole numbers without a point, a gain as the shortest text of its float32."""
    if name in ("min_thr", "correction"):
        return str(int(value))
    text = str(np.float32(value))
    return text[:-2] if text.endswith(".0") else text


def set_param(name: str, value: str | float) -> Command:
    """SET_PARAM ``name`` = ``value``, checked as the firmware checks it (one-sentence UserError)."""
    key = name.strip().lower().replace("-", "_")
    if key not in PARAMS:
        raise UserError(f"unknown parameter {name!r}; parameters: {', '.join(PARAMS)}")
    if key == "correction":
        text = str(value).strip().lower()
        if text not in _ON | _OFF:
            raise UserError(f"correction takes on or off, got {value!r}")
        return Command(P.CMD_SET_PARAM, PARAMS[key], 1.0 if text in _ON else 0.0)
    try:
        v = float(value)
    except ValueError:
        raise UserError(f"{key} takes a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0:
        raise UserError(f"{key} must be a finite number >= 0, got {value!r}")
    if key == "min_thr":
        if v != int(v) or v > 32767:
            raise UserError(f"min_thr must be a whole number from 0 to 32767, got {value!r}")
    elif v > GAIN_MAX:
        raise UserError(f"{key} must be at most {GAIN_MAX:g}, got {value!r}")
    return Command(P.CMD_SET_PARAM, PARAMS[key], v)


def parse_command(text: str) -> Command:
    """A typed line (see ``_SYNTAX``; ``NAME VALUE`` as ``set NAME VALUE``) → :class:`Command`, else a UserError."""
    try:
        words = shlex.split(text.strip().lower())
    except ValueError:
        words = text.strip().lower().split()
    if not words:
        raise UserError("empty command; " + _SYNTAX)
    head, rest = words[0], words[1:]
    if head == "set" and len(rest) == 2:
        return set_param(rest[0], rest[1])
    if head.replace("-", "_") in PARAMS and len(rest) == 1:
        return set_param(head, rest[0])
    if head in ("reset", "reset-filter", "reset_filter") and not rest:
        return Command(P.CMD_RESET_FILTER)
    if head in ("status", "request-status") and not rest:
        return Command(P.CMD_REQUEST_STATUS)
    if head == "mode" and len(rest) == 1:
        if rest[0] not in MODES:
            raise UserError(f"mode takes text or binary, got {rest[0]!r}")
        return Command(P.CMD_SET_MODE, MODES[rest[0]])
    raise UserError(f"not a command: {text.strip()!r}; " + _SYNTAX)


def parse_script(text: str, source: str = "commands") -> list[tuple[float, Command]]:
    """A command script: ``TIME_S COMMAND...`` lines (emulated s since power-up), ``#`` comments; errors name lines."""
    out: list[tuple[float, Command]] = []
    for i, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        t_text, _, rest = line.partition(" ")
        try:
            t = float(t_text)
            if not math.isfinite(t) or t < 0:
                raise ValueError
        except ValueError:
            raise UserError(
                f"{source} line {i}: a line starts with the emulated time in seconds "
                f"(e.g. '5.0 set ki 1.0'), got {t_text!r}"
            ) from None
        try:
            out.append((t, parse_command(rest)))
        except UserError as exc:
            raise UserError(f"{source} line {i}: {exc}") from None
    return sorted(out, key=lambda tc: tc[0])


def describe_settings(status) -> str:
    """The filter settings a status frame reports, in one line."""
    return (
        f"kp_ground {float(status.kp_ground):.9g}, kp_flight {float(status.kp_flight):.9g}, "
        f"ki {float(status.ki):.9g}, min_thr {int(status.min_thr)}, correction {param_of_status(status, 'correction')}"
    )


def param_of_status(status, name: str):
    """One parameter's value as a status frame reports it (correction as "on"/"off")."""
    if name == "correction":
        return "off" if int(status.flags) & P.FLAG_NO_CORRECTION else "on"
    return int(status.min_thr) if name == "min_thr" else float(getattr(status, name))


def describe_ack(command: Command | None, ack) -> str:
    """What the drone did with a command, one sentence (``command`` None: an ack for a command not sent here)."""
    what = command.describe() if command is not None else f"command #{int(ack.cmd_seq)}"
    counts = f"(commands received {int(ack.rx_ok)}, rejected {int(ack.rx_bad)})"
    if int(ack.result) != P.ACK_ACCEPTED:
        return f"{what}: {RESULTS.get(int(ack.result), f'refused (result {int(ack.result)})')} {counts}"
    if command is not None and command.cmd in (P.CMD_SET_PARAM, P.CMD_RESET_FILTER):  # it changes the filter
        return f"{what}: accepted, applies from step {int(ack.step)} {counts}"
    return f"{what}: accepted {counts}"


@dataclass
class Sent:
    """A command sent and not yet acknowledged."""

    cmd_seq: int
    command: Command
    frame: bytes


Writer = Callable[[bytes], object]  #: takes a frame's bytes (sends or records them)


class CommandChannel:
    """Numbers commands (from a random start: another session's acks are not taken for ours), sends and records them
    (the capture's ``H`` chunks); :meth:`match` pairs an ack with its command."""

    def __init__(self, send: Writer, record: Writer | None = None, *, first_seq: int | None = None) -> None:
        self._send = send
        self._record = record
        self._seq = random.randrange(P.SEQ_MODULUS) if first_seq is None else int(first_seq) % P.SEQ_MODULUS
        self.pending: dict[int, Sent] = {}
        self.sent = 0

    def next_frame(self, command: Command) -> Sent:
        """Number ``command`` and encode it, without sending (scripts that send at a given time)."""
        seq = self._seq
        self._seq = (self._seq + 1) % P.SEQ_MODULUS
        s = Sent(seq, command, command.encode(seq))
        self.pending[seq] = s
        while len(self.pending) > 256:  # never answered (lost): forget the oldest
            self.pending.pop(next(iter(self.pending)))
        return s

    def send(self, command: Command) -> Sent:
        """Number, send, then record ``command`` (a write that fails raises and records nothing)."""
        s = self.next_frame(command)
        self._send(s.frame)
        if self._record is not None:
            self._record(s.frame)
        self.sent += 1
        return s

    def match(self, ack) -> Sent | None:
        """The sent command ``ack`` answers (removed from :attr:`pending`), or None."""
        s = self.pending.get(int(ack.cmd_seq))
        if s is None or s.command.cmd != int(ack.cmd):
            return None
        del self.pending[int(ack.cmd_seq)]
        return s


def ack_of_text(line: str):
    """A text-mode acknowledgement line (``#ACK seq cmd result step rx_ok rx_bad``) as an ``AckFrame``, else None."""
    words = line.strip().split()
    if len(words) != 7 or words[0] != "#ACK" or not all(w.isdigit() for w in words[1:]):
        return None
    seq, cmd, result, step, ok, bad = (int(w) for w in words[1:])
    return AckFrame(cmd_seq=seq, cmd=cmd, result=result, step=step, rx_ok=ok, rx_bad=bad)


def _ack_of_row(a) -> AckFrame:
    """One ``Telemetry.acks`` row as an ``AckFrame``."""
    return AckFrame(**{name: int(a[name]) for name in P.payload_fields(P.ACK_DTYPE)})


def command_log(commands, acks) -> list[dict]:
    """The ``Telemetry.commands`` with their ``acks`` in time order, each ``{"t_host_s", "cmd_seq", "command" (as
    typed; None for an ack of a command not in the capture), "result" (None: no ack), "step", "text"}``."""
    out = []
    first: dict[tuple[int, int], int] = {}  # (cmd_seq, cmd) -> its first ack row
    for j, a in enumerate(acks):
        first.setdefault((int(a["cmd_seq"]), int(a["cmd"])), j)
    answered = set()
    for c in commands:
        command = Command(int(c["cmd"]), int(c["param"]), float(c["value"]))
        j = first.get((int(c["cmd_seq"]), int(c["cmd"])))
        ack = None if j is None or j in answered else _ack_of_row(acks[j])
        answered.add(j)
        out.append(_log_row(c["t_host_s"], int(c["cmd_seq"]), command, ack))
    out += [
        _log_row(a["t_host_s"], int(a["cmd_seq"]), None, _ack_of_row(a))
        for j, a in enumerate(acks)
        if j not in answered
    ]
    return sorted(out, key=lambda r: r["t_host_s"])


def _log_row(t_host_s, cmd_seq: int, command: Command | None, ack: AckFrame | None) -> dict:
    """A command sent, or (``command`` None) an ack of one not in the capture; ``result`` None: no ack."""
    return {
        "t_host_s": float(t_host_s),
        "cmd_seq": cmd_seq,
        "command": None if command is None else command.describe(),
        "result": None if ack is None else ack.result,
        "step": None if ack is None else ack.step,
        "text": f"{command.describe()}: no ack" if ack is None else describe_ack(command, ack),
    }

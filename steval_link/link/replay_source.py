"""A recorded stream played back as a live serial port: ``--port replay://recordings/demo.stv``.

As pyserial's URL handlers (``loop://``), :class:`ReplayPort` has the surface of ``serial.Serial``, so a replay
walks the whole live path. A capture's bytes come out at their recorded host times, a dump or log at its frames'
firmware times, else at the baud rate; the lead-in before the first attitude frame at once.
"""

from __future__ import annotations

import math
import threading
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import serial

from steval_link import constants as C
from steval_link.errors import UserError
from steval_link.link.ble_payloads import is_ble_source
from steval_link.link.decoder import StreamDecoder
from steval_link.link.load import read_recording, telemetry_of_recording
from steval_link.link.transport import READ_TIMEOUT_S

SCHEME = "replay://"
#: Bytes released together when pacing at the baud rate.
BAUD_BLOCK_BYTES = 32
#: Bit times per byte on the wire (8N1).
BITS_PER_BYTE = 10
#: A gap in firmware time longer than this (restart, wrap) is replayed as one AHRS period, s.
MAX_FW_GAP_S = 1.0
#: Why a command cannot be sent to a replay (the error of :meth:`ReplayPort.write`) ...
NO_COMMANDS = "a replay takes no commands"
#: ... and what the prompt says once, at the start.
PROMPT_NOTE = f"{NO_COMMANDS}: lines typed here are not sent anywhere"


def is_replay_url(port: str) -> bool:
    """True for ``replay://PATH`` (any case of the scheme)."""
    return port.lower().startswith(SCHEME)


@dataclass(frozen=True)
class ReplayUrl:
    """``replay://PATH[?speed=X&rate=N&loop=1]``: the file, times faster than recorded, ``rate``, start again at end."""

    path: Path
    speed: float = 1.0
    rate: float | None = None  #: records per second of a text log without times (``?rate=N``)
    loop: bool = False


#: the options a replay URL takes, in the order its errors name them
OPTIONS = ("speed", "rate", "loop")
_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def parse_replay_url(url: str) -> ReplayUrl:
    """Parse ``replay://recordings/demo.stv`` (relative), ``replay:///abs/x.stv`` or ``...?speed=5``."""
    if not is_replay_url(url):
        raise UserError(f"{url} is not a replay URL (replay://CAPTURE.stv)")
    path_text, _, query = url[len(SCHEME) :].partition("?")
    if not path_text:
        raise UserError(f"{url}: no file to replay; give one as replay://recordings/demo.stv")
    opts: dict = {}
    try:
        params = urllib.parse.parse_qs(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise UserError(f"{url}: cannot read the options after '?' (replay://FILE?speed=5)") from None
    for key, values in params.items():
        if key not in OPTIONS:
            raise UserError(f"{url}: unknown replay option {key!r} (known: {', '.join(OPTIONS)}, e.g. ?speed=5)")
        if key == "loop":
            word = values[-1].strip().lower()
            if word not in _TRUE + _FALSE:
                raise UserError(f"{url}: loop is 1 (start again at the end) or 0, got {values[-1]!r}")
            opts[key] = word in _TRUE
        else:  # speed, or rate: the records per second of a text log without times
            opts[key] = _positive(url, key, values[-1])
    return ReplayUrl(Path(urllib.parse.unquote(path_text)), **opts)


def _positive(url: str, key: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise UserError(f"{url}: {key} must be a positive number, got {text!r}")
    return value


def pace_of(src, tel, baud: int, rate: float | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """``(ends, t_s, how)``: bytes ``[0, ends[i])`` of ``src`` are out ``t_s[i]`` s into the replay, paced by how."""
    n = len(src.data)
    att = tel.attitude
    first = int(att.offset[0]) if len(att) else 0
    t = np.maximum.accumulate(np.asarray(src.chunk_times_s, np.float64))  # a capture's chunks (NaN: none)
    if len(t) and np.isfinite(t).all():
        ends = np.append(np.asarray(src.chunk_offsets[1:], np.int64), n)
        k = min(int(np.searchsorted(ends, first, side="right")), len(t) - 1)  # the chunk holding frame 0's start
        return ends, np.maximum(t - t[k], 0.0), "the capture's host times"
    t_fw, how = np.asarray(att.t_fw_s, np.float64), "the frames' firmware times"
    series = tel.text_series
    if len(series) >= 2 and not tel.has_own_attitude:  # text telemetry: records paced
        if rate is None and series.t_source.startswith("the record index"):
            t_fw = np.zeros(0)  # no times: the baud rate below
        else:
            att, t_fw = series, series.t_s if rate is None else np.arange(len(series)) / rate
            how = f"{rate:g} records/s" if rate else f"the records' times ({series.t_source})"
    if len(t_fw) >= 2 and np.isfinite(t_fw).all():
        dt = np.diff(t_fw)
        dt[(dt <= 0) | (dt > MAX_FW_GAP_S)] = C.AHRS_PERIOD_S
        t = np.concatenate([[0.0], np.cumsum(dt)])
        # frame i (and the bytes before frame i+1) is out at its own firmware time; the tail at the baud rate
        ends = np.append(np.asarray(att.offset[1:], np.int64), n)
        return ends, np.append(t[:-1], t[-1] + (n - int(att.offset[-1])) * BITS_PER_BYTE / baud), how
    ends = np.append(np.arange(BAUD_BLOCK_BYTES, n, BAUD_BLOCK_BYTES, dtype=np.int64), n)
    return ends, ends * (BITS_PER_BYTE / baud), f"{baud} baud"


class ReplayPort:
    """A file's bytes as a serial port: bytes ``[0, ends[i])`` readable ``t_s[i] / speed`` s after the first read."""

    def __init__(
        self,
        data: bytes,
        ends: np.ndarray,
        t_s: np.ndarray,
        *,
        port: str,
        path: Path,
        baudrate: int = C.BAUD,
        speed: float = 1.0,
        timeout: float = READ_TIMEOUT_S,
        paced_by: str = "",
        clock: Callable[[], float] = time.monotonic,
        emulated: bool = False,
        loop: bool = False,
        line_start: bool = False,
    ) -> None:
        self.data = bytes(data)
        self.ends = np.asarray(ends, np.int64)
        self.t_s = np.asarray(t_s, np.float64) / speed
        self.port, self.path, self.baudrate, self.timeout = port, path, baudrate, timeout  # as pyserial's
        self.speed, self.paced_by, self.prompt_note = speed, paced_by, PROMPT_NOTE
        self.emulated = emulated  #: the file came from an emulator (its cycle counts are instructions)
        self.line_start = line_start  #: the file's first byte starts a line (a log: its first line is whole)
        self._clock, self._t0, self._pos = clock, None, 0  # the replay starts at the first read
        #: start again after the last byte, one AHRS period later; ``loops``: how many times it did
        self.loop, self.loops, self._t_loop = bool(loop) and len(self.data) > 0, 0, 0.0
        self._period_s = (float(self.t_s[-1]) if len(self.t_s) else 0.0) + C.AHRS_PERIOD_S / speed
        self._cancel = threading.Event()
        self.is_open = True

    def _elapsed_s(self) -> float:
        now = self._clock()
        if self._t0 is None:
            self._t0 = now  # the replay starts when it is first read
        return now - self._t0

    def _released(self) -> tuple[int, float]:
        """(bytes out by now, seconds until the next bytes come out, ``inf`` after the last)."""
        if self.loop and self._pos >= len(self.data):  # every byte read: the next round starts one period on
            self._pos, self._t_loop, self.loops = 0, self._t_loop + self._period_s, self.loops + 1
        el = self._elapsed_s() - self._t_loop
        i = int(np.searchsorted(self.t_s, el, side="right"))
        out = int(self.ends[i - 1]) if i else 0
        return out, float(self.t_s[i]) - el if i < len(self.t_s) else math.inf

    @property
    def in_waiting(self) -> int:
        """Bytes out and not yet read."""
        return max(0, self._released()[0] - self._pos)

    @property
    def at_end(self) -> bool:
        """Every byte has been read (never, looping)."""
        return not self.loop and self._pos >= len(self.data)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes: waits until that many are out or :attr:`timeout` passed (or :meth:`cancel_read`)."""
        if not self.is_open:
            raise serial.SerialException(f"{self.port} is closed")
        deadline_s = self._elapsed_s() + (math.inf if self.timeout is None else self.timeout)
        while True:
            out, wait_s = self._released()
            avail = out - self._pos
            left_s = deadline_s - self._elapsed_s()
            if avail >= size or left_s <= 0 or self._cancel.is_set():
                break
            self._cancel.wait(min(wait_s, left_s))
        n = max(0, min(size, avail))
        chunk = self.data[self._pos : self._pos + n]
        self._pos += n
        return chunk

    def cancel_read(self) -> None:
        """Wake a read that waits (as pyserial's); later reads no longer wait."""
        self._cancel.set()

    def write(self, data: bytes) -> int:
        """Nothing can be sent to a recording: raises ``serial.SerialException`` (an ``OSError``)."""
        raise serial.SerialException(NO_COMMANDS)

    def close(self) -> None:
        self.is_open = False
        self._cancel.set()

    def describe(self) -> str:
        """Where the bytes come from, in words (for the session's first note)."""
        pace = "the recorded pace" if self.speed == 1 else f"{self.speed:g}x the recorded pace"
        return f"{self.path} replayed at {pace} ({self.paced_by})" + (", in a loop" if self.loop else "")


def open_replay(url: str, *, baud: int = C.BAUD) -> ReplayPort:
    """Open ``replay://PATH[?speed=X]``; ``baud``: the pace of a file without times (a capture's header wins)."""
    parsed = parse_replay_url(url)
    try:
        src = read_recording(parsed.path)
        if is_ble_source(src):
            raise UserError(f"{parsed.path} is a BLE capture (no serial bytes); open it with steval replay")
        tel = telemetry_of_recording(src)
    except UserError as exc:
        raise UserError(f"cannot replay {url}: {str(exc).rstrip('.')}") from None
    rate = int(src.header.get("baud") or baud) if src.header else baud
    ends, t_s, how = pace_of(src, tel, rate if rate > 0 else baud, parsed.rate)
    data = src.data
    if parsed.loop:  # each round ends after the last whole frame: no cut frame at the seam
        data, ends, t_s = _to_whole_frames(data, ends, t_s)
    return ReplayPort(
        data,
        ends,
        t_s,
        port=url,
        path=parsed.path,
        baudrate=rate,
        speed=parsed.speed,
        paced_by=how,
        emulated=bool((src.header or {}).get("extra", {}).get("emulated")),
        loop=parsed.loop,
        line_start=src.line_start,
    )


def _to_whole_frames(data: bytes, ends: np.ndarray, t_s: np.ndarray) -> tuple[bytes, np.ndarray, np.ndarray]:
    """``data`` up to the end of its last whole frame or line, and its pace (``ends``, ``t_s``) cut there."""
    dec = StreamDecoder()
    cut = 0
    for frame in dec.feed(data) + dec.finish():
        cut = max(cut, getattr(frame, "offset", 0) + getattr(frame, "nbytes", 0))
    if cut <= 0 or cut >= len(data):
        return data, ends, t_s
    ends, t_s = np.asarray(ends), np.asarray(t_s)
    keep = ends < cut
    return data[:cut], np.append(ends[keep], cut), np.append(t_s[keep], t_s[int(np.argmax(ends >= cut))])

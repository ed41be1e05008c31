"""Serial ports: listing them (``steval ports``), finding the drone's (probing candidates, recognising a wrong baud
rate, finding a port again), and the other programs that have it open (:func:`port_holders`).

A program reading the port without its lock (``cat``) takes bytes from our stream: Linux's ``/proc/PID/fd`` links or
``lsof`` find it (Windows opens ports exclusively).
"""

from __future__ import annotations

import contextlib
import glob
import math
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field

import numpy as np
import serial

from steval_link.errors import ParamError
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import TextFrame
from steval_link.link.transport import close_quietly, open_serial

#: Baud rates the USART1 setups of the STEVAL firmware use, most likely first after the default.
COMMON_BAUDS = (115200, 921600, 460800, 230400, 57600, 38400, 19200, 9600)


def is_glob(port: str) -> bool:
    """True when ``port`` is a pattern (``*``, ``?`` or ``[``) rather than one path."""
    return any(c in port for c in "*?[")


#: Longest wait for ``lsof``, s.
LSOF_TIMEOUT_S = 2.0


@dataclass(frozen=True, slots=True)
class PortInfo:
    """One serial port as pyserial sees it; ``vid_pid`` is ``"0483:5740"`` style or None (not USB)."""

    device: str
    description: str
    vid_pid: str | None
    serial_number: str | None
    manufacturer: str | None
    hwid: str

    def as_dict(self) -> dict:
        return asdict(self)


def list_ports() -> list[PortInfo]:
    """Every serial port of this machine, sorted by device name."""
    out = []
    for p in _comports():
        vid_pid = f"{p.vid:04X}:{p.pid:04X}" if p.vid is not None and p.pid is not None else None
        desc = p.description if p.description and p.description != "n/a" else ""
        out.append(PortInfo(p.device, desc, vid_pid, p.serial_number, p.manufacturer, p.hwid or ""))
    return sorted(out, key=lambda x: x.device)


def port_holders(device: str) -> list[tuple[int, str]]:
    """(PID, program name) of every other process that has ``device`` open, sorted by PID."""
    real = os.path.realpath(device)
    if sys.platform.startswith("linux") and os.path.isdir("/proc/self/fd"):
        found = _proc_holders(real)
    elif sys.platform == "win32":  # a port is opened exclusively there
        found = []
    else:
        found = _lsof_holders(real)
    return sorted((pid, name) for pid, name in found if pid != os.getpid())


def _proc_holders(real: str) -> list[tuple[int, str]]:
    pids = set()
    for link in glob.glob("/proc/[0-9]*/fd/*"):  # another user's processes: their fds are not listed
        with contextlib.suppress(OSError):  # gone meanwhile
            if os.readlink(link) == real:
                pids.add(int(link.split("/")[2]))
    return [(pid, _proc_name(str(pid))) for pid in pids]


def _proc_name(pid: str) -> str:
    try:
        with open(f"/proc/{pid}/comm") as f:
            return f.read().strip() or "?"
    except OSError:
        return "?"


def _lsof_holders(real: str) -> list[tuple[int, str]]:
    lsof = shutil.which("lsof")
    if lsof is None:
        return []
    try:
        done = subprocess.run([lsof, "-F", "pc", real], capture_output=True, text=True, timeout=LSOF_TIMEOUT_S)
    except (OSError, subprocess.SubprocessError):
        return []
    out, pid = [], None
    for line in done.stdout.splitlines():
        if line.startswith("p") and line[1:].isdigit():
            pid = int(line[1:])
        elif line.startswith("c") and pid is not None:
            out.append((pid, line[1:] or "?"))
            pid = None
    return out


def holders_sentence(device: str, holders: list[tuple[int, str]]) -> str:
    """The sentence for other programs that have the port open."""
    who = ", ".join(f"PID {pid}, {name}" for pid, name in holders)
    many = len(holders) > 1
    return (
        f"{'other programs' if many else 'another program'} ({who}) {'have' if many else 'has'} {device} open: "
        f"{'they take' if many else 'it takes'} bytes from this stream (close {'them' if many else 'it'})"
    )


def list_candidate_ports() -> list[str]:
    """Device paths that may carry the drone: the USB ports when there are any, else every port."""

    listed = list_ports()
    return [p.device for p in listed if p.vid_pid] or [p.device for p in listed]


def _comports():
    from serial.tools import list_ports

    try:
        return list(list_ports.comports())
    except OSError:  # a sysfs entry vanished while being read (unplug in progress)
        return []


@dataclass(frozen=True)
class PortIdentity:
    """What a port is, to find it again: the path given, its real device, and USB identity where there is one."""

    path: str
    device: str
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    location: str | None = None

    @classmethod
    def of(cls, path: str) -> "PortIdentity":
        """Identity of the port at ``path`` now (USB fields from pyserial's port list; ``None`` for ptys)."""
        device = os.path.realpath(path)
        for info in _comports():
            if os.path.realpath(info.device) == device and info.vid is not None:
                return cls(path, device, info.vid, info.pid, info.serial_number, info.location)
        return cls(path, device)

    @property
    def has_usb_id(self) -> bool:
        return self.vid is not None and self.pid is not None

    def describe(self) -> str:
        if self.has_usb_id:
            sn = f" serial {self.serial_number}" if self.serial_number else ""
            return f"{self.path} (USB {self.vid:04X}:{self.pid:04X}{sn})"
        return self.path


def family_glob(path: str) -> str | None:
    """The pattern of a port's sibling names: ``/dev/ttyUSB0`` → ``/dev/ttyUSB*``; ``None`` when no trailing digits."""
    m = re.match(r"^(.*?)(\d+)$", path)
    return glob.escape(m.group(1)) + "*" if m and m.group(1) else None


@dataclass
class PortFinder:
    """Finds a lost port again (:meth:`find`, cheap at 10 Hz): a USB adapter by its identity, whatever its name; else
    its path or a new name matching ``pattern``. A path :meth:`reject` ed is skipped while its node stays the same."""

    identity: PortIdentity
    pattern: str | None = None
    _present_at_loss: set[str] = field(default_factory=set)
    _rejected: dict[str, tuple] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.pattern = family_glob(self.identity.path) if self.pattern is None else self.pattern

    def mark_lost(self) -> None:
        """Remember which sibling names exist now, so that only a name that appears later is taken for the port."""
        self._present_at_loss = set(self._siblings()) - {self.identity.path, self.identity.device}

    def reject(self, path: str) -> None:
        """``path`` (as :meth:`find` returned it) is not the drone: skip it until its device node changes."""
        self._rejected[os.path.realpath(path)] = _node(path)

    def _siblings(self) -> list[str]:
        return sorted(glob.glob(self.pattern)) if self.pattern else []

    def _usable(self, path: str) -> bool:
        return os.path.exists(path) and self._rejected.get(os.path.realpath(path)) != _node(path)

    def find(self) -> str | None:
        """The path to reopen (the most likely of those that may be the port now), or None while it is not back."""
        ident = self.identity
        if ident.has_usb_id:
            infos = [info for info in _comports() if info.vid == ident.vid and info.pid == ident.pid]
            if ident.serial_number is not None:
                infos = [info for info in infos if info.serial_number == ident.serial_number]
            # without a serial number: the same USB socket first, then the old name, then any adapter of that kind
            infos.sort(key=lambda info: (info.location != ident.location, info.device != ident.device, info.device))
            found = [info.device for info in infos]
        else:  # its path, then a name that appeared since it was lost
            found = [ident.path] + [p for p in self._siblings() if p not in self._present_at_loss and p != ident.path]
        return next((p for p in found if self._usable(p)), None)


def _node(path: str) -> tuple:
    """What tells one device node from a new one at the same name (device number, inode, change time)."""
    try:
        st = os.stat(path)
    except OSError:
        return ()
    return st.st_rdev, st.st_ino, st.st_ctime_ns


#: Bytes a probe reads at most.
PROBE_MAX_BYTES = 64 * 1024


def probe_port(port: str, baud: int, duration_s: float = 0.6) -> int:
    """Valid frames but text frames read from ``port`` at ``baud`` within ``duration_s`` (it stops at 2; 0: failed)."""
    t0 = time.monotonic()
    try:
        ser = open_serial(port, baud, timeout_s=0.02)
    except (serial.SerialException, OSError):
        return 0
    decoder, frames, nbytes = StreamDecoder(), 0, 0
    try:
        with contextlib.suppress(serial.SerialException, OSError):  # a read failed: the frames so far
            while time.monotonic() - t0 < duration_s and nbytes < PROBE_MAX_BYTES and frames < 2:
                data = ser.read(4096)
                nbytes += len(data)
                # text frames do not count: any device's text lines decode as firmware log lines
                frames += sum(1 for f in decoder.feed(data) if not isinstance(f, TextFrame))
    finally:
        close_quietly(ser)
    return frames


def probe_ports(ports: list[str], baud: int, duration_s: float = 0.6) -> list[int]:
    """:func:`probe_port` on several ports at once (one thread each): their frame counts, in the order of ``ports``."""
    counts = [0] * len(ports)  # a probe that does not finish counts none

    def work(i: int, p: str) -> None:
        counts[i] = probe_port(p, baud, duration_s)

    threads = [threading.Thread(target=work, args=(i, p), daemon=True) for i, p in enumerate(ports)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(duration_s + 5.0)
    return counts


class PortChoiceError(ParamError):
    """``--port auto`` could not decide; the message is one sentence for the user."""


def choose_port(spec: str, baud: int, *, probe_s: float = 0.6, candidates: list[str] | None = None) -> str:
    """A path as is; ``auto`` or a glob: the one candidate, or the one probed that sends frames (else an error)."""
    if spec != "auto" and not is_glob(spec):
        return spec
    if candidates is None:
        candidates = list_candidate_ports() if spec == "auto" else sorted(glob.glob(spec))
    where = "" if spec == "auto" else f" matching {spec}"
    if not candidates:
        raise PortChoiceError(
            f"no serial ports found{where}; plug in the drone's USB-UART adapter (or give {{port}}, or {{wait}})",
            "port",
            "wait",
        )
    if len(candidates) == 1:
        return candidates[0]
    answering = [p for p, frames in zip(candidates, probe_ports(candidates, baud, probe_s)) if frames > 0]
    if len(answering) == 1:
        return answering[0]
    listing = ", ".join(candidates)
    if answering:
        raise PortChoiceError(
            f"several ports carry steval frames ({', '.join(answering)}); pick one with {{port}}", "port"
        )
    raise PortChoiceError(
        f"none of the serial ports{where} sent valid frames at {baud} baud within {probe_s:.1f} s "
        f"({listing}); pick one with {{port}}",
        "port",
    )


def describe_bytes(data: bytes, total: int | None = None) -> str:
    """A few words on what bytes without any valid frame look like; ``data``: a sample, ``total``: all bytes."""
    n = len(data) if total is None else total
    if n == 0:
        return "no bytes at all"
    sample = data[:4096]
    counts = np.bincount(np.frombuffer(sample, np.uint8), minlength=256).tolist()
    m = len(sample)
    printable = sum(counts[32:127]) + counts[9] + counts[10] + counts[13]
    zeros, ffs = counts[0], counts[0xFF]
    distinct = sum(1 for c in counts if c)
    if zeros / m > 0.9:
        return f"all 0x00 ({n} bytes: a line held low, or a much slower baud rate)"
    if ffs / m > 0.9:
        return f"all 0xFF ({n} bytes: framing noise from a much faster baud rate)"
    if printable / m > 0.9:
        text = sample.decode("ascii", "replace")
        lines = [ln.strip() for ln in text.replace("\r", "\n").split("\n") if ln.strip()]
        shown = (lines[0] if lines else text.strip())[:40]
        return f'text, not steval frames ({n} bytes, e.g. "{shown}": another device, or firmware without the patch)'
    if distinct < 8:
        shown = " ".join(f"{b:02X}" for b in sorted(range(256), key=lambda b: -counts[b])[: min(distinct, 4)])
        return f"a few repeating values ({shown}; {n} bytes: framing noise from another baud rate)"
    if (zeros + ffs) / m > 0.4 or counts[0x80] + counts[0xF8] + counts[0xE0] + counts[0xFE] > 0.3 * m:
        return f"framing noise ({n} bytes, mostly 0x00/0x80/0xF8/0xFF: another baud rate)"
    return f"random binary ({n} bytes, {100 * printable / m:.0f}% printable: another baud rate or another protocol)"


def bit_run_length(data: bytes) -> float:
    """Mean length of runs of equal bits inside the 8N1 frames of ``data``: about 1.8 at the reader's rate (or a
    faster one), 2.7 for a sender 2 times slower, 3.8 for 3..4, 5 for 8 and more."""
    a = np.frombuffer(bytes(data[:8192]), dtype=np.uint8)
    if a.size == 0:
        return 0.0
    bits = np.ones((a.size, 10), dtype=np.uint8)
    bits[:, 0] = 0
    bits[:, 1:9] = (a[:, None] >> np.arange(8, dtype=np.uint8)) & 1
    runs = (np.diff(bits, axis=1) != 0).sum(axis=1) + 1
    return float(10.0 / runs.mean())


def suggest_bauds(data: bytes, baud: int) -> list[int]:
    """Baud rates worth trying, most likely first, for bytes without frames read at ``baud``: slower ones by
    :func:`bit_run_length` when bit runs are long, else faster ones, 921600 (the patch's fast setting) first."""
    others = [b for b in COMMON_BAUDS if b != baud]
    faster = sorted((b for b in others if b > baud), key=lambda b: (b != 921600, -b))
    slower = [b for b in others if b < baud]
    run = bit_run_length(data)
    if run < 2.3 or not slower:
        return faster + sorted(slower, key=lambda b: -b)
    guess = baud / (2.0 if run < 3.2 else 4.0 if run < 4.4 else 8.0)  # the sender's rate by the bit runs
    slower.sort(key=lambda b: abs(math.log(b / guess)))
    return slower + faster


def no_frames_message(port: str, baud: int, data: bytes, seconds: float, total: int | None = None) -> ParamError:
    """The one line for a port without valid frames in ``seconds``: what its bytes look like, which baud to try."""
    if not data:
        return ParamError(
            f"no bytes at all from {port} in {seconds:.1f} s: is the drone powered and its TX (PA9, header P7) "
            "wired to the adapter's RX? ({wait} keeps waiting)",
            "wait",
        )
    tries = suggest_bauds(data, baud)
    what = describe_bytes(data, total)
    if what.startswith("text"):
        hint = "flash the steval firmware patch (or check {port})"
    else:
        hint = f"try {{baud}} {tries[0]}" + (f" (or {', '.join(str(b) for b in tries[1:3])})" if len(tries) > 1 else "")
    return ParamError(f"no valid frames at {baud} baud on {port}; bytes look like {what}; {hint}", "port", "baud")

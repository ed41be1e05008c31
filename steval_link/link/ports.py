"""Serial ports: listing (``steval ports``) and the other programs that have a port open (:func:`port_holders`).

A program reading the port without its lock (``cat``) takes bytes from our stream: Linux's ``/proc/PID/fd`` links or
``lsof`` find it (Windows opens ports exclusively).
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import subprocess
import sys
from dataclasses import asdict, dataclass

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
    from serial.tools import list_ports as lp

    out = []
    for p in lp.comports():
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

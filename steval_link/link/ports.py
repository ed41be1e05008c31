"""Serial ports: listing (``steval ports``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["PortInfo", "list_ports"]


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

"""The links a live session reads, behind one interface, :class:`Source` (as pyserial's ``Protocol``, cflib's
drivers); a URL picks the driver (:func:`.session.source_for`, as ``serial_for_url``), which parses it (``from_url``):

====================================  ======================================================================
``/dev/ttyUSB0``, ``COM3``, ``auto``  a serial port, or the one that carries frames (:mod:`.serial_source`)
``replay://FILE.stv[?speed=X]``       a capture played at its recorded pace, as a serial port (same driver)
``emulated:ELF``                      the emulated board running an ELF (:mod:`.emulated`, ``steval emulate``)
``ble:NAME``, ``ble:ADDRESS``, ``ble:``  a drone over Bluetooth (:mod:`.ble_source`, ``--ble``)
====================================  ======================================================================

A source hands each chunk to the ``record`` function it is given (the capture) first; it never reads the session.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from steval_link.errors import ParamError, UserError
from steval_link.link.ble_payloads import ble_chunk
from steval_link.link.capture import CHUNK_BLE, CHUNK_SYMBOLS, CaptureWriter

__all__ = ["Chunk", "LinkInfo", "LinkStatus", "PROMPT_HELP", "Record", "Source", "open_capture", "record_chunk"]

PROMPT_HELP = (
    "type a command and Enter: set ki 1.0 | correction off | correction on | reset | status | "
    "set min_thr 300 | mode text"
)

#: Chunk kinds besides the capture's own
NOTE, BREAK, END = "note", "break", "end"


@dataclass
class Chunk:
    """One timestamped piece of a link; ``t_s`` on the capture's clock (s since it started; None: now)."""

    #: D drone bytes, B (char id, payload) a BLE notification, H host bytes, T truth rows, E (kind, text) a link
    #: event, S symbol rows; ``note`` for the terminal, ``break`` a BLE reconnection, ``end`` the stop reason
    kind: str
    data: Any
    t_s: float | None
    t_unix_s: float | None = None  #: the host's Unix time as the link gave it, where it has one


#: ``record(chunk)``: the session's capture, written first (thread-safe)
Record = Callable[[Chunk], None]

#: how each kind of chunk goes into the capture (``data``, ``t_s`` of a :class:`Chunk`)
_WRITE = {
    "D": lambda cap, data, t_s: cap.write(data, t_s),
    "B": lambda cap, data, t_s: cap.write_chunk(CHUNK_BLE, ble_chunk(*data), t_s),
    "H": lambda cap, data, t_s: cap.write_host(data, t_s),
    "T": lambda cap, rows, t_s: cap.write_truth(rows.step, rows.t_s, rows.q_wxyz, rows.movement, t_s),
    "E": lambda cap, data, t_s: cap.mark_event(*data, t_s),
    "S": lambda cap, data, t_s: cap.write_chunk(CHUNK_SYMBOLS, data, t_s),
}


def record_chunk(capture: CaptureWriter, chunk: Chunk) -> None:
    """A chunk into ``capture`` as its kind is written (notes, breaks and ends are not recorded)."""
    if (write := _WRITE.get(chunk.kind)) is not None:
        write(capture, chunk.data, chunk.t_s)


def open_capture(path, *, port: str, baud: int, extra: dict, discard_empty: bool = False) -> CaptureWriter:
    """A new capture at ``path`` (never overwritten): one UserError sentence when it exists or cannot be written."""
    try:
        return CaptureWriter(path, discard_empty=discard_empty, port=port, baud=baud, extra=extra)
    except FileExistsError:
        raise ParamError(
            f"{path} already exists; choose another {{out}} (captures are never overwritten)", "out"
        ) from None
    except OSError as exc:
        raise UserError(f"cannot write the capture {path}: {exc.strerror or exc}") from None


@dataclass
class LinkInfo:
    """What a source says about itself."""

    link: str  # the capture header's ``link`` (``/dev/ttyUSB0``, ``emulated:ref.elf``, ``ble:DRN1110``)
    baud: int  # 0: none
    extra: dict[str, Any] = field(default_factory=dict)  # the capture header's extra fields
    discard_empty: bool = True  # a capture that got no byte is removed
    kind: str = "serial"  # the summary's layout (serial, emulated, ble)
    note: str = ""  # the opening note's first words ("": none)
    takes_commands: bool = True
    prompt_note: str = PROMPT_HELP
    recording_name: str | None = None  # None: the capture's name
    own_clock: bool = False  # the chunks' times are the link's own (emulated): the stop event takes the last one
    commands: list = field(default_factory=list)  # (s, Command) the session sends at those link times


@dataclass
class LinkStatus:
    """How a link is doing, kept up to date by its driver (the session reads it for the health line and summary)."""

    connected: bool = False
    port: str | None = None  # the one opened now
    connections: int = 0
    disconnects: int = 0
    bytes_total: int = 0
    lost_at_s: float | None = None  # monotonic time of the last loss
    connected_at_s: float | None = None  # monotonic time of the last connection
    connect_bytes: int = 0  # bytes of the current connection
    live_dropped_bytes: int = 0  # bytes dropped from the live view (in the capture)
    reopen_error: Any = None  # (path, exception): it is back but cannot be opened
    t_link_s: float = 0.0  # the link's own clock (emulated s)
    started_s: float | None = None  # monotonic time it began running before the session (the emulated board)
    duration_s: float | None = None  # emulated
    report: Any = None  # emulated: the board's report
    wait: bool = False  # keep waiting for frames instead of stopping
    symbol_rows: int = 0  # emulated: AHRS steps whose attitude the emulator read by symbol
    probing: str | None = None  # a port reopened after a loss, on probation until it sends valid frames
    offline: list = field(default_factory=list)  # (lost, back or None) host Unix times of each loss
    pace: float = 1.0  # a replay's ``?speed=``: its rate is that many times the drone's


class Source:
    """One link of a live session: :meth:`open`, :meth:`describe` (the capture header), :meth:`chunks` (each item:
    one round's chunks, [] when none came), :meth:`write` (any thread), :meth:`close` (then what is left, once)."""

    status: LinkStatus

    def open(self, note: Callable[[str], None]) -> None:
        """The input, or one UserError sentence (``note(text)``: a line while it waits, e.g. for a port)."""
        raise NotImplementedError

    def describe(self) -> LinkInfo:
        raise NotImplementedError

    def chunks(self, record: Record, clock) -> Iterator[list[Chunk]]:
        """The link's chunks, each handed to ``record`` first; ``clock``: the session's ``HostClock``."""
        raise NotImplementedError

    def write(self, frame: bytes, at_s: float | None = None) -> None:
        """Send a command frame (``at_s``: at that time of the link's own clock, where it has one)."""
        raise UserError("this link takes no commands")

    def close(self) -> None:
        pass

"""The links a live session reads, behind one narrow interface (as pyserial's ``Protocol`` and cflib's link
drivers): :class:`Source`. A URL chooses the driver (:func:`steval_link.live.session.source_for`, as pyserial's
``serial_for_url``); each driver parses its own URL (``from_url``):

====================================  ======================================================================
``/dev/ttyUSB0``, ``COM3``, ``auto``  a serial port, or the one that carries frames (:mod:`.serial_source`)
``replay://FILE.stv[?speed=X]``       a capture played at its recorded pace, as a serial port (same driver)
``emulated:ELF``                      the emulated board running an ELF (:mod:`.emulated`, ``steval emulate``)
``ble:NAME``, ``ble:ADDRESS``, ``ble:``  a drone over Bluetooth (:mod:`.ble_source`, ``--ble``)
====================================  ======================================================================

A source has five public methods: :meth:`Source.open`, :meth:`Source.describe`, :meth:`Source.chunks`,
:meth:`Source.write`, :meth:`Source.close`. It moves its chunks into the capture first (through the ``record``
function it is given, in its own thread or its round) and hands them on, timestamped; it never reads the session.
:class:`~steval_link.live.session.LiveSession` owns the rest once: the capture file, the decoder and estimators
(the one pipeline), the viewer, the command prompt, the stop requests and signals, the health line and the summary.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from steval_link.errors import UserError
from steval_link.live.console import PROMPT_HELP

__all__ = ["Chunk", "LinkInfo", "LinkStatus", "Record", "Source"]

#: Chunk kinds besides the capture's own (D drone bytes, B BLE notification, H host bytes, T truth, E event)
NOTE, BREAK, END = "note", "break", "end"


@dataclass
class Chunk:
    """One timestamped piece of a link: ``kind`` D (bytes from the drone), B ((char id, payload): a BLE
    notification), H (bytes the host sent), T (a BROAD trial's truth rows), E ((kind, text): a link event), ``note``
    (a sentence for the terminal only), ``break`` (a BLE link lost and found again) or ``end`` (the link ended: the
    stop reason); ``t_s`` on the capture's clock (s since it started; None: now)."""

    kind: str
    data: Any
    t_s: float | None
    t_unix_s: float | None = None  #: the host's Unix time as the link gave it, where it has one


#: ``record(chunk)``: the session's capture, written first (thread-safe)
Record = Callable[[Chunk], None]


@dataclass
class LinkInfo:
    """What a source says about itself: the capture header's ``link`` (``/dev/ttyUSB0``, ``emulated:ref.elf``,
    ``ble:DRN1110``), baud rate (0: none) and ``extra`` fields; ``discard_empty``: a capture that got no byte is
    removed; ``kind`` the summary's layout (serial, emulated, ble); ``note`` the opening note's first words ("":
    none); ``takes_commands``, ``prompt_note``; ``recording_name`` (None: the capture's name); ``own_clock``: the
    chunks' times are the link's own (emulated), so the stop event takes the last one; ``commands``: (s, Command)
    the session sends at those link times."""

    link: str
    baud: int
    extra: dict[str, Any] = field(default_factory=dict)
    discard_empty: bool = True
    kind: str = "serial"
    note: str = ""
    takes_commands: bool = True
    prompt_note: str = PROMPT_HELP
    recording_name: str | None = None
    own_clock: bool = False
    commands: list = field(default_factory=list)


@dataclass
class LinkStatus:
    """How a link is doing, kept up to date by its driver (the session reads it for the health line and the
    summary): connected, ``port`` (the one opened now), connections and losses, bytes received, the monotonic
    times of the last loss and connection, the seconds offline, the bytes of the current connection, bytes dropped
    from the live view, ``reopen_error`` ((path, exception): it is back but cannot be opened), ``t_link_s``
    (the link's own clock: emulated s), ``duration_s`` and ``report`` (emulated), ``wait`` (keep waiting for frames
    instead of stopping), ``symbol_rows`` (emulated: AHRS steps whose attitude the emulator read by symbol),
    ``probing`` (a port reopened after a loss, on probation until it sends valid frames), ``offline`` ((lost, back
    or None) host Unix times of each loss), ``pace`` (a replay's ``?speed=``: its rate is that many times the
    drone's)."""

    connected: bool = False
    port: str | None = None
    connections: int = 0
    disconnects: int = 0
    bytes_total: int = 0
    lost_at_s: float | None = None
    connected_at_s: float | None = None
    offline_s: float = 0.0
    connect_bytes: int = 0
    live_dropped_bytes: int = 0
    reopen_error: Any = None
    t_link_s: float = 0.0
    duration_s: float | None = None
    report: Any = None
    wait: bool = False
    symbol_rows: int = 0
    probing: str | None = None
    offline: list = field(default_factory=list)
    pace: float = 1.0


class Source:
    """One link of a live session; see the module docstring. The session calls :meth:`open` (the input: one
    UserError before any file is made), :meth:`describe` (the capture header; :meth:`close` if the capture cannot
    be made), :meth:`chunks` (bytes flow into the capture from then on, before the viewer starts; each item is the
    list of chunks of one round, [] when none came; the iterator ends when the link ends), :meth:`write` for a
    command (any thread: a driver that swaps its port holds a lock) and :meth:`close` (threads stopped; the
    iterator then yields what is left, once). ``status``: a :class:`LinkStatus`."""

    status: LinkStatus

    def open(self, note: Callable[[str], None]) -> None:
        """The input, or one UserError sentence (``note(text)``: a line while it waits, e.g. for a port)."""
        raise NotImplementedError

    def describe(self) -> LinkInfo:
        raise NotImplementedError

    def chunks(self, record: Record, clock) -> Iterator[list[Chunk]]:
        """The link's chunks, each handed to ``record`` first; ``clock``: the session's ``HostClock`` (its origin
        is the capture's start)."""
        raise NotImplementedError

    def write(self, frame: bytes, at_s: float | None = None) -> None:
        """Send a command frame (``at_s``: at that time of the link's own clock, where it has one)."""
        raise UserError("this link takes no commands")

    def close(self) -> None:
        pass

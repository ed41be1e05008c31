"""The links a live session reads, behind one interface (as cflib's link drivers): :class:`Source`. A URL chooses
the driver (:func:`steval_link.live.session.source_for`, as pyserial's ``serial_for_url``):

====================================  ======================================================================
``/dev/ttyUSB0``, ``COM3``, ``auto``  a serial port, or the one that carries frames (:mod:`.serial_source`)
``replay://FILE.stv[?speed=X]``       a capture played at its recorded pace, as a serial port (same driver)
``emulated:``                         the emulated board running an ELF (:mod:`.emulated`, ``steval emulate``)
``ble:NAME``, ``ble:ADDRESS``, ``ble:``  ST's stock firmware over Bluetooth (:mod:`.ble_source`, ``--ble``)
====================================  ======================================================================

A source moves bytes into the capture first (in its own thread, or in its round), decodes them for the live side
and says how the link is doing; :class:`~steval_link.live.session.LiveSession` owns the rest once: the capture
file, the viewer, the command prompt, the stop requests and signals, the summary. ``session`` below is that
session (its ``capture``, ``viewer``, ``display``, ``clock``, ``console``, ``options``, ``request_stop``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from steval_link.errors import UserError
from steval_link.live.console import PROMPT_HELP

__all__ = ["CaptureFields", "Source"]


@dataclass
class CaptureFields:
    """The capture header's ``port`` (``link``: ``/dev/ttyUSB0``, ``emulated:ref.elf``, ``ble:DRN1110``), baud rate
    (0: none) and the source's ``extra`` fields; ``discard_empty``: a capture that got no byte is removed."""

    link: str
    baud: int
    extra: dict[str, Any] = field(default_factory=dict)
    discard_empty: bool = True


class Source:
    """One link of a live session. The session calls :meth:`open` (the input: one UserError before any file is
    made), :meth:`capture_fields` (then opens the capture; :meth:`close_input` if that fails), :meth:`start` (bytes
    flow into the capture, before the viewer starts), :meth:`attach` (the decoder and estimators, on
    ``session.viewer``), :meth:`round` until it returns False (the link ended) or a stop is requested, with
    :meth:`health` after each; :meth:`finish` (threads stopped, the rest decoded), then it closes the capture and
    the viewer and asks :meth:`summary_fields`. :meth:`write` sends a command from the prompt (any thread: a
    driver that swaps its port holds a lock); :meth:`record` keeps what was sent."""

    kind = "serial"  # the summary's layout: serial, emulated, ble
    takes_commands = True  # False: no prompt
    prompt_note = PROMPT_HELP

    def open(self, session) -> None:
        self.session = session

    def close_input(self) -> None:
        pass

    def describe(self) -> str:
        """The opening note's first words (``reading /dev/ttyUSB0 at 115200 baud``; "": no opening note)."""
        return ""

    def capture_fields(self) -> CaptureFields:
        raise NotImplementedError

    def recording_name(self, session) -> str:
        return session.capture.path.stem

    def start(self, session) -> None:
        pass

    def attach(self, session) -> None:
        pass

    def round(self) -> bool:
        raise NotImplementedError

    def health(self, now_mono_s: float) -> str:
        """The health line after a round ("": none yet)."""
        raise NotImplementedError

    def write(self, frame: bytes) -> None:
        raise UserError("this link takes no commands")

    def record(self, frame: bytes) -> None:
        pass

    def finish(self, error: BaseException | None) -> None:
        pass

    def t_stop_s(self) -> float | None:
        """The stop event's time on the capture's clock (None: the host clock now)."""
        return None

    def error_of(self, error: BaseException) -> BaseException:
        """The error the session raises for ``error`` (a source may say where the bytes until then are)."""
        return error

    def summary_fields(self) -> dict[str, Any]:
        raise NotImplementedError

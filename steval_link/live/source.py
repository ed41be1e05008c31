"""The interface of a live session's link (as cflib's link driver): :class:`Source`. The drivers are chosen by URL in
:mod:`steval_link.live.sources`; :class:`~steval_link.live.session.LiveSession` drives them. ``session`` below is
that session: its ``capture``, ``viewer``, ``display``, ``clock``, ``console``, ``options`` and ``request_stop``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from steval_link.errors import UserError
from steval_link.live.console import PROMPT_HELP

__all__ = ["CaptureFields", "Source"]


@dataclass
class CaptureFields:
    """What a source writes into the capture's header: ``link`` (the header's ``port``, e.g. ``/dev/ttyUSB0``,
    ``emulated:ref.elf``, ``ble:DRN1110``), the baud rate (0: none), the source's own ``extra`` fields, and whether
    a capture that got no byte is removed at the end."""

    link: str
    baud: int
    extra: dict[str, Any] = field(default_factory=dict)
    discard_empty: bool = True


class Source:
    """One link of a live session. The session calls, in this order:

    - :meth:`open`: the input (a port opened, an ELF read, a BLE backend); UserError before any file is made;
    - :meth:`capture_fields`, then the capture is opened; :meth:`close_input` if that fails;
    - :meth:`start`: bytes begin to flow into ``session.capture`` (before the viewer starts: nothing is missed);
    - :meth:`attach`: the live side (decoder, estimators) on ``session.viewer`` (None: no Rerun);
    - :meth:`round` until it returns False (the link ended) or a stop is requested, :meth:`health` after each;
    - :meth:`finish`: threads stopped, what is left decoded; then the session closes the capture and the viewer;
    - :meth:`summary_fields`: the source's part of the :class:`~steval_link.live.summary.LiveSummary`.

    :meth:`write` sends a command frame from the prompt (any thread; a driver that swaps its port holds a lock).
    """

    #: the summary's layout (``serial``, ``emulated``, ``ble``)
    kind = "serial"
    #: whether typed commands reach the link (False: no prompt)
    takes_commands = True
    #: what the prompt says once at the start
    prompt_note = PROMPT_HELP

    def open(self, session: Any) -> None:
        """Open the input (one UserError sentence when it cannot be)."""

    def close_input(self) -> None:
        """Release what :meth:`open` took (the session failed before :meth:`start`)."""

    def describe(self) -> str:
        """The opening note's first words (``reading /dev/ttyUSB0 at 115200 baud``; "": no opening note)."""
        raise NotImplementedError

    def capture_fields(self) -> CaptureFields:
        raise NotImplementedError

    def recording_name(self, session: Any) -> str:
        """The Rerun recording's name."""
        return session.capture.path.stem

    def start(self, session: Any) -> None:
        """Bytes begin to flow into the capture."""

    def attach(self, session: Any) -> None:
        """Build the live side (decoder, estimators) on ``session.viewer``."""

    def round(self) -> bool:
        """One round of the session's loop; False when the link ended (a replay played out, the emulation done)."""
        raise NotImplementedError

    def health(self, now_mono_s: float) -> str:
        """The health line after a round."""
        raise NotImplementedError

    def write(self, frame: bytes) -> None:
        """Send a command frame (OSError or UserError when it cannot go)."""
        raise UserError("this link takes no commands")

    def record(self, frame: bytes) -> None:
        """A command frame sent: into the capture and the live log (the emulated board records its own)."""

    def finish(self, error: BaseException | None) -> None:
        """Stop the source's threads and decode what is left (the capture holds it already)."""

    def t_stop_s(self) -> float | None:
        """The stop event's time on the capture's clock (None: the host clock now)."""
        return None

    def error_of(self, error: BaseException) -> BaseException:
        """The error the session raises for ``error`` (a source may say where the bytes until then are)."""
        return error

    def summary_fields(self) -> dict[str, Any]:
        raise NotImplementedError

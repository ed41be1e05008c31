"""The BLE driver of a live session (``ble:NAME``, ``ble:ADDRESS``, ``ble:``; ``steval live --ble``): a drone over
Bluetooth, found, connected, recorded and reconnected.

The same order as a serial port: the link runs its event loop in its own thread, where every notification goes to
the capture first (a ``B`` chunk with its arrival time), then to a bounded inbox; each round of the session (10 Hz)
hands the inbox to the one :class:`~steval_link.live.pipeline.LivePipeline` (:meth:`~steval_link.live.pipeline.
LivePipeline.feed_ble`: the notifications become frames, the motion samples rows on the sender's grid, then the
estimators and the one live logger). The link (:class:`~steval_link.link.ble_transport.BleLink`) reconnects on
loss; each loss and reconnection is a capture event.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from steval_link.link.ble_payloads import DEVICE_NAME_PREFIX, ble_chunk, layout_named
from steval_link.link.ble_transport import BleBackend, BleDevice, BleLink
from steval_link.link.capture import CHUNK_BLE
from steval_link.live.pipeline import LivePipeline
from steval_link.live.sources import CaptureFields, Source

__all__ = ["BleSource", "INBOX_MAX"]

#: notifications held between two rounds at most (10 s of the three characteristics); older ones are dropped from
#: the live view only (the capture has them all)
INBOX_MAX = 5000
ROUND_S = 0.1


class BleSource(Source):
    """See the module docstring. ``target``: a drone's name or address (None: the strongest ``DRN1…``);
    ``backend``: a ``link.ble_transport.BleBackend`` (bleak, or a fake in tests); ``layout``: what the motion
    notifications hold (``link.ble_payloads.LAYOUTS``: ``stock``, ``euler``), kept in the capture header."""

    kind = "ble"
    takes_commands = False  # ST's stock firmware takes no commands over BLE

    def __init__(
        self,
        target: str | None,
        *,
        backend: BleBackend,
        clock: Callable[[], float] = time.time,
        scan_timeout_s: float = 5.0,
        layout: str = "stock",
    ) -> None:
        self.target = target
        self.backend = backend
        self.clock = clock
        self.scan_timeout_s = scan_timeout_s
        self.layout = layout_named(layout)
        self._inbox: deque[tuple[int | None, bytes, float]] = deque(maxlen=INBOX_MAX)
        self._notes: deque[str] = deque(maxlen=64)  # the link's events, said by the session's thread
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self.link: BleLink | None = None
        self._device: BleDevice | None = None  # the drone found by open()
        self.pipeline: LivePipeline | None = None

    @classmethod
    def from_url(cls, url: str, **settings: Any) -> BleSource:
        """``ble:NAME``, ``ble:ADDRESS``, or ``ble:`` / ``ble:auto`` (the strongest ``DRN1…``)."""
        target = url.split(":", 1)[1].strip() if ":" in url else ""
        return cls(None if target.lower() in ("", "auto") else target, **settings)

    @property
    def what(self) -> str:
        """The drone asked for: its name or address, or any ``DRN1…``."""
        return self.target or f"{DEVICE_NAME_PREFIX}*"

    def capture_fields(self) -> CaptureFields:
        extra = {"link": "ble", "target": self.target, "ble_layout": self.layout.name}
        return CaptureFields(f"ble:{self.what}", 0, extra)

    def recording_name(self, session) -> str:
        return f"steval live --ble {self.what}"

    def open(self, session) -> None:
        """The input first: the drone is found (or the adapter's failure said) before any file or viewer."""
        super().open(session)
        self.link = BleLink(
            self.backend,
            self.target,
            self._on_notification,
            on_event=self._on_event,
            clock=self.clock,
            scan_timeout_s=self.scan_timeout_s,
        )
        self._device = asyncio.run(self.link.find_first())

    def start(self, session) -> None:
        """The link runs its event loop in its own thread: notifications go to the capture there, first."""
        self._start_unix = self.clock() - session.capture.now()
        self._thread = threading.Thread(target=self._run_link, name="steval-ble-link", daemon=True)
        self._thread.start()

    def attach(self, session) -> None:
        self.pipeline = LivePipeline.for_session(session)

    def _run_link(self) -> None:
        async def main() -> None:
            self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
            await self.link.run(self._stop, self._device)

        try:
            asyncio.run(main())
        except BaseException as exc:  # noqa: BLE001 - a UserError of the link (no adapter, drone not found...)
            self._error = exc

    def round(self) -> bool:
        self._thread.join(ROUND_S)
        alive = self._thread.is_alive()
        if not alive and self._error is not None:
            self._say()
            raise self._error
        self._feed(final=not alive)
        return alive

    def _feed(self, final: bool) -> None:
        items = []
        while self._inbox:  # appended by the link's thread meanwhile: taken one by one, none lost
            items.append(self._inbox.popleft())
        self.pipeline.feed_ble(items, final=final)
        self._say()

    def _say(self) -> None:
        """The link's events and the pipeline's notes on the terminal, in the session's thread."""
        session = self.session
        for _ in range(len(self._notes)):
            session.display.note(self._notes.popleft())
        if self.pipeline is None:
            return
        for _ in range(len(self.pipeline.texts)):
            session.display.note("firmware: " + self.pipeline.texts.popleft()[:200])
        for _ in range(len(self.pipeline.notes)):
            session.display.note(self.pipeline.notes.popleft())

    def finish(self, error: BaseException | None) -> None:
        if self._thread is None:
            return
        loop, stop = getattr(self, "_loop", None), getattr(self, "_stop", None)
        if loop is not None and stop is not None and self._thread.is_alive():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:  # the loop closed meanwhile
                pass
        self._thread.join()
        if error is None and self._error is None and self.pipeline is not None:
            self._feed(final=True)
            self.pipeline.flush_view()
        else:
            self._say()

    def health(self, now_mono_s: float) -> str:
        pipe = self.pipeline
        c = pipe.ble.counts if pipe is not None and pipe.ble is not None else {}
        if not any(c.values()):
            return ""  # nothing received yet: no line
        cad = pipe.grid.cadence()
        what = cad.describe() if cad is not None else "finding the motion cadence"
        return (
            f"BLE {c.get('motion', 0)} motion / {c.get('environment', 0)} env / {c.get('arming', 0)} arming "
            f"notifications; {what}"
        )

    def summary_fields(self) -> dict[str, Any]:
        link, pipe = self.link, self.pipeline
        ble = pipe.ble if pipe is not None else None
        return {
            "counts": dict(ble.counts) if ble is not None else {},
            "rows_held": pipe.grid.rows_held if ble is not None else 0,
            "connections": link.connections if link is not None else 0,
            "disconnects": link.losses if link is not None else 0,
            "cadence": pipe.grid.cadence() if ble is not None else None,
        }

    # -- the link's callbacks (the event loop's thread)
    def _on_notification(self, cid: int, data: bytes, t_unix: float) -> None:
        t = t_unix - self._start_unix
        self.session.capture.write_chunk(CHUNK_BLE, ble_chunk(cid, data), t)
        self._inbox.append((cid, data, t))

    def _on_event(self, kind: str, text: str) -> None:
        self.session.capture.mark_event(kind, text)
        if kind == "connect":
            self._notes.append(f"connected to {text} over BLE")
        elif kind == "disconnect":
            self._notes.append("BLE link lost; reconnecting (Ctrl-C stops)")
        elif kind == "reconnect":
            self._inbox.append((None, b"", 0.0))  # the next motion sample follows a lost link
            self._notes.append(f"reconnected to {text}")
        else:
            self._notes.append(f"{kind}: {text}")

"""The BLE driver of a live session (``ble:NAME``, ``ble:ADDRESS``, ``ble:``; ``steval live --ble``). The link
(``BleLink``) runs its event loop in its own thread, where every notification goes to the capture first (a ``B``
chunk), then to a bounded inbox each round (10 Hz) takes; each loss and reconnection is a capture event."""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections import deque
from collections.abc import Iterator
from typing import Any

from steval_link.link.ble_payloads import DEVICE_NAME_PREFIX, layout_named
from steval_link.link.ble_transport import BleBackend, BleLink
from steval_link.live.sources import BREAK, END, NOTE, Chunk, LinkInfo, LinkStatus, Record, Source

__all__ = ["BleSource", "INBOX_MAX"]

INBOX_MAX = 5000  # notifications held between two rounds at most (older ones leave the live view only)
ROUND_S = 0.1


class BleSource(Source):
    """``target``: name or address (None: the strongest ``DRN1…``); ``layout``: what motion notifications hold."""

    def __init__(self, target: str | None, *, backend: BleBackend, layout: str = "stock") -> None:
        self.target = target
        self.what = target or f"{DEVICE_NAME_PREFIX}*"  # the drone asked for: its name or address, or any DRN1…
        self.backend = backend
        self.layout = layout_named(layout)
        self._inbox: deque[Chunk] = deque(maxlen=INBOX_MAX)
        self._closed = False
        self.link: BleLink | None = None
        self._thread = self._error = self._device = None  # the link's thread, its error, the drone found by open()
        self._loop = self._stop = None  # the link's event loop and its stop event, once its thread runs

    @classmethod
    def from_url(cls, url: str, **settings: Any) -> BleSource:
        """``ble:NAME``, ``ble:ADDRESS``, or ``ble:`` / ``ble:auto`` (the strongest ``DRN1…``)."""
        target = url.split(":", 1)[1].strip() if ":" in url else ""
        return cls(None if target.lower() in ("", "auto") else target, **settings)

    @property
    def status(self) -> LinkStatus:
        made, lost = (self.link.connections, self.link.losses) if self.link is not None else (0, 0)
        return LinkStatus(connected=made > lost, port=self.what, connections=made, disconnects=lost)

    def open(self, note=None) -> None:
        """The input first: the drone is found (or the adapter's failure said) before any file or viewer."""
        self.link = BleLink(self.backend, self.target, self._on_notification, on_event=self._on_event)
        self._device = asyncio.run(self.link.find_first())

    def describe(self) -> LinkInfo:
        return LinkInfo(
            f"ble:{self.what}",
            0,
            {"link": "ble", "target": self.target, "ble_layout": self.layout.name},
            kind="ble",
            takes_commands=False,  # ST's stock firmware takes no commands over BLE
            recording_name=f"steval live ble:{self.what}",
        )

    def chunks(self, record: Record, clock) -> Iterator[list[Chunk]]:
        self._record = record
        self._start_unix = time.time() - (clock.now_s() - clock.wall0_s)
        self._thread = threading.Thread(target=self._run_link, name="steval-ble-link", daemon=True)
        self._thread.start()
        return self._rounds()

    def _run_link(self) -> None:
        async def main() -> None:
            self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
            await self.link.run(self._stop, self._device)

        try:
            asyncio.run(main())
        except BaseException as exc:  # noqa: BLE001 - a UserError of the link (no adapter, drone not found...)
            self._error = exc

    def _rounds(self) -> Iterator[list[Chunk]]:
        alive = True
        while alive:
            self._thread.join(ROUND_S)
            alive = self._thread.is_alive()
            if not alive and self._error is not None and not self._closed:
                raise self._error
            out = [self._inbox.popleft() for _ in range(len(self._inbox))]  # the link's thread may append meanwhile
            yield out if alive else [*out, Chunk(END, "end", None)]

    def close(self) -> None:
        self._closed = True
        if self._thread is None:
            return
        if self._stop is not None and self._thread.is_alive():
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join()

    def _on_notification(self, cid: int, data: bytes, t_unix: float) -> None:
        chunk = Chunk("B", (cid, data), t_unix - self._start_unix)
        self._record(chunk)
        self._inbox.append(chunk)

    def _on_event(self, kind: str, text: str) -> None:
        self._record(Chunk("E", (kind, text), time.time() - self._start_unix))  # on the notifications' clock
        say = {
            "connect": f"connected to {text} over BLE",
            "disconnect": "BLE link lost; reconnecting (Ctrl-C stops)",
            "reconnect": f"reconnected to {text}",
        }.get(kind, f"{kind}: {text}")
        if kind == "reconnect":
            self._inbox.append(Chunk(BREAK, None, None))  # the next motion sample follows a lost link
        self._inbox.append(Chunk(NOTE, say, None))

"""BLE without a radio: :class:`FakeBleBackend` (a ``BleBackend`` that plays notifications: scan results, a
connection that can be made to fail or to drop after N notifications, notifications in order), a live session run
until it has played them all, a logger that keeps what it is given, and notifications loaded as the one model."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Sequence

from steval_link.link.ble_payloads import CHAR_UUIDS, char_id_of_uuid
from steval_link.link.ble_transport import BleDevice, BleError


def run_until_played(session, fake):
    """``session.run()`` of a ``LiveSession`` over a BLE source and ``fake`` (a ``FakeBleBackend``), stopped
    ("test") once the fake has sent its last notification; returns the session's summary."""

    def stopper():
        while fake.finished is None or not fake.finished.is_set():
            time.sleep(0.01)
        session.request_stop("test")

    threading.Thread(target=stopper, daemon=True).start()
    return session.run()


class RecordingViewer:
    """A live session's logger (the ``LiveViewer`` protocol, whatever the link) that keeps what it is given: the
    row batches (``LiveRows``), the BLE environment and arming frames with their times, the notes, and whether it
    was closed."""

    has_viewer = True

    def __init__(self) -> None:
        self.batches, self.env, self.arming, self.notes, self.texts = [], [], [], [], []
        self.closed = False

    def log_batch(self, batch) -> None:
        self.batches.append(batch)

    def log_environment(self, frame, at) -> None:
        self.env.append((frame, at))

    def log_arming(self, frame, at) -> None:
        self.arming.append((frame, at))

    def log_note(self, text, at) -> None:
        self.notes.append(text)

    def log_text(self, frame, at) -> None:
        self.texts.append(frame)

    def log_status(self, frame, at) -> None:
        pass

    def log_event(self, text, at, level="INFO") -> None:
        pass

    def log_link(self, stats, t_unix_s) -> None:
        pass

    def close(self) -> None:
        self.closed = True


def telemetry_of_records(records, events=()):
    """The one model (``Telemetry``, its ``link`` the BLE facts) of notifications ``(t_host_s, char id, payload)``,
    as a capture holding them loads (``events``: the capture's, e.g. ``reconnect``)."""
    from pathlib import Path

    import numpy as np

    from steval_link.link.ble_payloads import ble_chunk
    from steval_link.link.capture import CHUNK_BLE
    from steval_link.link.load import Recording, telemetry_of_recording

    none = np.zeros(0, np.int64)
    chunks = {CHUNK_BLE: [(t, ble_chunk(c, p)) for t, c, p in records]}
    src = Recording(Path("notifications.stv"), {"extra": {"link": "ble"}}, b"", none, none.astype(float), list(events))
    src.chunks = chunks
    return telemetry_of_recording(src)


def held_rows(tel):
    """(N,) bool over the rows: True for a row that holds the last sample over a notification sent and lost."""
    import numpy as np

    held = np.ones(len(tel.attitude), bool)
    held[tel.link.samples["row"]] = False
    return held


class FakeBleBackend:
    """A :class:`~steval_link.link.ble_transport.BleBackend` without a radio (see this module's docstring).

    ``notifications``: ``(char id, payload)`` in the order the drone sends them. ``devices``: what a scan finds.
    ``fail_connects``: the first N connection attempts fail. ``drop_after``: the link is lost after each of these
    counts of notifications (one per connection, in order). Each notification is delivered after ``pace_s``.
    """

    def __init__(
        self,
        notifications: Sequence[tuple[int, bytes]],
        *,
        devices: Sequence[BleDevice] = (BleDevice("DRN1110", "C0:11:22:33:44:55", -60.0),),
        fail_connects: int = 0,
        drop_after: Sequence[int] = (),
        pace_s: float = 0.0,
        scan_error: Exception | None = None,
    ) -> None:
        self._items = list(notifications)
        self.devices = list(devices)
        self.fail_connects = int(fail_connects)
        self.drop_after = list(drop_after)
        self.pace_s = float(pace_s)
        self.scan_error = scan_error
        self.scans = 0
        self.connects = 0
        self.connected_to: str | None = None
        self.subscribed: dict[str, Callable[[bytes], None]] = {}
        self._on_disconnect: Callable[[], None] | None = None
        self._pos = 0
        self._task: asyncio.Task | None = None
        self.finished: asyncio.Event | None = None  #: set when every notification was played (made in connect)

    async def scan(self, timeout_s: float) -> list[BleDevice]:
        self.scans += 1
        if self.scan_error is not None:
            raise self.scan_error
        await asyncio.sleep(0)
        return list(self.devices)

    async def connect(self, address: str, on_disconnect: Callable[[], None]) -> None:
        self.connects += 1
        if self.finished is None:
            self.finished = asyncio.Event()
        if self.connects <= self.fail_connects:
            raise BleError(f"connection to {address} failed (fake: attempt {self.connects})")
        if not any(d.address.lower() == address.lower() for d in self.devices):
            raise BleError(f"device {address} not found")
        self.connected_to = address
        self._on_disconnect = on_disconnect
        self.subscribed = {}

    async def start_notify(self, uuid: str, callback: Callable[[bytes], None]) -> None:
        if self.connected_to is None:
            raise BleError("not connected")
        if char_id_of_uuid(uuid) is None:
            raise BleError(f"characteristic {uuid} not found")
        self.subscribed[uuid.lower()] = callback
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(self._play())

    async def _play(self) -> None:
        await asyncio.sleep(0)
        limit = self.drop_after.pop(0) if self.drop_after else None
        sent = 0
        while self._pos < len(self._items) and self.connected_to is not None:
            if limit is not None and sent >= limit:
                self._lose()
                return
            cid, payload = self._items[self._pos]
            self._pos += 1
            cb = self.subscribed.get(CHAR_UUIDS.get(cid, ""))
            if cb is not None:
                cb(bytes(payload))
                sent += 1
            await asyncio.sleep(self.pace_s)
        if self._pos >= len(self._items):
            self.finished.set()

    def _lose(self) -> None:
        self.connected_to = None
        cb, self._on_disconnect = self._on_disconnect, None
        if cb is not None:
            cb()

    async def disconnect(self) -> None:
        self.connected_to = None
        self._on_disconnect = None
        if self._task is not None and not self._task.done():
            self._task.cancel()

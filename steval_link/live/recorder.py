"""The reader-thread side of a live session: every chunk goes to the capture first (:class:`RecorderProtocol`), then
into a bounded :class:`Inbox` for the main thread (oldest chunks dropped from the live view only, counted).
"""

from __future__ import annotations

import collections
import threading
import time

from steval_link.errors import UserError
from steval_link.link import autodetect
from steval_link.link.capture import CaptureWriter
from steval_link.link.transport import HostClock, Protocol

#: Most bytes waiting between the reader thread and the decoder before the oldest are dropped from the live view.
INBOX_MAX_BYTES = 4 * 1024 * 1024


class Inbox:
    """Chunks handed from the reader thread to the main thread; bounded by bytes (oldest dropped, counted)."""

    def __init__(self, max_bytes: int = INBOX_MAX_BYTES) -> None:
        self.max_bytes = max_bytes
        self._chunks: collections.deque[tuple[bytes, float]] = collections.deque()
        self._bytes = 0
        self._cond = threading.Condition()
        #: bytes dropped from the live view because the main thread fell behind (still in the capture)
        self.dropped_bytes = 0

    def put(self, data: bytes, t_unix_s: float) -> None:
        with self._cond:
            self._chunks.append((data, t_unix_s))
            self._bytes += len(data)
            while self._bytes > self.max_bytes and len(self._chunks) > 1:
                old, _ = self._chunks.popleft()
                self._bytes -= len(old)
                self.dropped_bytes += len(old)
            self._cond.notify()

    def get_all(self, timeout_s: float) -> list[tuple[bytes, float]]:
        """Every waiting chunk (waits up to ``timeout_s`` for the first one)."""
        with self._cond:
            if not self._chunks:
                self._cond.wait(timeout_s)
            out = list(self._chunks)
            self._chunks.clear()
            self._bytes = 0
            return out


class RecorderProtocol(Protocol):
    """Reader-thread side: every chunk goes to the capture first, then to the inbox for the main thread.

    The capture writer hands each chunk to the OS at once (a ``kill -9`` loses nothing written) and syncs it to
    disk in its own thread. Connection events are written into the capture (``disconnect`` / ``reconnect`` mark
    the gap) and kept as plain attributes and messages that the main thread reads.
    """

    def __init__(self, capture, inbox: Inbox, finder: autodetect.PortFinder | None, clock: HostClock) -> None:
        self.capture, self.inbox, self.finder, self.clock = capture, inbox, finder, clock
        self.connected = False
        self.port: str | None = None
        self.connections = self.disconnects = 0
        self.lost_at_s: float | None = None  # monotonic time of the last disconnect
        self.offline_s = 0.0
        self.events: collections.deque[str] = collections.deque(maxlen=64)  # messages for the display
        self.bytes_total = 0
        self.connect_bytes = 0  # bytes since the current connection was made
        self.connected_at_s: float | None = None  # monotonic

    def _t_capture(self, t_unix_s: float | None = None) -> float:
        """Capture time base: s since the capture started (the clock's origin is the capture's start)."""
        return (self.clock.now_s() if t_unix_s is None else t_unix_s) - self.clock.wall0_s

    def connection_made(self, port: str) -> None:
        now = time.monotonic()
        self.connections += 1
        if self.connections > 1:
            gap = now - (self.lost_at_s or now)
            self.offline_s += gap
            self.capture.mark_event("reconnect", f"{port} back after {gap:.2f} s", self._t_capture())
            self.events.append(f"reconnected on {port} after {gap:.1f} s")
        self.port = port
        self.connect_bytes = 0
        self.connected_at_s = now
        self.connected = True

    def data_received(self, data: bytes, t_unix_s: float) -> None:
        self.capture.write(data, self._t_capture(t_unix_s))  # first: whatever happens next, the bytes are kept
        self.bytes_total += len(data)
        self.connect_bytes += len(data)
        self.inbox.put(data, t_unix_s)

    def connection_lost(self, exc: BaseException | None) -> None:
        self.connected = False
        if exc is None:  # closed by stop()
            return
        self.disconnects += 1
        self.lost_at_s = time.monotonic()
        if self.finder is not None:
            self.finder.mark_lost()
        self.capture.mark_event("disconnect", f"{self.port}: {exc}", self._t_capture())
        self.events.append(f"disconnected from {self.port}, waiting for it to come back")


def open_capture(path, *, port: str, baud: int, extra: dict, discard_empty: bool = False) -> CaptureWriter:
    """A new capture at ``path`` (never overwritten): one UserError sentence when it exists or cannot be written."""
    try:
        return CaptureWriter(path, discard_empty=discard_empty, port=port, baud=baud, extra=extra)
    except FileExistsError:
        raise UserError(f"{path} already exists; choose another --out (captures are never overwritten)") from None
    except OSError as exc:
        raise UserError(f"cannot write the capture {path}: {exc.strerror or exc}") from None

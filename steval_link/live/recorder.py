"""The reader-thread side of a live session: every chunk goes to the capture first (:class:`RecorderProtocol`), then
into a bounded :class:`Inbox` for the main thread (oldest chunks dropped from the live view only, counted).
"""

from __future__ import annotations

import collections
import math
import os
import threading
import time

from steval_link.errors import ParamError, UserError
from steval_link.link import autodetect, ports
from steval_link.link.capture import CaptureWriter
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AttitudeFrame, StatusFrame
from steval_link.link.transport import HostClock, PortRejected, Protocol
from steval_link.live.health import _fmt_bytes
from steval_link.live.sources import LinkStatus

#: Most bytes waiting between the reader thread and the decoder before the oldest are dropped from the live view.
INBOX_MAX_BYTES = 4 * 1024 * 1024
#: A port reopened after a loss that sends no valid frame for this long is not the drone, s ...
PROBATION_S = 3.0
#: ... and it is the drone once it sent this many valid attitude or status frames.
PROBATION_FRAMES = 2
#: Other programs holding the port are looked for at a (re)connection, when a read finds its bytes taken, and
#: while the port is silent for SILENT_S; at most every HOLDERS_CHECK_S, s.
HOLDERS_CHECK_S = 5.0
SILENT_S = 1.0


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
    """Reader-thread side: every chunk to the capture first (handed to the OS at once), then to the inbox.

    Connection events go into the capture (``disconnect`` / ``reconnect`` mark the gap) and :attr:`status`.
    A port reopened after a loss is on probation until it sends valid frames; one that sends none for
    :data:`PROBATION_S` is rejected (:class:`~steval_link.link.transport.PortRejected`) and the search goes on.
    Another program that reads the port is named once and the port is kept.
    """

    def __init__(self, capture, inbox: Inbox, finder: autodetect.PortFinder | None, clock: HostClock) -> None:
        self.capture, self.inbox, self.finder, self.clock = capture, inbox, finder, clock
        #: the link as the session sees it (``offline``: host Unix times; ``lost_at_s``, ``connected_at_s``: monotonic)
        self.status = LinkStatus()
        self.events: collections.deque[str] = collections.deque(maxlen=64)  # messages for the display
        self._probe: StreamDecoder | None = None
        self._probe_frames = 0
        self._holders_said: set[int] = set()
        self._holders: list[tuple[int, str]] = []
        self._last_data_s = -math.inf  # monotonic time of the last chunk
        self._holders_checked_s = -math.inf

    def _t_capture(self, t_unix_s: float | None = None) -> float:
        """Capture time base: s since the capture started (the clock's origin is the capture's start)."""
        return (self.clock.now_s() if t_unix_s is None else t_unix_s) - self.clock.wall0_s

    def connection_made(self, port: str) -> None:
        st, now = self.status, time.monotonic()
        st.connections += 1
        st.port, st.connect_bytes, st.connected_at_s = port, 0, now
        if st.connections > 1:  # back after a loss: the drone only once it sends valid frames
            st.probing, self._probe, self._probe_frames = port, StreamDecoder(), 0
            self._probe_at = self._t_capture()  # its bytes flow from now on (the capture marks where)
            self.capture.mark_event(
                "reconnect", f"{port} opened again after {now - (st.lost_at_s or now):.2f} s", self._probe_at
            )
            return
        st.connected = True
        self._say_holders(port)

    def _confirm(self) -> None:
        """The port reopened sent valid frames: the drone is back."""
        st = self.status
        back = st.connected_at_s or time.monotonic()  # its bytes flowed from the reopening on
        gap = max(0.0, back - (st.lost_at_s or back))
        st.offline_s += gap
        if st.offline and st.offline[-1][1] is None:
            st.offline[-1] = (st.offline[-1][0], self._probe_at + self.clock.wall0_s)
        port, st.probing, self._probe = st.probing, None, None
        self.events.append(f"reconnected on {port} after {gap:.1f} s")
        st.connected = True
        self._say_holders(port)

    def data_received(self, data: bytes, t_unix_s: float) -> None:
        self.capture.write(data, self._t_capture(t_unix_s))  # first: whatever happens next, the bytes are kept
        self.status.bytes_total += len(data)
        self.status.connect_bytes += len(data)
        self.inbox.put(data, t_unix_s)
        self._last_data_s = time.monotonic()
        if self._probe is not None:
            self._probe_frames += sum(1 for f in self._probe.feed(data) if isinstance(f, (AttitudeFrame, StatusFrame)))
            if self._probe_frames >= PROBATION_FRAMES:
                self._confirm()

    def idle(self, t_unix_s: float) -> None:
        now = time.monotonic()
        if self.status.probing is not None and now - (self.status.connected_at_s or 0.0) >= PROBATION_S:
            raise PortRejected(f"{self.status.probing} sent no valid frames in {PROBATION_S:.0f} s")
        if self.status.connected and now - max(self._last_data_s, self.status.connected_at_s or now) >= SILENT_S:
            self._say_holders(self.status.port)  # silent: another reader may take every byte (at most every few s)

    def shared_access(self, exc: BaseException) -> bool:
        if self.status.port is None or not os.path.exists(self.status.port):
            return False  # the node is gone: an unplug
        return bool(self._say_holders(self.status.port, force=True))

    def _say_holders(self, port: str, *, force: bool = False) -> list[tuple[int, str]]:
        """Name the other programs that have ``port`` open, once each (looked up at most every few seconds)."""
        now = time.monotonic()
        if not force and now - self._holders_checked_s < HOLDERS_CHECK_S:
            return []
        if force and now - self._holders_checked_s < 1.0:
            return self._holders
        self._holders_checked_s = now
        self._holders = ports.port_holders(port)
        new = [h for h in self._holders if h[0] not in self._holders_said]
        if new:
            self._holders_said.update(pid for pid, _ in new)
            sentence = ports.holders_sentence(port, new)
            self.capture.mark_event("shared", sentence, self._t_capture())
            self.events.append(sentence)
        return self._holders

    def connection_lost(self, exc: BaseException | None) -> None:
        was_probing, self.status.connected = self.status.probing, False
        self.status.probing, self._probe = None, None
        if exc is None:  # closed by stop()
            return
        if isinstance(exc, PortRejected):  # not the drone: keep looking (still the same disconnect)
            if self.finder is not None:
                self.finder.reject(was_probing)
            self.capture.mark_event("rejected", str(exc), self._t_capture())
            self.events.append(f"{was_probing} answers but sends no valid frames: not the drone; still looking")
            return
        if was_probing is not None:  # lost again before it sent a frame: the same disconnect goes on
            return
        st = self.status
        st.disconnects += 1
        st.lost_at_s = time.monotonic()
        st.offline.append((self.clock.now_s(), None))
        if self.finder is not None:
            self.finder.mark_lost()
        self.capture.mark_event("disconnect", f"{self.status.port}: {exc}", self._t_capture())
        self.events.append(f"disconnected from {self.status.port}, waiting for it to come back")


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


def offline_within(offline: list, t0_s: float, t1_s: float, now_s: float) -> float:
    """Seconds without the drone between host times ``t0_s`` and ``t1_s`` (``offline``: (lost, back or None) host
    times, as :class:`RecorderProtocol` keeps them; a loss not over yet lasts to ``now_s``)."""
    total = 0.0
    for lost, back in offline:
        total += max(0.0, min(t1_s, now_s if back is None else back) - max(t0_s, lost))
    return total


def capture_failure_sentence(capture: CaptureWriter, failure: OSError) -> str:
    """The one sentence for a capture that can take no more (disk full, deleted, replaced), naming what it holds."""
    amount = _fmt_bytes(capture.bytes_written)
    if "cannot be written" in str(failure) and capture.path.exists():
        return f"{failure}; stopped: the {amount} received until then are in {capture.path}"
    return f"the capture {failure}; stopped: the {amount} received until then went with it"

"""The live session behind ``steval live`` and ``steval record``: serial port → capture → decoder → estimators → viewer.

Flow (one way)::

    SerialReader thread ──► RecorderProtocol: capture.write(chunk)  [always first, in the reader thread]
                                   │ (bounded inbox of chunks)
                                   ▼
    main thread: StreamDecoder.feed ──► frames ──► LiveEstimators (ST port seeded from status snapshots,
                                                   accel, EKF...) ──► viewer logger (optional)
                                   └─► LinkHealth ──► HealthDisplay (stderr) and the summary line

The capture is written before anything is decoded (each chunk goes to the OS at once, so even ``kill -9`` loses
nothing already received; the writer syncs to disk at least once a second), and a slow viewer never costs bytes: when the main thread falls behind,
the inbox drops the oldest chunks from the *live* display only (counted), never from the capture.

Faults the session survives: unplug/replug (the reader reopens the port, by path or USB identity, and the capture
marks the gap), garbage and truncated frames (counted by the decoder), non-finite values (counted, never fed to an
estimator, never plotted), a wrong baud rate or another device (one line and :class:`LinkError`, see
:func:`steval_link.autodetect.no_frames_message`).
"""

from __future__ import annotations

import collections
import math
import os
import shutil
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TextIO

import numpy as np
import serial

from steval_link import autodetect, protocol
from steval_link.capture import CaptureWriter, default_capture_path
from steval_link.errors import UserError
from steval_link.transport import HostClock, Protocol, SerialReader, open_error_message, open_serial
from steval_viewer.sink_options import DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT, SinkOptions, check_sinks, resolve_sinks

#: Most bytes waiting between the reader thread and the decoder before the oldest are dropped from the live view.
INBOX_MAX_BYTES = 4 * 1024 * 1024
#: Bytes kept from the start of a connection to describe a stream without frames.
SAMPLE_BYTES = 4096
#: Wrong baud / not a STEVAL: give up after this long with bytes but no valid frame, s (sooner with many bytes) ...
NO_FRAMES_TIMEOUT_S = 2.5
#: ... or after this long once at least NO_FRAMES_EARLY_BYTES arrived without a valid frame.
NO_FRAMES_EARLY_S = 1.0
NO_FRAMES_EARLY_BYTES = 2048
#: Frames go to a live viewer as soon as they are decoded (every processing round: latency goal p99 <= 5 ms,
#: ``benchmarks/bench_live_latency.py``; a viewer over gRPC costs this process no memory per chunk) ...
VIEW_INTERVAL_S = 0.0
#: ... and to an ``.rrd`` at most this often, or once this much stream time waits (with a live viewer too, the file
#: has its own stream of the same recording, fed these merged batches). Rerun's file sink keeps about 1 kB per
#: chunk for the file's footer (its manifest) until the file closes, and each batch is about one chunk per entity
#: (~25): 30 s keeps an hour's growth near 3 MB (``benchmarks/bench_soak.py``).
RRD_ONLY_INTERVAL_S = 30.0
#: Health line refresh on a terminal / plain health lines otherwise, s.
HEALTH_TTY_INTERVAL_S = 0.25
HEALTH_PLAIN_INTERVAL_S = 5.0
#: Default estimators run next to the firmware (those not installed are skipped when not asked for explicitly).
DEFAULT_ESTIMATORS = ("st-mahony", "accel", "ekf3")


class LinkError(UserError):
    """The port carries no valid frames (wrong baud rate, another device, silence): one line, exit code 2."""


# ----------------------------------------------------------------------------------------------------------------
# reader thread side: capture first, then the inbox


class Inbox:
    """Chunks handed from the reader thread to the main thread; bounded by bytes (oldest dropped, counted)."""

    def __init__(self, max_bytes: int = INBOX_MAX_BYTES) -> None:
        self.max_bytes = max_bytes
        self._chunks: collections.deque[tuple[bytes, float]] = collections.deque()
        self._bytes = 0
        self._cond = threading.Condition()
        #: bytes dropped from the live view because the main thread fell behind (still in the capture)
        self.dropped_bytes = 0

    def put(self, data: bytes, t_host_s: float) -> None:
        with self._cond:
            self._chunks.append((data, t_host_s))
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
        self.capture = capture
        self.inbox = inbox
        self.finder = finder
        self.clock = clock
        self.connected = False
        self.port: str | None = None
        self.connections = 0
        self.disconnects = 0
        self.lost_at_s: float | None = None  # monotonic time of the last disconnect
        self.offline_s = 0.0
        self.last_error: str | None = None
        self.events: collections.deque[str] = collections.deque(maxlen=64)  # messages for the display
        self.bytes_total = 0
        self.connect_bytes = 0  # bytes since the current connection was made
        self.connected_at_s: float | None = None  # monotonic

    def _t_capture(self, t_host_s: float | None = None) -> float:
        """Capture time base: s since the capture started (the clock's origin is the capture's start)."""
        return (self.clock.now_s() if t_host_s is None else t_host_s) - self.clock.wall0_s

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

    def data_received(self, data: bytes, t_host_s: float) -> None:
        self.capture.write(data, self._t_capture(t_host_s))  # first: whatever happens next, the bytes are kept
        self.bytes_total += len(data)
        self.connect_bytes += len(data)
        self.inbox.put(data, t_host_s)

    def connection_lost(self, exc: BaseException | None) -> None:
        self.connected = False
        if exc is None:  # closed by stop()
            return
        self.disconnects += 1
        self.lost_at_s = time.monotonic()
        self.last_error = str(exc)
        if self.finder is not None:
            self.finder.mark_lost()
        self.capture.mark_event("disconnect", f"{self.port}: {exc}", self._t_capture())
        self.events.append(f"disconnected from {self.port}, waiting for it to come back")


# ----------------------------------------------------------------------------------------------------------------
# estimators


@dataclass
class AttitudeBatch:
    """The attitude frames of one processing round as arrays, with every estimate (units in the names).

    ``estimates`` maps a source name (``st-mahony``, ``accel``, ``ekf3``...) to (N, 4) q_wxyz, NaN where the
    estimate is undefined (port not seeded yet, non-finite input): such rows must not be plotted.
    """

    step: np.ndarray  # (N,) int64
    t_us: np.ndarray  # (N,) int64 (firmware µs, as sent)
    t_host_s: np.ndarray  # (N,) float64, Unix epoch
    acc_mg: np.ndarray  # (N, 3) float32
    gyro_mdps: np.ndarray  # (N, 3) float32
    q_wxyz: np.ndarray  # (N, 4) float32, firmware
    thz_rad: np.ndarray  # (N,) float32
    thr: np.ndarray  # (N,) int16
    finite: np.ndarray  # (N,) bool, every value of the frame is finite
    exact: np.ndarray  # (N,) bool, binary frame (bit-exact); False: rounded text-mode row without q
    thx_rad: np.ndarray  # (N,) float32, text-mode pitch (about x); NaN for binary frames (derive from q)
    thy_rad: np.ndarray  # (N,) float32, text-mode roll (about y); NaN for binary frames
    estimates: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.step.shape[0])

    @classmethod
    def concat(cls, batches: list["AttitudeBatch"]) -> "AttitudeBatch":
        """One batch of the frames of ``batches``, in order (estimate names must agree)."""
        if len(batches) == 1:
            return batches[0]
        arrays = {
            name: np.concatenate([getattr(b, name) for b in batches])
            for name in cls.__dataclass_fields__
            if name != "estimates"
        }
        estimates = {name: np.concatenate([b.estimates[name] for b in batches]) for name in batches[0].estimates}
        return cls(**arrays, estimates=estimates)


class LivePort:
    """The bit-exact ST Mahony port run live, (re)seeded from the firmware's status snapshots.

    Semantics as :func:`steval_link.estimators.st_mahony.replay_firmware`: the port starts from the power-up state
    when the stream starts at step 0; otherwise (joined mid-flight, frames lost, non-finite input) it is unseeded
    (NaN) until the next status snapshot, and bit-exact from the step after it.
    """

    def __init__(self) -> None:
        from steval_link.estimators import st_mahony

        self._sm = st_mahony
        self.state = None  # MahonyState, or None when unseeded
        self.settings = st_mahony.MahonySettings()
        self.next_step: int | None = None
        self.seeds = 0
        self.snapshots_confirmed = 0  # status snapshots that matched the port's own state bit for bit
        self.rows_exact = 0
        self.rows_mismatch = 0
        self.rows_unseeded = 0
        self.last_rows_mismatch = 0  # mismatching rows of the latest call

    @property
    def seeded(self) -> bool:
        return self.state is not None

    def attitude(self, step: np.ndarray, acc_mg, gyro_mdps, thr, fw_q_wxyz, finite: np.ndarray) -> np.ndarray:
        """Step the port over these frames (in order); returns (N, 4) float32 q, NaN where unseeded."""
        n = step.shape[0]
        out = np.full((n, 4), np.nan, dtype=np.float32)
        mismatch_before = self.rows_mismatch
        a = 0
        while a < n:
            # a run of consecutive steps with finite inputs
            if not finite[a]:
                self.state = None
                self.next_step = None
                a += 1
                continue
            b = a + 1
            while b < n and finite[b] and step[b] == step[b - 1] + 1:
                b += 1
            s0 = int(step[a])
            if self.state is not None and self.next_step != s0:
                self.state = None  # frames lost: out of sync until the next snapshot
            if self.state is None and s0 == 0:
                self.state = self._sm.MahonyState()  # the stream starts at power-up
                self.seeds += 1
            if self.state is not None:
                q, _, _, self.state = self._sm.run(
                    acc_mg[a:b], gyro_mdps[a:b], thr[a:b], settings=self.settings, state=self.state, euler=False
                )
                out[a:b] = q
                exact = self._sm.bits_equal(q, fw_q_wxyz[a:b]).all(axis=1)
                k = int(np.count_nonzero(exact))
                self.rows_exact += k
                self.rows_mismatch += (b - a) - k
                self.next_step = int(step[b - 1]) + 1
            else:
                self.rows_unseeded += b - a
                self.next_step = int(step[b - 1]) + 1
            a = b
        self.last_rows_mismatch = self.rows_mismatch - mismatch_before
        return out

    def status(self, frame) -> None:
        """A status frame: seed the port from its snapshot when unseeded or out of sync (else confirm it)."""
        st = self._sm
        snap = st.MahonyState(q_wxyz=_field(frame, "q_wxyz"), int_xyz=_field(frame, "int_xyz"))
        settings = st.MahonySettings.from_status(
            kp_ground=_field(frame, "kp_ground"),
            kp_flight=_field(frame, "kp_flight"),
            ki=_field(frame, "ki"),
            dt_s=_field(frame, "dt_s"),
            min_thr=_field(frame, "min_thr"),
            flags=_field(frame, "flags"),
        )
        step = int(_field(frame, "step"))
        if (
            self.state is not None
            and self.next_step == step + 1
            and settings == self.settings
            and self.state.bits_equal(snap)
        ):
            self.snapshots_confirmed += 1
            return
        if not np.all(np.isfinite(snap.as_array())):
            self.state = None  # the firmware's own filter holds NaN: nothing to follow
            return
        self.state = snap
        self.settings = settings
        self.next_step = step + 1
        self.seeds += 1

    def describe(self) -> str:
        """The port's state in a few words for the health line."""
        if self.state is None:
            return "port resyncing" if self.seeds else "port waiting for a status snapshot"
        if self.last_rows_mismatch:
            return f"port DIFFERS from firmware ({self.rows_mismatch} frames)"
        return "port bit-exact" if self.rows_exact else "port seeded"


def _field(frame, name: str):
    value = getattr(frame, name)
    return value


class LiveEstimators:
    """Every host estimator run on each attitude frame: the seeded ST port plus any registry estimator.

    Rows with a non-finite input are never fed to an estimator (one NaN would poison a filter's state for good);
    their estimates are NaN.
    """

    def __init__(self, names: list[str]) -> None:
        from steval_link.estimators import registry

        self.port = LivePort() if "st-mahony" in names else None
        self.others = {name: registry.create(name) for name in names if name != "st-mahony"}
        self.names = list(names)

    def process(self, batch: AttitudeBatch) -> None:
        if self.port is not None:
            batch.estimates["st-mahony"] = self.port.attitude(
                batch.step, batch.acc_mg, batch.gyro_mdps, batch.thr, batch.q_wxyz, batch.finite & batch.exact
            )
        rows = np.flatnonzero(batch.finite)
        for name, est in self.others.items():
            q = np.full((len(batch), 4), np.nan, dtype=np.float64)
            if rows.size:
                res = est.run(batch.acc_mg[rows], batch.gyro_mdps[rows], batch.thr[rows].astype(np.int64))
                qq = np.asarray(res.q_wxyz, dtype=np.float64)
                qq[~np.asarray(res.valid, dtype=bool)] = np.nan
                q[rows] = qq
            batch.estimates[name] = q

    def status(self, frame) -> None:
        if self.port is not None:
            self.port.status(frame)


def resolve_estimators(spec: str | None) -> list[str]:
    """``--estimators``: comma list of registry names, ``none``, or None for the defaults that are installed."""
    from steval_link.estimators import registry

    if spec is None:
        return [n for n in DEFAULT_ESTIMATORS if registry.is_available(n)]
    names = [s.strip() for s in spec.split(",") if s.strip()]
    if names in (["none"], []):
        return []
    for n in names:
        if n not in registry.names():
            raise UserError(f"unknown estimator {n!r}; choose from: {', '.join(registry.names())} (or none)")
        if not registry.is_available(n):
            raise UserError(f"estimator {n!r} needs an optional package: pip install 'steval-link[{n}]'")
    return names


# ----------------------------------------------------------------------------------------------------------------
# health


class LinkHealth:
    """Counters and rates of the live link, for the health line and the summary (times: host s, Unix epoch)."""

    def __init__(self) -> None:
        self.attitude = 0
        self.status = 0
        self.text = 0
        self.nonfinite = 0
        self._times: collections.deque[tuple[float, int]] = collections.deque(maxlen=512)
        self.first_frame_s: float | None = None  # host receive time of the first attitude frame
        self.last_frame_s: float | None = None
        self.last_text: str | None = None

    def count(self, n_attitude: int, t_first_s: float, t_last_s: float) -> None:
        """``n_attitude`` frames received between host times ``t_first_s`` and ``t_last_s``."""
        if n_attitude:
            if self.first_frame_s is None:
                self.first_frame_s = t_first_s
            self.last_frame_s = t_last_s
            self.attitude += n_attitude
            self._times.append((t_last_s, self.attitude))

    def rate_hz(self, now_s: float, window_s: float = 2.0) -> float:
        """Attitude frames per second received over the last ``window_s`` (NaN while too little is known)."""
        if self.last_frame_s is None or now_s - self.last_frame_s > 1.0:
            return 0.0
        recent = [(t, n) for t, n in self._times if now_s - t <= window_s]
        if len(recent) < 2 or recent[-1][0] - recent[0][0] < 0.2:
            return float("nan")
        return (recent[-1][1] - recent[0][1]) / (recent[-1][0] - recent[0][0])


def _fmt_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} GB"


def _fmt_duration(s: float) -> str:
    s = max(0.0, s)
    if s < 60:
        return f"{s:.1f} s"
    m, sec = divmod(int(round(s)), 60)
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m{sec:02d}s" if h else f"{m}m{sec:02d}s"


class HealthDisplay:
    """The health line on ``stream``: one line rewritten in place on a terminal, periodic plain lines otherwise."""

    def __init__(self, stream: TextIO, *, tty: bool | None = None) -> None:
        self.stream = stream
        self.tty = stream.isatty() if tty is None else tty
        self.interval_s = HEALTH_TTY_INTERVAL_S if self.tty else HEALTH_PLAIN_INTERVAL_S
        self._last = -math.inf
        self._dirty = False

    def note(self, text: str) -> None:
        """A message on its own line (events: connected, disconnected...)."""
        if self.tty and self._dirty:
            self.stream.write("\r\x1b[2K")
            self._dirty = False
        self.stream.write(f"steval: {text}\n")
        self.stream.flush()

    def show(self, line: str, now_mono: float, *, force: bool = False) -> None:
        if not force and now_mono - self._last < self.interval_s:
            return
        self._last = now_mono
        if self.tty:
            width = max(20, shutil.get_terminal_size((160, 24)).columns - 1)  # a wrapped line cannot be redrawn
            self.stream.write("\r\x1b[2K" + line[:width])
            self._dirty = True
        else:
            self.stream.write(f"steval: {line}\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self._dirty:
            self.stream.write("\r\x1b[2K")
            self.stream.flush()
            self._dirty = False


class BatchOutlet:
    """One logger fed merged batches at its own cadence (see :class:`LivePipeline`).

    ``logger`` takes ``log_batch(batch)``, ``log_status(frame, t_host_s)`` and ``log_text(frame, t_host_s)``.
    Batches wait at most ``interval_s`` (monotonic wall time) or ``interval_s`` × 161.5 frames of stream time (a
    stream fed faster than real time, e.g. catching up or a benchmark, still makes chunks of the same size).
    """

    def __init__(self, logger, interval_s: float) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self.max_rows = max(1, math.ceil(interval_s * protocol.AHRS_RATE_HZ))
        self._batches: list[AttitudeBatch] = []
        self._rows = 0
        self._events: list[tuple[str, object, float]] = []  # ("status" | "text", frame, t_host_s)
        self._since = 0.0  # monotonic time the oldest pending item came

    def _touch(self) -> None:
        if not self._batches and not self._events:
            self._since = time.monotonic()

    def add_batch(self, batch: AttitudeBatch) -> None:
        self._touch()
        self._batches.append(batch)
        self._rows += len(batch)

    def add_event(self, kind: str, frame, t_host_s: float) -> None:
        self._touch()
        self._events.append((kind, frame, t_host_s))

    def tick(self, now_mono: float | None = None) -> None:
        """Flush when the pending frames have waited ``interval_s`` or fill ``max_rows``."""
        if not (self._batches or self._events):
            return
        if self._rows >= self.max_rows or (now_mono or time.monotonic()) - self._since >= self.interval_s:
            self.flush()

    def flush(self) -> None:
        """Log every pending frame now: one merged batch, then the status and text frames in stream order."""
        if self._batches:
            batch = AttitudeBatch.concat(self._batches)
            self._batches = []
            self._rows = 0
            self.logger.log_batch(batch)
        if self._events:
            events, self._events = self._events, []
            for kind, frame, t_host_s in events:
                if kind == "status":
                    self.logger.log_status(frame, t_host_s)
                else:
                    self.logger.log_text(frame, t_host_s)


class LivePipeline:
    """Bytes → frames → estimators → viewer, for one live stream (runs in the session's main thread).

    ``feed([(bytes, t_host_s), ...])`` decodes the chunks in order and, per processing round, turns the
    attitude frames into one :class:`AttitudeBatch` that goes through :class:`LiveEstimators` and then to
    ``viewer.log_batch`` (status and text frames are logged in stream order between batches). Counters are in
    ``decoder.stats`` and ``health``. Memory is bounded: nothing per frame is kept beyond one view interval.

    ``view_interval_s``: batches are handed to the viewer at most this often, or once that much stream time
    (``view_interval_s`` × 161.5 frames) waits (merged; the status and text frames
    that came meanwhile follow the merged batch, in stream order, and are timed by their own firmware time, so
    they never cut a batch): every Rerun log call costs a chunk per entity, and Rerun keeps some memory per chunk
    for the whole recording (the ``.rrd`` footer), so fewer, larger batches keep memory flat.

    ``file_logger``: a second logger (the ``.rrd``'s own stream next to a live viewer) that gets the same frames
    merged at its own cadence, ``file_interval_s``. Each logger gets every frame once. Call :meth:`tick`
    regularly and :meth:`flush_view` at the end.
    """

    def __init__(
        self,
        estimator_names: list[str],
        viewer=None,
        *,
        view_interval_s: float = 0.0,
        file_logger=None,
        file_interval_s: float = RRD_ONLY_INTERVAL_S,
    ) -> None:
        from steval_link.decoder import StreamDecoder

        self.view_interval_s = view_interval_s
        #: the loggers, each with its own cadence (the viewer first)
        self.outlets = [
            BatchOutlet(logger, interval_s)
            for logger, interval_s in ((viewer, view_interval_s), (file_logger, file_interval_s))
            if logger is not None
        ]
        self.decoder = StreamDecoder()
        self.health = LinkHealth()
        self.estimators = LiveEstimators(estimator_names) if estimator_names else None
        self.viewer = viewer
        self.file_logger = file_logger
        self.step_unwrap = StepUnwrapper()
        #: the first bytes of the current connection (to describe a stream without frames)
        self.sample = bytearray()
        #: firmware log lines not shown yet (the session prints them; bounded)
        self.texts: collections.deque[str] = collections.deque(maxlen=32)

    @property
    def port(self) -> "LivePort | None":
        return self.estimators.port if self.estimators is not None else None

    def feed(self, chunks: list[tuple[bytes, float]]) -> None:
        """Decode and process chunks received at host times ``t_host_s`` (s, Unix epoch), in stream order."""
        from steval_link.frames import AttitudeFrame, StatusFrame, TextFrame

        outlets = self.outlets
        att: list[tuple[object, float]] = []
        for data, t_host_s in chunks:
            if len(self.sample) < SAMPLE_BYTES:
                self.sample += data[: SAMPLE_BYTES - len(self.sample)]
            for frame in self.decoder.feed(data):
                if isinstance(frame, AttitudeFrame):
                    att.append((frame, t_host_s))
                elif isinstance(frame, StatusFrame):
                    self._attitude(att)  # the port must step through the frames before the snapshot
                    att = []
                    self.health.status += 1
                    self.step_unwrap.status(int(frame.step))
                    if self.estimators is not None:
                        self.estimators.status(frame)
                    if outlets:
                        self._event("status", frame, t_host_s)
                elif isinstance(frame, TextFrame):
                    self._attitude(att)
                    att = []
                    self.health.text += 1
                    self.health.last_text = frame.text
                    self.texts.append(frame.text)
                    if outlets:
                        self._event("text", frame, t_host_s)
        self._attitude(att)
        self.tick()

    def _event(self, kind: str, frame, t_host_s: float) -> None:
        for outlet in self.outlets:
            outlet.add_event(kind, frame, t_host_s)

    def tick(self, now_mono: float | None = None) -> None:
        """Hand the pending frames to each logger whose interval has passed."""
        for outlet in self.outlets:
            outlet.tick(now_mono)

    def flush_view(self) -> None:
        """Hand every pending frame to every logger now: one merged batch each, then the status and text frames."""
        for outlet in self.outlets:
            outlet.flush()

    def _attitude(self, att: list) -> None:
        if not att:
            return
        frames = [f for f, _ in att]
        n = len(frames)
        acc = np.array([f.acc_mg for f in frames], dtype=np.float32).reshape(n, 3)
        gyro = np.array([f.gyro_mdps for f in frames], dtype=np.float32).reshape(n, 3)
        q = np.array([f.q_wxyz for f in frames], dtype=np.float32).reshape(n, 4)
        thz = np.array([f.thz_rad for f in frames], dtype=np.float32)
        exact = np.array([f.exact for f in frames], dtype=bool)
        # binary frames must carry a finite q; text-mode rows carry no q but angles instead
        angles = np.array([(f.thx_rad, f.thy_rad) for f in frames], dtype=np.float32).reshape(n, 2)
        finite = np.isfinite(acc).all(axis=1) & np.isfinite(gyro).all(axis=1) & np.isfinite(thz)
        finite &= np.where(exact, np.isfinite(q).all(axis=1), np.isfinite(angles).all(axis=1))
        batch = AttitudeBatch(
            step=self.step_unwrap.frames(frames),
            t_us=np.array([f.t_us for f in frames], dtype=np.int64),
            t_host_s=np.array([t for _, t in att], dtype=np.float64),
            acc_mg=acc,
            gyro_mdps=gyro,
            q_wxyz=q,
            thz_rad=thz,
            thr=np.array([f.thr for f in frames], dtype=np.int16),
            finite=finite,
            exact=exact,
            thx_rad=angles[:, 0],
            thy_rad=angles[:, 1],
        )
        self.health.nonfinite += int(n - np.count_nonzero(finite))
        self.health.count(n, float(batch.t_host_s[0]), float(batch.t_host_s[-1]))
        if self.estimators is not None:
            self.estimators.process(batch)
        for outlet in self.outlets:
            outlet.add_batch(batch)


# ----------------------------------------------------------------------------------------------------------------
# the session


@dataclass
class LiveOptions:
    """Everything ``steval live`` / ``steval record`` configure."""

    port: str = "auto"
    baud: int = protocol.DEFAULT_BAUD
    out: Path | None = None
    rrd: Path | None = None
    view: bool = True  # False: --no-view
    spawn: bool = False
    serve: bool = False
    connect: str | None = None
    web_port: int = DEFAULT_WEB_PORT
    grpc_port: int = DEFAULT_GRPC_PORT
    estimators: list[str] = field(default_factory=list)
    duration_s: float | None = None
    wait: bool = False
    recordings_dir: Path = Path("recordings")

    @property
    def uses_rerun(self) -> bool:
        return bool(self.rrd) or self.view


@dataclass
class LiveSummary:
    """What a session did (the summary line prints it)."""

    capture_path: Path
    rrd_path: Path | None
    seconds: float
    streaming_s: float  # from the first to the last attitude frame, less the time disconnected
    bytes_total: int
    attitude: int
    status: int
    text: int
    frames_missing: int
    crc_failures: int
    bytes_skipped: int
    nonfinite: int
    disconnects: int
    offline_s: float
    live_dropped_bytes: int
    port_note: str | None
    stopped_by: str
    capture_discarded: bool = False  # no byte came: the header-only file was removed

    def line(self) -> str:
        rate = self.attitude / self.streaming_s if self.streaming_s > 0.5 else float("nan")
        parts = [
            f"{_fmt_duration(self.seconds)}",
            f"{self.attitude} attitude frames" + ("" if math.isnan(rate) else f" ({rate:.1f} Hz)"),
            f"{self.frames_missing} missing",
            f"{self.crc_failures} CRC failures",
            f"{_fmt_bytes(self.bytes_skipped)} skipped",
        ]
        if self.nonfinite:
            parts.append(f"{self.nonfinite} with NaN/inf")
        if self.disconnects:
            parts.append(f"{self.disconnects} disconnect{'s' if self.disconnects > 1 else ''} ({self.offline_s:.1f} s)")
        if self.live_dropped_bytes:
            parts.append(f"{_fmt_bytes(self.live_dropped_bytes)} not shown live (in the capture)")
        if self.port_note:
            parts.append(self.port_note)
        if self.capture_discarded:
            out = "no byte received, so no capture file was kept"
        else:
            out = f"capture {self.capture_path} ({_fmt_bytes(self.bytes_total)})"
        if self.rrd_path:
            out += f", rerun {self.rrd_path}"
        return "recorded " + ", ".join(parts) + "; " + out


class LiveSession:
    """One ``steval live`` / ``steval record`` run; :meth:`run` returns the summary or raises :class:`UserError`.

    ``stream``: where the health line and notes go (stderr). ``viewer_factory(options) -> logger`` makes the
    Rerun side (``None``: :func:`make_viewer_logger`); the logger takes ``log_batch(batch)``, ``log_status(frame)``,
    ``log_text(t_host_s, text)``, ``log_health(...)`` and ``close()``; an optional ``file`` attribute (another such
    logger: the ``.rrd``'s own stream next to a live viewer) is fed merged batches every RRD_ONLY_INTERVAL_S.
    """

    def __init__(
        self,
        options: LiveOptions,
        *,
        stream: TextIO | None = None,
        tty: bool | None = None,
        viewer_factory: Callable | None = None,
    ) -> None:
        self.options = options
        self.display = HealthDisplay(stream or sys.stderr, tty=tty)
        self.viewer_factory = viewer_factory
        self.clock = HostClock()
        self._stop_reason: str | None = None

    # -- control ----------------------------------------------------------------------------------------------

    def request_stop(self, reason: str = "stopped") -> None:
        """Finish cleanly at the next round (thread-safe; what Ctrl-C and SIGTERM do)."""
        if self._stop_reason is None:
            self._stop_reason = reason

    # -- opening ----------------------------------------------------------------------------------------------

    def _open_port(self) -> tuple[str, serial.Serial]:
        opts = self.options
        deadline = time.monotonic() + (math.inf if opts.wait else 0.0)
        announced = False
        while True:
            try:
                path = autodetect.choose_port(opts.port, opts.baud)
            except autodetect.PortChoiceError as exc:
                if time.monotonic() >= deadline or self._stop_reason:
                    raise UserError(str(exc)) from None
                if not announced:
                    self.display.note(f"{exc}; waiting (--wait)")
                    announced = True
                time.sleep(0.25)
                continue
            try:
                return path, open_serial(path, opts.baud)
            except serial.SerialException as exc:
                missing = getattr(exc, "errno", None) == 2 or not os.path.exists(path)
                if missing and time.monotonic() < deadline and not self._stop_reason:
                    if not announced:
                        self.display.note(f"{path} is not there; waiting for it (--wait)")
                        announced = True
                    time.sleep(0.1)
                    continue
                try:
                    available = autodetect.list_candidate_ports()
                except Exception:  # noqa: BLE001 - the listing is only a hint in the message
                    available = []
                raise UserError(open_error_message(path, exc, available)) from None

    # -- main -------------------------------------------------------------------------------------------------

    def run(self) -> LiveSummary:
        opts = self.options
        if opts.uses_rerun:
            viewer_sink_options(opts)  # e.g. no display and no --rrd: say so before anything is opened
        path, ser = self._open_port()
        identity = autodetect.PortIdentity.of(path)
        finder = autodetect.PortFinder(identity, pattern=opts.port if autodetect.is_glob(opts.port) else None)
        capture_path = Path(opts.out) if opts.out else default_capture_path(opts.recordings_dir)
        try:
            capture_path.parent.mkdir(parents=True, exist_ok=True)
            capture = CaptureWriter(
                capture_path,
                discard_empty=True,  # a session that got no byte leaves no header-only file behind
                port=path,
                baud=opts.baud,
                extra={"device": identity.device, "usb": identity.describe(), "estimators": list(opts.estimators)},
            )
        except FileExistsError:
            ser.close()
            raise UserError(f"{capture_path} already exists; choose another --out (captures are never overwritten)")
        except OSError as exc:
            ser.close()
            raise UserError(f"cannot write the capture {capture_path}: {exc.strerror or exc}") from None
        self.clock = HostClock(wall0_s=capture.header["start_time_unix_s"])

        inbox = Inbox()
        proto = RecorderProtocol(capture, inbox, finder, self.clock)
        reader = SerialReader(ser, proto, baud=opts.baud, clock=self.clock, find_port=finder.find)
        viewer = None
        t0 = time.monotonic()
        error: BaseException | None = None
        old_handlers = self._install_signals()
        try:
            self.display.note(
                f"reading {identity.describe()} at {opts.baud} baud; recording to {capture_path}"
                + (f" and {opts.rrd}" if opts.rrd else "")
                + " (Ctrl-C to stop)"
            )
            reader.start()
            if opts.uses_rerun:
                viewer = (self.viewer_factory or make_viewer_logger)(opts, capture_path.stem)
            self._loop(reader, proto, inbox, viewer, t0)
        except BaseException as exc:  # noqa: BLE001 - finish the files first, then re-raise
            error = exc
        finally:
            reader.stop()
            # whatever is still queued goes to the live side; the capture already holds it
            try:
                if error is None or isinstance(error, (LinkError, KeyboardInterrupt)):
                    self._drain(inbox)
            except Exception:  # noqa: BLE001
                pass
            try:
                capture.mark_event("stop", self._stop_reason or (type(error).__name__ if error else "end"))
            except Exception:  # noqa: BLE001
                pass
            capture.close()
            if viewer is not None:
                try:
                    viewer.close()
                except Exception as exc:  # noqa: BLE001 - the capture is safe; say what went wrong
                    self.display.note(f"could not finalise the Rerun output: {exc}")
            self.display.close()
            self._restore_signals(old_handlers)
        if isinstance(error, KeyboardInterrupt):
            self.request_stop("interrupted")
        elif error is not None:
            raise error
        seconds = time.monotonic() - t0
        summary = self._summary(capture_path, seconds, proto, inbox)
        summary.capture_discarded = capture.discarded
        return summary

    # -- internals --------------------------------------------------------------------------------------------

    def _install_signals(self):
        if threading.current_thread() is not threading.main_thread():
            return None
        old = {}

        def on_signal(signum, _frame):
            if self._stop_reason is not None:  # second Ctrl-C: stop now (files are flushed often)
                raise KeyboardInterrupt
            self.request_stop("interrupted" if signum == signal.SIGINT else "terminated")

        for sig in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)):
            if sig is None:  # pragma: no cover - Windows has no SIGHUP
                continue
            try:
                old[sig] = signal.signal(sig, on_signal)
            except (ValueError, OSError):
                pass
        return old

    @staticmethod
    def _restore_signals(old) -> None:
        if not old:
            return
        for sig, handler in old.items():
            try:
                signal.signal(sig, handler)
            except (ValueError, OSError):
                pass

    def _loop(self, reader: SerialReader, proto: RecorderProtocol, inbox: Inbox, viewer, t0: float) -> None:
        opts = self.options
        # a viewer sink, not only an .rrd (headless `steval live --rrd X` resolves to the file alone)
        live_viewer = viewer is not None and bool(getattr(viewer, "has_viewer", opts.view))
        # a live viewer gets every round at once; an .rrd merged batches (its own stream when a viewer runs too)
        pipe = self.pipeline = LivePipeline(
            opts.estimators,
            viewer,
            view_interval_s=VIEW_INTERVAL_S if live_viewer else RRD_ONLY_INTERVAL_S,
            file_logger=getattr(viewer, "file", None) if live_viewer else None,
            file_interval_s=RRD_ONLY_INTERVAL_S,
        )
        self.warned_no_frames = False
        was_connected = True
        while self._stop_reason is None:
            if reader.error is not None:
                if isinstance(reader.error, OSError):  # the capture could not be written (disk full, removed)
                    raise UserError(
                        f"writing the capture failed ({reader.error.strerror or reader.error}); "
                        f"what was received until then is in {proto.capture.path}"
                    )
                raise reader.error
            chunks = inbox.get_all(0.02)
            now = time.monotonic()
            if chunks:
                pipe.feed(chunks)
                if viewer is not None:
                    viewer.log_link(pipe.decoder.stats, self.clock.now_s())
            pipe.tick(now)
            for _ in range(len(proto.events)):
                self.display.note(proto.events.popleft())
            for _ in range(len(pipe.texts)):
                self.display.note("firmware: " + pipe.texts.popleft()[:200])
            if proto.connected != was_connected:
                was_connected = proto.connected
                if proto.connected:
                    pipe.sample.clear()
            self._check_frames(proto, now)
            self.display.show(self._health_line(proto, inbox, now, reader), now)
            if opts.duration_s is not None and now - t0 >= opts.duration_s:
                self.request_stop("duration")

    def _drain(self, inbox: Inbox) -> None:
        pipe = getattr(self, "pipeline", None)
        if pipe is None:
            return
        chunks = inbox.get_all(0.0)
        if chunks:
            pipe.feed(chunks)
        pipe.flush_view()

    def _check_frames(self, proto: RecorderProtocol, now: float) -> None:
        """Wrong baud rate / not a STEVAL / silence: give up (or warn once with --wait) when no frame ever came."""
        stats = self.pipeline.decoder.stats
        if stats.attitude + stats.status > 0 or self.warned_no_frames or not proto.connected or proto.connected_at_s is None:
            return
        elapsed = now - proto.connected_at_s
        nbytes = proto.connect_bytes
        if not (elapsed >= NO_FRAMES_TIMEOUT_S or (elapsed >= NO_FRAMES_EARLY_S and nbytes >= NO_FRAMES_EARLY_BYTES)):
            return
        message = autodetect.no_frames_message(
            proto.port or "?", self.options.baud, bytes(self.pipeline.sample), elapsed, total=nbytes
        )
        if self.options.wait:
            self.warned_no_frames = True
            self.display.note(message + "; still waiting (--wait)")
            return
        raise LinkError(message)

    def _health_line(self, proto: RecorderProtocol, inbox: Inbox, now: float, reader: SerialReader) -> str:
        s = self.pipeline.decoder.stats
        h = self.pipeline.health
        if not proto.connected:
            lost = now - (proto.lost_at_s or now)
            head = f"disconnected, waiting for {proto.port} ({lost:.0f} s)"
            failed = reader.reopen_error
            if failed is not None:  # it is back but cannot be opened: say why (busy, permissions)
                head += f"; {open_error_message(failed[0], failed[1])}"
        elif s.attitude + s.status == 0:
            head = f"{proto.port}: waiting for frames ({_fmt_bytes(proto.connect_bytes)} received)"
        else:
            rate = h.rate_hz(self.clock.now_s())
            head = f"{proto.port} {'--' if math.isnan(rate) else f'{rate:5.1f}'} Hz"
        parts = [
            head,
            f"frames {h.attitude}",
            f"missing {_stat(s, 'frames_missing')}",
            f"CRC {_stat(s, 'crc_failures')}",
            f"skipped {_fmt_bytes(_stat(s, 'bytes_skipped'))}",
        ]
        if h.nonfinite:
            parts.append(f"NaN/inf {h.nonfinite}")
        if proto.disconnects:
            parts.append(f"disconnects {proto.disconnects}")
        if inbox.dropped_bytes:
            parts.append(f"live lag: {_fmt_bytes(inbox.dropped_bytes)} not shown")
        if self.pipeline.port is not None:
            parts.append(self.pipeline.port.describe())
        parts.append(f"rec {_fmt_bytes(proto.bytes_total)}")
        return " | ".join(parts)

    def _summary(self, capture_path: Path, seconds: float, proto: RecorderProtocol, inbox: Inbox) -> LiveSummary:
        pipe = getattr(self, "pipeline", None)
        s = pipe.decoder.stats if pipe is not None else None
        h = pipe.health if pipe is not None else LinkHealth()
        port_note = None
        streaming_s = 0.0
        if h.first_frame_s is not None and h.last_frame_s is not None:
            streaming_s = max(0.0, h.last_frame_s - h.first_frame_s - proto.offline_s)
        p = pipe.port if pipe is not None else None
        if p is not None:
            if p.rows_mismatch:
                port_note = f"ST port differs from the firmware on {p.rows_mismatch} frames"
            elif p.rows_exact:
                port_note = f"ST port bit-exact on {p.rows_exact} frames"
            else:
                port_note = "ST port not seeded (no status snapshot)"
        return LiveSummary(
            capture_path=capture_path,
            rrd_path=self.options.rrd,
            seconds=seconds,
            streaming_s=streaming_s,
            bytes_total=proto.bytes_total,
            attitude=h.attitude,
            status=h.status,
            text=h.text,
            frames_missing=_stat(s, "frames_missing"),
            crc_failures=_stat(s, "crc_failures"),
            bytes_skipped=_stat(s, "bytes_skipped"),
            nonfinite=h.nonfinite,
            disconnects=proto.disconnects,
            offline_s=proto.offline_s,
            live_dropped_bytes=inbox.dropped_bytes,
            port_note=port_note,
            stopped_by=self._stop_reason or "end",
        )


def _stat(stats, name: str) -> int:
    return int(getattr(stats, name, 0) or 0) if stats is not None else 0


class StepUnwrapper:
    """Full AHRS step numbers from the 16-bit ``seq`` of attitude frames, corrected by status frames' 32-bit step."""

    def __init__(self) -> None:
        self.last: int | None = None

    def frames(self, frames) -> np.ndarray:
        """(N,) int64 steps of these attitude frames, in order: ``step`` where the frame has it (text mode), else
        unwrapped from ``seq`` (a repeated seq keeps its step)."""
        out = np.empty(len(frames), dtype=np.int64)
        last = self.last
        for i, f in enumerate(frames):
            if f.step is not None:
                last = int(f.step)
            elif last is None:
                last = int(f.seq)
            else:
                last = last + ((int(f.seq) - last) % protocol.SEQ_MODULUS)
            out[i] = last
        self.last = last
        return out

    def status(self, step: int) -> None:
        """A status frame describes the step of the attitude frame just before it: take its full number."""
        if self.last is None or self.last % protocol.SEQ_MODULUS == step % protocol.SEQ_MODULUS:
            self.last = step


class ViewerLogger:
    """The Rerun side of a live session: the sinks of ``options`` and a :class:`steval_viewer.live_log.LiveLogger`.

    ``log_batch``/``log_status``/``log_text`` go to the session's main stream (the viewer's; the ``.rrd``'s when
    there is no viewer). With a viewer *and* ``--rrd`` the file has its own stream of the same recording and its
    own logger, ``file`` (else None), which the pipeline feeds merged batches every RRD_ONLY_INTERVAL_S (Rerun's file
    sink keeps ~1 kB per chunk until the file closes); ``log_link`` goes to both; ``close`` flushes and closes both.

    Imported only when a viewer or an ``.rrd`` is asked for (``--no-view`` without ``--rrd``: no Rerun at all).
    """

    def __init__(self, options: LiveOptions, recording_name: str | None = None) -> None:
        from steval_viewer import live_log, sinks

        self.session = sinks.open_session(
            viewer_sink_options(options), recording_name=recording_name, split_file=True
        )
        self.logger = live_log.LiveLogger(self.session.rec, estimator_names=options.estimators)
        self.file: live_log.LiveLogger | None = None
        if self.session.file_rec is not None:
            # same host-time origin as the live view, so the .rrd lines up with it when opened together
            self.file = live_log.LiveLogger(
                self.session.file_rec, estimator_names=options.estimators, t0_from=self.logger
            )

    @property
    def has_viewer(self) -> bool:
        """Whether a viewer gets the stream (else only the ``.rrd``: merged batches, few chunks)."""
        return self.session.has_viewer

    def log_batch(self, batch: AttitudeBatch) -> None:
        self.logger.log_batch(batch)

    def log_status(self, frame, t_host_s: float) -> None:
        self.logger.log_status(frame, t_host_s)

    def log_text(self, frame, t_host_s: float) -> None:
        self.logger.log_text(frame, t_host_s)

    def log_link(self, stats, t_host_s: float) -> None:
        self.logger.log_link(stats, t_host_s)
        if self.file is not None:
            self.file.log_link(stats, t_host_s)

    def close(self) -> None:
        """Send what the loggers hold and finish both streams (the ``.rrd`` is complete afterwards)."""
        try:
            try:
                self.logger.close()
            finally:
                if self.file is not None:
                    self.file.close()
        finally:
            self.session.close()


def viewer_sink_options(options: LiveOptions) -> SinkOptions:
    """The Rerun sinks of a session (``steval_viewer.sink_options.SinkOptions``): the chosen viewer, or the default
    one (``--spawn`` where a display exists), and the ``.rrd``; ``--no-view``: the ``.rrd`` alone. UserError when
    they cannot work (no display and no ``--rrd``, a ``--connect`` URL where nothing listens, a busy port, a
    missing ``.rrd`` folder)."""
    chosen = SinkOptions(rrd=options.rrd, web_port=options.web_port, grpc_port=options.grpc_port)
    if options.view:
        chosen.spawn, chosen.serve, chosen.connect = options.spawn, options.serve, options.connect
        chosen = resolve_sinks(chosen)
    check_sinks(chosen)
    return chosen


def make_viewer_logger(options: LiveOptions, recording_name: str | None = None) -> ViewerLogger:
    """The Rerun side of a live session (see :class:`ViewerLogger`)."""
    return ViewerLogger(options, recording_name)

"""Chunks → frames → rows → estimators → viewer for one live stream, whatever the link (:class:`LivePipeline`),
rows timed by ``load_telemetry``'s rules. Estimators per :class:`LiveRows`: the ST Mahony filter followed bit for
bit from status snapshots (:class:`LiveMahony`), the registry's and your own (:class:`LiveEstimators`)."""

from __future__ import annotations

import collections
import math
import time
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import numpy as np

from steval_link import constants as C
from steval_link.estimators import firmware_replay, registry, st_mahony
from steval_link.estimators.runner import created_at
from steval_link.link import ble_payloads as B
from steval_link.link import frames as F
from steval_link.link import protocol as P
from steval_link.link.ble_telemetry import NOT_BIT_EXACT, LiveGrid, link_notes
from steval_link.link.commands import Command, ack_of_text, describe_ack, describe_settings
from steval_link.link.decoder import StreamDecoder
from steval_link.link.plausibility import attitude_inputs_bad
from steval_link.link.telemetry import AttitudeArrays, SeqUnwrapper, StreamClock, TelemetryParts
from steval_link.link.text_series import RecordAttitude
from steval_link.live.health import LinkHealth

#: Bytes kept from the start of a connection to describe a stream without frames.
SAMPLE_BYTES = 4096


#: Frames go to a live viewer every processing round (latency goal p99 <= 5 ms, ``bench_live_latency.py``) ...
VIEW_INTERVAL_S = 0.0
#: ... and to an ``.rrd`` (its own stream, merged batches: about one chunk per entity) at most this often, s.
RRD_ONLY_INTERVAL_S = 0.5
#: An ``.rrd``'s batch holds at most this much stream time, s (a stream fed faster than real time).
RRD_BATCH_MAX_STREAM_S = 30.0


@dataclass
class LiveRows:
    """The attitude rows of one processing round (times on the capture's base) with every live estimate:
    ``estimates`` maps a source name (``st-mahony``, ``accel``...) to (N, 4) q_wxyz, NaN where undefined."""

    attitude: AttitudeArrays
    estimates: dict[str, np.ndarray] = field(default_factory=dict)
    #: (N, 3) float32 magnetometer of each row, mgauss, where the link sends it (BLE); None: not sent
    mag_mgauss: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.attitude)

    @property
    def finite(self) -> np.ndarray:
        """(N,) bool: the filter inputs (acc, gyro) are finite, so estimators may take the row."""
        a = self.attitude
        return np.isfinite(a.acc_mg).all(axis=1) & np.isfinite(a.gyro_mdps).all(axis=1)

    @classmethod
    def concat(cls, parts: list[LiveRows]) -> LiveRows:
        """One set of the rows of ``parts``, in order (estimate names must agree)."""
        if len(parts) == 1:
            return parts[0]
        estimates = {name: np.concatenate([p.estimates[name] for p in parts]) for name in parts[0].estimates}
        mags = [p.mag_mgauss for p in parts]
        mag = np.concatenate(mags) if all(m is not None for m in mags) else None
        return cls(AttitudeArrays.concat([p.attitude for p in parts]), estimates, mag)


class LiveMahony(firmware_replay.ReplicaFollower):
    """The bit-exact ST Mahony filter run live (``replay_firmware``'s follower), (re)seeded from the firmware's status
    snapshots: NaN until one unless the stream starts at step 0; a snapshot that disagrees re-seeds it."""

    def __init__(self) -> None:
        super().__init__(euler=False)
        self.rows_exact = self.rows_mismatch = 0
        self.last_rows_mismatch = 0  # mismatching rows of the latest call

    def attitude(self, step: np.ndarray, acc_mg, gyro_mdps, thr, fw_q_wxyz, finite: np.ndarray) -> np.ndarray:
        """Step the filter over these frames (in order); returns (N, 4) float32 q, NaN where unseeded."""
        q, _, _, seeded = self.rows_recognising(step, acc_mg, gyro_mdps, thr, finite, fw_q_wxyz)
        k = int(np.count_nonzero(seeded & st_mahony.bits_equal(q, fw_q_wxyz).all(axis=1)))
        self.rows_exact += k
        self.last_rows_mismatch = int(np.count_nonzero(seeded)) - k
        self.rows_mismatch += self.last_rows_mismatch
        return q

    def status(self, frame) -> None:
        if not frame.exact:  # a text-mode $STA row has no q, integral or gains: nothing to seed from
            return
        snap = st_mahony.MahonyState(q_wxyz=frame.q_wxyz, int_xyz=frame.int_xyz)
        self.snapshot(int(frame.step), snap, st_mahony.MahonySettings.of_status(frame))

    def describe(self) -> str:
        """The filter's state in a few words for the health line."""
        if not self.seeded:
            return "replica resyncing" if self.seed_count else "replica waiting for a status snapshot"
        if self.last_rows_mismatch:
            return f"replica DIFFERS from firmware ({self.rows_mismatch} frames)"
        return "replica bit-exact" if self.rows_exact else "replica seeded"


#: A live estimator is disabled when it gives NaN on NAN_FLOOD_S of finite input in a row, needs more than SLOW_SHARE
#: of the stream time it is fed over SLOW_WINDOW_S of wall time, or stalls the view in one call over STALL_S, s.
NAN_FLOOD_S = 3.0
SLOW_SHARE = 0.5
SLOW_WINDOW_S = 5.0
STALL_S = 2.0


@dataclass
class _Watch:
    """One estimator's NaN rows in a row and its processing and stream time in the current window."""

    window_start_s: float
    nan_rows: int = 0
    busy_s: float = 0.0
    stream_s: float = 0.0


class LiveEstimators:
    """Every host estimator on each row with finite inputs (one NaN would poison its state). One that raises, floods
    NaN or cannot keep up is disabled: one line from :meth:`process`, NaN from then on, and the session goes on."""

    def __init__(self, names: list[str], *, clock=time.perf_counter) -> None:
        self.mahony = LiveMahony() if "st-mahony" in names else None
        self.others = {name: registry.create(name) for name in names if name != "st-mahony"}
        self.names = list(names)
        self.clock = clock
        self.disabled: dict[str, str] = {}  # name → why it was disabled (one sentence)
        self._watch = {name: _Watch(clock()) for name in self.others}

    def use_dt(self, dt_s: float) -> None:
        """Every estimator at ``dt_s`` on rows no firmware filter made (BLE): the replica as a plain filter."""
        self.mahony = None
        self.others = {name: created_at(name, dt_s) for name in self.names}
        self._watch = {name: _Watch(self.clock()) for name in self.others}

    def process(self, rows: LiveRows) -> list[str]:
        a, finite = rows.attitude, rows.finite
        notes: list[str] = []  # a sentence per estimator disabled now (returned)
        if self.mahony is not None:
            rows.estimates["st-mahony"] = self.mahony.attitude(
                a.step, a.acc_mg, a.gyro_mdps, a.thr, a.q_wxyz, finite & a.exact
            )
        rows_in = np.flatnonzero(finite)
        for name, est in self.others.items():
            q = np.full((len(rows), 4), np.nan, dtype=np.float64)
            if rows_in.size and name not in self.disabled:
                t0 = self.clock()
                try:
                    res = est.run(a.acc_mg[rows_in], a.gyro_mdps[rows_in], a.thr[rows_in].astype(np.int64))
                    valid = np.asarray(res.valid, dtype=bool)
                    q[rows_in] = np.where(valid[:, None], res.q_wxyz, np.nan)
                except registry.PluginError as exc:  # a user's estimator: names their file and line
                    why = str(exc)
                except Exception as exc:  # noqa: BLE001 - any failure of an estimator costs it, never the session
                    text = str(exc).strip().splitlines()
                    why = f"estimator {name} failed: {type(exc).__name__}" + (f": {text[0]}" if text else "")
                else:
                    why = self._verdict(name, est, rows_in.size, valid, self.clock() - t0)
                if why is not None:
                    self.disabled[name] = why
                    notes.append(f"{why}; {name} disabled, recording and viewing go on")
            rows.estimates[name] = q
        return notes

    def _verdict(self, name: str, est, n: int, valid: np.ndarray, elapsed_s: float) -> str | None:
        """Why ``name`` is disabled after a call of ``n`` rows (None: it keeps up)."""
        w = self._watch[name]
        last_valid = np.flatnonzero(valid)
        w.nan_rows = n - 1 - int(last_valid[-1]) if last_valid.size else w.nan_rows + n
        if w.nan_rows >= NAN_FLOOD_S * C.AHRS_RATE_HZ:
            where = est.origin("step") if hasattr(est, "origin") else name
            return (
                f"estimator {name} gave no estimate (NaN) for {w.nan_rows} frames of valid input in "
                f"a row ({w.nan_rows / C.AHRS_RATE_HZ:.1f} s); look at {where}"
            )
        if elapsed_s > STALL_S:
            return (
                f"estimator {name} took {elapsed_s:.1f} s for {n} frames ({n / C.AHRS_RATE_HZ:.2f} s "
                "of stream): too slow to run live (steval compare runs it offline)"
            )
        w.busy_s += elapsed_s
        w.stream_s += n / C.AHRS_RATE_HZ
        now = self.clock()
        if now - w.window_start_s < SLOW_WINDOW_S:
            return None
        if w.stream_s > 0 and w.busy_s > SLOW_SHARE * w.stream_s:
            return (
                f"estimator {name} needed {1000 * w.busy_s / max(w.stream_s, 1e-9):.0f} ms per "
                f"second of stream for {now - w.window_start_s:.0f} s (at most "
                f"{1000 * SLOW_SHARE:.0f} ms to keep up live; steval compare runs it offline)"
            )
        w.busy_s = w.stream_s = 0.0
        w.window_start_s = now
        return None


class EventTime(NamedTuple):
    """When a frame or a note happened: firmware s since boot (NaN before the first row), host s since capture start."""

    t_fw_s: float
    t_host_s: float


class LiveViewer(Protocol):
    """What a live session logs to (the viewer's ``ViewerLogger``, a test's fake). Optional: ``has_viewer``, ``file``
    (the .rrd's own) and ``log_flight/record/environment/arming/note``, each ``(frame, at)``."""

    def log_batch(self, batch: LiveRows) -> None: ...

    def log_status(self, frame, at: EventTime) -> None: ...

    def log_text(self, frame, at: EventTime) -> None: ...

    def log_link(self, stats, t_unix_s: float) -> None: ...

    def log_event(self, text: str, at: EventTime, level: str) -> None: ...

    def close(self) -> None: ...


class StepUnwrapper(SeqUnwrapper):
    """Full AHRS steps of live attitude frames: a text-mode frame's own, a binary frame's u16 ``seq`` unwrapped."""

    def frames(self, frames) -> tuple[np.ndarray, np.ndarray]:
        """(steps (N,) int64, restart (N,) bool: a binary frame that begins a new firmware run) of these frames."""
        out, restart = np.empty(len(frames), dtype=np.int64), np.zeros(len(frames), dtype=bool)
        run: list[int] = []  # indexes of the current run of binary frames
        for i, f in enumerate(frames + [None]):
            if f is not None and f.step is None:
                run.append(i)
                continue
            if run:
                out[run], restart[run] = self.steps(np.array([int(frames[j].seq) for j in run], dtype=np.int64))
                run = []
            if f is not None:
                out[i] = self.last = int(f.step)
        return out, restart


class BatchOutlet:
    """One logger's merged batches, out after ``interval_s`` or ``max_stream_s`` × 161.5 rows; events after them."""

    def __init__(self, logger, interval_s: float, max_stream_s: float | None = None) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self.max_rows = max(1, math.ceil((interval_s if max_stream_s is None else max_stream_s) * C.AHRS_RATE_HZ))
        self._batches: list[LiveRows] = []
        self._events: list[tuple[str, tuple]] = []  # (logger method, its arguments)
        self._since = 0.0  # monotonic time the oldest pending item came

    def add(self, batch: LiveRows | None = None, event: tuple[str, tuple] | None = None) -> None:
        if not self._batches and not self._events:
            self._since = time.monotonic()
        if batch is not None:
            self._batches.append(batch)
        else:
            self._events.append(event)

    def tick(self, now_mono: float | None = None) -> None:
        late = (now_mono or time.monotonic()) - self._since >= self.interval_s
        if (self._batches or self._events) and (late or sum(map(len, self._batches)) >= self.max_rows):
            self.flush()

    def flush(self) -> None:
        if self._batches:
            batches, self._batches = self._batches, []
            self.logger.log_batch(LiveRows.concat(batches))
        events, self._events = self._events, []
        for name, args in events:
            if (log := getattr(self.logger, name, None)) is not None:
                log(*args)


class LivePipeline:
    """Each round's attitude frames → one :class:`LiveRows`; other frames → events at their :class:`EventTime`.
    ``view_interval_s``: viewer batches merged at most this often (keeps Rerun's memory flat); ``file_logger``: the
    ``.rrd``'s own, at ``file_interval_s``. Call :meth:`tick` often, :meth:`flush_view` at the end."""

    def __init__(
        self,
        estimator_names: list[str],
        viewer=None,
        *,
        view_interval_s: float = 0.0,
        file_logger=None,
        file_interval_s: float = RRD_ONLY_INTERVAL_S,
        t0_unix_s: float | None = None,
        baud: int | None = None,
        ble_layout: B.BleLayout = B.LAYOUTS["stock"],
        text_map: dict[str, tuple[str, str]] | None = None,
        line_start: bool = False,
    ) -> None:
        self.outlets = [  # each logger at its own cadence
            BatchOutlet(logger, interval_s, RRD_BATCH_MAX_STREAM_S if interval_s == RRD_ONLY_INTERVAL_S else None)
            for logger, interval_s in ((viewer, view_interval_s), (file_logger, file_interval_s))
            if logger is not None
        ]
        self.decoder = StreamDecoder(line_start=line_start)
        self.health = LinkHealth()
        self.estimators = LiveEstimators(estimator_names) if estimator_names else None
        self.step_unwrap = StepUnwrapper()
        self.clock = StreamClock(t0_unix_s, baud)  # the rows' firmware and host times (the capture's base)
        self._last_row: tuple[int, float, float] | None = None  # (step, t_fw_s, t_host_s) of the latest row
        self.sample = bytearray()  # the first bytes of the current connection (to describe a stream without frames)
        self.texts: collections.deque[str] = collections.deque(maxlen=32)  # firmware log lines not shown yet
        self.notes: collections.deque[str] = collections.deque(maxlen=32)  # command answers, estimator, link notes
        self.host_decoder = StreamDecoder()  # the commands the host sent: logged, and matched to their acks
        self._sent: collections.OrderedDict[int, Command] = collections.OrderedDict()
        self.text_attitude = RecordAttitude(text_map)  # records of text telemetry that are an attitude, as rows
        self.binary = False  # binary attitude frames came (the replica's bit-exact inputs): records are only series
        self.ble = B.BleDecoder()  # BLE notifications
        self.grid = LiveGrid(ble_layout)  # → the sender's sample grid

    @classmethod
    def for_session(cls, session) -> LivePipeline:
        """A live session's: a live viewer gets every round at once, an ``.rrd`` merged batches."""
        viewer = session.viewer
        live = viewer is not None and bool(getattr(viewer, "has_viewer", True))
        pipe = cls(
            session.options.estimators,
            viewer,
            view_interval_s=VIEW_INTERVAL_S if live else RRD_ONLY_INTERVAL_S,
            file_logger=getattr(viewer, "file", None) if live else None,
            t0_unix_s=session.clock.wall0_s,
            baud=session.capture.header["baud"],
            ble_layout=B.layout_named((session.capture.header.get("extra") or {}).get("ble_layout")),
            text_map=session.options.text_map,
            line_start=bool(session.info.extra.get("line_start")),
        )
        variant = session.options.variant or (session.info.extra.get("filter") or {}).get("variant")
        if variant is not None and pipe.mahony is not None:  # --variant: the release's filter, whatever the status
            pipe.mahony.force_variant(variant)
        return pipe

    @property
    def mahony(self) -> LiveMahony | None:
        return self.estimators.mahony if self.estimators is not None else None

    def feed(self, chunks: list[tuple[bytes, float]]) -> None:
        """Decode and process chunks received at host times ``t_unix_s`` (s, Unix epoch), in stream order."""
        att: list[tuple[object, float]] = []  # attitude frames and rows not processed yet, with their chunk's time
        for data, t_unix_s in chunks:
            if len(self.sample) < SAMPLE_BYTES:
                self.sample += data[: SAMPLE_BYTES - len(self.sample)]
            self.clock.chunk(len(data), t_unix_s)
            for frame in self.decoder.feed(data):
                if isinstance(frame, F.AttitudeFrame):
                    att.append((frame, t_unix_s))
                    self.binary = self.binary or frame.exact
                    continue
                ack = ack_of_text(frame.text) if isinstance(frame, F.TextFrame) else frame  # "#ACK ..." in text mode
                if isinstance(ack, F.AckFrame):
                    self._ack(ack, self._at_frame(frame))
                    continue
                if isinstance(frame, (F.StatusFrame, F.TextFrame, F.FlightFrame)):
                    self._attitude(att)  # the rows before it first (the filter steps before a snapshot)
                if isinstance(frame, F.StatusFrame):
                    self.step_unwrap.status(int(frame.step))
                    if self.mahony is not None:
                        self.mahony.status(frame)
                    at = EventTime(float(self.clock.fw_s([int(frame.t_us)])[0]), self._host_of_frame(frame))
                    self._event("log_status", frame, at)
                    if int(frame.flags) & P.FLAG_EVENT:
                        text = f"drone: {describe_settings(frame)} from step {int(frame.step) + 1}"
                        self._note(text, at, "INFO", show=False)
                elif isinstance(frame, F.TextFrame):
                    self.health.text += 1
                    self.texts.append(frame.text)
                    self._event("log_text", frame, self._at_frame(frame))
                elif isinstance(frame, F.FlightFrame):  # at its step, from the latest row's (as ``Telemetry.fc``)
                    step, t_fw_s = self._last_row[:2] if self._last_row is not None else (0, 0.0)
                    t_fw_s += (int(frame.step) - step) * C.AHRS_PERIOD_S
                    self._event("log_flight", frame, EventTime(t_fw_s, self._host_of_frame(frame)))
                elif isinstance(frame, F.TextRecordFrame):  # text telemetry: a series a name; an attitude row too
                    self.health.count_record(frame.names)
                    row = self.text_attitude.frame(frame, self._host_of_frame(frame)) if not self.binary else None
                    for note in self.text_attitude.take_notes():
                        self._note(note, self._at_frame(frame), "INFO")
                    if row is not None:
                        att.append((row, t_unix_s))
                    self._event("log_record", frame, self._at_frame(frame))
        self._attitude(att)
        self.clock.prune(self.decoder.pending_bytes)
        self.tick()

    def _host_of_frame(self, frame) -> float:
        return float(self.clock.host_s([frame.offset + frame.nbytes - 1])[0])

    def _at(self, t_host_s: float) -> EventTime:
        """An event at ``t_host_s``: firmware time from the latest row's and the host time since (NaN before one)."""
        if self._last_row is None:
            return EventTime(math.nan, t_host_s)
        return EventTime(max(0.0, self._last_row[1] + (t_host_s - self._last_row[2])), t_host_s)

    def _at_frame(self, frame) -> EventTime:
        return self._at(self._host_of_frame(frame))

    def feed_host(self, data: bytes, t_unix_s: float) -> None:
        """Bytes the host sent to the drone at ``t_unix_s``: each command is logged and remembered for its ack."""
        for frame in self.host_decoder.feed(data):
            if isinstance(frame, F.CommandFrame):
                command = Command(int(frame.cmd), int(frame.param), float(frame.value))
                self._sent[int(frame.cmd_seq)] = command
                while len(self._sent) > 256:
                    self._sent.popitem(last=False)
                self._note(f"sent: {command.describe()}", self._at(self.clock.host_of(t_unix_s)), "DEBUG", show=False)

    def _ack(self, ack, at: EventTime) -> None:
        command = self._sent.get(int(ack.cmd_seq))
        command = command if command is not None and command.cmd == int(ack.cmd) else None
        self._note(describe_ack(command, ack), at, "INFO" if int(ack.result) == P.ACK_ACCEPTED else "WARN")

    def _note(self, text: str, at: EventTime, level: str, *, show: bool = True) -> None:
        if show:
            self.notes.append(text)
        self._event("log_event", text, at, level)

    def _event(self, name: str, *args) -> None:
        for outlet in self.outlets:
            outlet.add(event=(name, args))

    def tick(self, now_mono: float | None = None) -> None:
        for outlet in self.outlets:
            outlet.tick(now_mono)

    def flush_view(self) -> None:
        for outlet in self.outlets:
            outlet.flush()

    def _attitude(self, att: list) -> None:
        """The pending attitude frames and rows (emptied) as one batch of rows."""
        if not att:
            return
        parts = TelemetryParts()  # the frames as the bulk path's records
        for f, _ in att:
            parts.add_frame(f)
        rec = parts.attitude_records()
        step, restart = self.step_unwrap.frames([f for f, _ in att])
        t_us = rec["t_us"].astype(np.int64)
        t_host_s = self.clock.host_s(rec["offset"] + rec["nbytes"] - 1)
        a = AttitudeArrays.from_records(rec, step=step, t_fw_s=self.clock.fw_s(t_us, restart), t_host_s=t_host_s)
        rows = LiveRows(a)
        # the estimators take a row whose inputs are finite; the firmware's q may hold NaN (its filter diverged)
        all_finite = rows.finite & np.isfinite(a.thz_rad)
        all_finite &= np.where(
            a.exact, np.isfinite(a.q_wxyz).all(axis=1), np.isfinite(a.thx_rad) & np.isfinite(a.thy_rad)
        )
        h = self.health
        if h.count_bad(a.values_bad, attitude_inputs_bad(a.acc_mg, a.gyro_mdps), step, t_us):
            self.notes.append(  # the session's first bad frame; the viewer marks the step itself (log/filter)
                f"firmware values bad from step {h.first_bad_step} on (t = {h.first_bad_t_s:.3f} s): "
                "NaN or out of range, as sent (CRC-valid); the summary counts them"
            )
        # (text-mode rows: those flagged; a row of text telemetry is NaN where nothing was printed)
        h.nonfinite += int(np.count_nonzero(np.where(a.exact, ~all_finite, a.values_bad)))
        self._deliver(rows, float(att[0][1]), float(att[-1][1]))
        att.clear()

    def _deliver(self, rows: LiveRows, t_first_unix_s: float, t_last_unix_s: float) -> None:
        """Rows of any link: counted, through the estimators, to every logger."""
        a = rows.attitude
        self._last_row = (int(a.step[-1]), float(a.t_fw_s[-1]), float(a.t_host_s[-1]))
        self.health.count(len(a), t_first_unix_s, t_last_unix_s)
        if self.estimators is not None:
            for why in self.estimators.process(rows):  # an estimator disabled: one line, the session goes on
                self._note(why, EventTime(float(a.t_fw_s[-1]), float(a.t_host_s[-1])), "WARN")
        for outlet in self.outlets:
            outlet.add(rows)

    def feed_ble(self, records: list, *, final: bool = False) -> None:
        """BLE notifications ``(char id, payload, t_host_s)`` (char id None: a reconnection) → samples on one grid
        (dt from their cadence) → estimators → loggers; other frames are events. ``final``: release held rows."""
        motion = []
        for cid, payload, t_host_s in records:
            frame = None if cid is None else self.ble.feed(cid, payload, t_host_s)
            if cid is None or isinstance(frame, B.BleMotionFrame):
                motion.append(frame)
            elif isinstance(frame, B.BleConsoleFrame):  # at the latest row's time
                self.texts.append(f"[{frame.stream}] {frame.text}")
                self._event("log_text", frame, self._at(frame.t_host_s))
            elif frame is not None:
                kind = "log_environment" if isinstance(frame, B.BleEnvFrame) else "log_arming"
                self._event(kind, frame, EventTime(frame.tick * B.TICK_S, frame.t_host_s))
        self.grid.add(motion)
        a = self.grid.rows(final)
        if a is not None and len(a):
            if not self.health.attitude:  # the grid's first rows: its cadence was just found; what they are, once
                if self.estimators is not None:
                    self.estimators.use_dt(self.grid.dt_s)
                for text in link_notes(a.acc_mg, self.grid.layout):  # on the terminal too unless the stock note
                    if text != NOT_BIT_EXACT:
                        self.notes.append(text)
                    self._event("log_note", text, EventTime(float(a.t_fw_s[0]), float(a.t_host_s[0])))
            t0 = self.clock.t0_unix_s or 0.0
            mag = self.grid.mag_mgauss if not self.grid.layout.sends_attitude else None
            self._deliver(LiveRows(a, mag_mgauss=mag), t0 + float(a.t_host_s[0]), t0 + float(a.t_host_s[-1]))
        self.tick()

"""Chunks → frames → rows → estimators → viewer for one live stream, whatever the link (:class:`LivePipeline`).
The pipeline times the rows (``t_fw_s``, ``t_host_s`` on the capture's base, by ``load_telemetry``'s rules)."""

from __future__ import annotations

import collections
import math
import time
from typing import NamedTuple, Protocol

import numpy as np

from steval_link import constants as C
from steval_link.link import ble_payloads as B
from steval_link.link import frames as F
from steval_link.link import protocol as P
from steval_link.link.ble_telemetry import NOT_BIT_EXACT, LiveGrid, link_notes
from steval_link.link.commands import Command, ack_of_text, describe_ack, describe_settings
from steval_link.link.decoder import StreamDecoder
from steval_link.link.plausibility import attitude_inputs_bad
from steval_link.link.telemetry import AttitudeArrays, SeqUnwrapper, StreamClock, TelemetryParts
from steval_link.link.text_series import RecordAttitude
from steval_link.live.estimators import LiveEstimators, LiveMahony, LiveRows
from steval_link.live.health import LinkHealth

#: Bytes kept from the start of a connection to describe a stream without frames.
SAMPLE_BYTES = 4096


#: Frames go to a live viewer every processing round (latency goal p99 <= 5 ms, ``bench_live_latency.py``) ...
VIEW_INTERVAL_S = 0.0
#: ... and to an ``.rrd`` (its own stream, merged batches: about one chunk per entity) at most this often, s.
RRD_ONLY_INTERVAL_S = 0.5
#: An ``.rrd``'s batch holds at most this much stream time, s (a stream fed faster than real time).
RRD_BATCH_MAX_STREAM_S = 30.0


class EventTime(NamedTuple):
    """When a frame or a note happened: firmware s since boot (NaN before the first row), host s since capture start."""

    t_fw_s: float
    t_host_s: float


class LiveViewer(Protocol):
    """What a live session logs to (``steval_viewer.live_adapter.ViewerLogger``, a test's fake). Optional, used when
    present: ``has_viewer``, ``file`` (the ``.rrd``'s own LiveViewer), ``log_flight``, ``log_record``,
    ``log_environment``, ``log_arming`` and ``log_note`` (each ``(frame, at)``)."""

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
        out = np.empty(len(frames), dtype=np.int64)
        restart = np.zeros(len(frames), dtype=bool)
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
    """One logger fed merged rows at its own cadence: batches wait at most ``interval_s`` (monotonic) or
    ``max_stream_s`` (else ``interval_s``) × 161.5 rows of stream; events follow the merged batch in stream order."""

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
        if not (self._batches or self._events):
            return
        rows = sum(map(len, self._batches))
        if rows >= self.max_rows or (now_mono or time.monotonic()) - self._since >= self.interval_s:
            self.flush()

    def flush(self) -> None:
        if self._batches:
            batch = LiveRows.concat(self._batches)
            self._batches = []
            self.logger.log_batch(batch)
        events, self._events = self._events, []
        for name, args in events:
            log = getattr(self.logger, name, None)
            if log is not None:
                log(*args)


class LivePipeline:
    """Bytes → frames → estimators → viewer, in the session's main thread: each round's attitude frames become one
    :class:`LiveRows`; other frames are events at their :class:`EventTime`. ``view_interval_s``: batches go to the
    viewer merged at most this often (fewer, larger batches keep Rerun's memory flat); ``file_logger``: the
    ``.rrd``'s own, at ``file_interval_s``. Call :meth:`tick` regularly and :meth:`flush_view` at the end."""

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
        self.ble, self.grid = B.BleDecoder(), LiveGrid(ble_layout)  # BLE notifications → the sender's sample grid

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
        clock = self.clock
        for data, t_unix_s in chunks:
            if len(self.sample) < SAMPLE_BYTES:
                self.sample += data[: SAMPLE_BYTES - len(self.sample)]
            clock.chunk(len(data), t_unix_s)
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
                    at = EventTime(float(clock.fw_s([int(frame.t_us)])[0]), self._host_of_frame(frame))
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
        clock.prune(self.decoder.pending_bytes)
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
        self.health.nonfinite += int(np.count_nonzero(np.where(a.exact, ~all_finite, a.values_bad)))
        self._deliver(rows, float(att[0][1]), float(att[-1][1]))
        att.clear()

    def _deliver(self, rows: LiveRows, t_first_unix_s: float, t_last_unix_s: float) -> None:
        """Rows of any link: counted, through the estimators, to every logger."""
        a = rows.attitude
        self._last_row = (int(a.step[-1]), float(a.t_fw_s[-1]), float(a.t_host_s[-1]))
        self.health.count(len(a), t_first_unix_s, t_last_unix_s)
        if self.estimators is not None:
            self.estimators.process(rows)
            for why in self.estimators.notes:  # an estimator disabled: one line, the session goes on
                self._note(why, EventTime(float(a.t_fw_s[-1]), float(a.t_host_s[-1])), "WARN")
            self.estimators.notes.clear()
        for outlet in self.outlets:
            outlet.add(rows)

    def feed_ble(self, records: list, *, final: bool = False) -> None:
        """BLE notifications ``(char id, payload, t_host_s)`` (char id None: the link was lost and found again) →
        the sender's samples on one grid (dt from their cadence) → estimators → loggers; other frames are events.
        ``final``: the stream ended (rows held back for the cadence go out)."""
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

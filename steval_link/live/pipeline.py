"""Chunks → frames → rows → estimators → viewer for one live stream, whatever the link (:class:`LivePipeline`: serial
bytes, BLE notifications), each viewer fed merged rows at its own cadence (:class:`BatchOutlet`); AHRS step numbers
from the 16-bit ``seq`` (:class:`StepUnwrapper`).

The pipeline owns the rows' times: ``t_fw_s`` and ``t_host_s`` on the capture's base, by the rules (and the code,
:mod:`steval_link.link.unwrap`) of ``load_telemetry``; a viewer logs the times it is given.
"""

from __future__ import annotations

import collections
import math
import time
import typing
from typing import NamedTuple

import numpy as np

from steval_link import constants as C
from steval_link.link import protocol as P
from steval_link.link.ble_payloads import (
    LAYOUTS,
    BleConsoleFrame,
    BleDecoder,
    BleEnvFrame,
    BleLayout,
    BleMotionFrame,
    layout_named,
)
from steval_link.link.ble_payloads import TICK_S as BLE_TICK_S
from steval_link.link.ble_telemetry import NOT_BIT_EXACT, LiveGrid, link_notes
from steval_link.link.commands import Command, ack_of_text, describe_ack, describe_settings
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import (
    AckFrame,
    AttitudeFrame,
    CommandFrame,
    FlightFrame,
    StatusFrame,
    TextFrame,
    TextRecordFrame,
)
from steval_link.link.plausibility import attitude_inputs_bad
from steval_link.link.telemetry import AttitudeArrays, TelemetryParts
from steval_link.link.text_series import RecordAttitude
from steval_link.link.unwrap import SeqUnwrapper, StreamClock
from steval_link.live.estimators import LiveEstimators, LiveMahony, LiveRows
from steval_link.live.health import LinkHealth

#: Bytes kept from the start of a connection to describe a stream without frames.
SAMPLE_BYTES = 4096


#: Frames go to a live viewer as soon as they are decoded (every processing round: latency goal p99 <= 5 ms,
#: ``benchmarks/bench_live_latency.py``; a viewer over gRPC costs this process no memory per chunk) ...
VIEW_INTERVAL_S = 0.0


#: ... and to an ``.rrd`` at most this often, or once this much stream time waits (with a live viewer too, the file
#: has its own stream of the same recording, fed these merged batches). The file is written as the data arrives
#: (``steval_viewer.rrd_writer``: appended and synced within a second), so a ``kill -9`` loses at most about a
#: second of it; each batch is about one chunk per entity (~25).
RRD_ONLY_INTERVAL_S = 0.5
#: An ``.rrd``'s batch holds at most this much stream time, s: a stream fed faster than real time (a replay at
#: ``?speed=40``, catching up) makes few large chunks, not one small batch per processing round.
RRD_BATCH_MAX_STREAM_S = 30.0


class EventTime(NamedTuple):
    """When a frame or a note (not an attitude row) happened: firmware s since boot (of a text line or a note:
    estimated from the latest row, NaN before the first) and host s since capture start."""

    t_fw_s: float
    t_host_s: float


class LiveViewer(typing.Protocol):
    """What a live session logs to: the Rerun side (``steval_viewer.live_adapter.ViewerLogger``) or a test's fake.

    Rows and events come timed (:class:`~steval_link.live.estimators.LiveRows`, :class:`EventTime`); ``log_link``
    gets the session's Unix time, only to pace itself. Optional attributes, read when present: ``has_viewer`` (a
    viewer gets the stream, not only an ``.rrd``: then every processing round goes out at once) and ``file`` (the
    ``.rrd``'s own LiveViewer next to a live viewer, fed merged rows), ``log_flight(frame, at)``,
    ``log_record(frame, at)`` (a record of text telemetry) and a BLE link's ``log_environment(frame, at)``,
    ``log_arming(frame, at)``, ``log_note(text, at)``.
    """

    def log_batch(self, batch: LiveRows) -> None: ...

    def log_status(self, frame, at: EventTime) -> None: ...

    def log_text(self, frame, at: EventTime) -> None: ...

    def log_link(self, stats, t_unix_s: float) -> None: ...

    def log_event(self, text: str, at: EventTime, level: str) -> None: ...

    def close(self) -> None: ...


class StepUnwrapper:
    """Full AHRS step numbers of live attitude frames: a text-mode frame carries its step, a binary frame's u16
    ``seq`` goes through :class:`~steval_link.link.unwrap.SeqUnwrapper` (the bulk decoder's rule: a repeated seq
    is the same step, a step back a firmware restart), and status frames give the full step back."""

    def __init__(self) -> None:
        self.seq = SeqUnwrapper()

    def frames(self, frames) -> tuple[np.ndarray, np.ndarray]:
        """(steps (N,) int64, restart (N,) bool: a binary frame that begins a new firmware run) of these attitude
        frames, in order."""
        out = np.empty(len(frames), dtype=np.int64)
        restart = np.zeros(len(frames), dtype=bool)
        run: list[int] = []  # indexes of the current run of binary frames
        for i, f in enumerate(frames):
            if f.step is None:
                run.append(i)
                continue
            self._binary(frames, run, out, restart)
            run = []
            out[i] = self.seq.last = int(f.step)
        self._binary(frames, run, out, restart)
        return out, restart

    def _binary(self, frames, run: list[int], out: np.ndarray, restart: np.ndarray) -> None:
        if run:
            out[run], restart[run] = self.seq.steps(np.array([int(frames[i].seq) for i in run], dtype=np.int64))

    def status(self, step: int) -> None:
        """A status frame describes the step of the attitude frame just before it: take its full number."""
        self.seq.status(step)


class BatchOutlet:
    """One logger fed merged rows at its own cadence (see :class:`LivePipeline`).

    ``logger`` takes ``log_batch(rows)``, ``log_status(frame, at)`` and ``log_text(frame, at)``.
    Batches wait at most ``interval_s`` (monotonic wall time) or ``interval_s`` × 161.5 frames of stream time (a
    stream fed faster than real time, e.g. catching up or a benchmark, still makes chunks of the same size).
    """

    def __init__(self, logger, interval_s: float, max_stream_s: float | None = None) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self.max_rows = max(1, math.ceil((interval_s if max_stream_s is None else max_stream_s) * C.AHRS_RATE_HZ))
        self._batches: list[LiveRows] = []
        self._rows = 0
        self._events: list[tuple[str, object, EventTime]] = []  # ("status" | "text" | ..., frame, when)
        self._since = 0.0  # monotonic time the oldest pending item came

    def _touch(self) -> None:
        if not self._batches and not self._events:
            self._since = time.monotonic()

    def add_batch(self, batch: LiveRows) -> None:
        self._touch()
        self._batches.append(batch)
        self._rows += len(batch)

    def add_event(self, kind: str, frame, at: EventTime) -> None:
        self._touch()
        self._events.append((kind, frame, at))

    def tick(self, now_mono: float | None = None) -> None:
        """Flush when the pending frames have waited ``interval_s`` or fill ``max_rows``."""
        if not (self._batches or self._events):
            return
        if self._rows >= self.max_rows or (now_mono or time.monotonic()) - self._since >= self.interval_s:
            self.flush()

    def flush(self) -> None:
        """Log every pending frame now: one merged batch, then the status and text frames in stream order."""
        if self._batches:
            batch = LiveRows.concat(self._batches)
            self._batches = []
            self._rows = 0
            self.logger.log_batch(batch)
        if self._events:
            events, self._events = self._events, []
            for kind, frame, at in events:  # log_status, log_text; log_flight, log_event where present
                log = getattr(self.logger, "log_" + kind, None)
                if log is not None:  # an "event" is (text, level): a command sent or answered
                    log(frame[0], at, frame[1]) if kind == "event" else log(frame, at)


class LivePipeline:
    """Bytes → frames → estimators → viewer, for one live stream (runs in the session's main thread).

    ``feed([(bytes, t_unix_s), ...])`` decodes the chunks in order and, per processing round, turns the
    attitude frames into one :class:`~steval_link.live.estimators.LiveRows` (``AttitudeArrays`` with ``t_fw_s``
    and ``t_host_s`` as ``load_telemetry`` of the capture has them: ``t0_unix_s`` and ``baud`` are its header's
    ``start_time_unix_s`` and ``baud``) that goes through :class:`LiveEstimators` and then to ``viewer.log_batch``
    (status and text frames are logged in stream order between batches, at their :class:`EventTime`). Counters are in
    ``decoder.stats`` and ``health``. Memory is bounded: nothing per frame is kept beyond one view interval.

    ``view_interval_s``: batches are handed to the viewer at most this often, or once that much stream time
    (``view_interval_s`` × 161.5 frames) waits (merged; the status and text frames
    that came meanwhile follow the merged batch, in stream order, and are timed by their own firmware time, so
    they never cut a batch): every Rerun log call costs a chunk per entity, and Rerun keeps some memory per chunk
    for the whole recording (the ``.rrd`` footer), so fewer, larger batches keep memory flat.

    ``text_map``: which series of text telemetry are the attitude ({target: (series, unit)},
    :func:`~steval_link.link.text_series.parse_map`; names and ST's format are mapped without it). ``line_start``:
    the stream's first byte starts a line (the replay of a log), so its first line is read whole.

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
        t0_unix_s: float | None = None,
        baud: int | None = None,
        ble_layout: BleLayout = LAYOUTS["stock"],
        text_map: dict[str, tuple[str, str]] | None = None,
        line_start: bool = False,
    ) -> None:

        self.view_interval_s = view_interval_s
        #: the loggers, each with its own cadence (the viewer first)
        self.outlets = [
            BatchOutlet(logger, interval_s, RRD_BATCH_MAX_STREAM_S if interval_s == RRD_ONLY_INTERVAL_S else None)
            for logger, interval_s in ((viewer, view_interval_s), (file_logger, file_interval_s))
            if logger is not None
        ]
        self.decoder = StreamDecoder(line_start=line_start)
        self.health = LinkHealth()
        self.estimators = LiveEstimators(estimator_names) if estimator_names else None
        self.viewer = viewer
        self.file_logger = file_logger
        self.step_unwrap = StepUnwrapper()
        #: the rows' firmware and host times (the capture's base)
        self.clock = StreamClock(t0_unix_s, baud)
        self._last_row: tuple[int, float, float] | None = None  # (step, t_fw_s, t_host_s) of the latest row
        #: the first bytes of the current connection (to describe a stream without frames)
        self.sample = bytearray()
        #: firmware log lines not shown yet (the session prints them; bounded)
        self.texts: collections.deque[str] = collections.deque(maxlen=32)
        #: commands sent and their answers, one sentence each, not shown yet (the session prints them; bounded)
        self.notes: collections.deque[str] = collections.deque(maxlen=32)
        #: the host's own bytes (commands it sent), decoded to log them and to match the acknowledgements
        self.host_decoder = StreamDecoder()
        #: records of text telemetry that are an attitude (ST's line, pitch/roll, acc/gyro names) as attitude rows
        self.text_attitude = RecordAttitude(text_map)
        self._binary = False  # binary attitude frames came: they are the attitude, records are only series
        self._sent: collections.OrderedDict[int, Command] = collections.OrderedDict()
        self.acks = 0
        #: BLE notifications: their decoder and the grid of the sender's samples (made by the first one)
        self.ble_layout = ble_layout
        self.ble: BleDecoder | None = None
        self.grid: LiveGrid | None = None
        self._ble_dt_set = False
        self._ble_noted = False

    @classmethod
    def for_session(cls, session) -> LivePipeline:
        """The pipeline of a live session (:class:`~steval_link.live.session.LiveSession`): its estimators and
        viewer side, times on its capture's base (``t0_unix_s``, ``baud``: see the class). A live viewer gets every
        processing round at once and its ``.rrd`` (the viewer's ``file``) merged batches every RRD_ONLY_INTERVAL_S;
        a viewer side that writes only an ``.rrd`` (``has_viewer`` false: headless ``--rrd X``) gets merged batches
        too."""
        viewer = session.viewer
        live = viewer is not None and bool(getattr(viewer, "has_viewer", True))
        pipe = cls(
            session.options.estimators,
            viewer,
            view_interval_s=VIEW_INTERVAL_S if live else RRD_ONLY_INTERVAL_S,
            file_logger=getattr(viewer, "file", None) if live else None,
            file_interval_s=RRD_ONLY_INTERVAL_S,
            t0_unix_s=session.clock.wall0_s,
            baud=session.capture.header["baud"],
            ble_layout=layout_named((session.capture.header.get("extra") or {}).get("ble_layout")),
            text_map=getattr(session.options, "text_map", None),
            line_start=bool(session.info.extra.get("line_start")),
        )
        variant = getattr(session.options, "variant", None) or (session.info.extra.get("filter") or {}).get("variant")
        if variant is not None and pipe.mahony is not None:  # --variant: the release's filter, whatever the status
            pipe.mahony.force_variant(variant)
        return pipe

    @property
    def binary(self) -> bool:
        """Binary attitude frames came (the replica's bit-exact inputs); text rows alone are not."""
        return self._binary

    @property
    def mahony(self) -> LiveMahony | None:
        """The ST Mahony filter followed live (None when ``st-mahony`` is not among the estimators)."""
        return self.estimators.mahony if self.estimators is not None else None

    def feed(self, chunks: list[tuple[bytes, float]]) -> None:
        """Decode and process chunks received at host times ``t_unix_s`` (s, Unix epoch), in stream order."""

        outlets = self.outlets
        att: list[tuple[object, float]] = []
        clock = self.clock
        for data, t_unix_s in chunks:
            if len(self.sample) < SAMPLE_BYTES:
                self.sample += data[: SAMPLE_BYTES - len(self.sample)]
            clock.chunk(len(data), t_unix_s)
            for frame in self.decoder.feed(data):
                if isinstance(frame, AttitudeFrame):
                    att.append((frame, t_unix_s))
                    self._binary = self._binary or frame.exact
                elif isinstance(frame, StatusFrame):
                    self._attitude(att)  # the filter must step through the frames before the snapshot
                    att = []
                    self.health.status += 1
                    self.step_unwrap.status(int(frame.step))
                    # its t_us goes through the unwrapper in stream order, as in Telemetry
                    t_fw_s = float(clock.fw_s([int(frame.t_us)])[0])
                    if self.estimators is not None:
                        self.estimators.status(frame)
                    if outlets:
                        self._event("status", frame, EventTime(t_fw_s, self._host_of_frame(frame)))
                    if int(frame.flags) & P.FLAG_EVENT:
                        self._note(
                            f"drone: {describe_settings(frame)} from step {int(frame.step) + 1}",
                            t_unix_s,
                            "INFO",
                            show=False,
                        )
                elif isinstance(frame, AckFrame) or (
                    isinstance(frame, TextFrame)
                    and frame.text.startswith("#ACK")
                    and ack_of_text(frame.text) is not None
                ):
                    self._ack(frame if isinstance(frame, AckFrame) else ack_of_text(frame.text), self._at_frame(frame))
                elif isinstance(frame, TextFrame):
                    self._attitude(att)
                    att = []
                    self.health.text += 1
                    self.health.last_text = frame.text
                    self.texts.append(frame.text)
                    if outlets:
                        self._event("text", frame, self._at_frame(frame))
                elif isinstance(frame, FlightFrame) and outlets:
                    self._attitude(att)  # its step's attitude frame first
                    att = []
                    self._event("flight", frame, self._at_flight(frame))
                elif isinstance(frame, TextRecordFrame):  # text telemetry: a series a name; an attitude row too
                    self.health.count_record(frame.names)
                    row = self.text_attitude.frame(frame, self._host_of_frame(frame)) if not self._binary else None
                    for note in self.text_attitude.take_notes():
                        self._note(note, self._at_frame(frame), "INFO")
                    if row is not None:
                        att.append((row, t_unix_s))
                    if outlets:
                        self._event("record", frame, self._at_frame(frame))
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

    def _at_flight(self, frame) -> EventTime:
        """A flight-control frame: the time of its step from the latest attitude row's (as ``Telemetry.fc``)."""
        step, t_fw_s = self._last_row[:2] if self._last_row is not None else (0, 0.0)
        return EventTime(t_fw_s + (int(frame.step) - step) * C.AHRS_PERIOD_S, self._host_of_frame(frame))

    def feed_host(self, data: bytes, t_unix_s: float) -> None:
        """Bytes the host sent to the drone at ``t_unix_s``: each command is logged and remembered for its ack."""
        for frame in self.host_decoder.feed(data):
            if isinstance(frame, CommandFrame):
                command = Command(int(frame.cmd), int(frame.param), float(frame.value))
                self._sent[int(frame.cmd_seq)] = command
                while len(self._sent) > 256:
                    self._sent.popitem(last=False)
                self._note(f"sent: {command.describe()}", self._at_unix(t_unix_s), "DEBUG", show=False)

    def _at_unix(self, t_unix_s: float) -> EventTime:
        return self._at(self.clock.host_of(t_unix_s))

    def _ack(self, ack, at: EventTime) -> None:
        self.acks += 1
        command = self._sent.get(int(ack.cmd_seq))
        if command is not None and command.cmd != int(ack.cmd):
            command = None
        self._note(describe_ack(command, ack), at, "INFO" if int(ack.result) == P.ACK_ACCEPTED else "WARN")

    def _note(self, text: str, at: EventTime, level: str, *, show: bool = True) -> None:
        if show:
            self.notes.append(text)
        if self.outlets:
            self._event("event", (text, level), at)

    def _event(self, kind: str, frame, at: EventTime) -> None:
        for outlet in self.outlets:
            outlet.add_event(kind, frame, at)

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
        if self.health.count_bad(a.values_bad, attitude_inputs_bad(a.acc_mg, a.gyro_mdps), step, t_us):
            i = int(np.argmax(a.values_bad))  # a note on the terminal; the viewer marks the step itself (log/filter)
            self.notes.append(
                f"firmware values bad from step {int(step[i])} on (t = {int(t_us[i]) / 1e6:.3f} s): "
                "NaN or out of range, as sent (CRC-valid); the summary counts them"
            )
        # (text-mode rows: those flagged; a row of text telemetry is NaN where nothing was printed)
        self.health.nonfinite += int(np.count_nonzero(np.where(a.exact, ~all_finite, a.values_bad)))
        self._deliver(rows, float(att[0][1]), float(att[-1][1]))

    def _deliver(self, rows: LiveRows, t_first_unix_s: float, t_last_unix_s: float) -> None:
        """Rows of any link: counted, through the estimators, to every logger."""
        a = rows.attitude
        self._last_row = (int(a.step[-1]), float(a.t_fw_s[-1]), float(a.t_host_s[-1]))
        self.health.count(len(a), t_first_unix_s, t_last_unix_s)
        if self.estimators is not None:
            self.estimators.process(rows)
            for why in self.estimators.take_notes():  # an estimator disabled: one line, the session goes on
                self._note(why, EventTime(float(a.t_fw_s[-1]), float(a.t_host_s[-1])), "WARN")
        for outlet in self.outlets:
            outlet.add_batch(rows)

    # -- BLE notifications --------------------------------------------------------------------------------------

    def feed_ble(self, records: list, *, final: bool = False) -> None:
        """BLE notifications ``(char id, payload, t_host_s)`` (s since the capture started; char id None: the link
        was lost and found again) → frames (:class:`BleDecoder`) → the sender's samples on one grid
        (:class:`LiveGrid`: dt from their cadence) → estimators → loggers; environment, arming and console frames
        are events at their tick. ``final``: the stream ended (rows held back for the cadence go out)."""
        if self.ble is None:
            self.ble, self.grid = BleDecoder(), LiveGrid(self.ble_layout)
        motion = []
        for cid, payload, t_host_s in records:
            frame = None if cid is None else self.ble.feed(cid, payload, t_host_s)
            if cid is None or isinstance(frame, BleMotionFrame):
                motion.append(frame)
            elif frame is not None:
                self._ble_event(frame)
        self.grid.add(motion)
        a = self.grid.rows(final)
        if a is not None and len(a):
            if self.estimators is not None and not self._ble_dt_set:  # the cadence was just found
                self.estimators.use_dt(self.grid.dt_s)
                self._ble_dt_set = True
            if not self._ble_noted:
                self._ble_notes(a)
            t0 = self.clock.t0_unix_s or 0.0
            mag = self.grid.mag_mgauss if not self.ble_layout.sends_attitude else None
            self._deliver(LiveRows(a, mag_mgauss=mag), t0 + float(a.t_host_s[0]), t0 + float(a.t_host_s[-1]))
        self.tick()

    def _ble_notes(self, a: AttitudeArrays) -> None:
        """What the BLE rows are, once (to every logger; on the terminal too when it is not the stock note)."""
        self._ble_noted = True
        for text in link_notes(a.acc_mg, self.ble_layout):
            if text != NOT_BIT_EXACT:
                self.notes.append(text)
            if self.outlets:
                self._event("note", text, EventTime(float(a.t_fw_s[0]), float(a.t_host_s[0])))

    def _ble_event(self, frame) -> None:
        """An environment, arming or console frame: an event at its tick (console: at the latest row's time)."""
        if isinstance(frame, BleConsoleFrame):
            self.texts.append(f"[{frame.stream}] {frame.text}")
            kind, at = "text", self._at(frame.t_host_s)
        else:
            kind = "environment" if isinstance(frame, BleEnvFrame) else "arming"
            at = EventTime(frame.tick * BLE_TICK_S, frame.t_host_s)
        if self.outlets:
            self._event(kind, frame, at)

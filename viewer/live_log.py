"""Low-latency logging of a live session: each batch of frames that arrived together is logged at once.

The live session (``steval_link.live``) decodes the serial bytes and calls, in arrival order::

    logger = LiveLogger(session.rec, estimator_names=["st-mahony", "accel", "ekf3"])
    logger.log_batch(batch)              # an AttitudeBatch: arrays of N frames + their estimates
    logger.log_status(frame, t_unix_s)   # a StatusFrame
    logger.log_text(frame, t_unix_s)     # a TextFrame
    logger.log_link(stats, t_unix_s)     # DecoderStats (CRC failures), at most every LINK_INTERVAL_S is logged
    logger.close()

Attitude rows are not held back: ``log_batch`` sends them with one Arrow record batch (one chunk per entity)
before it returns (the per-call cost is per entity, not per sample, so a batch of 1 or of 50 frames costs about the
same). Status and link rows (about 1 Hz) are queued and sent with the next batch, one chunk per entity, and on
``close()``: an ``.rrd`` sink keeps memory per chunk until the file closes. Status rows are timed by their own
``t_us``, so the session need not cut a batch at a status frame. The entity
layout is the replay's (:mod:`steval_viewer.entities`), the blueprint the live one (10 s scrolling window on
``host_time``). ``host_time`` is seconds since the first logged frame (Unix-epoch inputs are converted);
``fw_time`` is the firmware's ``t_us`` unwrapped across its 2³² µs wrap.

With a live viewer and an ``.rrd`` the session runs two loggers, one per stream of the same recording
(``sinks.open_session(..., split_file=True)``): the viewer's gets every round, the file's merged batches and
``t0_from=`` the viewer's logger, so ``host_time`` agrees between them.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping

import numpy as np
import rerun as rr

from steval_link import constants as C
from steval_link.estimators.st_mahony import quaternion_to_euler
from steval_link.link.plausibility import attitude_rows_bad
from steval_link.link.protocol import SEQ_MODULUS
from steval_link.link.unwrap import TimeUnwrapper
from steval_viewer import blueprint as bp
from steval_viewer import entities as ent
from steval_viewer import flight_log, scene
from steval_viewer.columns import Times, quaternion_from_euler, send_rows, send_scalars
from steval_viewer.record_batch import RowBatch
from steval_viewer.replay_log import values_bad_note

#: The live 3D view (drone attitudes, gravity arrow) is updated at most this often per second, with the newest
#: frame of a batch: the view shows only the latest attitude, and this keeps the per-frame cost down. Plots get
#: every frame. (The capture keeps everything; ``steval replay`` logs every frame's attitude.)
LIVE_3D_MAX_HZ = 60.0

#: The live path logs link counters (CRC failures) at most this often, s.
LINK_INTERVAL_S = 0.5

#: Estimator names of the live session that mean the bit-exact firmware port.
PORT_NAMES = ("st-mahony", "st_mahony", "st-mahony-port", "st_mahony_port")


def live_source(name: str) -> str:
    """Entity segment of a live estimate name (the seeded ST port -> ``st_mahony_port``, as in replays)."""
    return ent.SOURCE_PORT if name in PORT_NAMES else ent.source_name(name)


class LiveLogger:
    """Logs a live session to a RecordingStream, batch by batch.

    ``rec``: the recording (``sinks.open_session(...).rec``). ``estimator_names``: the names the session will put
    in ``batch.estimates`` (known up front so the blueprint and the series styles are sent once). ``ghost``: which
    estimate the 3D ghost shows (default: the ST port, else EKF3...). ``t0_host_s``: host time origin (default:
    the first frame's host time). ``t0_from``: another LiveLogger of the same recording whose origin this one takes
    when it has one (a live session's ``.rrd`` stream follows its viewer stream, so both share ``host_time``).
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        estimator_names: Iterable[str] = (),
        *,
        ghost: str | None = None,
        t0_host_s: float | None = None,
        blueprint: bool = True,
        t0_from: "LiveLogger | None" = None,
    ) -> None:
        self.rec = rec
        self.t0_from = t0_from
        self.sources = {name: live_source(name) for name in estimator_names}
        segs = list(dict.fromkeys(self.sources.values()))
        if blueprint:
            bp.send_blueprint(
                rec,
                live=True,
                ghost_sources=segs,
                ghost=None if ghost is None else live_source(ghost),
                flight_control=True,
            )
        scene.log_static(rec, segs, with_port=ent.SOURCE_PORT in segs)
        flight_log.log_flight_static(rec)
        self._last_motors_fw = -math.inf  # fw time of the last motor-arrow update
        self.t0_host_s = t0_host_s
        self.fw_clock = TimeUnwrapper()
        self.frames = 0
        self.frames_missing = 0
        self._last_step: int | None = None
        self._bin_start: float | None = None  # host s of the current 1 s frame-rate bin
        self._bin_count = 0
        self._last_link_s = -math.inf
        self._last_times: tuple[float, float] | None = None  # (fw, host) of the latest frame
        self._bad: dict[str, bool] = {}  # entity path -> its last row was a gap
        self._last_3d_s = -math.inf  # fw time of the last 3D update
        self._arrow_cache: dict = {}  # Arrow fields/offsets reused by every batch
        self._values_bad_noted = False  # the first frame with NaN/out-of-range values has its note
        self._last_good_step: int | None = None  # step of the latest frame without bad values
        #: link/status rows waiting for the next batch: path -> [(fw s, host s, values)], sent as one chunk per
        #: entity with the batch (or on :meth:`close`); every Rerun log call is a chunk that an .rrd sink keeps
        #: some memory for, so fewer calls keep a long session's memory flat
        self._pending_rows: dict[str, list[tuple[float, float, tuple[float, ...]]]] = {}

    # -- time ------------------------------------------------------------------------------------------------
    def _host(self, t_unix_s: np.ndarray) -> np.ndarray:
        t = np.asarray(t_unix_s, dtype=np.float64)
        if self.t0_host_s is None and self.t0_from is not None:
            self.t0_host_s = self.t0_from.t0_host_s
        if self.t0_host_s is None:
            finite = t[np.isfinite(t)]
            if finite.size:
                self.t0_host_s = float(finite[0])
        return t - (self.t0_host_s if self.t0_host_s is not None else 0.0)

    def _scalar_times(self, t_unix_s: float) -> Times | None:
        """Times for an event at host time ``t_unix_s``: fw time estimated from the latest frame (the host time
        elapsed since it, or before it: events are logged after the batch they arrived within)."""
        host = float(self._host(np.array([t_unix_s]))[0])
        if self._last_times is None:
            return None
        fw_last, host_last = self._last_times
        return Times(np.array([max(0.0, fw_last + (host - host_last))]), np.array([host]))

    # -- frames ----------------------------------------------------------------------------------------------
    def log_batch(self, batch: Any) -> None:
        """Log N attitude frames that arrived together (an ``AttitudeBatch``: ``step``, ``t_us``, ``t_unix_s``,
        ``acc_mg``, ``gyro_mdps``, ``q_wxyz``, ``thz_rad``, ``thr``, ``estimates`` name -> (N, 4) q_wxyz with NaN
        where undefined; optionally ``exact`` with ``thx_rad``/``thy_rad`` for text-mode rows, which have no q).
        Non-finite values are gaps, never plotted."""
        n = len(batch.step)
        if n == 0:
            return
        rec = self.rec
        step = np.asarray(batch.step, dtype=np.int64)
        times = Times(self.fw_clock.seconds(batch.t_us), self._host(batch.t_unix_s), step)
        q = np.asarray(batch.q_wxyz, dtype=np.float32)
        thx, thy = quaternion_to_euler(q)
        exact = getattr(batch, "exact", None)
        if exact is not None and not np.all(exact):
            # text-mode rows carry no q: their (rounded) angles come with the row
            rows = ~np.asarray(exact, dtype=bool)
            thx[rows] = np.asarray(batch.thx_rad, dtype=np.float32)[rows]
            thy[rows] = np.asarray(batch.thy_rad, dtype=np.float32)[rows]
            q = q.astype(np.float64)
            q[rows] = quaternion_from_euler(thx[rows], thy[rows], np.asarray(batch.thz_rad)[rows])
        acc = np.asarray(batch.acc_mg, dtype=np.float64)
        bad = attitude_rows_bad(
            exact if exact is not None else np.ones(n, bool),
            batch.acc_mg,
            batch.gyro_mdps,
            batch.q_wxyz,
            batch.thz_rad,
            getattr(batch, "thx_rad", thx),
            getattr(batch, "thy_rad", thy),
        )
        q3d = q
        if bad.any():  # the firmware's filter output is NaN or off range: the 3D drone stays where it was
            q3d = np.where(bad[:, None], np.nan, q)
            if not self._values_bad_noted:
                self._values_bad_noted = True
                i = int(np.argmax(bad))
                sentence = (
                    f"the firmware's values are NaN or out of range from step {int(step[i])} on "
                    f"(t = {float(times.t_fw_s[i]):.3f} s), as sent"
                )
                text = values_bad_note(sentence, self._good_before(step, bad, i))
                send_rows(
                    rec,
                    ent.LOG_FILTER,
                    times.take(np.array([i])),
                    lambda sel: rr.TextLog.columns(text=[text], level=["WARN"]),
                )
        good_rows = np.flatnonzero(~bad)
        if good_rows.size:
            self._last_good_step = int(step[good_rows[-1]])

        # 3D entities show only the latest attitude: at most LIVE_3D_MAX_HZ updates (the batch's last row)
        t_last = float(times.t_fw_s[-1])
        do3d = not (0.0 <= t_last - self._last_3d_s < 1.0 / LIVE_3D_MAX_HZ)
        sel3d = None
        if do3d:
            self._last_3d_s = t_last
            sel3d = np.zeros(n, dtype=bool)
            sel3d[-1] = True
        rb = RowBatch(times, self._bad, self._arrow_cache)
        if do3d:
            sel_fw = sel3d
            if bad[-1]:  # the drone: the batch's last frame without bad values, if any
                sel_fw = np.zeros(n, dtype=bool)
                sel_fw[good_rows[-1:]] = True
            rb.quaternions(ent.DRONE_FIRMWARE, q3d, sel_fw)
            with np.errstate(invalid="ignore"):
                rb.vectors(ent.ACC_GRAVITY, -acc / 1000.0, sel3d)
        rb.scalars(ent.pitch_path(ent.SOURCE_FIRMWARE), np.degrees(thx.astype(np.float64)))
        rb.scalars(ent.roll_path(ent.SOURCE_FIRMWARE), np.degrees(thy.astype(np.float64)))
        rb.scalars(ent.yaw_path(ent.SOURCE_FIRMWARE), np.degrees(np.asarray(batch.thz_rad, np.float64)))
        rb.scalars(ent.PLOT_ACC, acc)
        rb.scalars(ent.PLOT_GYRO, np.asarray(batch.gyro_mdps, dtype=np.float64) / 1000.0)
        rb.scalars(ent.PLOT_THROTTLE, np.asarray(batch.thr, dtype=np.float64))

        estimates: Mapping[str, np.ndarray] = getattr(batch, "estimates", None) or {}
        for name, eq in estimates.items():
            source = self.sources.get(name) or live_source(name)
            eq = np.asarray(eq).reshape(n, 4)
            ex, ey = quaternion_to_euler(eq.astype(np.float32))
            if do3d:
                rb.quaternions(ent.estimate_path(source), eq, sel3d)
            rb.scalars(ent.pitch_path(source), np.degrees(ex.astype(np.float64)))
            rb.scalars(ent.roll_path(source), np.degrees(ey.astype(np.float64)))
            if source == ent.SOURCE_PORT:
                rb.scalars(ent.DIFF_THX, np.degrees(thx.astype(np.float64) - ex))
                rb.scalars(ent.DIFF_THY, np.degrees(thy.astype(np.float64) - ey))
        rb.send(rec)

        self.frames += n
        self._last_times = (float(times.t_fw_s[-1]), float(times.t_host_s[-1]) if times.t_host_s is not None else 0.0)
        self._link_from_frames(times, step)
        self.flush_rows()

    def _good_before(self, step: np.ndarray, bad: np.ndarray, i: int) -> int | None:
        """Step of the last row before row ``i`` of this batch without bad values (else of an earlier batch)."""
        good = np.flatnonzero(~bad[:i])
        return int(step[good[-1]]) if good.size else self._last_good_step

    def _queue_row(self, path: str, t_fw_s: float, t_host_s: float, values) -> None:
        self._pending_rows.setdefault(path, []).append((t_fw_s, t_host_s, tuple(float(v) for v in values)))

    def flush_rows(self) -> None:
        """Send the queued link/status rows: one ``send_columns`` per entity (rows in time order)."""
        if not self._pending_rows:
            return
        pending, self._pending_rows = self._pending_rows, {}
        for path, rows in pending.items():
            rows.sort(key=lambda r: r[0])
            t_fw = np.array([r[0] for r in rows], dtype=np.float64)
            t_host = np.array([r[1] for r in rows], dtype=np.float64)
            values = np.array([r[2] for r in rows], dtype=np.float64)
            if values.shape[1] == 1:
                values = values[:, 0]
            send_scalars(self.rec, path, Times(t_fw, t_host), values)

    def _link_from_frames(self, times: Times, step: np.ndarray) -> None:
        """Frame rate (1 s bins of host time) and frames missing (sequence gaps), logged when a bin closes."""
        prev = self._last_step
        steps = step if prev is None else np.concatenate(([prev], step))
        gaps = np.clip(np.diff(steps) - 1, 0, None)
        self.frames_missing += int(gaps[(gaps < SEQ_MODULUS)].sum())  # a firmware restart is not a loss
        self._last_step = int(step[-1])
        host = times.t_host_s if times.t_host_s is not None else times.t_fw_s
        for i, h in enumerate(host.tolist()):
            if self._bin_start is None:
                self._bin_start = h
            if h - self._bin_start >= 1.0:
                fw = float(times.t_fw_s[i])
                host_i = float(times.t_host_s[i]) if times.t_host_s is not None else math.nan
                self._queue_row(ent.LINK_RATE, fw, host_i, (self._bin_count / (h - self._bin_start),))
                self._queue_row(ent.LINK_MISSING, fw, host_i, (float(self.frames_missing),))
                self._bin_start = h
                self._bin_count = 0
            self._bin_count += 1

    def log_status(self, frame: Any, t_unix_s: float) -> None:
        """A status frame: AHRS cycles (min/mean/max), firmware TX drops and queue peak.

        Timed by the frame's own ``t_us`` (unwrapped like the attitude rows; a status frame repeats the time of
        the attitude frame before it), so it may be logged before or after the batch holding that frame. The rows
        are queued and sent with the next batch (or on :meth:`close`)."""
        host = float(self._host(np.array([t_unix_s], dtype=np.float64))[0]) if t_unix_s is not None else math.nan
        fw = self.fw_clock.nearest(int(frame.t_us))
        if int(getattr(frame, "cyc_n", 0) or 0) > 0:
            self._queue_row(ent.LINK_CYCLES, fw, host, (frame.cyc_min, frame.cyc_mean, frame.cyc_max))
        self._queue_row(ent.LINK_TX_DROPPED, fw, host, (float(frame.tx_dropped),))
        self._queue_row(ent.LINK_QUEUE, fw, host, (float(getattr(frame, "queue_peak", 0)),))

    def log_text(self, frame: Any, t_unix_s: float) -> None:
        """A firmware text line (TextFrame or str)."""
        self._log_line(ent.LOG_FIRMWARE, frame if isinstance(frame, str) else frame.text, t_unix_s, "INFO")

    def _log_line(self, path: str, text: str, t_unix_s: float | None, level: str) -> None:
        """One TextLog entry at ``path``, on the host timeline and (when known) the firmware one."""
        host = float(self._host(np.array([t_unix_s]))[0]) if t_unix_s is not None else math.nan
        self.rec.reset_time()
        if math.isfinite(host):
            self.rec.set_time(ent.TIMELINE_HOST, duration=host)
        times = self._scalar_times(t_unix_s) if math.isfinite(host) else None
        if times is not None:
            self.rec.set_time(ent.TIMELINE_FW, duration=float(times.t_fw_s[0]))
        self.rec.log(path, rr.TextLog(text, level=level))
        self.rec.reset_time()

    def log_flight(self, frame: Any, t_unix_s: float) -> None:
        """A flight-control frame: targets, outer s1, inner s2, motors, sticks, battery (queued like the status
        rows; timed by its step from the latest attitude frame); the motors' arrows at most every 0.1 s."""
        if self._last_times is None:
            return
        host = float(self._host(np.array([t_unix_s], dtype=np.float64))[0]) if t_unix_s is not None else math.nan
        fw_last, _ = self._last_times
        d = int(frame.step) - (self._last_step if self._last_step is not None else int(frame.step))
        fw = fw_last + (d * C.AHRS_PERIOD_S if abs(d) < SEQ_MODULUS else 0.0)  # (a restart: the latest time)
        rc = np.degrees(np.asarray(frame.euler_rc_rad, dtype=np.float64))
        for path, v in zip(ent.FC_TARGETS, rc):
            self._queue_row(path, fw, host, (v,))
        for path, v in zip(ent.FC_OUTER, frame.outer_s1):
            self._queue_row(f"{path}/s1", fw, host, (v,))
        self._queue_row(ent.FC_INNER, fw, host, frame.inner_s2)
        self._queue_row(ent.FC_MOTORS, fw, host, frame.motor_pwm)
        self._queue_row(ent.FC_STICKS, fw, host, frame.rc)
        self._queue_row(ent.FC_VBAT, fw, host, (frame.vbat_v,))
        if abs(fw - self._last_motors_fw) >= 0.1:
            self._last_motors_fw = fw
            self.rec.reset_time()
            self.rec.set_time(ent.TIMELINE_FW, duration=fw)
            if math.isfinite(host):
                self.rec.set_time(ent.TIMELINE_HOST, duration=host)
            for k, v in enumerate(frame.motor_pwm):
                frac = min(max(float(v), 0.0), C.MOTOR_MAX_PWM) / C.PWM_PERIOD
                self.rec.log(ent.motor_path(k + 1), rr.Arrows3D.from_fields(vectors=[(0.0, 0.0, frac)]))
            self.rec.reset_time()

    def log_event(self, text: str, t_unix_s: float, level: str = "INFO") -> None:
        """A command sent to the drone, its acknowledgement or the settings it announced: an entry on the
        timeline (``log/commands``)."""
        self._log_line(ent.LOG_COMMANDS, text, t_unix_s, level)

    def log_link(self, stats: Any, t_unix_s: float, *, force: bool = False) -> None:
        """Decoder counters (``DecoderStats``): CRC failures, cumulative; at most every LINK_INTERVAL_S."""
        if not force and t_unix_s - self._last_link_s < LINK_INTERVAL_S:
            return
        times = self._scalar_times(t_unix_s)
        if times is None:
            return
        self._last_link_s = t_unix_s
        self._queue_row(
            ent.LINK_CRC,
            float(times.t_fw_s[0]),
            float(times.t_host_s[0]) if times.t_host_s is not None else math.nan,
            (float(getattr(stats, "crc_failures", 0)),),
        )

    def close(self) -> None:
        """Send the queued rows and flush what was logged."""
        self.flush_rows()
        self.rec.flush()

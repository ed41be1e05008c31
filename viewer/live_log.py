"""Low-latency logging of a live session: the attitude rows of each batch of frames go out before ``log_batch``
returns, in one Arrow record batch for every entity (:class:`RowBatch`). Status and link rows wait for the next
batch, text records :data:`RECORDS_INTERVAL_S` (an ``.rrd`` sink keeps some memory per chunk).

Why not ``rr.send_columns`` per entity: a live round logs ~22 entities for a handful of frames, and one record
batch costs about half as much (``benchmarks/bench_live_latency.py``). The price: Rerun's column metadata keys tie
this module to the pinned Rerun SDK; ``tests/test_viewer.py`` reads every live entity back."""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np
import rerun as rr

from steval_link import constants as C
from steval_link.estimators.st_mahony import quaternion_to_euler
from steval_link.link.protocol import SEQ_MODULUS
from steval_viewer import blueprint as bp
from steval_viewer import drone_model, flight_log
from steval_viewer import entities as ent
from steval_viewer.columns import Times, log_text_style, send_records, send_scalars, unit_xyzw
from steval_viewer.replay_log import REPLICA_NAMES, display_quaternions, firmware_series, send_values_bad_note

#: (column name, archetype, component type) of each component kind a live round logs
_SCALAR = ("Scalars:scalars", "rerun.archetypes.Scalars", "rerun.components.Scalar")
_QUAT = ("Transform3D:quaternion", "rerun.archetypes.Transform3D", "rerun.components.RotationQuat")
_VEC = ("Arrows3D:vectors", "rerun.archetypes.Arrows3D", "rerun.components.Vector3D")


def _field(pa, cache: dict, name: str, typ, **meta: str):
    """The Arrow field ``name`` with Rerun's ``rerun:<key>`` metadata ``meta`` (cached in ``cache``)."""
    key = (name, str(typ))
    if key not in cache:
        cache[key] = pa.field(name, typ, metadata={f"rerun:{k}".encode(): v.encode() for k, v in meta.items()})
    return cache[key]


class RowBatch:
    """Many entities' columns for N rows in one record batch; a non-finite value is a null, a ``Clear`` a gap."""

    def __init__(self, times: Times, bad_state: dict[str, bool], cache: dict) -> None:
        import pyarrow as pa

        self._pa = pa
        self.times = times
        self.n = len(times)
        self.fields: list = []
        self.arrays: list = []
        self.bad_state = bad_state  # entity path -> its last row was a gap
        self.clear_rows: dict[str, np.ndarray] = {}
        self.cache = cache  # Arrow fields and offsets, reused across batches

    def _index(self) -> None:
        pa = self._pa
        t = self.times
        cols = [(ent.TIMELINE_FW, np.round(t.t_fw_s * 1e9).astype(np.int64))]
        if t.host_complete():
            cols.append((ent.TIMELINE_HOST, np.round(t.t_host_s * 1e9).astype(np.int64)))
        if t.step is not None:
            cols.append((ent.TIMELINE_STEP, t.step))
        for name, values in cols:
            typ = pa.int64() if name == ent.TIMELINE_STEP else pa.duration("ns")
            f = _field(pa, self.cache, name, typ, kind="index", index_name=name)
            self.fields.insert(0, f)
            self.arrays.insert(0, pa.array(values, type=f.type))

    def _add(
        self, path: str, kind: tuple[str, str, str], values: np.ndarray, width: int, good: np.ndarray, all_good: bool
    ) -> None:
        if not good.any() and self.bad_state.get(path, False):
            return  # a gap that goes on: nothing to send (its Clear was sent where it began)
        pa = self._pa
        if kind is _SCALAR:
            inner, step = pa.array(values.reshape(-1)), width
        else:
            inner, step = pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1).astype(np.float32)), width), 1
        mask = None if all_good else pa.array(~good)
        arr = pa.ListArray.from_arrays(self._offsets_for(self.n, step), inner, mask=mask)
        comp, arch, ctype = kind
        meta = dict(kind="data", entity_path="/" + path, component=comp, archetype=arch, component_type=ctype)
        self.fields.append(_field(pa, self.cache, f"/{path}:{comp}", arr.type, **meta))
        self.arrays.append(arr)
        # gaps: a Clear at each row where the entity turns bad (state carried across batches)
        bad = ~good
        if not all_good:
            starts = np.flatnonzero(bad & ~np.concatenate(([self.bad_state.get(path, False)], bad[:-1])))
            if starts.size:
                self.clear_rows[path] = starts
        self.bad_state[path] = bool(bad[-1])

    def _offsets_for(self, n: int, step: int):
        key = ("offsets", n, step)
        off = self.cache.get(key)
        if off is None:
            off = self._pa.array(np.arange(0, n * step + 1, step, dtype=np.int32))
            if n <= 64:
                self.cache[key] = off
        return off

    def scalars(self, path: str, values: np.ndarray) -> None:
        v2 = np.asarray(values, dtype=np.float64).reshape(self.n, -1)
        good = np.isfinite(v2).all(axis=1)
        all_good = bool(good.all())
        if not all_good:
            v2 = np.where(good[:, None], v2, 0.0)
        self._add(path, _SCALAR, v2, v2.shape[1], good, all_good)

    def quaternions(self, path: str, q_wxyz: np.ndarray, select: np.ndarray) -> None:
        self.kept(path, _QUAT, *unit_xyzw(np.reshape(q_wxyz, (self.n, 4))), select)

    def kept(self, path: str, kind, values: np.ndarray, good: np.ndarray, select: np.ndarray) -> None:
        """A 3D entity's ``good`` and ``select`` rows, never cleared; unsent until one is (no all-null column)."""
        good = good & select
        if path not in self.bad_state and not good.any():
            return
        self._add(path, kind, np.where(good[:, None], values, 0.0), values.shape[1], good, bool(good.all()))
        self.bad_state[path] = False

    def send(self, rec: rr.RecordingStream) -> None:
        if not self.arrays:
            return
        self._index()
        pa = self._pa
        rec.send_record_batch(pa.RecordBatch.from_arrays(self.arrays, schema=pa.schema(self.fields)))
        for path, rows in self.clear_rows.items():
            if path.startswith(ent.PLOTS + "/") or path.startswith(ent.LINK + "/"):
                sub = self.times.take(rows)
                rec.send_columns(path, indexes=sub.indexes, columns=rr.Clear.columns(is_recursive=[False] * len(rows)))


#: The live 3D view is updated at most this often per second (the batch's newest frame); plots get every frame.
LIVE_3D_MAX_HZ = 60.0

#: The live path logs link counters (CRC failures) at most this often, s.
LINK_INTERVAL_S = 0.5
#: Text telemetry: queued records are sent when this many wait, or RECORDS_INTERVAL_S after the last send.
RECORDS_PER_SEND = 64
RECORDS_INTERVAL_S = 0.05


def live_source(name: str) -> str:
    """Entity segment of a live estimate name (the seeded ST replica -> ``st_mahony_replica``, as in replays)."""
    return ent.SOURCE_REPLICA if name in REPLICA_NAMES else ent.source_name(name)


class LiveLogger:
    """Logs a live session to ``rec``, batch by batch. ``estimator_names``: the names of ``batch.estimates``.
    ``live``: the scrolling blueprint and at most LIVE_3D_MAX_HZ 3D updates (else every row). ``ble``: a BLE link."""

    def __init__(
        self, rec: rr.RecordingStream, estimator_names: Iterable[str] = (), *, live: bool = True, ble: bool = False
    ) -> None:
        self.rec = rec
        self.sources = {name: live_source(name) for name in estimator_names}
        segs = list(dict.fromkeys(self.sources.values()))
        self.max_3d_hz = LIVE_3D_MAX_HZ if live else math.inf  # a replay: every row
        # the blueprint's arguments; ``ble`` and ``text``: the tabs the blueprint sent last has
        self._blueprint = dict(live=live, ghost_sources=segs, flight_control=True, ble=False, text=False)
        self._binary_seen = False  # binary attitude frames came: the attitude tabs stay in front
        if ble:
            self._ble_layout()
        else:
            bp.send_blueprint(rec, **self._blueprint)
        drone_model.log_static(rec, segs, with_replica=ent.SOURCE_REPLICA in segs)
        flight_log.log_flight_static(rec)  # the motor arrows with the first flight-control frame
        self.frames = 0
        self.frames_missing = 0
        self._bin_count = 0
        self._records_queued = 0
        self._last_motors_fw = -math.inf  # fw s of the last motor-arrow update
        self._last_3d_s = -math.inf  # fw s of the last 3D update
        self._last_link_s = -math.inf  # host s of the last link row
        self._records_sent_s = -math.inf  # host s of the last text-record send
        self._last_step: int | None = None
        self._bin_start: float | None = None  # host s of the current 1 s frame-rate bin
        self._last_times: tuple[float, float] | None = None  # (fw, host) of the latest frame
        self._bad: dict[str, bool] = {}  # RowBatch.bad_state
        self._arrow_cache: dict = {}  # RowBatch.cache
        self._values_bad_noted = False  # the first frame with NaN/out-of-range values has its note
        self._last_good_step: int | None = None  # step of the latest frame without bad values
        #: rows waiting, [(fw s, host s, values)]: link/status rows by path, text records by shape (their names)
        self._pending_rows: dict[str, list[tuple[float, float, tuple[float, ...]]]] = {}
        self._records: dict[tuple[str, ...], list[tuple[float, float, tuple[float, ...]]]] = {}

    def log_batch(self, batch: Any) -> None:
        """N attitude rows that arrived together (``LiveRows``: ``attitude``; ``estimates``, name -> (N, 4) q_wxyz)."""
        a, n = batch.attitude, len(batch.attitude)
        if n == 0:
            return
        self._binary_seen = self._binary_seen or bool(a.exact.any())
        step, times = a.step, Times(a.t_fw_s, a.t_host_s, a.step)
        bad = a.values_bad
        if bad.any() and not self._values_bad_noted:  # the first row of the session with bad values: one warning
            self._values_bad_noted = True
            i = int(np.argmax(bad))
            where = f"from step {int(step[i])} on (t = {float(times.t_fw_s[i]):.3f} s)"
            sentence = f"the firmware's values are NaN or out of range {where}, as sent"
            last = int(step[i - 1]) if i else self._last_good_step  # the rows before the first bad one are good
            send_values_bad_note(self.rec, times.take(np.array([i])), sentence, last)
        good_rows = np.flatnonzero(~bad)
        if good_rows.size:
            self._last_good_step = int(step[good_rows[-1]])

        # 3D entities show only the latest attitude: at most LIVE_3D_MAX_HZ updates (the batch's last row)
        t_last = float(times.t_fw_s[-1])
        rb = RowBatch(times, self._bad, self._arrow_cache)
        sel3d = None
        if not (0.0 <= t_last - self._last_3d_s < 1.0 / self.max_3d_hz):
            self._last_3d_s = t_last
            every = not math.isfinite(self.max_3d_hz)
            sel3d = np.zeros(n, dtype=bool)
            sel3d[slice(None) if every else -1] = True
            # the drone: the batch's last frame without bad values (else it stays where it was)
            sel_fw = np.zeros(n, dtype=bool)
            sel_fw[good_rows if every else good_rows[-1:]] = True
            rb.quaternions(ent.DRONE_FIRMWARE, display_quaternions(a), sel_fw)
            with np.errstate(invalid="ignore"):
                gravity = -a.acc_mg.astype(np.float64).reshape(n, 3) / 1000.0
            rb.kept(ent.ACC_GRAVITY, _VEC, gravity, np.isfinite(gravity).all(axis=1), sel3d)
        for path, values in firmware_series(a):
            rb.scalars(path, values)
        if getattr(batch, "mag_mgauss", None) is not None:
            self._ble_layout()
            rb.scalars(ent.BLE_MAG, batch.mag_mgauss.astype(np.float64))

        for name, eq in (batch.estimates or {}).items():
            source = self.sources.get(name) or live_source(name)
            eq = np.asarray(eq).reshape(n, 4)
            ex, ey = quaternion_to_euler(eq.astype(np.float32))
            if sel3d is not None:
                rb.quaternions(ent.estimate_path(source), eq, sel3d)
            rb.scalars(ent.pitch_path(source), np.degrees(ex.astype(np.float64)))
            rb.scalars(ent.roll_path(source), np.degrees(ey.astype(np.float64)))
            if source == ent.SOURCE_REPLICA:
                rb.scalars(ent.DIFF_THX, np.degrees(a.thx_rad.astype(np.float64) - ex))
                rb.scalars(ent.DIFF_THY, np.degrees(a.thy_rad.astype(np.float64) - ey))
        rb.send(self.rec)

        self.frames += n
        self._last_times = (float(times.t_fw_s[-1]), float(times.t_host_s[-1]) if times.t_host_s is not None else 0.0)
        self._link_from_frames(times, step)
        self.flush_rows(records=False)  # the records go after the rows (log_record): not in the rows' latency

    def _queue_row(self, path: str, at: tuple[float, float], values) -> None:
        self._pending_rows.setdefault(path, []).append((*at, tuple(float(v) for v in values)))

    def flush_rows(self, *, records: bool = True) -> None:
        """Send the queued rows (and, with ``records``, the text records): one ``send_columns`` per entity."""
        for names, rows in self._records.items() if records else ():
            if rows:
                send_records(self.rec, names, *_columns(rows))
                rows.clear()
        pending, self._pending_rows = self._pending_rows, {}
        for path, rows in pending.items():
            times, values = _columns(sorted(rows, key=lambda r: r[0]))
            send_scalars(self.rec, path, times, values[:, 0] if values.shape[1] == 1 else values)

    def _link_from_frames(self, times: Times, step: np.ndarray) -> None:
        """Frame rate (1 s bins of host time) and frames missing (sequence gaps), logged when a bin closes."""
        steps = step if self._last_step is None else np.concatenate(([self._last_step], step))
        gaps = np.clip(np.diff(steps) - 1, 0, None)
        self.frames_missing += int(gaps[(gaps < SEQ_MODULUS)].sum())  # a firmware restart is not a loss
        self._last_step = int(step[-1])
        host = times.t_host_s if times.t_host_s is not None else times.t_fw_s
        for i, h in enumerate(host.tolist()):
            if self._bin_start is None:
                self._bin_start = h
            if h - self._bin_start >= 1.0:
                at = (float(times.t_fw_s[i]), float(times.t_host_s[i]) if times.t_host_s is not None else math.nan)
                self._queue_row(ent.LINK_RATE, at, (self._bin_count / (h - self._bin_start),))
                self._queue_row(ent.LINK_MISSING, at, (float(self.frames_missing),))
                self._bin_start, self._bin_count = h, 0
            self._bin_count += 1

    def log_status(self, frame: Any, at: Any) -> None:
        """A status frame: AHRS cycles (min/mean/max), TX drops and queue peak, queued for the next batch."""
        if int(getattr(frame, "cyc_n", 0) or 0) > 0:
            self._queue_row(ent.LINK_CYCLES, at, (frame.cyc_min, frame.cyc_mean, frame.cyc_max))
        self._queue_row(ent.LINK_TX_DROPPED, at, (float(frame.tx_dropped),))
        self._queue_row(ent.LINK_QUEUE, at, (float(getattr(frame, "queue_peak", 0)),))

    def log_text(self, frame: Any, at: Any) -> None:
        """A firmware text line (TextFrame or str) at ``at``."""
        self.log_event(frame if isinstance(frame, str) else frame.text, at, path=ent.LOG_FIRMWARE)

    def _log_at(self, path: str, archetype: Any, at: tuple[float, float]) -> None:
        """Log ``archetype`` at ``path`` at ``at`` = (fw s, host s), on each timeline only when finite."""
        fw, host = at
        self.rec.reset_time()
        for timeline, t in ((ent.TIMELINE_FW, fw), (ent.TIMELINE_HOST, host)):
            if math.isfinite(t):
                self.rec.set_time(timeline, duration=t)
        self.rec.log(path, archetype)
        self.rec.reset_time()

    def log_record(self, frame: Any, at: Any) -> None:
        """A record of text telemetry: a row of its shape's entity under ``text/`` at host time, sent in blocks."""
        host = at.t_host_s
        if not math.isfinite(host):
            return
        fw = at.t_fw_s if math.isfinite(at.t_fw_s) else host
        if frame.names not in self._records:
            self._records[frame.names] = []
            log_text_style(self.rec, frame.names, frame.units)
            self._text_layout()
        self._records[frame.names].append((fw, host, frame.values))
        self._records_queued += 1
        if self._records_queued >= RECORDS_PER_SEND or host - self._records_sent_s >= RECORDS_INTERVAL_S:
            self._records_queued, self._records_sent_s = 0, host
            self.flush_rows()

    def log_flight(self, frame: Any, at: Any) -> None:
        """A flight-control frame, queued (none before the first attitude row); the motors' arrows every 0.1 s."""
        if self._last_times is None:
            return
        rc = np.degrees(np.asarray(frame.euler_rc_rad, dtype=np.float64))
        for path, v in zip(ent.FC_TARGETS, rc):
            self._queue_row(path, at, (v,))
        for path, v in zip(ent.FC_OUTER, frame.outer_s1):
            self._queue_row(f"{path}/s1", at, (v,))
        self._queue_row(ent.FC_INNER, at, frame.inner_s2)
        self._queue_row(ent.FC_MOTORS, at, frame.motor_pwm)
        self._queue_row(ent.FC_STICKS, at, frame.rc)
        self._queue_row(ent.FC_VBAT, at, (frame.vbat_v,))
        if abs(at.t_fw_s - self._last_motors_fw) >= 0.1:
            if self._last_motors_fw == -math.inf:  # the arrows' fixed parts with their first vectors
                flight_log.log_motors_static(self.rec)
            self._last_motors_fw = at.t_fw_s
            for k, v in enumerate(frame.motor_pwm):
                frac = min(max(float(v), 0.0), C.MOTOR_MAX_PWM) / C.PWM_PERIOD
                self._log_at(ent.motor_path(k + 1), rr.Arrows3D.from_fields(vectors=[(0.0, 0.0, frac)]), at)

    def log_environment(self, frame: Any, at: Any) -> None:
        """A BLE environment frame (``BleEnvFrame``) at its tick: pressure, battery, temperature, RSSI (queued)."""
        self._ble_layout()
        values = (frame.pressure_hpa, frame.battery_pct, frame.temperature_c, frame.rssi_dbm)
        for path, v in zip(ent.BLE_ENVIRONMENT, values):
            self._queue_row(path, at, (v,))

    def log_arming(self, frame: Any, at: Any) -> None:
        """A BLE arming frame (``BleArmingFrame``) at its tick (queued)."""
        self._ble_layout()
        self._queue_row(ent.BLE_ARMED, at, (float(frame.armed),))

    def log_note(self, text: str, at: Any) -> None:
        """What the link's rows are (a BLE stream's note), shown beside its values."""
        self._ble_layout()
        self.rec.log(ent.BLE_NOTE, rr.TextDocument(text), static=True)

    def _show(self, tab: str) -> bool:
        """Send the blueprint with ``tab`` (``ble``, ``text``) added the first time; whether it was sent."""
        if self._blueprint[tab]:
            return False
        self._blueprint[tab] = True
        bp.send_blueprint(self.rec, **self._blueprint)
        return True

    def _text_layout(self) -> None:
        """The text telemetry tab in front, once the first record comes on a stream without binary frames."""
        if self._binary_seen or not self._show("text"):
            return
        # printed lines give the replica no inputs: its ghost would stand level; no accelerometer arrow either
        self.rec.log(ent.estimate_path(ent.SOURCE_REPLICA), rr.Clear(recursive=True), static=True)
        self.rec.log(ent.ACC_GRAVITY, rr.Clear(recursive=False), static=True)

    def _ble_layout(self) -> None:
        """The blueprint with the BLE tab, once a BLE value comes (a stream says what it is by its frames)."""
        if not self._show("ble"):
            return
        for path in (*ent.BLE_ENVIRONMENT, ent.BLE_ARMED):
            self.rec.log(path, rr.SeriesLines(names=[path.rsplit("/", 1)[-1]], widths=[1.5]), static=True)
        self.rec.log(ent.BLE_MAG, rr.SeriesLines(names=["mag x", "mag y", "mag z"], widths=[1.5] * 3), static=True)

    def log_event(self, text: str, at: Any, level: str = "INFO", path: str = ent.LOG_COMMANDS) -> None:
        """A command sent to the drone, its acknowledgement or the settings it announced (``log/commands``)."""
        host = math.nan if at is None else at.t_host_s
        self._log_at(path, rr.TextLog(text, level=level), (at.t_fw_s if math.isfinite(host) else math.nan, host))

    def log_link(self, stats: Any, t_unix_s: float) -> None:
        """Decoder CRC failures (cumulative) at the latest row's times, at most every LINK_INTERVAL_S (host s)."""
        if t_unix_s - self._last_link_s < LINK_INTERVAL_S or self._last_times is None:
            return
        self._last_link_s = t_unix_s
        self._queue_row(ent.LINK_CRC, self._last_times, (float(getattr(stats, "crc_failures", 0)),))

    def close(self) -> None:
        self.flush_rows()
        self.rec.flush()


def _columns(rows: list) -> tuple[Times, np.ndarray]:
    """Queued rows [(fw s, host s, values)] as their times and (N, k) values."""
    t = np.array([r[:2] for r in rows], dtype=np.float64)
    return Times(t[:, 0], t[:, 1]), np.array([r[2] for r in rows], dtype=np.float64)

"""``Telemetry``: every field of a decoded stream as numpy arrays in stream order, with units in the names.

Derived fields (one implementation for the whole stream and the live path, :class:`StreamClock`):

* ``step``: binary rows unwrap ``seq`` (u16); a status frame (the full u32 step of the attitude frame before it)
  anchors the absolute step, the first of each firmware run. Text-mode rows carry the full step.
* ``t_fw_s``: ``t_us`` unwrapped mod 2³² (from 0 again after a firmware restart) / 10⁶.
* ``thx_rad``/``thy_rad``: of binary rows ``QuaternionToEuler`` of ``q_wxyz``, bit-exact; of text rows the line's.
* ``values_bad``: NaN/inf or out-of-range values (:mod:`steval_link.link.plausibility`); protocol v2 keeps such
  frames when CRC, sequence and time are right (the firmware's filter diverged).
"""

from __future__ import annotations

from dataclasses import dataclass, field, make_dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from steval_link import constants as C
from steval_link.fw_math import quaternion_to_euler
from steval_link.link import protocol as P
from steval_link.link.frames import (
    AckFrame,
    AttitudeFrame,
    CommandFrame,
    FlightFrame,
    StatusFrame,
    TextFrame,
    TextRecordFrame,
)
from steval_link.link.plausibility import attitude_rows_bad, status_rows_bad
from steval_link.link.text_series import RecordBlock, TextSeries, apply_plan, attitude_plan, record_blocks, text_series

if TYPE_CHECKING:  # annotations only
    from steval_link.link.frames import DecoderStats, Frame

_HALF = P.T_US_MODULUS // 2


class TimeUnwrapper:
    """Firmware seconds since boot from ``t_us`` in stream order, across calls: a drop by over half the range wraps."""

    def __init__(self) -> None:
        self.wraps = 0
        self.last: int | None = None

    def seconds(self, t_us) -> np.ndarray:
        """(N,) float64 seconds of these ``t_us`` values, in order (state carried to the next call)."""
        raw = np.asarray(t_us, dtype=np.int64) % P.T_US_MODULUS
        if raw.size == 0:
            return np.zeros(0, dtype=np.float64)
        prev = np.concatenate([[raw[0] if self.last is None else self.last], raw[:-1]])
        wraps = self.wraps + np.cumsum((prev - raw) > _HALF)
        self.wraps, self.last = int(wraps[-1]), int(raw[-1])
        return (raw + wraps * P.T_US_MODULUS) / 1e6

    def nearest(self, t_us: int) -> float:
        """Seconds of one ``t_us`` (a status frame's) at the wrap count closest to the latest value; no state change."""
        v = int(t_us) % P.T_US_MODULUS
        if self.last is None:
            return v / 1e6
        wraps = self.wraps
        if v - self.last > _HALF and wraps > 0:
            wraps -= 1  # from before the latest wrap
        elif self.last - v > _HALF:
            wraps += 1  # already past the next wrap
        return (v + wraps * P.T_US_MODULUS) / 1e6


class SeqUnwrapper:
    """Full AHRS steps from binary frames' u16 ``seq`` (high bits: :meth:`status`); a step back is a restart."""

    def __init__(self) -> None:
        #: full step of the latest binary frame (None before the first)
        self.last: int | None = None

    def steps(self, seq) -> tuple[np.ndarray, np.ndarray]:
        """(steps (N,) int64, restart (N,) bool: this frame begins a new firmware run) for these ``seq`` values."""
        raw = np.asarray(seq, dtype=np.int64) % P.SEQ_MODULUS
        n = raw.size
        if n == 0:
            return np.zeros(0, np.int64), np.zeros(0, bool)
        prev = np.concatenate([[raw[0] if self.last is None else self.last % P.SEQ_MODULUS], raw[:-1]])
        advance = (raw - prev) % P.SEQ_MODULUS
        restart = advance >= P.SEQ_MODULUS // 2
        cs = np.cumsum(np.where(restart, 0, advance))
        seg = np.cumsum(restart)  # 0: continues the previous call's run
        first = np.flatnonzero(restart)  # the row where each later run starts
        steps = (raw[0] if self.last is None else self.last) + cs
        if first.size:
            later = seg > 0
            starts = first[seg[later] - 1]
            steps[later] = raw[starts] + (cs[later] - cs[starts])
        self.last = int(steps[-1])
        return steps, restart

    def status(self, step: int) -> None:
        """A status frame names the full step of the attitude frame just before it: take it when it agrees."""
        if self.last is None or self.last % P.SEQ_MODULUS == step % P.SEQ_MODULUS:
            self.last = int(step)


def host_times(last_byte, chunk_times, baud: int | None, total: int, *, before_s: float = -np.inf) -> np.ndarray:
    """Host time of each frame's ``last_byte``: its chunk's (offsets, times; None: NaN) less the bytes after it at
    ``baud``, never before the previous chunk's."""
    if chunk_times is None or len(chunk_times[0]) == 0:
        return np.full(len(last_byte), np.nan)
    c_off = np.asarray(chunk_times[0], dtype=np.int64)
    c_t = np.asarray(chunk_times[1], dtype=np.float64)
    k = np.clip(np.searchsorted(c_off, last_byte, side="right") - 1, 0, len(c_off) - 1)
    t = c_t[k].copy()
    if baud:
        c_end = np.append(c_off[1:], total)
        t -= (c_end[k] - (last_byte + 1)) * (10.0 / baud)
        # a byte cannot have arrived before the previous chunk was received
        prev = np.where(k > 0, c_t[np.maximum(k - 1, 0)], before_s)
        t = np.maximum(t, prev)
    return t


class StreamClock:
    """A live stream's rows timed by the bulk rules from ``t0_unix_s`` (None: the first chunk's); :meth:`chunk` each."""

    def __init__(self, t0_unix_s: float | None = None, baud: int | None = None) -> None:
        self.t0_unix_s, self.baud = t0_unix_s, baud
        self.total = 0  # bytes of the stream so far
        self._offsets, self._times = [], []  # the kept chunks' stream offsets and host times, s
        self._before_s = -np.inf  # time of the chunk before the first kept one
        self.fw = TimeUnwrapper()

    def host_of(self, t_unix_s: float) -> float:
        """A host time (s, Unix epoch) on the capture's base (as the recorder stores chunk times)."""
        if self.t0_unix_s is None:
            self.t0_unix_s = float(t_unix_s)
        return float(t_unix_s) - self.t0_unix_s

    def chunk(self, nbytes: int, t_unix_s: float) -> None:
        """A chunk of ``nbytes`` received at ``t_unix_s`` (an empty one is not kept, as in a capture)."""
        t_s = self.host_of(t_unix_s)
        if nbytes:
            self._offsets.append(self.total)
            self._times.append(t_s)
            self.total += nbytes

    def host_s(self, last_byte) -> np.ndarray:
        """Host times of frames ending at stream offsets ``last_byte`` (:func:`host_times` over the chunks)."""
        chunks = (self._offsets, self._times)
        return host_times(np.asarray(last_byte), chunks, self.baud, self.total, before_s=self._before_s)

    def fw_s(self, t_us, restart=None) -> np.ndarray:
        """Firmware seconds of these ``t_us`` (stream order); counting starts again at each ``restart`` row."""
        restart = np.zeros(len(t_us), bool) if restart is None else np.asarray(restart, bool)
        cuts = sorted({0, len(t_us), *np.flatnonzero(restart).tolist()})
        out = [np.zeros(0)]
        for a, b in zip(cuts[:-1], cuts[1:]):
            if restart[a]:
                self.fw = TimeUnwrapper()  # a firmware restart: its own time from boot
            out.append(self.fw.seconds(t_us[a:b]))
        return np.concatenate(out)

    def prune(self, pending_bytes: int) -> None:
        """Forget the chunks before the one holding the first of the ``pending_bytes`` not decoded yet."""
        k = int(np.searchsorted(self._offsets, self.total - pending_bytes, side="right")) - 1
        if k > 0:
            self._before_s = self._times[k - 1]  # a frame's time is never before the previous chunk's
            del self._offsets[:k], self._times[:k]


_EXTRA = [("offset", "<i8"), ("nbytes", "<i4"), ("exact", "?")]
#: Internal row layouts: the wire payload plus where the row came from.
ATT_RECORD_DTYPE = np.dtype(P.ATTITUDE_DTYPE.descr + _EXTRA + [("step", "<i8"), ("thx_rad", "<f4"), ("thy_rad", "<f4")])
STA_RECORD_DTYPE = np.dtype(P.STATUS_DTYPE.descr + _EXTRA)
_ROW_EXTRA = [("offset", "<i8"), ("nbytes", "<i4"), ("t_host_s", "<f8")]
#: Rows of the v2 frames kept as structured arrays (payload fields + where and when the frame arrived).
FLIGHT_ROW_DTYPE = np.dtype(P.FLIGHT_DTYPE.descr + _ROW_EXTRA)
ACK_ROW_DTYPE = np.dtype(P.ACK_DTYPE.descr + _ROW_EXTRA)
COMMAND_ROW_DTYPE = np.dtype(P.COMMAND_DTYPE.descr + _ROW_EXTRA)


#: the attitude columns taken as they are from the records (ATT_RECORD_DTYPE has each one's type)
_RECORD_COLUMNS = tuple(name for name in ATT_RECORD_DTYPE.names if name not in ("nbytes", "step"))


@dataclass
class AttitudeArrays:
    """One row per attitude frame. Axes are the firmware's (x right, y forward, z up): ``thx_rad`` is pitch (about
    x, nose up +), ``thy_rad`` roll (about y), ``thz_rad`` the ISR-integrated yaw."""

    step: np.ndarray  #: (N,) int64, AHRS step counter
    seq: np.ndarray  #: (N,) uint16, as sent
    t_us: np.ndarray  #: (N,) uint32, firmware time as sent, µs mod 2³²
    t_fw_s: np.ndarray  #: (N,) float64, firmware time, s since boot
    t_host_s: np.ndarray  #: (N,) float64, host receive time, s since capture start (NaN when unknown)
    acc_mg: np.ndarray  #: (N,3) float32, accelerometer input of ahrs_fusion_ag, mg
    gyro_mdps: np.ndarray  #: (N,3) float32, gyroscope input of ahrs_fusion_ag, mdps
    thr: np.ndarray  #: (N,) int16, gTHR
    q_wxyz: np.ndarray  #: (N,4) float32, ahrs.q after the step (NaN for text-mode rows)
    thz_rad: np.ndarray  #: (N,) float32, yaw, rad
    thx_rad: np.ndarray  #: (N,) float32, pitch (about x), rad
    thy_rad: np.ndarray  #: (N,) float32, roll (about y), rad
    exact: np.ndarray  #: (N,) bool, True for binary frames (bit-exact), False for rounded text-mode rows
    offset: np.ndarray  #: (N,) int64, stream byte offset of the frame
    #: (N,) bool, NaN/inf or out-of-range values as sent (see the module docstring); all False by default
    values_bad: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.values_bad is None:
            self.values_bad = attitude_rows_bad(
                self.exact, self.acc_mg, self.gyro_mdps, self.q_wxyz, self.thz_rad, self.thx_rad, self.thy_rad
            )

    def __len__(self) -> int:
        return len(self.step)

    @classmethod
    def of(cls, step, t_fw_s, t_host_s, acc_mg, gyro_mdps, euler_rad, *, thr=None, q_wxyz=None, offset=None, **kw):
        """Rows that are not binary frames: ``euler_rad`` (N, 3) thx, thy, thz; thr 0, q NaN, offset -1 by default."""
        step, t_fw_s = np.asarray(step, np.int64), np.asarray(t_fw_s, np.float64)
        n = len(step)
        euler = np.asarray(euler_rad, np.float32).reshape(n, 3)
        return cls(
            step=step,
            seq=(step % P.SEQ_MODULUS).astype(np.uint16),
            t_us=(np.round(t_fw_s * 1e6).astype(np.int64) % P.T_US_MODULUS).astype(np.uint32),
            t_fw_s=t_fw_s,
            t_host_s=np.asarray(t_host_s, np.float64),
            acc_mg=np.ascontiguousarray(acc_mg, np.float32),
            gyro_mdps=np.ascontiguousarray(gyro_mdps, np.float32),
            thr=np.zeros(n, np.int16) if thr is None else np.asarray(thr, np.int16),
            q_wxyz=np.full((n, 4), np.nan, np.float32) if q_wxyz is None else np.ascontiguousarray(q_wxyz, np.float32),
            thz_rad=np.ascontiguousarray(euler[:, 2]),
            thx_rad=np.ascontiguousarray(euler[:, 0]),
            thy_rad=np.ascontiguousarray(euler[:, 1]),
            exact=np.full(n, kw.pop("exact", False), bool),
            offset=np.full(n, -1, np.int64) if offset is None else np.asarray(offset, np.int64),
            **kw,
        )

    @classmethod
    def from_records(cls, att: np.ndarray, *, step, t_fw_s, t_host_s) -> AttitudeArrays:
        """Rows of ATT_RECORD_DTYPE records (stream order) with their step and times; binary rows' angles from q."""
        cols = {name: np.array(att[name]) for name in _RECORD_COLUMNS}  # copies
        ex = cols["exact"]
        if ex.any():
            cols["thx_rad"][ex], cols["thy_rad"][ex] = quaternion_to_euler(att["q_wxyz"][ex])
        t_fw_s, t_host_s = np.asarray(t_fw_s, np.float64), np.asarray(t_host_s, np.float64)
        return cls(step=np.asarray(step, dtype=np.int64), t_fw_s=t_fw_s, t_host_s=t_host_s, **cols)

    @classmethod
    def concat(cls, parts: list[AttitudeArrays]) -> AttitudeArrays:
        if len(parts) == 1:
            return parts[0]
        return cls(**{name: np.concatenate([getattr(p, name) for p in parts]) for name in cls.__dataclass_fields__})


_STATUS_COLUMNS = (*P.STATUS_DTYPE.names, "t_fw_s", "t_host_s", "exact", "offset")


@dataclass
class StatusArrays(make_dataclass("StatusColumns", [(name, np.ndarray) for name in _STATUS_COLUMNS])):
    """One row per status frame: its STATUS_DTYPE fields, times, ``exact``, ``offset``, ``values_bad`` (NaN, |q|>2)."""

    values_bad: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.values_bad is None:
            self.values_bad = status_rows_bad(
                self.exact, self.q_wxyz, self.int_xyz, self.kp_ground, self.kp_flight, self.ki, self.dt_s
            )

    def __len__(self) -> int:
        return len(self.step)


@dataclass
class FlightControlArrays:
    """One row per flight-control frame (after ``FlightControlPID_OuterLoop`` of ``step``); axes x (pitch), y (roll),
    z (yaw). ``t_fw_s``: the attitude row before it plus the AHRS periods between (the frame carries no time)."""

    step: np.ndarray  #: (N,) int64, the AHRS step (as the attitude rows' step)
    t_fw_s: np.ndarray  #: (N,) float64, firmware time of the step, s since boot
    t_host_s: np.ndarray  #: (N,) float64, host receive time, s since capture start (NaN when unknown)
    euler_rc_rad: np.ndarray  #: (N,3) float32, the remote's targets thx, thy, thz passed to the outer loop
    rc: np.ndarray  #: (N,4) int16, gAIL, gELE, gRUD, gTHR
    outer_s1_radps: np.ndarray  #: (N,3) float32, outer (angle) loop outputs x_s1, y_s1, z_s1: rate setpoints
    inner_s2_pwm: np.ndarray  #: (N,3) float32, inner (rate) loop outputs x_s2, y_s2, z_s2, PWM counts
    motor_pwm: np.ndarray  #: (N,4) float32, motor1..4_pwm as computed (TIM4 counts of 2000; 0 when stopped)
    vbat_v: np.ndarray  #: (N,) float32, battery voltage as the firmware last measured it, V
    fc_flags: np.ndarray  #: (N,) uint16, bit0 armed, bit1 RC connected, bit2 RC calibration
    fc_every: np.ndarray  #: (N,) uint8, a frame every this many steps
    offset: np.ndarray  #: (N,) int64, stream byte offset of the frame

    def __len__(self) -> int:
        return len(self.step)

    @property
    def armed(self) -> np.ndarray:
        return (self.fc_flags & P.FC_ARMED).astype(bool)

    @classmethod
    def from_rows(cls, rows: np.ndarray, att: AttitudeArrays) -> FlightControlArrays:
        step = rows["step"].astype(np.int64)
        if len(att):
            j = np.clip(np.searchsorted(att.offset, rows["offset"]) - 1, 0, len(att) - 1)
            t = att.t_fw_s[j] + (step - att.step[j]) * C.AHRS_PERIOD_S
        else:
            t = step * C.AHRS_PERIOD_S
        cols = {name: np.array(rows[name]) for name in FLIGHT_ROW_DTYPE.names if name not in (P.RESERVED, "nbytes")}
        cols["outer_s1_radps"], cols["inner_s2_pwm"] = cols.pop("outer_s1"), cols.pop("inner_s2")  # units named
        cols["step"] = step
        return cls(t_fw_s=np.asarray(t, np.float64), **cols)


#: the columns of ``steval export --csv`` that make its rows the frames' own float32 values (the replica runs bit-exact)
EXPORT_EXACT_COLUMNS = ("step", "exact", "q_w", "q_x", "q_y", "q_z")


class TelemetryParts:
    """Accumulates decoded rows (numpy blocks or single frames) before :meth:`Telemetry.from_parts`."""

    def __init__(self) -> None:
        self.att_blocks: list[np.ndarray] = []
        self.sta_blocks: list[np.ndarray] = []
        self.att_frames: list[AttitudeFrame] = []
        self.sta_frames: list[StatusFrame] = []
        self.texts: list[TextFrame] = []
        self.records: list[TextRecordFrame] = []
        self.record_blocks: list[RecordBlock] = []  # records the bulk decoder made as arrays
        self.others: list[FlightFrame | AckFrame | CommandFrame] = []
        #: commands the host sent (``COMMAND_ROW_DTYPE`` rows, timed), kept after those found in the stream
        self.sent_commands: np.ndarray | None = None
        self._settled = False  # the blocks are one sorted block each (records asked for, nothing added since)

    def add_payloads(self, kind: int, arr: np.ndarray, payload_starts, frame_starts, frame_sizes) -> None:
        """Binary attitude or status frames (``kind``) whose payloads start at ``payload_starts`` in ``arr``."""
        if len(payload_starts) == 0:
            return
        attitude = kind == P.TYPE_ATTITUDE
        payload, record = (P.ATTITUDE_DTYPE, ATT_RECORD_DTYPE) if attitude else (P.STATUS_DTYPE, STA_RECORD_DTYPE)
        win = np.lib.stride_tricks.sliding_window_view(arr, payload.itemsize)
        pay = np.ascontiguousarray(win[payload_starts]).view(payload).reshape(-1)
        rec = np.empty(len(pay), record)
        for name in payload.names:
            rec[name] = pay[name]
        rec["offset"], rec["nbytes"], rec["exact"] = frame_starts, frame_sizes, True
        if attitude:
            rec["step"], rec["thx_rad"], rec["thy_rad"] = -1, np.nan, np.nan
        (self.att_blocks if attitude else self.sta_blocks).append(rec)
        self._settled = False

    def add_frame(self, frame: Frame) -> None:
        kind = type(frame)
        lists = {AttitudeFrame: self.att_frames, StatusFrame: self.sta_frames, TextFrame: self.texts}
        lists.get(kind, self.records if kind is TextRecordFrame else self.others).append(frame)
        self._settled = self._settled and kind not in (AttitudeFrame, StatusFrame)

    def attitude_records(self) -> np.ndarray:
        """Every attitude row so far, in stream order."""
        return self._settle()[0]

    def status_records(self) -> np.ndarray:
        """Every status row so far, in stream order."""
        return self._settle()[1]

    def _settle(self) -> tuple[np.ndarray, np.ndarray]:
        """Blocks and single frames into one block each, in stream order (once until more rows come)."""
        if not self._settled:
            self.att_blocks = [_sorted_records(self.att_blocks, self.att_frames, ATT_RECORD_DTYPE)]
            self.sta_blocks = [_sorted_records(self.sta_blocks, self.sta_frames, STA_RECORD_DTYPE)]
            self.att_frames, self.sta_frames = [], []
            self._settled = True
        return self.att_blocks[0], self.sta_blocks[0]


def _frame_records(frames: list, dtype: np.dtype, skip: tuple[str, ...] = ()) -> np.ndarray:
    """Records of ``dtype`` from the frames' attributes (``skip``: fields left 0; a ``step`` None is -1)."""
    rec = np.zeros(len(frames), dtype)
    for name in dtype.names if frames else ():
        if name not in skip:
            values = [getattr(f, name) for f in frames]
            rec[name] = [-1 if v is None else v for v in values] if name == "step" else values
    return rec


def _sorted_records(blocks: list[np.ndarray], frames: list, dtype: np.dtype) -> np.ndarray:
    """The record blocks and the single frames together, in stream order."""
    blocks = blocks + ([_frame_records(frames, dtype)] if frames else [])
    rec = np.concatenate(blocks) if blocks else np.zeros(0, dtype)
    return rec[np.argsort(rec["offset"], kind="stable")]


def _unwrap_steps(att: np.ndarray, sta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(step per attitude row, restart offsets): ``seq`` unwrapped, each firmware run anchored by its first status."""
    step = att["step"].copy()
    b = np.flatnonzero(att["exact"])
    restarts = np.zeros(0, np.int64)
    if len(b):
        local, reset = SeqUnwrapper().steps(att["seq"][b])
        seg = np.cumsum(reset)
        delta = np.zeros(int(seg[-1]) + 1, np.int64)
        if len(sta):
            j = np.searchsorted(att["offset"][b], sta["offset"]) - 1
            ok = j >= 0
            j_ok = j[ok]
            sstep = sta["step"][ok].astype(np.int64)
            match = (local[j_ok] - sstep) % P.SEQ_MODULUS == 0
            j_m, s_m = j_ok[match], sstep[match]
            if len(j_m):
                segs, first = np.unique(seg[j_m], return_index=True)
                delta[segs] = s_m[first] - local[j_m[first]]
        step[b] = local + delta[seg]
        restarts = att["offset"][b][reset]
    return step, restarts


@dataclass
class Telemetry:
    """A decoded stream: ``attitude``/``status`` rows, ``text`` lines, ``events``, ``stats``, ``source`` (``path``,
    ``kind`` 'stv' | 'raw' | 'text', capture ``header``, ``warnings``); the v2 frames as structured arrays (``flight``,
    ``acks``, ``commands``: found in the bytes, then those the host sent)."""

    attitude: AttitudeArrays
    status: StatusArrays
    text: list[tuple[float, str]]
    stats: DecoderStats
    events: list[Any] = field(default_factory=list)
    source: dict[str, Any] = field(default_factory=dict)
    flight: np.ndarray = field(default_factory=lambda: np.zeros(0, FLIGHT_ROW_DTYPE))
    acks: np.ndarray = field(default_factory=lambda: np.zeros(0, ACK_ROW_DTYPE))
    commands: np.ndarray = field(default_factory=lambda: np.zeros(0, COMMAND_ROW_DTYPE))
    #: the records of text telemetry as named series (:class:`~steval_link.link.text_series.TextSeries`)
    text_series: TextSeries = field(default_factory=TextSeries)
    #: how the text series became the attitude rows (one note per mapped name), [] when they did not
    text_attitude_notes: list[str] = field(default_factory=list)
    #: the link's own facts when they are not a serial stream's (a BLE capture's
    #: :class:`~steval_link.link.ble_telemetry.BleStream`: cadence, dt, layout, environment); None for serial
    link: Any = None

    @classmethod
    def from_parts(
        cls,
        parts: TelemetryParts,
        stats: DecoderStats,
        *,
        chunk_times: tuple[np.ndarray, np.ndarray] | None = None,
        baud: int | None = None,
        source: dict | None = None,
        events: list | None = None,
    ) -> Telemetry:
        att, sta = parts._settle()
        texts = sorted(parts.texts, key=lambda f: f.offset)
        total = int(stats.bytes_total)

        def host_s(last_byte) -> np.ndarray:
            return host_times(np.asarray(last_byte, np.int64), chunk_times, baud, total)

        step, restarts = _unwrap_steps(att, sta)
        # firmware time over attitude and status rows together, in stream order, from 0 again at each restart
        off_all = np.concatenate([att["offset"], sta["offset"]])
        order = np.argsort(off_all, kind="stable")
        t_all = np.empty(len(off_all))
        run = np.searchsorted(restarts, off_all[order], side="right")
        t_us = np.concatenate([att["t_us"], sta["t_us"]]).astype(np.int64)[order]
        t_all[order] = StreamClock().fw_s(t_us, np.diff(run, prepend=0) > 0)
        na = len(att)
        attitude = AttitudeArrays.from_records(
            att, step=step, t_fw_s=t_all[:na], t_host_s=host_s(att["offset"] + att["nbytes"] - 1)
        )
        status = StatusArrays(
            **{name: np.array(sta[name]) for name in (*P.STATUS_DTYPE.names, "exact", "offset")},  # their own types
            t_fw_s=t_all[na:],
            t_host_s=host_s(sta["offset"] + sta["nbytes"] - 1),
        )
        text = [(float(t), f.text) for t, f in zip(host_s([f.offset + f.nbytes - 1 for f in texts]), texts)]
        rows = {}
        for name, kind, dtype in (
            ("flight", FlightFrame, FLIGHT_ROW_DTYPE),
            ("acks", AckFrame, ACK_ROW_DTYPE),
            ("commands", CommandFrame, COMMAND_ROW_DTYPE),
        ):
            frames = sorted((f for f in parts.others if isinstance(f, kind)), key=lambda f: f.offset)
            rec = _frame_records(frames, dtype, skip=("t_host_s", P.RESERVED))
            rec["t_host_s"] = host_s(rec["offset"] + rec["nbytes"] - 1)
            rows[name] = rec
        if parts.sent_commands is not None and len(parts.sent_commands):
            rows["commands"] = np.concatenate([rows["commands"], parts.sent_commands])
        blocks = parts.record_blocks + record_blocks(sorted(parts.records, key=lambda f: f.offset))
        series = text_series(blocks, host_s)
        tel = cls(attitude, status, text, stats, list(events or []), dict(source or {}), **rows, text_series=series)
        if len(series) and not len(attitude):
            tel.map_text()
        return tel

    @property
    def has_own_attitude(self) -> bool:
        """The attitude rows are the stream's own frames (binary or ``$ATT``), not text telemetry."""
        return len(self.attitude) > 0 and not self.text_attitude_notes

    @property
    def printed_only(self) -> bool:
        """The stream is text telemetry alone: records, and no attitude frames of its own."""
        return len(self.text_series) > 0 and not self.has_own_attitude

    @property
    def binary_rows(self) -> int:
        """Attitude rows that are the stream's binary frames; printed rows are not, even float32-exact ones."""
        return 0 if self.printed_only else int(self.attitude.exact.sum())

    def map_text(self, user_map: dict[str, tuple[str, str]] | None = None) -> None:
        """Attitude rows from the text series when the stream has no frames of its own (``text_attitude_notes``)."""
        if len(self.attitude) and self.attitude.exact.any():
            return
        s = self.text_series
        plan, self.text_attitude_notes = attitude_plan(s, user_map)
        if not plan:
            return
        cols = apply_plan(plan, s.values)
        n = len(s)
        t_fw = np.asarray(s.t_s, np.float64)
        # AHRS steps from the records' times: the estimators run at the line rate (rows decimated as text mode's)
        raw = np.round(np.nan_to_num(t_fw - (t_fw[0] if n else 0.0)) / C.AHRS_PERIOD_S).astype(np.int64)
        idx = np.arange(n, dtype=np.int64)
        step = np.maximum.accumulate(raw - idx) + idx if n else raw  # strictly increasing
        bad = ~(np.isfinite(cols["thx_rad"]) | np.isfinite(cols["thy_rad"]))
        bad &= ~np.isfinite(cols["acc_mg"]).all(axis=1)
        euler = np.stack([cols["thx_rad"], cols["thy_rad"], cols["thz_rad"]], axis=1)
        acc, gyro = cols["acc_mg"], cols["gyro_mdps"]
        q, exact = None, False
        if set(EXPORT_EXACT_COLUMNS) <= set(s.names):  # steval export --csv: the frames' own values, float32-exact
            step = s.column("step").astype(np.int64)
            q = np.stack([s.column(f"q_{c}") for c in "wxyz"], axis=1).astype(np.float32)
            exact = (s.column("exact") == 1) & np.isfinite(q).all(axis=1) & np.isfinite(acc).all(axis=1)
        kw = dict(thr=cols["thr"], q_wxyz=q, offset=s.offset, values_bad=bad, exact=exact)
        self.attitude = AttitudeArrays.of(step, t_fw, s.t_host_s, acc, gyro, euler, **kw)

    @cached_property
    def fc(self) -> FlightControlArrays:
        """The flight-control frames with units in the names (:class:`FlightControlArrays`)."""
        return FlightControlArrays.from_rows(self.flight, self.attitude)

    def flight_columns(self) -> dict[str, np.ndarray]:
        """The flight-control fields as columns on the attitude rows, joined by step (NaN where none); {} if none."""
        fc = self.fc
        if len(fc) == 0:
            return {}
        n = len(self.attitude)
        # the flight-control row of each attitude row: same step, the nearest one after it in the stream
        row = np.full(n, -1, np.int64)
        j = np.searchsorted(self.attitude.offset, fc.offset) - 1
        ok = (j >= 0) & (self.attitude.step[np.clip(j, 0, max(n - 1, 0))] == fc.step) if n else np.zeros(len(fc), bool)
        row[j[ok]] = np.flatnonzero(ok)
        has = row >= 0
        cols: dict[str, np.ndarray] = {}

        def col(values, dtype=np.float32):
            out = np.full(n, np.nan, dtype)
            out[has] = np.asarray(values)[row[has]]
            return out

        xyz = ("x_pitch", "y_roll", "z_yaw")
        for key, values, names in (
            ("target_{}_rad", fc.euler_rc_rad, ("thx_pitch", "thy_roll", "thz_yaw")),
            ("rc_{}", fc.rc.astype(np.float32), ("ail", "ele", "rud", "thr")),
            ("outer_s1_{}_radps", fc.outer_s1_radps, xyz),
            ("inner_s2_{}_pwm", fc.inner_s2_pwm, xyz),
            ("motor{}_pwm", fc.motor_pwm, "1234"),
        ):
            for i, name in enumerate(names):
                cols[key.format(name)] = col(values[:, i])
        cols["vbat_v"] = col(fc.vbat_v)
        for bit, name in ((P.FC_ARMED, "fc_armed"), (P.FC_RC_CONNECTED, "fc_rc_connected"), (P.FC_RC_CAL, "fc_rc_cal")):
            cols[name] = col(((fc.fc_flags & bit) != 0).astype(np.float32))
        cols["fc_every"] = col(fc.fc_every.astype(np.float32))
        return cols

    def attitude_table(self) -> dict[str, np.ndarray]:
        """One 1-D column per attitude field, units in the names (``pandas.DataFrame(tel.attitude_table())``)."""
        a = self.attitude
        cols: dict[str, np.ndarray] = {"step": a.step, "seq": a.seq, "t_fw_s": a.t_fw_s, "t_host_s": a.t_host_s}
        for key, values, axes in (
            ("acc_{}_mg", a.acc_mg, "xyz"),
            ("gyro_{}_mdps", a.gyro_mdps, "xyz"),
            ("q_{}", a.q_wxyz, "wxyz"),
        ):
            for i, ax in enumerate(axes):
                cols[key.format(ax)] = values[:, i]
        cols.update(thx_pitch_rad=a.thx_rad, thy_roll_rad=a.thy_rad, thz_yaw_rad=a.thz_rad, thr=a.thr)
        cols.update(exact=a.exact, offset=a.offset, values_bad=a.values_bad)
        return cols


def telemetry_from_frames(frames: list[Frame], stats: DecoderStats) -> Telemetry:
    """A :class:`Telemetry` from a ``StreamDecoder``'s frames (host times unknown)."""
    parts = TelemetryParts()
    for f in frames:
        parts.add_frame(f)
    return Telemetry.from_parts(parts, stats)

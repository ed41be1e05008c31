"""Bit-exact port of the STEVAL-FCU001V1 firmware's Mahony filter (ST release 170120).

Reproduces ``ahrs_fusion_ag`` and ``QuaternionToEuler`` in float32 exactly as the drone computes them (Cortex-M4F,
hard float, -O0, no FMA), rounding included. Units are the firmware's: accelerometer in mg, gyro in mdps, angles in
rad; axes x right, y forward, z up; ``thx`` is the rotation about x (pitch, nose up +), ``thy`` about y (roll).

The firmware's quirks are kept on purpose: the fast inverse square root (0x5f3759df, one Newton step; finite for
0, so free fall gives no correction instead of NaN); gyro scaled by ``(float)1.745329252e-5``; kp switched by
throttle (10 below MIN_THR, else 0.4); integral ``ex*KI*dt`` in float; the in-place quaternion update (q1..q3 use
the new q0); and the final normalisation with the squares from **before** the update, so |q| ≈ 0.9983 and
``asin`` in ``QuaternionToEuler`` can return NaN near ±90° roll, as on the drone.

Two loops give the same bits: a C extension (``_st_mahony_native``, ≈ 10 M steps/s) and a numpy-float32 loop
(≈ 70 k steps/s) used when the extension is not built. Entry points: :func:`run`, :func:`quaternion_to_euler`,
:class:`StMahony` (the shared estimator interface) and :func:`replay_firmware` (a capture against the drone).
Its size is the firmware's: the reference loop, the settings and state types and the replay against a capture
stay together, since each of them is part of what "bit-exact" means.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from steval_link import constants as C
from steval_link.estimators.base import AttitudeEstimate, Estimator, check_inputs
from steval_link.link.protocol import FLAG_EVENT, FLAG_FRESH_SQUARES, FLAG_NO_CORRECTION

__all__ = [
    "COE_MDPS_TO_RADPS_F32",
    "NATIVE_AVAILABLE",
    "MahonySettings",
    "MahonyState",
    "StMahony",
    "FirmwareReplay",
    "ReplaySeed",
    "run",
    "replay_firmware",
    "bits_equal",
    "handout_yaw",
    "quaternion_to_euler",
    "inv_sqrt",
]

from steval_link.fw_math import (  # the firmware's float32 arithmetic, shared with the link layer
    _F32,
    _HALF,
    _INVSQRT_MAGIC,
    _THREE_HALVES,
    _TWO,
    NATIVE_AVAILABLE,
    _native,
    inv_sqrt,
    quaternion_to_euler,
)

# ---------------------------------------------------------------------------------------------------------------
# ahrs_fusion_ag
# ---------------------------------------------------------------------------------------------------------------

#: ``(float)COE_MDPS_TO_RADPS``: the firmware's double literal 1.745329252e-5 cast to float32 (mdps → rad/s).
COE_MDPS_TO_RADPS_F32 = _F32(1.745329252e-5)


@dataclass(frozen=True)
class MahonySettings:
    """Filter constants of ``ahrs_fusion_ag`` (release 170120 defaults); each is used as float32 like the firmware.

    Attributes:
        kp_ground: proportional gain when ``thr < min_thr`` (``AHRS_KP_BIG``, 10).
        kp_flight: proportional gain otherwise (``AHRS_KP_NORM``, 0.4).
        ki: integral gain ``AHRS_KI`` (0.1; ETH exercise 4 sets 1.0).
        dt_s: integration period ``SENSOR_SAMPLING_TIME`` assumed by the filter, s (0.00625; the real main-loop
            period set by TIM9 is ≈ 0.00619 s).
        min_thr: ``MIN_THR`` throttle threshold for the gain switch (200).
        correction: False drops the accelerometer correction (ETH exercise 5: g* = g; the integral terms are then
            left unchanged).
        fresh_squares: True normalises with the squares of the updated quaternion (2017 releases); False (170120)
            with the squares from before the update, which leaves |q| ≈ 0.9983.
    """

    kp_ground: float = C.KP_GROUND
    kp_flight: float = C.KP_FLIGHT
    ki: float = C.KI
    dt_s: float = C.DT_S
    min_thr: int = C.MIN_THR
    correction: bool = True
    fresh_squares: bool = False

    def __post_init__(self) -> None:
        for name in ("kp_ground", "kp_flight", "ki", "dt_s"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"MahonySettings.{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        min_thr = int(self.min_thr)
        if not -(2**31) <= min_thr < 2**31:
            raise ValueError(f"MahonySettings.min_thr must fit 32 bits, got {min_thr}")
        object.__setattr__(self, "min_thr", min_thr)
        object.__setattr__(self, "correction", bool(self.correction))
        object.__setattr__(self, "fresh_squares", bool(self.fresh_squares))

    @property
    def flags(self) -> int:
        """The status-frame ``flags`` bits these settings correspond to (bit 0 no correction, bit 1 fresh squares)."""
        return (0 if self.correction else FLAG_NO_CORRECTION) | (FLAG_FRESH_SQUARES if self.fresh_squares else 0)

    @classmethod
    def from_status(cls, *, kp_ground, kp_flight, ki, dt_s, min_thr, flags) -> MahonySettings:
        """Settings reported by a status frame (its float32 fields are kept exactly)."""
        flags = int(flags)
        return cls(
            kp_ground=float(kp_ground),
            kp_flight=float(kp_flight),
            ki=float(ki),
            dt_s=float(dt_s),
            min_thr=int(min_thr),
            correction=not flags & FLAG_NO_CORRECTION,
            fresh_squares=bool(flags & FLAG_FRESH_SQUARES),
        )

    @classmethod
    def of_status(cls, status, j: int | None = None) -> MahonySettings:
        """The settings a status frame reports: ``status`` is one frame (``j`` None) or a table of status rows
        (``Telemetry.status`` or a structured array) and ``j`` its row. The one builder of settings from status
        frames (replay, compare, the live port and the diagnosis all use it)."""

        def field(name: str):
            return getattr(status, name) if j is None else _col(status, name)[j]

        return cls.from_status(**{name: field(name) for name in _STATUS_SETTING_FIELDS})

    def _params_f32(self) -> np.ndarray:
        return np.array([self.kp_ground, self.kp_flight, self.ki, self.dt_s], dtype=_F32)


@dataclass(frozen=True)
class MahonyState:
    """The filter's memory between steps: the ``ahrs.c`` globals q0..q3 and exInt, eyInt, ezInt (float32).

    ``MahonyState()`` is the power-up state (q = 1, 0, 0, 0; integrals 0). A status frame's snapshot
    (``q_wxyz``, ``int_xyz``) seeds the port so it is bit-exact from the next step on.
    """

    q_wxyz: tuple = (1.0, 0.0, 0.0, 0.0)
    int_xyz: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        q = np.asarray(self.q_wxyz, dtype=_F32).reshape(-1)
        i = np.asarray(self.int_xyz, dtype=_F32).reshape(-1)
        if q.shape != (4,) or i.shape != (3,):
            raise ValueError(f"MahonyState needs 4 q_wxyz and 3 int_xyz values, got {q.shape[0]} and {i.shape[0]}")
        object.__setattr__(self, "q_wxyz", tuple(_F32(v) for v in q))
        object.__setattr__(self, "int_xyz", tuple(_F32(v) for v in i))

    def as_array(self) -> np.ndarray:
        """(7,) float32: q0, q1, q2, q3, exInt, eyInt, ezInt."""
        return np.array(self.q_wxyz + self.int_xyz, dtype=_F32)

    @classmethod
    def from_array(cls, values) -> MahonyState:
        v = np.asarray(values, dtype=_F32).reshape(7)
        return cls(q_wxyz=tuple(v[:4]), int_xyz=tuple(v[4:]))

    def bits_equal(self, other: MahonyState) -> bool:
        """True when both states hold the same float32 bits (any NaN equals any NaN, as in :func:`bits_equal`)."""
        return bool(bits_equal(self.as_array(), other.as_array()).all())


def run(
    acc_mg,
    gyro_mdps,
    thr=None,
    *,
    settings: MahonySettings | None = None,
    state: MahonyState | None = None,
    euler: bool = True,
    native: bool | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, MahonyState]:
    """Run ``ahrs_fusion_ag`` + ``QuaternionToEuler`` over N steps, bit-exact with the firmware.

    Args:
        acc_mg: (N, 3) accelerometer ``acc_ahrs``, mg (converted to float32).
        gyro_mdps: (N, 3) gyro ``gyro_ahrs``, mdps (converted to float32).
        thr: (N,) throttle ``gTHR`` (or a scalar, or None for 0): selects kp_ground below ``min_thr``.
        settings: filter constants; default: the firmware's.
        state: starting state; default: power-up (q = 1, 0, 0, 0; integrals 0).
        euler: False skips ``QuaternionToEuler`` (thx, thy are then None).
        native: force the C loop (True) or the pure-numpy loop (False); default: C when built.

    Returns:
        ``(q_wxyz (N, 4) float32, thx_rad (N,) float32, thy_rad (N,) float32, final_state)``: ``ahrs.q`` after
        each step, ``euler_ahrs.thx`` (about x, pitch) and ``thy`` (about y, roll); NaN where the firmware gives
        NaN.
    """
    settings = MahonySettings() if settings is None else settings
    state = MahonyState() if state is None else state
    acc, gyro, thr_arr = check_inputs(acc_mg, gyro_mdps, thr)
    if native is None:
        native = NATIVE_AVAILABLE
    elif native and not NATIVE_AVAILABLE:
        raise RuntimeError("the native Mahony loop is not built (reinstall steval-link with a C compiler)")
    n = acc.shape[0]
    q = np.empty((n, 4), dtype=_F32)
    st = state.as_array()
    if native:
        thx = np.empty(n, dtype=_F32) if euler else None
        thy = np.empty(n, dtype=_F32) if euler else None
        flags = (settings.min_thr & 0xFFFFFFFF) | ((not settings.correction) << 32) | (settings.fresh_squares << 33)
        _native.run(acc, gyro, thr_arr, q, thx, thy, st, settings._params_f32(), flags)
    else:
        st = _run_pure(acc, gyro, thr_arr, q, st, settings)
        thx, thy = quaternion_to_euler(q, native=False) if euler else (None, None)
    return q, thx, thy, MahonyState.from_array(st)


def _run_pure(acc, gyro, thr, q_out, st, settings: MahonySettings) -> np.ndarray:
    """The firmware's loop with numpy float32 scalars, statement by statement (same bits as the C loop)."""
    kp_ground, kp_flight, ki, dt = (_F32(v) for v in settings._params_f32())
    min_thr = settings.min_thr
    correction = settings.correction
    fresh = settings.fresh_squares
    coe = COE_MDPS_TO_RADPS_F32
    two = _TWO
    half_t = _HALF * dt
    q0, q1, q2, q3, ex_int, ey_int, ez_int = (_F32(v) for v in st)
    acc_rows = acc.tolist()  # exact: float32 → Python float → float32 round-trips
    gyro_rows = gyro.tolist()
    thr_list = thr.tolist()
    with np.errstate(all="ignore"):
        for k in range(acc.shape[0]):
            ahrs_kp = kp_ground if thr_list[k] < min_thr else kp_flight
            ax, ay, az = acc_rows[k]
            gx, gy, gz = gyro_rows[k]
            axf, ayf, azf = _F32(ax), _F32(ay), _F32(az)
            gxf = _F32(gx) * coe
            gyf = _F32(gy) * coe
            gzf = _F32(gz) * coe

            q0q0 = q0 * q0
            q0q1 = q0 * q1
            q0q2 = q0 * q2
            q1q1 = q1 * q1
            q1q3 = q1 * q3
            q2q2 = q2 * q2
            q2q3 = q2 * q3
            q3q3 = q3 * q3

            if correction:
                norm = _inv_sqrt_scalar(axf * axf + ayf * ayf + azf * azf)
                axf = axf * norm
                ayf = ayf * norm
                azf = azf * norm

                vx = two * (q1q3 - q0q2)
                vy = two * (q0q1 + q2q3)
                vz = q0q0 - q1q1 - q2q2 + q3q3

                ex = ayf * vz - azf * vy
                ey = azf * vx - axf * vz
                ez = axf * vy - ayf * vx

                ex_int = ex_int + ex * ki * dt
                ey_int = ey_int + ey * ki * dt
                ez_int = ez_int + ez * ki * dt

                gxf = gxf + ahrs_kp * ex + ex_int
                gyf = gyf + ahrs_kp * ey + ey_int
                gzf = gzf + ahrs_kp * ez + ez_int

            q0 = q0 + (-q1 * gxf - q2 * gyf - q3 * gzf) * half_t
            q1 = q1 + (q0 * gxf + q2 * gzf - q3 * gyf) * half_t
            q2 = q2 + (q0 * gyf - q1 * gzf + q3 * gxf) * half_t
            q3 = q3 + (q0 * gzf + q1 * gyf - q2 * gxf) * half_t

            if fresh:
                norm = _inv_sqrt_scalar(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            else:
                norm = _inv_sqrt_scalar(q0q0 + q1q1 + q2q2 + q3q3)
            q0 = q0 * norm
            q1 = q1 * norm
            q2 = q2 * norm
            q3 = q3 * norm
            q_out[k] = (q0, q1, q2, q3)
    return np.array([q0, q1, q2, q3, ex_int, ey_int, ez_int], dtype=_F32)


def _inv_sqrt_scalar(x: np.float32) -> np.float32:
    """``invSqrt`` on one float32 scalar (see :func:`inv_sqrt`)."""
    halfx = _HALF * x
    i = _INVSQRT_MAGIC - (np.array(x, dtype=_F32).view(np.int32) >> np.int32(1))
    y = i.view(_F32)[()]
    return y * (_THREE_HALVES - (halfx * y * y))


def handout_yaw(q_wxyz) -> np.ndarray:
    """Yaw (about z), rad, float32: the Lab 5 handout's ``thz = atan2(2*q1*q2+2*q0*q3, q0*q0+q1*q1-q2*q2-q3*q3)``.

    Evaluated like the handout's C (float32 products and sums, double ``atan2``, stored to float32). The 170120
    firmware does not compute this (its thz is the gyro yaw integrated in the ISR); the Lab 5 simulator does.
    """
    q = np.asarray(q_wxyz, dtype=_F32)
    with np.errstate(invalid="ignore", over="ignore"):
        q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
        num = (_TWO * q1) * q2 + (_TWO * q0) * q3
        den = ((q0 * q0 + q1 * q1) - q2 * q2) - q3 * q3
        return np.arctan2(num.astype(np.float64), den.astype(np.float64)).astype(_F32)


class StMahony(Estimator):
    """The firmware's Mahony filter as an :class:`~steval_link.estimators.base.Estimator` (bit-exact, float32).

    Options (all keyword): ``kp_ground``, ``kp_flight`` (or ``kp`` for both), ``ki``, ``dt_s``, ``min_thr``,
    ``correction``, ``fresh_squares`` (see :class:`MahonySettings`), or a whole ``settings``; ``state`` seeds the
    filter (a :class:`MahonyState`, e.g. a status-frame snapshot); ``native`` forces the C or pure path.
    ``run`` returns q and thx/thy exactly as the firmware computes them (float32) and thz from the Lab 5 handout's
    yaw formula (the firmware's own thz is integrated in its ISR, not derived from q).
    """

    name = "st-mahony"

    def __init__(
        self,
        *,
        settings: MahonySettings | None = None,
        state: MahonyState | None = None,
        native: bool | None = None,
        kp: float | None = None,
        **setting_overrides,
    ) -> None:
        base = MahonySettings() if settings is None else settings
        if kp is not None:
            setting_overrides.setdefault("kp_ground", kp)
            setting_overrides.setdefault("kp_flight", kp)
        unknown = set(setting_overrides) - set(MahonySettings.__dataclass_fields__)
        if unknown:
            raise TypeError(f"StMahony() got an unexpected keyword argument {sorted(unknown)[0]!r}")
        self.settings = replace(base, **setting_overrides) if setting_overrides else base
        if native and not NATIVE_AVAILABLE:
            raise RuntimeError("the native Mahony loop is not built (reinstall steval-link with a C compiler)")
        self.native = native
        self.state = MahonyState() if state is None else state

    def reset(self) -> None:
        """Back to the power-up state (q = 1, 0, 0, 0; integrals 0)."""
        self.state = MahonyState()

    def seed(self, state: MahonyState) -> None:
        """Continue from ``state`` (e.g. a status frame's ``q_wxyz``/``int_xyz`` snapshot)."""
        self.state = state

    def step(self, acc_mg, gyro_mdps, thr: int = 0) -> np.ndarray:
        """One ``ahrs_fusion_ag`` call: returns ``ahrs.q`` after it, (4,) float32."""
        acc = np.asarray(acc_mg, dtype=_F32).reshape(1, 3)
        gyro = np.asarray(gyro_mdps, dtype=_F32).reshape(1, 3)
        q, _, _, self.state = run(
            acc, gyro, np.array([thr]), settings=self.settings, state=self.state, euler=False, native=self.native
        )
        return q[0]

    def run(self, acc_mg, gyro_mdps, thr=None) -> AttitudeEstimate:
        """N steps from the current state; q, thx, thy float32 bit-exact, thz float32 (handout formula)."""
        q, thx, thy, self.state = run(
            acc_mg, gyro_mdps, thr, settings=self.settings, state=self.state, native=self.native
        )
        valid = np.isfinite(q).all(axis=1) & np.isfinite(thx) & np.isfinite(thy)
        return AttitudeEstimate(q_wxyz=q, thx_rad=thx, thy_rad=thy, thz_rad=handout_yaw(q), valid=valid)


# ---------------------------------------------------------------------------------------------------------------
# Replaying a capture against the firmware's own outputs
# ---------------------------------------------------------------------------------------------------------------


def bits_equal(a, b) -> np.ndarray:
    """Element-wise float32 identity: same bits, or both NaN (any NaN payload)."""
    a = np.asarray(a, dtype=_F32)
    b = np.asarray(b, dtype=_F32)
    return (a.view(np.uint32) == b.view(np.uint32)) | (np.isnan(a) & np.isnan(b))


class PortFollower:
    """The bit-exact port followed along a stream in order: runs of attitude rows and the status frames' filter
    snapshots. One implementation for the replay of a whole capture (:func:`replay_firmware`) and the live port
    (``steval_link.live.estimators.LivePort``).

    The port starts from the power-up state when a run of consecutive steps begins at step 0, or from a status
    snapshot (it then continues with the step after the snapshot's). Any step gap, or a row the caller marks as not
    usable (text-mode rows, non-finite inputs), leaves it unseeded (NaN) until the next snapshot or power-up.

    ``settings``: fixed filter settings for every seed (a what-if replay); None takes each snapshot's own and
    ``initial`` at power-up. ``follow_snapshots``: what a snapshot does while the port runs in sync: True (live) —
    confirm it when state and settings agree bit for bit, else re-seed from it (a settings change, a difference); False
    (replay of a capture, which measures how far the port and the firmware agree) — ignore it, unless it is an
    event snapshot (status flag ``EVENT``: sent at once because a host command changed the settings, reset the
    filter or asked for it), which the port always follows: its settings and state apply from the next step.
    """

    def __init__(
        self,
        settings: MahonySettings | None = None,
        *,
        initial: MahonySettings | None = None,
        follow_snapshots: bool = True,
        euler: bool = True,
        native: bool | None = None,
    ) -> None:
        self.fixed = settings
        self.settings = settings or initial or MahonySettings()
        self.follow_snapshots = follow_snapshots
        self.euler = euler
        self.native = native
        self.state: MahonyState | None = None
        self.next_step: int | None = None
        self.seed_count = 0  #: (re)starts of the port so far (power-up or snapshot)
        self.confirmed = 0  #: snapshots that matched the port's own state and settings bit for bit
        self._pending: tuple[str, int | None, MahonySettings] | None = None
        #: (first row of the seed in the caller's numbering, seed) of every seed, once its first row ran
        self.seed_rows: list[tuple[int, tuple[str, int | None, MahonySettings]]] = []

    @property
    def seeded(self) -> bool:
        return self.state is not None

    def snapshot(
        self,
        step: int,
        state: MahonyState,
        settings: MahonySettings,
        snapshot_id: int | None = None,
        *,
        event: bool = False,
    ) -> str:
        """The firmware's filter state right after step ``step`` (``event``: a status sent because of a host
        command, see the class docstring). Returns what it did: "confirmed", "seeded" or "ignored". A non-finite
        snapshot (the firmware's own filter holds NaN: it diverged) seeds nothing, but its settings are the build's:
        the port takes them (unless fixed) and, when it runs in sync, keeps running on the inputs."""
        in_sync = self.state is not None and self.next_step == step + 1
        if in_sync and not (self.follow_snapshots or event):
            return "ignored"
        if in_sync and (self.fixed is not None or settings == self.settings) and self.state.bits_equal(state):
            self.confirmed += 1
            return "confirmed"
        if not np.all(np.isfinite(state.as_array())):
            if self.fixed is None and (self.follow_snapshots or event or self.state is None):
                self.settings = settings
            return "ignored"
        self.state = state
        self.settings = self.fixed or settings
        self.next_step = step + 1
        self._pending = ("status", snapshot_id, self.settings)
        self.seed_count += 1
        return "seeded"

    def rows(self, step, acc_mg, gyro_mdps, thr, usable, *, first_row: int = 0):
        """Step the port over these attitude rows (in stream order; ``usable``: (N,) bool). Returns (q (N, 4),
        thx (N,), thy (N,) — None without ``euler`` —, seeded (N,) bool); NaN where unseeded."""
        step = np.asarray(step, dtype=np.int64)
        n = step.shape[0]
        q = np.full((n, 4), np.nan, dtype=_F32)
        thx = np.full(n, np.nan, dtype=_F32) if self.euler else None
        thy = np.full(n, np.nan, dtype=_F32) if self.euler else None
        seeded = np.zeros(n, dtype=bool)
        breaks = np.flatnonzero((np.diff(step) != 1) | ~usable[1:] | ~usable[:-1]) + 1
        for a, b in zip(np.concatenate(([0], breaks)).tolist(), np.concatenate((breaks, [n])).tolist()):
            if a >= b:
                continue
            if not usable[a]:
                self.state = self.next_step = None
                continue
            s0 = int(step[a])
            if self.state is not None and self.next_step != s0:
                self.state = None  # frames lost: out of sync until the next snapshot
            if self.state is None and s0 == 0:
                self.state = MahonyState()  # the stream starts at power-up
                self._pending = ("power-up", None, self.settings)
                self.seed_count += 1
            if self.state is not None:
                if self._pending is not None:
                    self.seed_rows.append((first_row + a, self._pending))
                    self._pending = None
                out = run(
                    acc_mg[a:b],
                    gyro_mdps[a:b],
                    thr[a:b],
                    settings=self.settings,
                    state=self.state,
                    euler=self.euler,
                    native=self.native,
                )
                q[a:b], self.state = out[0], out[3]
                if self.euler:
                    thx[a:b], thy[a:b] = out[1], out[2]
                seeded[a:b] = True
            self.next_step = int(step[b - 1]) + 1
        return q, thx, thy, seeded


@dataclass(frozen=True)
class ReplaySeed:
    """Where the port (re)started during a replay: attitude row ``row`` (AHRS step ``step``) onwards.

    ``source`` is ``"power-up"`` (capture from step 0) or ``"status"`` (snapshot of status row ``status_row``,
    taken right after step ``step - 1``).
    """

    row: int
    step: int
    source: str
    status_row: int | None
    settings: MahonySettings


@dataclass(frozen=True)
class FirmwareReplay:
    """The port re-run over a capture, row by row next to the firmware's attitude frames.

    Attributes:
        q_wxyz: (N, 4) float32, the port's ``ahrs.q`` per attitude row (NaN where not seeded).
        thx_rad, thy_rad: (N,) float32, the port's ``QuaternionToEuler`` (pitch about x, roll about y).
        bit_exact: (N,) bool, port q, thx and thy carry the firmware's bits (NaN == NaN).
        seeded: (N,) bool, the port had a known state for this row (from power-up or a status snapshot).
        first_mismatch: row index of the first seeded row that is not bit-exact, or None.
        seeds: every (re)start of the port, in row order.
    """

    q_wxyz: np.ndarray
    thx_rad: np.ndarray
    thy_rad: np.ndarray
    bit_exact: np.ndarray
    seeded: np.ndarray
    first_mismatch: int | None
    seeds: tuple[ReplaySeed, ...]

    @property
    def n_seeded(self) -> int:
        return int(np.count_nonzero(self.seeded))

    @property
    def n_bit_exact(self) -> int:
        return int(np.count_nonzero(self.bit_exact))

    @property
    def all_exact(self) -> bool:
        """True when every seeded row is bit-exact (and at least one row is seeded)."""
        return self.n_seeded > 0 and self.first_mismatch is None


#: the status-frame fields that make up a :class:`MahonySettings`
_STATUS_SETTING_FIELDS = ("kp_ground", "kp_flight", "ki", "dt_s", "min_thr", "flags")


def _col(table, name: str):
    """A column of a telemetry table given as an object with array attributes or as a structured array."""
    if isinstance(table, np.ndarray) and table.dtype.names:
        return table[name]
    return getattr(table, name)


def replay_firmware(tel, settings: MahonySettings | None = None, *, native: bool | None = None) -> FirmwareReplay:
    """Re-run the port over a capture's inputs and compare it with the firmware's outputs, bit for bit.

    Args:
        tel: a :class:`steval_link.link.telemetry.Telemetry` (uses ``attitude.step/acc_mg/gyro_mdps/thr/q_wxyz`` and
            ``thx_rad/thy_rad`` when present, and ``status.step/q_wxyz/int_xyz/kp_ground/kp_flight/ki/dt_s/
            min_thr/flags``).
        settings: filter constants; default: those reported by the status frames (the seeding one, else the
            first one), or the firmware's defaults when the capture has no status frame.
        native: force the C or the pure loop (default: C when built).

    The port starts from the power-up state when a run of consecutive steps begins at step 0; otherwise (joined
    mid-flight, or after dropped frames: any step gap) it waits for the first status snapshot inside that run and
    continues from the following step. Rows before a seed are unseeded: NaN, not bit-exact.
    """
    att = tel.attitude
    steps = np.asarray(_col(att, "step"), dtype=np.int64)
    n = steps.shape[0]
    acc = np.ascontiguousarray(_col(att, "acc_mg"), dtype=_F32).reshape(n, 3)
    gyro = np.ascontiguousarray(_col(att, "gyro_mdps"), dtype=_F32).reshape(n, 3)
    thr = np.asarray(_col(att, "thr"), dtype=np.int64).reshape(n)
    fw_q = np.asarray(_col(att, "q_wxyz"), dtype=_F32).reshape(n, 4)
    try:
        fw_thx = np.asarray(_col(att, "thx_rad"), dtype=_F32).reshape(n)
        fw_thy = np.asarray(_col(att, "thy_rad"), dtype=_F32).reshape(n)
    except (AttributeError, KeyError, ValueError):
        fw_thx, fw_thy = quaternion_to_euler(fw_q)

    status = getattr(tel, "status", None)
    st_steps = np.zeros(0, dtype=np.int64) if status is None else np.asarray(_col(status, "step"), dtype=np.int64)
    if st_steps.size:
        # Only binary status frames carry a snapshot and the settings; text-mode $STA rows hold NaN there.
        usable = (
            np.isfinite(np.asarray(_col(status, "kp_ground"), dtype=np.float64))
            & np.isfinite(np.asarray(_col(status, "q_wxyz"), dtype=np.float64)).all(axis=1)
            & np.isfinite(np.asarray(_col(status, "int_xyz"), dtype=np.float64)).all(axis=1)
        )
        st_steps = np.where(usable, st_steps, -1)  # -1 never matches a snapshot step
        order = np.flatnonzero(usable)[np.argsort(st_steps[usable], kind="stable")]
    else:
        order = np.zeros(0, dtype=np.int64)
    st_sorted = st_steps[order]
    st_events = np.zeros(st_steps.shape[0], dtype=bool)
    if st_steps.size:
        st_events = (np.asarray(_col(status, "flags"), dtype=np.int64) & FLAG_EVENT) != 0
    default_settings = settings
    if default_settings is None:
        # the build's settings: the first status frame that reports them (its snapshot may hold NaN: a filter
        # that diverged still runs with the build's settings)
        has_settings = np.zeros(st_steps.shape[0], dtype=bool)
        if st_steps.size:
            has_settings = np.all(
                [
                    np.isfinite(np.asarray(_col(status, k), dtype=np.float64))
                    for k in ("kp_ground", "kp_flight", "ki", "dt_s")
                ],
                axis=0,
            )
        first = np.flatnonzero(has_settings)
        default_settings = (
            MahonySettings.of_status(status, int(order[0]))
            if order.size
            else MahonySettings.of_status(status, int(first[0]))
            if first.size
            else MahonySettings()
        )

    try:  # rounded text-mode rows are no exact filter inputs: never replayed
        exact_rows = np.asarray(_col(att, "exact"), dtype=bool).reshape(n)
    except (AttributeError, KeyError, ValueError):
        exact_rows = np.ones(n, dtype=bool)

    # in stream order: each run of consecutive exact rows, seeded at power-up or by the first snapshot inside it
    port = PortFollower(settings, initial=default_settings, follow_snapshots=False, native=native)
    parts = []
    breaks = np.flatnonzero((np.diff(steps) != 1) | (exact_rows[1:] != exact_rows[:-1])) + 1
    for a, b in zip(np.concatenate(([0], breaks)).tolist(), np.concatenate((breaks, [n])).tolist()):
        if a >= b:
            continue
        cut = a
        s_first, s_last = int(steps[a]), int(steps[b - 1])
        if exact_rows[a]:
            # the first usable snapshot seeds a run that does not start at power-up; later ones are followed only
            # when they announce a host command's change (EVENT), else the replay measures agreement
            hi = int(np.searchsorted(st_sorted, s_last - 1, side="right"))
            lo = int(np.searchsorted(st_sorted, s_first - 1, side="left"))
            seeded_run = steps[a] == 0
            for k in range(lo, hi):
                j = int(order[k])
                is_event = bool(st_events[j])
                if seeded_run and not is_event:
                    continue
                end = a + int(st_sorted[k]) + 1 - s_first  # rows up to the snapshot's step
                if end > cut:
                    parts.append(
                        port.rows(
                            steps[cut:end],
                            acc[cut:end],
                            gyro[cut:end],
                            thr[cut:end],
                            exact_rows[cut:end],
                            first_row=cut,
                        )
                    )
                    cut = end
                port.snapshot(
                    int(st_sorted[k]),
                    MahonyState(q_wxyz=_col(status, "q_wxyz")[j], int_xyz=_col(status, "int_xyz")[j]),
                    MahonySettings.of_status(status, j),
                    snapshot_id=j,
                    event=is_event,
                )
                seeded_run = seeded_run or port.seeded
        parts.append(port.rows(steps[cut:b], acc[cut:b], gyro[cut:b], thr[cut:b], exact_rows[cut:b], first_row=cut))
    if parts:
        q = np.concatenate([p[0] for p in parts])
        thx = np.concatenate([p[1] for p in parts])
        thy = np.concatenate([p[2] for p in parts])
        seeded = np.concatenate([p[3] for p in parts])
    else:
        q, thx, thy = np.zeros((0, 4), _F32), np.zeros(0, _F32), np.zeros(0, _F32)
        seeded = np.zeros(0, dtype=bool)
    seeds = [ReplaySeed(row, int(steps[row]), src, sid, st) for row, (src, sid, st) in port.seed_rows]

    exact = seeded & bits_equal(q, fw_q).all(axis=1) & bits_equal(thx, fw_thx) & bits_equal(thy, fw_thy)
    bad = np.flatnonzero(seeded & ~exact)
    return FirmwareReplay(
        q_wxyz=q,
        thx_rad=thx,
        thy_rad=thy,
        bit_exact=exact,
        seeded=seeded,
        first_mismatch=int(bad[0]) if bad.size else None,
        seeds=tuple(seeds),
    )

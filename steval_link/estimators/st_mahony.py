"""Bit-exact port of the STEVAL-FCU001V1 firmware's Mahony filter (ST release 170120).

Reproduces ``ahrs_fusion_ag`` and ``QuaternionToEuler`` in float32 exactly as the drone computes them (Cortex-M4F,
hard float, -O0, no FMA), rounding included. Units are the firmware's: accelerometer in mg, gyro in mdps, angles in
rad; axes x right, y forward, z up; ``thx`` is the rotation about x (pitch, nose up +), ``thy`` about y (roll).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from steval_link.estimators.base import check_inputs
from steval_link.protocol import FLAG_FRESH_SQUARES, FLAG_NO_CORRECTION

__all__ = [
    "COE_MDPS_TO_RADPS_F32",
    "NATIVE_AVAILABLE",
    "MahonySettings",
    "MahonyState",
    "run",
    "quaternion_to_euler",
    "inv_sqrt",
]

_F32 = np.float32
_TWO = _F32(2.0)
_HALF = _F32(0.5)
_THREE_HALVES = _F32(1.5)
_INVSQRT_MAGIC = np.int32(0x5F3759DF)


def inv_sqrt(x) -> np.ndarray:
    """The firmware's ``invSqrt``: 0x5f3759df guess and one Newton step, all float32 (finite for 0).

    ``x`` is any float32 array (or scalar); returns float32 of the same shape.
    """
    x = np.asarray(x, dtype=_F32)
    halfx = _HALF * x
    i = x.view(np.int32)
    i = _INVSQRT_MAGIC - (i >> 1)  # arithmetic shift, as ``long`` on the Cortex-M4
    y = i.view(_F32)
    return y * (_THREE_HALVES - (halfx * y * y))


def quaternion_to_euler(q_wxyz) -> tuple[np.ndarray, np.ndarray]:
    """The firmware's ``QuaternionToEuler``: (thx_rad, thy_rad) as float32 arrays, bit-exact.

    ``q_wxyz`` is (N, 4) or (4,) float32 (``ahrs.q``: q0 scalar first). Products and sums are float32 in the C
    source's order; only ``atan2``/``asin`` run in double, and their results are stored to float32 as the firmware
    does. thx = atan2(2q0q1 + 2q2q3, q0² + q3² − q1² − q2²) is the rotation about x (pitch), thy =
    asin(2q0q2 − 2q1q3) the rotation about y (roll); thy is NaN where the (not quite unit) quaternion makes the
    argument leave [−1, 1], as on the drone.
    """
    q = np.asarray(q_wxyz, dtype=_F32)
    if q.shape[-1] != 4:
        raise ValueError(f"q_wxyz must have 4 components in its last axis, got shape {q.shape}")
    with np.errstate(invalid="ignore", over="ignore"):
        q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
        q0q0 = q0 * q0
        q1q1 = q1 * q1
        q2q2 = q2 * q2
        q3q3 = q3 * q3
        dq0 = _TWO * q0
        dq1 = _TWO * q1
        dq2 = _TWO * q2
        dq1q3 = dq1 * q3
        dq0q2 = dq0 * q2
        dq0q1 = dq0 * q1
        dq2q3 = dq2 * q3
        num_x = dq0q1 + dq2q3
        den_x = ((q0q0 + q3q3) - q1q1) - q2q2
        arg_y = dq0q2 - dq1q3
        thx = np.arctan2(num_x.astype(np.float64), den_x.astype(np.float64)).astype(_F32)
        thy = np.arcsin(arg_y.astype(np.float64)).astype(_F32)
    return thx, thy


# ---------------------------------------------------------------------------------------------------------------
# ahrs_fusion_ag
# ---------------------------------------------------------------------------------------------------------------

#: ``(float)COE_MDPS_TO_RADPS``: the firmware's double literal 1.745329252e-5 cast to float32 (mdps → rad/s).
COE_MDPS_TO_RADPS_F32 = _F32(1.745329252e-5)

try:  # the C loop (built by setup.py, optional); the pure-numpy path below gives the same bits, slower
    from steval_link.estimators import _st_mahony_native as _native
except ImportError:  # pragma: no cover - depends on the build
    _native = None

#: True when the compiled loop is available (≈ 100× faster than the pure path, same bits).
NATIVE_AVAILABLE = _native is not None


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

    kp_ground: float = 10.0
    kp_flight: float = 0.4
    ki: float = 0.1
    dt_s: float = 0.00625
    min_thr: int = 200
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
        """True when both states hold the same float32 bits."""
        return bool(np.array_equal(self.as_array().view(np.uint32), other.as_array().view(np.uint32)))


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
        thx, thy = quaternion_to_euler(q) if euler else (None, None)
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

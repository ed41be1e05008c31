"""Bit-exact replica of the STEVAL-FCU001V1 firmware's Mahony filter, in each of ST's releases' arithmetic.

``ahrs_fusion_ag`` and ``QuaternionToEuler`` in float32 exactly as the drone computes them, rounding included. Units
are the firmware's (acc mg, gyro mdps, angles rad; x right, y forward, z up); ``thx`` is the rotation about x (pitch,
nose up +), ``thy`` about y (roll).

The firmware's quirks are kept on purpose: the fast inverse square root (finite for 0: free fall gives no
correction, not NaN); kp switched by throttle; the in-place quaternion update (q1..q3 use the new q0); the final
normalisation with the squares from **before** the update, so |q| ≈ 0.9983 and ``asin`` can return NaN near ±90°
roll, as on the drone. ST 221117 (``VARIANTS``) computes the gyro scale, the integral step and halfT in double and
normalises with the fresh squares.
Two loops give the same bits: the C extension ``_st_mahony_native`` and a numpy-float32 loop without it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from steval_link import constants as C
from steval_link.estimators.base import AttitudeEstimate, Estimator, check_inputs
from steval_link.fw_math import (  # the firmware's float32 arithmetic, shared with the link layer
    _F32,
    _HALF,
    _TWO,
    NATIVE_AVAILABLE,
    _native,
    choose_native,
    inv_sqrt,
    quaternion_to_euler,
)
from steval_link.link.protocol import FLAG_FRESH_SQUARES, FLAG_NO_CORRECTION

#: ``(float)COE_MDPS_TO_RADPS``: the firmware's double literal 1.745329252e-5 cast to float32 (mdps → rad/s).
COE_MDPS_TO_RADPS_F32 = _F32(C.COE_MDPS_TO_RADPS)

#: The filter variants of ST's releases, by name: what each one's ``ahrs.c`` is shared with.
VARIANTS = {
    "ST 170120": "ST's 170120, 170318 and 301117 beta releases (one ahrs.c): float32 throughout, the final "
    "normalisation with the squares from before the update",
    "ST 221117": "ST's 221117 release: the gyro scale, the integral step and halfT in double, the final "
    "normalisation with the squares of the updated quaternion",
}
DEFAULT_VARIANT = "ST 170120"
# other spellings of the releases: each of 170318 and 301117 (beta) has 170120's ahrs.c
_VARIANT_ALIASES = {"170120": "ST 170120", "170318": "ST 170120", "301117": "ST 170120", "221117": "ST 221117"}


def variant_name(text: str) -> str:
    """The variant a release's name stands for ("221117", "st-301117 beta"...); ValueError for an unknown one."""
    key = str(text).strip().lower().removesuffix("beta").strip().removeprefix("st").strip(" -_")
    if key in _VARIANT_ALIASES:
        return _VARIANT_ALIASES[key]
    known = ", ".join(sorted(_VARIANT_ALIASES))
    raise ValueError(f"no ST release named {text!r} (known: {known}; 170318 and 301117 have 170120's filter)")


@dataclass(frozen=True)
class MahonySettings:
    """Filter constants of ``ahrs_fusion_ag`` (defaults: :mod:`steval_link.constants`) and the release whose
    arithmetic is reproduced (``variant``, any name :func:`variant_name` knows).

    ``kp_ground`` is the gain below ``min_thr``; ``dt_s`` is the filter's assumed period, s, not the real 6.19 ms;
    ``correction`` False drops the accelerometer correction (ETH exercise 5). In "ST 170120" each constant is used
    as float32; in "ST 221117" ``ki`` and ``dt_s`` are doubles, a float32 default standing for ST's literal.
    """

    kp_ground: float = C.KP_GROUND
    kp_flight: float = C.KP_FLIGHT
    ki: float = C.KI
    dt_s: float = C.DT_S
    min_thr: int = C.MIN_THR
    correction: bool = True
    variant: str = DEFAULT_VARIANT

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
        object.__setattr__(self, "variant", variant_name(self.variant))

    @property
    def fresh_squares(self) -> bool:
        """True when the final normalisation uses the updated quaternion's squares (ST 221117)."""
        return self.variant == "ST 221117"

    @property
    def flags(self) -> int:
        """The status-frame ``flags`` bits of these settings."""
        return (0 if self.correction else FLAG_NO_CORRECTION) | (FLAG_FRESH_SQUARES if self.fresh_squares else 0)

    @classmethod
    def of_status(cls, status, j: int | None = None) -> MahonySettings:
        """The settings a status frame reports, float32 fields kept exactly: one frame (``j`` None) or row ``j`` of a
        table of status rows (``Telemetry.status`` or a structured array)."""

        def field(name: str):
            return getattr(status, name) if j is None else table_column(status, name)[j]

        flags = int(field("flags"))
        gains = {k: float(field(k)) for k in ("kp_ground", "kp_flight", "ki", "dt_s")}
        return cls(
            **gains,
            min_thr=int(field("min_thr")),
            correction=not flags & FLAG_NO_CORRECTION,
            variant="ST 221117" if flags & FLAG_FRESH_SQUARES else DEFAULT_VARIANT,
        )

    def _params(self) -> np.ndarray:
        """(4,) float64: kp_ground, kp_flight, ki, dt_s as this variant's arithmetic uses them."""
        kp_ground, kp_flight, ki, dt = (float(_F32(v)) for v in (self.kp_ground, self.kp_flight, self.ki, self.dt_s))
        if self.variant == "ST 221117":
            ki = C.KI if ki == float(_F32(C.KI)) else self.ki
            dt = C.DT_S if dt == float(_F32(C.DT_S)) else self.dt_s
        return np.array([kp_ground, kp_flight, ki, dt], dtype=np.float64)


@dataclass(frozen=True)
class MahonyState:
    """The filter's memory between steps, float32: the ``ahrs.c`` globals q0..q3 and exInt, eyInt, ezInt.
    ``MahonyState()`` is the power-up state; a status frame's snapshot seeds the replica bit-exact."""

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

    def bits_equal(self, other: MahonyState) -> bool:
        """True when both states hold the same float32 bits (any NaN equals any NaN)."""
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

    ``acc_mg`` (N, 3) mg, ``gyro_mdps`` (N, 3) mdps (as float32); ``thr`` (N,) ``gTHR``, a scalar or None for 0.
    ``state`` default: power-up; ``euler`` False skips ``QuaternionToEuler``; ``native`` True/False forces the C or
    numpy loop. Returns ``ahrs.q`` (N, 4), thx (about x, pitch) and thy (about y, roll) after each step (float32,
    NaN where the firmware gives NaN; None without ``euler``) and the final state.
    """
    settings = MahonySettings() if settings is None else settings
    acc, gyro, thr_arr = check_inputs(acc_mg, gyro_mdps, thr)
    native = choose_native(native, NATIVE_AVAILABLE, "Mahony")
    n = acc.shape[0]
    q = np.empty((n, 4), dtype=_F32)
    st = (state or MahonyState()).as_array()
    if native:
        thx, thy = np.empty((2, n), dtype=_F32) if euler else (None, None)
        flags = (settings.min_thr & 0xFFFFFFFF) | ((not settings.correction) << 32) | (settings.fresh_squares << 33)
        _native.run(acc, gyro, thr_arr, q, thx, thy, st, settings._params(), flags)
    else:
        st = _run_pure(acc, gyro, thr_arr, q, st, settings)
        thx, thy = quaternion_to_euler(q, native=False) if euler else (None, None)
    return q, thx, thy, MahonyState(q_wxyz=st[:4], int_xyz=st[4:])


def _run_pure(acc, gyro, thr, q_out, st, settings: MahonySettings) -> np.ndarray:
    """The firmware's loop in numpy float32 scalars, statement by statement (the C loop's bits); what does not
    depend on the state (gyro scale, the accelerometer's normalisation, kp) is done for all rows first."""
    kp_ground, kp_flight, ki_d, dt_d = settings._params().tolist()
    ki, dt = _F32(ki_d), _F32(dt_d)
    st221117 = settings.variant == "ST 221117"
    half_t = _F32(0.5 * dt_d) if st221117 else _HALF * dt
    q0, q1, q2, q3, *integral = (_F32(v) for v in st)  # q, then exInt, eyInt, ezInt
    with np.errstate(all="ignore"):
        gyro_rad = gyro * COE_MDPS_TO_RADPS_F32
        if st221117:  # float * double literal: a double product, stored to float
            gyro_rad = (gyro.astype(np.float64) * C.COE_MDPS_TO_RADPS).astype(_F32)
        acc_unit = acc * inv_sqrt(acc[:, 0] * acc[:, 0] + acc[:, 1] * acc[:, 1] + acc[:, 2] * acc[:, 2])[:, None]
        kp_rows = np.where(thr < settings.min_thr, _F32(kp_ground), _F32(kp_flight)).astype(_F32)
        for k, (a, g, ahrs_kp) in enumerate(zip(acc_unit, gyro_rad, kp_rows)):
            g = list(g)  # float32 scalars, as a, v and e
            q0q0 = q0 * q0
            q0q1 = q0 * q1
            q0q2 = q0 * q2
            q1q1 = q1 * q1
            q1q3 = q1 * q3
            q2q2 = q2 * q2
            q2q3 = q2 * q3
            q3q3 = q3 * q3

            if settings.correction:  # e = a × v; exInt += ex * AHRS_KI * SENSOR_SAMPLING_TIME; g += kp·e + int
                v = (_TWO * (q1q3 - q0q2), _TWO * (q0q1 + q2q3), q0q0 - q1q1 - q2q2 + q3q3)
                for i, j, m in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
                    e = a[j] * v[m] - a[m] * v[j]
                    if st221117:  # in double, stored to float
                        integral[i] = _F32(float(integral[i]) + float(e) * ki_d * dt_d)
                    else:
                        integral[i] = integral[i] + e * ki * dt
                    g[i] = g[i] + ahrs_kp * e + integral[i]
            gxf, gyf, gzf = g
            q0 = q0 + (-q1 * gxf - q2 * gyf - q3 * gzf) * half_t
            q1 = q1 + (q0 * gxf + q2 * gzf - q3 * gyf) * half_t
            q2 = q2 + (q0 * gyf - q1 * gzf + q3 * gxf) * half_t
            q3 = q3 + (q0 * gzf + q1 * gyf - q2 * gxf) * half_t

            norm = inv_sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3 if st221117 else q0q0 + q1q1 + q2q2 + q3q3)
            q0, q1, q2, q3 = q0 * norm, q1 * norm, q2 * norm, q3 * norm
            q_out[k] = (q0, q1, q2, q3)
    return np.array([q0, q1, q2, q3, *integral], dtype=_F32)


def handout_yaw(q_wxyz) -> np.ndarray:
    """Yaw (about z), rad, float32, as the Lab 5 handout's C computes it (float32 products, double ``atan2``); the
    firmware's own thz is the gyro yaw integrated in the ISR."""
    q = np.asarray(q_wxyz, dtype=_F32)
    with np.errstate(invalid="ignore", over="ignore"):
        q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
        num = (_TWO * q1) * q2 + (_TWO * q0) * q3
        den = ((q0 * q0 + q1 * q1) - q2 * q2) - q3 * q3
        return np.arctan2(num.astype(np.float64), den.astype(np.float64)).astype(_F32)


class StMahony(Estimator):
    """The firmware's Mahony filter as an estimator (bit-exact, float32). Options: the fields of
    :class:`MahonySettings` (``kp`` sets both gains) or a whole ``settings``; ``state`` seeds the filter; ``native``
    forces the C or pure loop. thz is :func:`handout_yaw`."""

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
        if kp is not None:
            setting_overrides = {"kp_ground": kp, "kp_flight": kp, **setting_overrides}
        if unknown := set(setting_overrides) - set(MahonySettings.__dataclass_fields__):
            raise TypeError(f"StMahony() got an unexpected keyword argument {sorted(unknown)[0]!r}")
        self.settings = replace(settings or MahonySettings(), **setting_overrides)
        choose_native(native, NATIVE_AVAILABLE, "Mahony")  # raises now when the C loop is asked for and not built
        self.native = native
        self.state = MahonyState() if state is None else state

    def reset(self) -> None:
        self.state = MahonyState()

    def seed(self, state: MahonyState) -> None:
        """Continue from ``state`` (e.g. a status frame's snapshot)."""
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
        q, thx, thy, self.state = run(
            acc_mg, gyro_mdps, thr, settings=self.settings, state=self.state, native=self.native
        )
        valid = np.isfinite(q).all(axis=1) & np.isfinite(thx) & np.isfinite(thy)
        return AttitudeEstimate(q_wxyz=q, thx_rad=thx, thy_rad=thy, thz_rad=handout_yaw(q), valid=valid)


def bits_equal(a, b) -> np.ndarray:
    """Element-wise float32 identity: same bits, or both NaN (any NaN payload)."""
    a = np.asarray(a, dtype=_F32)
    b = np.asarray(b, dtype=_F32)
    return (a.view(np.uint32) == b.view(np.uint32)) | (np.isnan(a) & np.isnan(b))


def table_column(table, name: str):
    """A column of a telemetry table given as an object with array attributes or as a structured array."""
    if isinstance(table, np.ndarray) and table.dtype.names:
        return table[name]
    return getattr(table, name)

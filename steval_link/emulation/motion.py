"""Motion profiles: what the drone's body does at every TIM9 tick (807.7 Hz), in the firmware's axes (x right,
y forward, z up; at rest the specific force is (0, 0, +1000) mg). Angles follow ``QuaternionToEuler``: ``thx``
about x (pitch), ``thy`` about y (roll); ``q = Rz(yaw) ⊗ Ry(thy) ⊗ Rx(thx)``. :func:`render` renders a scenario's
kinematics, :func:`broad_profile` a BROAD trial (real motion, real IMU signals).

Physics: specific force ``f = Rᵀ(a + g·ẑ)``, ``a`` the IMU's acceleration (translation plus the lever arm of a
rotation about a pivot, e.g. a wrist); in flight it is the thrust along body z (``f = (0, 0, (g + a_z)/R₃₃)``), so
the accelerometer does not see the tilt: what the in-flight gain ``kp = 0.4`` is for. Motor vibration (4 motors,
harmonics 1 and 2, amplitude ∝ speed²) is added to both sensors while ``gTHR ≥ MIN_THR``, at the sensor *output*.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from steval_link import constants as C
from steval_link.emulation import sensor_model as sm
from steval_link.emulation.scenarios import MG_PER_MPS2, Kinematics, rotmat
from steval_link.errors import ParamError
from steval_link.quat import interpolate_quat, quat_conjugate, quat_multiply
from steval_link.units import RAD_TO_MDPS


@dataclass(frozen=True)
class MotionProfile:
    """The true motion at each ISR tick (body axes)."""

    name: str  #: scenario name (or the BROAD trial's name)
    t_s: np.ndarray  #: (T,) tick times, s since power-up
    q_wxyz: np.ndarray  #: (T, 4) true orientation, body → earth (NaN where unknown, e.g. occluded BROAD markers)
    acc_mg: np.ndarray  #: (T, 3) specific force the accelerometer senses, mg
    gyro_mdps: np.ndarray  #: (T, 3) angular rate as the gyro's 416 Hz output register holds it at the tick, mdps
    thr: np.ndarray  #: (T,) int16 throttle ``gTHR``
    measured: bool = False  #: acc/gyro are a real IMU's measurements (BROAD): add no sensor noise
    #: (T, 3) int16 the remote's ``gAIL, gELE, gRUD`` in the firmware's units and signs (None: centred):
    #: ``euler_rc.thx = -gELE·30°/1800`` (pitch), ``thy = -gAIL·30°/1800`` (roll), ``|gRUD| > 600`` turns the yaw target
    sticks: np.ndarray | None = None
    armed: np.ndarray | None = None  #: (T,) bool the remote's arming switch (``joydata[7]`` bit 2; None: never)


RC_RATE_HZ = 50.0  #: RC receiver frame rate, Hz: ``gTHR`` changes at this rate
_H_RATE = 1e-4
_H_ACC = 2e-3


def _vibration(t, thr_tick, rng: np.random.Generator, t_eval):
    """Motor vibration (acc mg at ``t``, gyro mdps at ``t_eval``): 4 motors, harmonics 1 and 2, ∝ speed²."""
    on = thr_tick >= C.MIN_THR
    if not np.any(on):
        return None
    thr = np.where(on, thr_tick, 0).astype(np.float64)
    f_m = np.where(on, 90.0 + 0.6 * thr, 0.0)  # motor rotation rate, Hz (≈ 390 Hz at the hover throttle)
    phase = 2 * np.pi * np.cumsum(f_m * np.diff(t, prepend=t[0]))
    scale = np.where(on, (thr / 500.0) ** 2, 0.0)
    acc, gyro = np.zeros((len(t), 3)), np.zeros((len(t_eval), 3))
    phase_e, scale_e = np.interp(t_eval, t, phase), np.interp(t_eval, t, scale)
    acc_amp = np.array([30.0, 30.0, 55.0])  # mg per motor-harmonic-1 at hover speed
    gyro_amp = np.array([500.0, 500.0, 250.0])  # mdps
    for _ in range(4):
        ratio = 1.0 + rng.normal(0.0, 0.015)
        for h, (ka, kg) in enumerate(((0.5, 0.5), (0.25, 0.2)), start=1):
            ph, pg = rng.uniform(0, 2 * np.pi, 3), rng.uniform(0, 2 * np.pi, 3)  # acc's, then gyro's
            acc += ka * acc_amp * scale[:, None] * np.sin(h * ratio * phase[:, None] + ph)
            gyro += kg * gyro_amp * scale_e[:, None] * np.sin(h * ratio * phase_e[:, None] + pg)
    return acc, gyro


def render(
    name: str, kin: Kinematics, t: np.ndarray, rng: np.random.Generator, throttle: Callable | None = None
) -> MotionProfile:
    """Scenario ``name``'s kinematics at tick times ``t`` (s since power-up); ``throttle`` overrides its own."""
    t = np.asarray(t, dtype=np.float64)
    q = kin.q(t)
    # gyro: the output register holds the rate sampled at the 416 Hz ODR
    t_hold = sm.gyro_hold_times_s(t, t[0])
    dq = (kin.q(t_hold + _H_RATE) - kin.q(t_hold - _H_RATE)) / (2 * _H_RATE)  # q̇ by a central difference
    gyro = 2.0 * quat_multiply(quat_conjugate(kin.q(t_hold)), dq)[:, 1:] * RAD_TO_MDPS  # ω = 2·vec(q* ⊗ q̇), body
    a = np.zeros((len(t), 3))  # earth-frame acceleration of the IMU rotating about a pivot lever_m away, mg
    if np.any(kin.lever_m):
        p = [(rotmat(kin.q(t + d)) @ kin.lever_m) for d in (-_H_ACC, 0.0, _H_ACC)]
        a = (p[0] - 2 * p[1] + p[2]) / (_H_ACC * _H_ACC) * MG_PER_MPS2
    if kin.lever_weight is not None:
        a *= kin.lever_weight(t)[:, None]
    if kin.lin_acc_mg is not None:
        a = kin.lin_acc_mg(t) + a
    rot = rotmat(q)
    g_plus_a = a + np.array([0.0, 0.0, 1000.0])
    f = np.einsum("nji,nj->ni", rot, g_plus_a)  # Rᵀ (a + g ẑ)
    if kin.airborne is not None:
        w = kin.airborne(t)
        f = (1 - w[:, None]) * f
        f[:, 2] += w * (g_plus_a[:, 2] / np.maximum(rot[:, 2, 2], 0.2))  # thrust along body z
    # throttle: the RC receiver updates gTHR at ~50 Hz, integer units with ±1 jitter while the stick is up
    thr_fn = throttle if throttle is not None else kin.thr
    t_rc = np.floor(t * RC_RATE_HZ) / RC_RATE_HZ
    uniq, inv = np.unique(t_rc, return_inverse=True)
    thr_val = np.asarray(thr_fn(uniq), dtype=np.float64)
    thr_rc = np.clip(np.rint(thr_val) + np.where(thr_val > 0, rng.integers(-1, 2, len(uniq)), 0), -32768, 32767)
    thr_rc = np.where(thr_val > 0, np.maximum(thr_rc, 0), thr_rc)
    thr_tick = thr_rc[inv].astype(np.int16)
    vib = _vibration(t, thr_tick, rng, t_hold)
    if vib is not None:
        f, gyro = f + vib[0], gyro + vib[1]
    sticks = None if kin.sticks is None else np.clip(np.rint(kin.sticks(uniq)), -32768, 32767)[inv].astype(np.int16)
    armed = None if kin.armed is None else (np.asarray(kin.armed(uniq)) > 0.5)[inv]
    return MotionProfile(name, t, q, f, gyro, thr_tick, sticks=sticks, armed=armed)


def parse_throttle(spec: str) -> Callable:
    """``N`` (constant) or ``t:v,t:v,...`` (s since power-up : gTHR, linear in between, held outside) as a function."""
    text = spec.strip()
    try:
        pairs = [item.split(":") for item in text.split(",")] if ":" in text else [("0", text)]
        ts, vs = np.array([(float(a), float(b)) for a, b in pairs]).T
    except ValueError:
        raise ParamError(
            f"{{throttle}} takes a number or 't:v,t:v,...' breakpoints, got {spec!r}", "throttle"
        ) from None
    if not (np.all(np.isfinite(ts)) and np.all(np.isfinite(vs))) or np.any(np.diff(ts) <= 0):
        raise ParamError(f"{{throttle}} breakpoints need finite, increasing times, got {spec!r}", "throttle")
    if np.any(vs < 0) or np.any(vs > 32767):
        raise ParamError(
            f"{{throttle}} values are the firmware's gTHR (int16, from 0): 0..32767, got {spec!r}", "throttle"
        )
    return lambda t: np.interp(t, ts, vs)


def broad_profile(trial, t_s: np.ndarray, first_tick_s: float, throttle: Callable | None = None) -> MotionProfile:
    """A BROAD trial at tick times ``t_s``, trial time 0 at ``first_tick_s``: acc interpolated, the gyro a 416 Hz
    sample-and-hold of its measurements. Throttle 0 (hand-held) unless ``throttle`` is given."""
    t_rel = np.asarray(t_s, dtype=np.float64) - first_tick_s
    t_trial = trial.t_s
    if t_rel[-1] > t_trial[-1] + 1e-9:
        raise ParamError(
            f"BROAD trial {trial.name} lasts {t_trial[-1]:.1f} s; ask for at most that much "
            f"({{join_at_s}} + {{duration_s}} ≤ {t_trial[-1] + first_tick_s:.1f} s)",
            "join_at_s",
            "duration_s",
        )
    t_hold = sm.gyro_hold_times_s(t_rel)
    acc = np.stack([np.interp(t_rel, t_trial, trial.acc_mg[:, i]) for i in range(3)], axis=-1)
    gyro = np.stack([np.interp(t_hold, t_trial, trial.gyro_mdps[:, i]) for i in range(3)], axis=-1)
    q = interpolate_quat(t_trial, trial.quat_wxyz, t_rel)
    if throttle is None:
        thr = np.zeros(len(t_rel), dtype=np.int16)
    else:
        t_rc = np.floor(np.asarray(t_s) * RC_RATE_HZ) / RC_RATE_HZ
        thr = np.clip(np.rint(throttle(t_rc)), -32768, 32767).astype(np.int16)
    return MotionProfile(trial.name, np.asarray(t_s, dtype=np.float64), q, acc, gyro, thr, measured=True)


@dataclass(frozen=True)
class Vibration:
    """A known input for spectra: ``amplitude · sin(2π · freq_hz · t)`` (t: s since power-up) on one sensor axis."""

    sensor: str  #: "acc" (mg, at each ISR tick) or "gyro" (mdps, as its 416 Hz output register holds it)
    axis: int  #: 0, 1, 2 for x, y, z (the firmware's body axes)
    freq_hz: float  #: Hz (> 0; above the 80.77 Hz AHRS Nyquist it aliases)
    amplitude: float  #: peak amplitude in the sensor's unit (mg or mdps)

    @property
    def spec(self) -> str:
        return f"{self.sensor}-{'xyz'[self.axis]}:{self.freq_hz:g}:{self.amplitude:g}"


def parse_vibration(spec: str) -> Vibration:
    """``SENSOR-AXIS:HZ:AMPLITUDE``, e.g. ``gyro-x:47:2000`` (mdps) or ``acc-z:130:200`` (mg)."""
    bad = ParamError(
        f"{{vibration}} takes SENSOR-AXIS:HZ:AMPLITUDE (SENSOR acc or gyro, AXIS x, y or z, amplitude in mg or "
        f"mdps), e.g. gyro-x:47:2000; got {spec!r}",
        "vibration",
    )
    parts = spec.strip().lower().split(":")
    if len(parts) != 3 or parts[0] not in {f"{s}-{a}" for s in ("acc", "gyro") for a in "xyz"}:
        raise bad
    sensor, axis = parts[0].split("-")
    try:
        freq, amp = float(parts[1]), float(parts[2])
    except ValueError:
        raise bad from None
    if not (np.isfinite(freq) and freq > 0 and np.isfinite(amp) and amp >= 0):
        raise ParamError(f"{{vibration}} needs a frequency > 0 Hz and an amplitude ≥ 0, got {spec!r}", "vibration")
    return Vibration(sensor, "xyz".index(axis), freq, amp)


def add_vibrations(profile: MotionProfile, vibrations: list[Vibration]) -> MotionProfile:
    """``profile`` plus ``vibrations``: acc at each tick, gyro when its 416 Hz output register was last refreshed."""
    if not vibrations:
        return profile
    t = np.asarray(profile.t_s, dtype=np.float64)
    t_hold = sm.gyro_hold_times_s(t, t[0])
    acc = np.array(profile.acc_mg, dtype=np.float64, copy=True)
    gyro = np.array(profile.gyro_mdps, dtype=np.float64, copy=True)
    for v in vibrations:
        if v.sensor == "acc":
            acc[:, v.axis] += v.amplitude * np.sin(2 * np.pi * v.freq_hz * t)
        else:
            gyro[:, v.axis] += v.amplitude * np.sin(2 * np.pi * v.freq_hz * t_hold)
    return MotionProfile(profile.name, profile.t_s, profile.q_wxyz, acc, gyro, profile.thr, profile.measured)

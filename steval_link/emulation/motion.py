"""Motion profiles for emulated captures: what the drone's body does at every TIM9 tick (807.7 Hz).

A profile (:class:`MotionProfile`) holds, per ISR tick, the true orientation (body → earth quaternion, the same
direction as the firmware's ``ahrs.q``), the true specific force the accelerometer senses (mg, body axes) and the
true angular rate as the gyro's output register holds it (mdps, body axes, refreshed at the gyro's 416 Hz ODR),
plus the throttle ``gTHR`` the remote control sets. Axes are the firmware's: x right, y forward, z up; at rest and
level the specific force is (0, 0, +1000) mg. Angles follow ``QuaternionToEuler``: ``thx`` about x (pitch),
``thy`` about y (roll); the orientation is ``q = Rz(yaw) ⊗ Ry(thy) ⊗ Rx(thx)``.

Built-in scenarios (:data:`SCENARIOS`, :func:`build_profile`): ``bench``, ``hand-tilts``, ``yaw-spin``, ``hover``,
``freefall``, ``demo``. Each is defined by smooth functions of time (so rates and accelerations are exact
derivatives, evaluated wherever the sensor samples), randomised by the seed (tilt amplitudes, tremor, wander,
surface tilt), and always starts at rest so the firmware's power-up offset calibration (1–2 s after TIM9 starts)
sees a still drone. :func:`broad_profile` turns a BROAD trial (real motion, real IMU signals) into a profile.

Physics in short: specific force ``f = Rᵀ(a + g·ẑ)`` with ``a`` the IMU's acceleration (translation plus the
lever-arm motion of a rotation about a pivot that is not the IMU, e.g. a wrist or a turntable axis); in flight a
quadrotor's specific force is its thrust, along body z (``f = (0, 0, (g + a_z)/R₃₃)``), so the accelerometer
does not see the tilt — exactly the situation the firmware's small in-flight gain ``kp = 0.4`` is made for.
Motor vibration (4 motors at slightly different speeds, first and second harmonic, amplitude ∝ speed²) is added
to both sensors whenever ``gTHR ≥ MIN_THR`` (the firmware stops the motors below). Its amplitudes are those of
the sensor *output* (after the LSM6DSL's own low-pass filters, which are not modelled separately).
Nothing here holds module-level mutable state. One module of this size on purpose: every scenario is a short
function over the same tick-time helpers, and a reader compares them side by side.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from steval_link import constants as C
from steval_link.emulation import sensor_model as sm
from steval_link.errors import UserError
from steval_link.quat import interpolate_quat, quat_multiply, quaternion_from_euler

__all__ = [
    "G_MPS2",
    "MotionProfile",
    "Scenario",
    "SCENARIOS",
    "scenario_names",
    "build_profile",
    "broad_profile",
    "tick_times_s",
    "parse_throttle",
    "PREFLIGHT_MOVES",
    "PREFLIGHT_IDLE_THR",
    "Vibration",
    "parse_vibration",
    "add_vibrations",
]

#: standard gravity, m/s² (the mg ↔ m/s² conversion of the kinematics)
G_MPS2 = 9.80665
_MG_PER_MPS2 = 1000.0 / G_MPS2
_DEG = np.pi / 180.0
#: TIM9 period in core-clock cycles (84 MHz / 52 / 2000): ticks land on exact cycle counts
TICK_CYCLES = C.TICK_CYCLES
CPU_HZ = C.CPU_HZ


@dataclass(frozen=True)
class MotionProfile:
    """The true motion at each ISR tick.

    Attributes:
        name: scenario name (or the BROAD trial's name).
        t_s: (T,) tick times, s since power-up.
        q_wxyz: (T, 4) float64 true orientation, body → earth (NaN where unknown, e.g. occluded BROAD markers).
        acc_mg: (T, 3) float64 specific force the accelerometer senses, mg, body axes.
        gyro_mdps: (T, 3) float64 angular rate as the gyro's output register holds it at the tick (416 Hz
            sample-and-hold of the true rate), mdps, body axes.
        thr: (T,) int16 throttle ``gTHR`` at the tick.
        sticks: (T, 3) int16 the remote's other sticks as the firmware's ``gAIL, gELE, gRUD`` at the tick (None:
            centred), in the firmware's units and signs (``euler_rc.thx = -gELE·30°/1800``, ``thy = -gAIL·30°/1800``,
            ``gRUD`` beyond ±600 turns the yaw target).
        armed: (T,) bool the remote's arming switch (the BLE app's ``joydata[7]`` bit 2) at the tick (None: never).
        measured: True when acc/gyro are a real IMU's measurements (BROAD) rather than true values, so no
            sensor noise should be added.
    """

    name: str
    t_s: np.ndarray
    q_wxyz: np.ndarray
    acc_mg: np.ndarray
    gyro_mdps: np.ndarray
    thr: np.ndarray
    measured: bool = False
    sticks: np.ndarray | None = None
    armed: np.ndarray | None = None


def tick_times_s(n_ticks: int, first_tick_s: float) -> np.ndarray:
    """(n,) times of TIM9 ticks, s since power-up: ``first_tick_s + k · 104000 / 84 MHz``."""
    return first_tick_s + np.arange(n_ticks, dtype=np.float64) * (TICK_CYCLES / CPU_HZ)


# ---- quaternions (float64, wxyz) ---------------------------------------------------------------------------------


def _rotmat(q) -> np.ndarray:
    """(N, 3, 3) rotation matrices body → earth of unit quaternions (N, 4)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


# ---- smooth building blocks -------------------------------------------------------------------------------------


def _s(u):
    """Quintic smootherstep on [0, 1] (C² at both ends)."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (u * (6 * u - 15) + 10)


def _s_int(u):
    """∫₀ᵘ smootherstep (for u in [0, 1])."""
    u = np.clip(u, 0.0, 1.0)
    return u**4 * (u * (u - 3) + 2.5)


def _s_dd(u):
    """Second derivative of smootherstep in u (0 outside [0, 1])."""
    inside = (u > 0) & (u < 1)
    return np.where(inside, 60 * u * (u * (2 * u - 3) + 1), 0.0)


class _Steps:
    """``base + Σ delta_i · S((t − t0_i) / dur_i)``: smooth moves that do not overlap (sorted by t0)."""

    def __init__(self, base: float = 0.0) -> None:
        self.base = float(base)
        self.moves: list[tuple[float, float, float]] = []

    def move(self, t0: float, dur: float, delta: float) -> None:
        if self.moves:
            p0, pd, _ = self.moves[-1]
            if t0 < p0 + pd - 1e-12:
                raise ValueError("moves on one axis must not overlap")
        self.moves.append((float(t0), float(dur), float(delta)))

    def _arrays(self):
        m = np.array(self.moves, dtype=np.float64).reshape(-1, 3)
        return m[:, 0], m[:, 1], m[:, 2]

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        if not self.moves:
            return np.full(t.shape, self.base)
        t0, dur, delta = self._arrays()
        i = np.searchsorted(t0, t, side="right") - 1
        before = np.concatenate(([0.0], np.cumsum(delta)))  # sum of deltas of moves < i
        ic = np.clip(i, 0, len(t0) - 1)
        partial = np.where(i >= 0, delta[ic] * _s((t - t0[ic]) / dur[ic]), 0.0)
        return self.base + np.where(i >= 0, before[ic], 0.0) + partial

    def integral(self, t) -> np.ndarray:
        """∫ from 0 to t (t ≥ 0), for angles integrated from rates."""
        t = np.asarray(t, dtype=np.float64)
        if not self.moves:
            return self.base * t
        t0, dur, delta = self._arrays()
        i = np.searchsorted(t0, t, side="right") - 1
        ic = np.clip(i, 0, len(t0) - 1)
        # completed moves j < i contribute delta_j · (t − t0_j − dur_j/2)
        cd = np.concatenate(([0.0], np.cumsum(delta)))
        cm = np.concatenate(([0.0], np.cumsum(delta * (t0 + dur / 2))))
        done = np.where(i >= 0, t * cd[ic] - cm[ic], 0.0)
        u = (t - t0[ic]) / dur[ic]
        active = np.where(
            i >= 0, np.where(u >= 1, delta[ic] * (t - t0[ic] - dur[ic] / 2), delta[ic] * dur[ic] * _s_int(u)), 0.0
        )
        return self.base * t + done + active

    def accel(self, t) -> np.ndarray:
        """Second time derivative (for positions)."""
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros(t.shape)
        for t0, dur, delta in self.moves:
            out += delta * _s_dd((t - t0) / dur) / (dur * dur)
        return out


@dataclass
class _Sines:
    """Σ a_k sin(2π f_k t + φ_k): smooth random wander / tremor, evaluable at any time."""

    amp: np.ndarray
    freq_hz: np.ndarray
    phase: np.ndarray

    @classmethod
    def random(cls, rng: np.random.Generator, rms: float, f_lo: float, f_hi: float, n: int = 5) -> _Sines:
        f = rng.uniform(f_lo, f_hi, n)
        a = rng.uniform(0.5, 1.0, n)
        a *= rms * np.sqrt(2.0) / np.sqrt(np.sum(a * a))
        return cls(a, f, rng.uniform(0, 2 * np.pi, n))

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        return np.sin(2 * np.pi * self.freq_hz * t[..., None] + self.phase) @ self.amp


def _zero(t):
    return np.zeros(np.shape(t))


@dataclass
class _Kinematics:
    """A scenario as functions of time (s since power-up)."""

    thx: Callable = _zero  #: rad
    thy: Callable = _zero  #: rad
    yaw: Callable = _zero  #: rad
    lin_acc_mg: Callable | None = None  #: (N,) → (N, 3) earth-frame translational acceleration, mg
    lever_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  #: pivot → IMU, body axes, m
    lever_weight: Callable | None = None  #: (N,) 0..1: how much the pivot is held fixed (0 in free fall)
    airborne: Callable | None = None  #: (N,) 0..1: thrust model weight
    thr: Callable = _zero  #: throttle profile (float, before RC sampling)
    sticks: Callable | None = None  #: (N,) → (N, 3) gAIL, gELE, gRUD (float, before RC sampling)
    armed: Callable | None = None  #: (N,) → (N,) 0/1 arming switch

    def q(self, t) -> np.ndarray:
        return quaternion_from_euler(self.thx(t), self.thy(t), self.yaw(t))


# ---- rendering ---------------------------------------------------------------------------------------------------

#: RC receiver frame rate, Hz: ``gTHR`` changes at this rate (PWM/PPM receivers: ~50 Hz)
RC_RATE_HZ = 50.0
_H_RATE = 1e-4
_H_ACC = 2e-3


def _body_rate_radps(kin: _Kinematics, t) -> np.ndarray:
    """ω in body axes: 2·vec(q* ⊗ q̇), q̇ by a central difference of the analytic orientation."""
    q = kin.q(t)
    dq = (kin.q(t + _H_RATE) - kin.q(t - _H_RATE)) / (2 * _H_RATE)
    qc = q * np.array([1.0, -1.0, -1.0, -1.0])
    return 2.0 * quat_multiply(qc, dq)[:, 1:]


def _lever_acc_mps2(kin: _Kinematics, t) -> np.ndarray:
    """Earth-frame acceleration of the IMU from rotating about a pivot ``lever_m`` away (second difference)."""
    if not np.any(kin.lever_m):
        return np.zeros((len(t), 3))
    p = [(_rotmat(kin.q(t + d)) @ kin.lever_m) for d in (-_H_ACC, 0.0, _H_ACC)]
    return (p[0] - 2 * p[1] + p[2]) / (_H_ACC * _H_ACC)


def _vibration(t, thr_tick, rng: np.random.Generator, t_eval=None):
    """Motor vibration (acc mg at ``t``, gyro mdps at ``t_eval``): 4 motors, harmonics 1 and 2, ∝ speed²."""
    on = thr_tick >= sm.MIN_THR
    if not np.any(on):
        return None
    t_eval = t if t_eval is None else t_eval
    thr = np.where(on, thr_tick, 0).astype(np.float64)
    f_m = np.where(on, 90.0 + 0.6 * thr, 0.0)  # motor rotation rate, Hz (≈ 390 Hz at the hover throttle)
    dt = np.diff(t, prepend=t[0])
    phase = 2 * np.pi * np.cumsum(f_m * dt)
    scale = np.where(on, (thr / 500.0) ** 2, 0.0)
    acc = np.zeros((len(t), 3))
    gyro = np.zeros((len(t_eval), 3))
    phase_e = np.interp(t_eval, t, phase)
    scale_e = np.interp(t_eval, t, scale)
    acc_amp = np.array([30.0, 30.0, 55.0])  # mg per motor-harmonic-1 at hover speed
    gyro_amp = np.array([500.0, 500.0, 250.0])  # mdps
    for _ in range(4):
        ratio = 1.0 + rng.normal(0.0, 0.015)
        for h, (ka, kg) in enumerate(((0.5, 0.5), (0.25, 0.2)), start=1):
            ph = rng.uniform(0, 2 * np.pi, 3)
            pg = rng.uniform(0, 2 * np.pi, 3)
            acc += ka * acc_amp * scale[:, None] * np.sin(h * ratio * phase[:, None] + ph)
            gyro += kg * gyro_amp * scale_e[:, None] * np.sin(h * ratio * phase_e[:, None] + pg)
    return acc, gyro


def _render(
    name: str, kin: _Kinematics, t: np.ndarray, rng: np.random.Generator, throttle: Callable | None = None
) -> MotionProfile:
    t = np.asarray(t, dtype=np.float64)
    q = kin.q(t)
    # gyro: the output register holds the rate sampled at the 416 Hz ODR
    t_hold = t[0] + np.floor((t - t[0]) * sm.GYRO_ODR_HZ + 1e-9) / sm.GYRO_ODR_HZ
    gyro = _body_rate_radps(kin, t_hold) * (180.0 / np.pi * 1000.0)
    # specific force
    a = np.zeros((len(t), 3))
    if kin.lin_acc_mg is not None:
        a += kin.lin_acc_mg(t)
    lever = _lever_acc_mps2(kin, t) * _MG_PER_MPS2
    if kin.lever_weight is not None:
        lever *= kin.lever_weight(t)[:, None]
    a += lever
    rot = _rotmat(q)
    g_plus_a = a + np.array([0.0, 0.0, 1000.0])
    f = np.einsum("nji,nj->ni", rot, g_plus_a)  # Rᵀ (a + g ẑ)
    if kin.airborne is not None:
        w = kin.airborne(t)[:, None]
        fz = g_plus_a[:, 2] / np.maximum(rot[:, 2, 2], 0.2)
        thrust = np.stack([np.zeros_like(fz), np.zeros_like(fz), fz], axis=-1)
        f = (1 - w) * f + w * thrust
    # throttle: the RC receiver updates gTHR at ~50 Hz, integer units with ±1 jitter while the stick is up
    thr_fn = throttle if throttle is not None else kin.thr
    t_rc = np.floor(t * RC_RATE_HZ) / RC_RATE_HZ
    uniq, inv = np.unique(t_rc, return_inverse=True)
    thr_val = np.asarray(thr_fn(uniq), dtype=np.float64)
    jitter = np.where(thr_val > 0, rng.integers(-1, 2, len(uniq)), 0)
    thr_rc = np.clip(np.rint(thr_val) + jitter, -32768, 32767)
    thr_rc = np.where(thr_val > 0, np.maximum(thr_rc, 0), thr_rc)
    thr_tick = thr_rc[inv].astype(np.int16)
    vib = _vibration(t, thr_tick, rng, t_hold)
    if vib is not None:
        f = f + vib[0]
        gyro = gyro + vib[1]
    sticks = armed = None
    if kin.sticks is not None:
        sticks = np.clip(np.rint(np.asarray(kin.sticks(uniq), dtype=np.float64)), -32768, 32767)[inv]
        sticks = sticks.astype(np.int16)
    if kin.armed is not None:
        armed = (np.asarray(kin.armed(uniq)) > 0.5)[inv]
    return MotionProfile(name, t, q, f, gyro, thr_tick, sticks=sticks, armed=armed)


# ---- scenarios ---------------------------------------------------------------------------------------------------


def _surface_tilt(rng) -> tuple[float, float]:
    """A bench/floor is level to within about a degree."""
    return tuple(float(v) for v in rng.normal(0.0, 0.6, 2) * _DEG)


def _add_tilts(kin_thx: _Steps, kin_thy: _Steps, t_start: float, t_end: float, rng) -> float:
    """Hand tilts: pitch ±30°, roll ±30°, then both, each out-hold-back-pause; repeated until ``t_end``.

    Returns the time the last move ends."""
    t = t_start
    pattern = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1)]
    last = t_start
    while True:
        for sx, sy in pattern:
            amp = rng.uniform(26.0, 34.0) * _DEG
            move = rng.uniform(1.0, 1.5)
            hold = rng.uniform(1.0, 2.0)
            pause = rng.uniform(0.6, 1.2)
            if t + 2 * move + hold > t_end:
                return last
            scale = 0.7 if sx and sy else 1.0  # combined tilts a bit smaller
            for steps, s in ((kin_thx, sx), (kin_thy, sy)):
                if s:
                    steps.move(t, move, s * amp * scale)
                    steps.move(t + move + hold, move, -s * amp * scale)
            last = t + 2 * move + hold
            t = last + pause


def _hand_held(rng, t_pick: float, t_put: float | None):
    """Weight 0..1 of 'in the hand' (picked up at t_pick, put down at t_put), tremor and wander per axis."""
    w = _Steps()
    w.move(t_pick - 0.5, 1.0, 1.0)
    if t_put is not None:
        w.move(t_put - 0.5, 1.0, -1.0)
    tremor = [_Sines.random(rng, 0.06 * _DEG, 7.0, 11.0, 4) for _ in range(3)]
    wander = [_Sines.random(rng, 0.8 * _DEG, 0.1, 0.7, 4) for _ in range(3)]

    def axis(i):
        return lambda t: w(t) * (tremor[i](t) + wander[i](t))

    return w, axis


def _lift(t_up: float, height_m: float, dur: float = 1.0, t_down: float | None = None) -> _Steps:
    z = _Steps()
    z.move(t_up - dur / 2, dur, height_m)
    if t_down is not None:
        z.move(t_down - dur / 2, dur, -height_m)
    return z


def _vertical_acc(steps: list[_Steps]) -> Callable:
    def f(t):
        a = np.zeros((len(t), 3))
        for z in steps:
            a[:, 2] += z.accel(t) * _MG_PER_MPS2
        return a

    return f


def _bench(T: float, rng) -> _Kinematics:
    x0, y0 = _surface_tilt(rng)
    yaw0 = rng.uniform(-np.pi, np.pi)
    return _Kinematics(
        thx=lambda t: np.full(np.shape(t), x0),
        thy=lambda t: np.full(np.shape(t), y0),
        yaw=lambda t: np.full(np.shape(t), yaw0),
    )


def _tilts_kin(T_start: float, T_end: float, rng, pick: bool = True) -> _Kinematics:
    x0, y0 = _surface_tilt(rng)
    yaw0 = rng.uniform(-np.pi, np.pi)
    sx, sy = _Steps(x0), _Steps(y0)
    # picked up at T_start, tilts, put back down at the end
    last = _add_tilts(sx, sy, T_start + 1.0, T_end - 1.5, rng)
    t_put = max(last + 0.8, T_start + 1.5)
    w, hand = _hand_held(rng, T_start, t_put)
    lift = _lift(T_start, 0.12, 1.0, t_put)
    return _Kinematics(
        thx=lambda t: sx(t) + hand(0)(t),
        thy=lambda t: sy(t) + hand(1)(t),
        yaw=lambda t: yaw0 + hand(2)(t),
        lin_acc_mg=_vertical_acc([lift]),
        lever_m=np.array([0.0, -0.04, 0.07]),  # the wrist is below and behind the board
        lever_weight=w,
    )


def _hand_tilts(T: float, rng) -> _Kinematics:
    return _tilts_kin(3.0, T, rng)


def _yaw_spin(T: float, rng) -> _Kinematics:
    x0, y0 = _surface_tilt(rng)
    rate = _Steps()
    t = 4.0
    sign = 1.0
    while t + 8.0 <= T:
        w = rng.uniform(160.0, 200.0) * _DEG * sign  # a turntable at ~30 rpm
        ramp = rng.uniform(1.2, 2.0)
        spin = min(rng.uniform(8.0, 12.0), T - t - 2 * ramp - 1.0)
        rate.move(t, ramp, w)
        rate.move(t + ramp + spin, ramp, -w)
        t += 2 * ramp + spin + rng.uniform(2.0, 3.0)
        sign = -sign
    yaw0 = rng.uniform(-np.pi, np.pi)
    return _Kinematics(
        thx=lambda t: np.full(np.shape(t), x0),
        thy=lambda t: np.full(np.shape(t), y0),
        yaw=lambda t: yaw0 + rate.integral(t),
        lever_m=np.array([rng.uniform(0.03, 0.06), rng.uniform(-0.02, 0.02), 0.0]),  # off the turntable axis
    )


def _hover_parts(t0: float, T: float, rng):
    """Throttle, airborne weight, attitude wander and altitude of a take-off at t0 and landing before T."""
    t_land = T - 6.0
    thr = _Steps()
    thr.move(t0, 1.5, 380.0)  # arm and spool up: passes MIN_THR (200) on the ground
    thr.move(t0 + 1.5, 1.0, 140.0)  # take-off throttle ~520
    thr.move(t_land, 2.0, -140.0)  # descend
    thr.move(t_land + 3.0, 1.0, -380.0)  # disarm
    thr_wander = _Sines.random(rng, 22.0, 0.2, 1.5, 5)
    air = _Steps()
    air.move(t0 + 2.0, 0.4, 1.0)
    air.move(t_land + 2.3, 0.3, -1.0)
    z = _lift(t0 + 3.0, 1.0, 2.0, t_land + 1.0)
    fly = _Steps()  # the wander fades in and out slowly around take-off and landing
    fly.move(t0 + 2.0, 2.5, 1.0)
    fly.move(t_land, 2.3, -1.0)

    def throttle(t):
        base = thr(t)
        return base + air(t) * thr_wander(t)

    wander = [_Sines.random(rng, 2.0 * _DEG, 0.08, 1.5, 6) for _ in range(2)]
    yaw_w = _Sines.random(rng, 12.0 * _DEG, 0.02, 0.2, 3)
    return throttle, air, fly, wander, yaw_w, z


def _hover(T: float, rng, t0: float = 4.0) -> _Kinematics:
    x0, y0 = _surface_tilt(rng)
    yaw0 = rng.uniform(-np.pi, np.pi)
    throttle, air, fly, wander, yaw_w, z = _hover_parts(t0, T, rng)
    return _Kinematics(
        thx=lambda t: x0 * (1 - fly(t)) + fly(t) * wander[0](t),
        thy=lambda t: y0 * (1 - fly(t)) + fly(t) * wander[1](t),
        yaw=lambda t: yaw0 + fly(t) * yaw_w(t),
        lin_acc_mg=_vertical_acc([z]),
        airborne=air,
        thr=throttle,
    )


def _freefall(T: float, rng) -> _Kinematics:
    x0, y0 = _surface_tilt(rng)
    yaw0 = rng.uniform(-np.pi, np.pi)
    t_pick = 3.0
    drops = []
    t = 5.0
    while t + 2.0 <= T:
        drops.append(t)
        t += 7.0
    fall_s, catch_s = 0.5, 0.25
    v_mps = G_MPS2 * fall_s
    peak = 2 * v_mps / catch_s * _MG_PER_MPS2  # Hann pulse with area v
    sx, sy = _Steps(x0), _Steps(y0)
    heights = [_lift(t_pick, 0.4, 1.0)]
    tumble = []
    for td in drops:
        # tumbles a little while falling, the catch leaves it tilted, the hand levels it and lifts it back
        dx, dy = rng.normal(0, 12.0, 2) * _DEG
        sx.move(td, fall_s + catch_s, dx)
        sy.move(td, fall_s + catch_s, dy)
        sx.move(td + 1.5, 1.0, -dx)
        sy.move(td + 1.5, 1.0, -dy)
        heights.append(_lift(td + 3.5, 1.84, 2.0))
        tumble.append(td)
    drops_a = np.array(drops)
    w_hand, hand = _hand_held(rng, t_pick, None)

    def in_fall(t):
        """1 while falling (hand off), 0 otherwise."""
        out = np.zeros(np.shape(t))
        for td in drops_a:
            out = np.maximum(out, ((t >= td) & (t < td + fall_s)).astype(float))
        return out

    def lin_acc(t):
        a = _vertical_acc(heights)(t)
        for td in drops_a:
            fall = (t >= td) & (t < td + fall_s)
            a[fall, 2] = -1000.0
            u = (t - td - fall_s) / catch_s
            c = (u >= 0) & (u < 1)
            a[c, 2] += peak * 0.5 * (1 - np.cos(2 * np.pi * u[c]))
        return a

    def hand_w(t):
        return w_hand(t) * (1 - in_fall(t))

    return _Kinematics(
        thx=lambda t: sx(t) + hand(0)(t),
        thy=lambda t: sy(t) + hand(1)(t),
        yaw=lambda t: yaw0 + hand(2)(t),
        lin_acc_mg=lin_acc,
        lever_m=np.array([0.0, -0.04, 0.07]),
        lever_weight=hand_w,
    )


def _demo(T: float, rng) -> _Kinematics:
    t_hover = max(T * 0.5, 20.0)
    tilts = _tilts_kin(3.0, t_hover - 1.0, rng)
    throttle, air, fly, wander, yaw_w, z = _hover_parts(t_hover + 1.0, T, rng)
    yaw_t = tilts.yaw

    def mix(base, extra):
        return lambda t: base(t) * (1 - fly(t)) + fly(t) * extra(t)

    return _Kinematics(
        thx=mix(tilts.thx, wander[0]),
        thy=mix(tilts.thy, wander[1]),
        yaw=lambda t: yaw_t(t) + fly(t) * yaw_w(t),
        lin_acc_mg=lambda t: tilts.lin_acc_mg(t) + _vertical_acc([z])(t),
        lever_m=tilts.lever_m,
        lever_weight=tilts.lever_weight,
        airborne=air,
        thr=throttle,
    )


#: the firmware's stick scaling (rc.c): gELE/gAIL of ±RC_FULLSCALE = ±30° target pitch/roll; a gRUD beyond
#: ±EULER_Z_TH turns the yaw target by 60°·SENSOR_SAMPLING_TIME per AHRS step
_RC_FULLSCALE = float(C.RC_FULLSCALE)
_MAX_TILT_RAD = C.MAX_TILT_DEG * _DEG
_YAW_STICK_RADPS = 60.0 * C.DT_S * _DEG * C.AHRS_RATE_HZ


def _lagged(moves: list[tuple[float, float, float]], scale: float, lag_s: float, dur_s: float) -> _Steps:
    """The drone's response to stick moves: the same moves, ``lag_s`` later, over ``dur_s``, times ``scale``."""
    out = _Steps()
    for t0, _, delta in moves:
        out.move(t0 + lag_s, dur_s, delta * scale)
    return out


def _flight(T: float, rng, t0: float = 5.0) -> _Kinematics:
    """Armed, take-off, hover, then stick moves the drone follows: nose down, roll right, turn right; landing."""
    x0, y0 = _surface_tilt(rng)
    yaw0 = rng.uniform(-np.pi, np.pi)
    throttle, air, fly, wander, yaw_w, z = _hover_parts(t0, T, rng)
    ele, ail, rud = _Steps(), _Steps(), _Steps()
    t = t0 + 5.0
    hold = 1.6
    for stick, value in ((ele, 700.0), (ail, -700.0), (rud, -900.0)):
        if t + hold + 1.2 > T - 7.0:
            break
        stick.move(t, 0.3, value)
        stick.move(t + 0.3 + hold, 0.3, -value)
        t += 0.6 + hold + 1.2
    k = _MAX_TILT_RAD / _RC_FULLSCALE
    resp_x = _lagged(ele.moves, -k * 0.95, 0.1, 0.5)  # euler_rc.thx = -gELE·k
    resp_y = _lagged(ail.moves, -k * 0.95, 0.1, 0.5)  # euler_rc.thy = -gAIL·k
    yaw_rate = _Steps()
    for t_m, _, delta in rud.moves:  # gRUD < -600: the yaw target turns right (clockwise)
        yaw_rate.move(t_m + 0.15, 0.4, np.sign(delta) * _YAW_STICK_RADPS * 0.95)
    t_arm, t_disarm = t0 - 1.0, T - 1.5

    return _Kinematics(
        thx=lambda t: x0 * (1 - fly(t)) + fly(t) * (wander[0](t) + resp_x(t)),
        thy=lambda t: y0 * (1 - fly(t)) + fly(t) * (wander[1](t) + resp_y(t)),
        yaw=lambda t: yaw0 + 0.1 * fly(t) * yaw_w(t) + yaw_rate.integral(t),  # holds its heading
        lin_acc_mg=_vertical_acc([z]),
        airborne=air,
        thr=throttle,
        sticks=lambda t: np.stack([ail(t), ele(t), rud(t)], axis=-1),
        armed=lambda t: ((t >= t_arm) & (t < t_disarm)).astype(np.float64),
    )


#: the preflight check's guided hand moves, in order: (name, axis 0 thx / 1 thy / 2 yaw, signed angle, rad)
PREFLIGHT_MOVES = (("tilt right", 1, 25.0 * _DEG), ("nose up", 0, 25.0 * _DEG), ("turn right", 2, -90.0 * _DEG))
#: the idle throttle of the preflight scenario: just above MIN_THR, so the armed firmware drives the motors
PREFLIGHT_IDLE_THR = 210.0


def _preflight(T: float, rng) -> _Kinematics:
    """The preflight check: armed on the bench, throttle at idle (props off), picked up, tilted right, nose up,
    turned right (each out, hold, back), put down, throttle 0, disarmed."""
    x0, y0 = _surface_tilt(rng)
    yaw0 = rng.uniform(-np.pi, np.pi)
    t_arm, t_pick = 3.5, 6.0
    axes = [_Steps(x0), _Steps(y0), _Steps(yaw0)]
    t = t_pick + 2.0
    for _, axis, angle in PREFLIGHT_MOVES:
        move = 1.5 if axis == 2 else 1.0
        axes[axis].move(t, move, angle)
        axes[axis].move(t + move + 2.0, move, -angle)
        t += 2 * move + 2.0 + 1.5
    t_put = t + 0.5
    w, hand = _hand_held(rng, t_pick, t_put)
    lift = _lift(t_pick, 0.15, 1.0, t_put)
    thr = _Steps()
    thr.move(t_arm + 0.5, 0.5, PREFLIGHT_IDLE_THR)
    thr.move(t_put + 1.0, 0.5, -PREFLIGHT_IDLE_THR)
    t_disarm = t_put + 2.0
    return _Kinematics(
        thx=lambda t: axes[0](t) + hand(0)(t),
        thy=lambda t: axes[1](t) + hand(1)(t),
        yaw=lambda t: axes[2](t) + hand(2)(t),
        lin_acc_mg=_vertical_acc([lift]),
        lever_m=np.array([0.0, -0.04, 0.07]),
        lever_weight=w,
        thr=thr,
        sticks=lambda t: np.zeros((len(np.atleast_1d(t)), 3)),
        armed=lambda t: ((t >= t_arm) & (t < t_disarm)).astype(np.float64),
    )


@dataclass(frozen=True)
class Scenario:
    """A built-in motion scenario."""

    name: str
    summary: str
    default_duration_s: float
    min_duration_s: float
    build: Callable[[float, np.random.Generator], _Kinematics]


#: Built-in scenarios by name.
SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("bench", "lying still on the bench (noise, bias, calibration only); throttle 0", 30.0, 3.0, _bench),
        Scenario(
            "hand-tilts",
            "picked up from the bench, smooth pitch/roll tilts of about ±30° with pauses, put back; throttle 0",
            40.0,
            8.0,
            _hand_tilts,
        ),
        Scenario(
            "yaw-spin",
            "on a turntable (~30 rpm, off-axis), spin up, spin, stop, reverse; throttle 0",
            40.0,
            14.0,
            _yaw_spin,
        ),
        Scenario(
            "hover",
            "take-off (throttle ramp past 200), hover at throttle 450-550 with motor vibration and "
            "small attitude wander, landing",
            40.0,
            16.0,
            _hover,
        ),
        Scenario(
            "freefall",
            "held in the hand, dropped (0.5 s free fall: acc ≈ 0), caught (≈ 4 g), lifted back; every 7 s; throttle 0",
            10.0,
            7.5,
            _freefall,
        ),
        Scenario("demo", "hand tilts on the bench, then a short hover", 60.0, 40.0, _demo),
        Scenario(
            "flight",
            "armed by the remote, take-off, hover, stick moves (nose down, roll right, turn right), landing, disarmed",
            30.0,
            27.0,
            _flight,
        ),
        Scenario(
            "preflight",
            "the preflight check's hand moves: armed with the throttle at idle (props off), "
            "picked up, tilt right, nose up, turn right, put down, disarmed",
            32.0,
            30.0,
            _preflight,
        ),
    )
}


def scenario_names() -> list[str]:
    return list(SCENARIOS)


def parse_throttle(spec: str) -> Callable:
    """``--throttle``: ``N`` (constant) or ``t:v,t:v,...`` (s since power-up : gTHR, linear in between, held
    outside). Raises :class:`UserError` for anything else."""
    text = spec.strip()
    try:
        if ":" not in text:
            v = float(text)
            pts = [(0.0, v)]
        else:
            pts = []
            for item in text.split(","):
                a, b = item.split(":")
                pts.append((float(a), float(b)))
    except ValueError:
        raise UserError(f"--throttle takes a number or 't:v,t:v,...' breakpoints, got {spec!r}") from None
    ts = np.array([p[0] for p in pts])
    vs = np.array([p[1] for p in pts])
    if not (np.all(np.isfinite(ts)) and np.all(np.isfinite(vs))) or np.any(np.diff(ts) <= 0):
        raise UserError(f"--throttle breakpoints need finite, increasing times, got {spec!r}")
    if np.any(vs < 0) or np.any(vs > 32767):
        raise UserError(f"--throttle values are the firmware's gTHR (int16, from 0): 0..32767, got {spec!r}")
    return lambda t: np.interp(t, ts, vs)


def build_profile(
    name: str,
    t_s: np.ndarray,
    rng: np.random.Generator,
    *,
    throttle: Callable | None = None,
    total_s: float | None = None,
) -> MotionProfile:
    """The built-in scenario ``name`` rendered at tick times ``t_s`` (s since power-up).

    ``total_s`` is the emulated length the scenario's timeline is laid out for (default: the last tick);
    ``throttle`` overrides the scenario's throttle profile (a function of time, see :func:`parse_throttle`).
    """
    sc = SCENARIOS.get(name)
    if sc is None:
        raise UserError(f"unknown scenario {name!r}; built-in: {', '.join(SCENARIOS)} (or a BROAD trial .npz)")
    T = float(t_s[-1]) if total_s is None else float(total_s)
    kin = sc.build(T, rng)
    return _render(sc.name, kin, t_s, rng, throttle)


def broad_profile(trial, t_s: np.ndarray, first_tick_s: float, throttle: Callable | None = None) -> MotionProfile:
    """A BROAD trial (:class:`steval_link.emulation.broad.BroadTrial`) at tick times ``t_s``: trial time 0 is the first
    TIM9 tick ``first_tick_s``. acc is linearly resampled, the gyro read as a 416 Hz sample-and-hold; values are
    the trial's measurements (its IMU's noise and bias included), so ``measured`` is True. Throttle 0 (hand-held)
    unless ``throttle`` is given."""
    t_rel = np.asarray(t_s, dtype=np.float64) - first_tick_s
    t_trial = trial.t_s
    if t_rel[-1] > t_trial[-1] + 1e-9:
        raise UserError(
            f"BROAD trial {trial.name} lasts {t_trial[-1]:.1f} s; ask for at most that much "
            f"(--join-at + --duration ≤ {t_trial[-1] + first_tick_s:.1f} s)"
        )
    t_hold = np.floor(t_rel * sm.GYRO_ODR_HZ + 1e-9) / sm.GYRO_ODR_HZ
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
    """A pure sinusoid added to one sensor axis (``steval synth --vibration``), to check spectra against a known
    input: ``amplitude · sin(2π · freq_hz · t)`` with t in s since power-up.

    Attributes:
        sensor: "acc" (mg, at each ISR tick) or "gyro" (mdps, as the gyro's 416 Hz output register holds it).
        axis: 0, 1, 2 for x, y, z (the firmware's body axes).
        freq_hz: frequency, Hz (> 0; above the 80.77 Hz AHRS Nyquist it aliases, see
            :mod:`steval_link.analysis.spectrum`).
        amplitude: peak amplitude in the sensor's unit (mg or mdps).
    """

    sensor: str
    axis: int
    freq_hz: float
    amplitude: float

    @property
    def spec(self) -> str:
        return f"{self.sensor}-{'xyz'[self.axis]}:{self.freq_hz:g}:{self.amplitude:g}"


def parse_vibration(spec: str) -> Vibration:
    """``--vibration``: ``SENSOR-AXIS:HZ:AMPLITUDE``, e.g. ``gyro-x:47:2000`` (mdps) or ``acc-z:130:200`` (mg).
    Raises :class:`UserError` for anything else."""
    bad = (
        f"--vibration takes SENSOR-AXIS:HZ:AMPLITUDE (SENSOR acc or gyro, AXIS x, y or z, amplitude in mg or "
        f"mdps), e.g. gyro-x:47:2000; got {spec!r}"
    )
    parts = spec.strip().lower().split(":")
    if len(parts) != 3 or parts[0] not in {f"{s}-{a}" for s in ("acc", "gyro") for a in "xyz"}:
        raise UserError(bad)
    sensor, axis = parts[0].split("-")
    try:
        freq, amp = float(parts[1]), float(parts[2])
    except ValueError:
        raise UserError(bad) from None
    if not (np.isfinite(freq) and freq > 0 and np.isfinite(amp) and amp >= 0):
        raise UserError(f"--vibration needs a frequency > 0 Hz and an amplitude ≥ 0, got {spec!r}")
    return Vibration(sensor, "xyz".index(axis), freq, amp)


def add_vibrations(profile: MotionProfile, vibrations) -> MotionProfile:
    """``profile`` with the sinusoids ``vibrations`` (:class:`Vibration`) added: acc at each tick time, gyro at the
    time its 416 Hz output register was last refreshed (as the motion's own gyro values)."""
    vibrations = list(vibrations)
    if not vibrations:
        return profile
    t = np.asarray(profile.t_s, dtype=np.float64)
    t_hold = t[0] + np.floor((t - t[0]) * sm.GYRO_ODR_HZ + 1e-9) / sm.GYRO_ODR_HZ
    acc = np.array(profile.acc_mg, dtype=np.float64, copy=True)
    gyro = np.array(profile.gyro_mdps, dtype=np.float64, copy=True)
    for v in vibrations:
        if v.sensor == "acc":
            acc[:, v.axis] += v.amplitude * np.sin(2 * np.pi * v.freq_hz * t)
        else:
            gyro[:, v.axis] += v.amplitude * np.sin(2 * np.pi * v.freq_hz * t_hold)
    return MotionProfile(profile.name, profile.t_s, profile.q_wxyz, acc, gyro, profile.thr, profile.measured)

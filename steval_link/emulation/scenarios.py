"""The built-in motion scenarios (:data:`SCENARIOS`), built of smooth functions of time (float64, s since power-up):
eased moves (:class:`Steps`) and random wander (:class:`Sines`), so rates and accelerations are exact derivatives the
sensors can sample anywhere. A scenario maps the run's length and a random generator to :class:`Kinematics`; each
starts at rest, so the offset calibration sees a still drone; :mod:`.motion` renders them. :func:`random_streams`:
one seed's random streams (``steval synth`` and ``steval emulate`` draw the same moves and offsets from them).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from steval_link import constants as C
from steval_link.errors import ParamError
from steval_link.quat import quaternion_from_euler

G_MPS2 = 9.80665  #: standard gravity, m/s² (the mg ↔ m/s² conversion of the kinematics)
MG_PER_MPS2 = 1000.0 / G_MPS2
DEG = np.pi / 180.0
SEED_SALT = 0x5EA1  #: mixed into every seed, so these streams differ from a plain ``default_rng(seed)``


@dataclass(frozen=True)
class RandomStreams:
    """Independent generators of one seed, one per job (spawned in this order)."""

    motion: np.random.Generator  #: the scenario's moves, throttle jitter, motor vibration
    sensor: np.random.Generator  #: the LSM6DSL's offsets and slow gyro drift
    noise: np.random.Generator  #: the sensor's white noise per reading
    fw: np.random.Generator  #: firmware step timing
    drop: np.random.Generator  #: forced frame drops
    host: np.random.Generator  #: host-side read timing
    boot: np.random.Generator  #: the boot text's timing


def random_streams(seed: int) -> RandomStreams:
    """The streams of ``seed``: ``SeedSequence([seed, SEED_SALT])`` spawned into seven generators."""
    return RandomStreams(*(np.random.default_rng(s) for s in np.random.SeedSequence([int(seed), SEED_SALT]).spawn(7)))


def rotmat(q) -> np.ndarray:
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


class Steps:
    """``base + Σ delta_i · S((t − t0_i) / dur_i)``: smooth moves that do not overlap (sorted by t0)."""

    def __init__(self, base: float = 0.0, moves=()) -> None:
        self.base = float(base)
        self.moves: list[tuple[float, float, float]] = []
        for t0, dur, delta in moves:
            self.move(t0, dur, delta)

    def move(self, t0: float, dur: float, delta: float) -> None:
        if self.moves and t0 < sum(self.moves[-1][:2]) - 1e-12:
            raise ValueError("moves on one axis must not overlap")
        self.moves.append((float(t0), float(dur), float(delta)))

    def _index(self, t):
        """t0, dur, delta of the moves; at each t the last move begun (−1: none), and that clipped to ≥ 0."""
        m = np.array(self.moves, dtype=np.float64).reshape(-1, 3)
        i = np.searchsorted(m[:, 0], t, side="right") - 1
        return m[:, 0], m[:, 1], m[:, 2], i, np.clip(i, 0, len(m) - 1)

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        if not self.moves:
            return np.full(t.shape, self.base)
        t0, dur, delta, i, ic = self._index(t)
        before = np.concatenate(([0.0], np.cumsum(delta)))  # sum of deltas of moves < i
        partial = np.where(i >= 0, delta[ic] * _s((t - t0[ic]) / dur[ic]), 0.0)
        return self.base + np.where(i >= 0, before[ic], 0.0) + partial

    def integral(self, t) -> np.ndarray:
        """∫ from 0 to t (t ≥ 0), for angles integrated from rates."""
        t = np.asarray(t, dtype=np.float64)
        if not self.moves:
            return self.base * t
        t0, dur, delta, i, ic = self._index(t)
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
class Sines:
    """Σ a_k sin(2π f_k t + φ_k): smooth random wander / tremor, evaluable at any time."""

    amp: np.ndarray
    freq_hz: np.ndarray
    phase: np.ndarray

    @classmethod
    def random(cls, rng: np.random.Generator, rms: float, f_lo: float, f_hi: float, n: int = 5) -> Sines:
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
class Kinematics:
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


@dataclass(frozen=True)
class Scenario:
    """A built-in motion scenario; ``summary`` is its builder's docstring."""

    name: str
    summary: str
    default_duration_s: float
    min_duration_s: float
    build: Callable[[float, np.random.Generator], Kinematics]


SCENARIOS: dict[str, Scenario] = {}  #: built-in scenarios by name, in the order they are defined below


def _scenario(name: str, default_duration_s: float, min_duration_s: float):
    def register(build):  # the builder ``(T, rng) -> Kinematics`` becomes the built-in scenario ``name``
        SCENARIOS[name] = Scenario(name, " ".join(build.__doc__.split()), default_duration_s, min_duration_s, build)
        return build

    return register


def _at_rest(rng) -> tuple[float, float, float]:
    """(thx, thy, yaw) of a drone put down anywhere."""
    return (*_surface_tilt(rng), rng.uniform(-np.pi, np.pi))


def _surface_tilt(rng) -> tuple[float, float]:
    """A bench/floor is level to within about a degree."""
    return tuple(float(v) for v in rng.normal(0.0, 0.6, 2) * DEG)


def _add_tilts(kin_thx: Steps, kin_thy: Steps, t_start: float, t_end: float, rng) -> float:
    """Hand tilts (pitch ±30°, roll ±30°, then both; each out, hold, back, pause) until ``t_end``; when they end."""
    t = last = t_start
    while True:
        for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1)):
            amp = rng.uniform(26.0, 34.0) * DEG
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
    """Weight 0..1 of 'in the hand' (picked up at t_pick, put down at t_put), and tremor plus wander per axis."""
    w = _lift(t_pick, 1.0, 1.0, t_put)
    tremor = [Sines.random(rng, 0.06 * DEG, 7.0, 11.0, 4) for _ in range(3)]
    wander = [Sines.random(rng, 0.8 * DEG, 0.1, 0.7, 4) for _ in range(3)]
    return w, [_weighted(w, tremor[i], wander[i]) for i in range(3)]


def _weighted(w: Callable, a: Callable, b: Callable) -> Callable:
    return lambda t: w(t) * (a(t) + b(t))


def _plus(a: Callable, b: Callable) -> Callable:
    return lambda t: a(t) + b(t)


def _held(axes: list[Steps], hand: list[Callable], **kw) -> Kinematics:
    """Held at the wrist (below and behind the board): each attitude axis ``axes[i]`` plus the hand's ``hand[i]``."""
    return Kinematics(*(_plus(axes[i], hand[i]) for i in range(3)), lever_m=np.array([0.0, -0.04, 0.07]), **kw)


def _between(t_on: float, t_off: float) -> Callable:
    return lambda t: ((t >= t_on) & (t < t_off)).astype(np.float64)


def _lift(t_up: float, height_m: float, dur: float = 1.0, t_down: float | None = None) -> Steps:
    down = [] if t_down is None else [(t_down - dur / 2, dur, -height_m)]
    return Steps(0.0, [(t_up - dur / 2, dur, height_m), *down])


def _vertical_acc(steps: list[Steps]) -> Callable:
    def f(t):
        a = np.zeros((len(t), 3))
        for z in steps:
            a[:, 2] += z.accel(t) * MG_PER_MPS2
        return a

    return f


@_scenario("bench", 30.0, 3.0)
def _bench(T: float, rng) -> Kinematics:
    """lying still on the bench (noise, bias, calibration only); throttle 0"""
    return Kinematics(*(Steps(v) for v in _at_rest(rng)))


@_scenario("hand-tilts", 40.0, 8.0)
def _hand_tilts(T_end: float, rng, T_start: float = 3.0) -> Kinematics:
    """picked up from the bench, smooth pitch/roll tilts of about ±30° with pauses, put back; throttle 0"""
    axes = [Steps(v) for v in _at_rest(rng)]
    last = _add_tilts(axes[0], axes[1], T_start + 1.0, T_end - 1.5, rng)
    t_put = max(last + 0.8, T_start + 1.5)
    w, hand = _hand_held(rng, T_start, t_put)
    return _held(axes, hand, lin_acc_mg=_vertical_acc([_lift(T_start, 0.12, 1.0, t_put)]), lever_weight=w)


@_scenario("yaw-spin", 40.0, 14.0)
def _yaw_spin(T: float, rng) -> Kinematics:
    """on a turntable (~30 rpm, off-axis), spin up, spin, stop, reverse; throttle 0"""
    x0, y0 = _surface_tilt(rng)
    rate, t, sign = Steps(), 4.0, 1.0
    while t + 8.0 <= T:
        w = rng.uniform(160.0, 200.0) * DEG * sign  # a turntable at ~30 rpm
        ramp = rng.uniform(1.2, 2.0)
        spin = min(rng.uniform(8.0, 12.0), T - t - 2 * ramp - 1.0)
        rate.move(t, ramp, w)
        rate.move(t + ramp + spin, ramp, -w)
        t += 2 * ramp + spin + rng.uniform(2.0, 3.0)
        sign = -sign
    yaw0 = rng.uniform(-np.pi, np.pi)
    return Kinematics(
        thx=Steps(x0),
        thy=Steps(y0),
        yaw=lambda t: yaw0 + rate.integral(t),
        lever_m=np.array([rng.uniform(0.03, 0.06), rng.uniform(-0.02, 0.02), 0.0]),  # off the turntable axis
    )


def _take_off(ground: Kinematics, t0: float, T: float, rng, steer=(_zero, _zero), yaw_gain=1.0, yaw_extra=_zero):
    """``ground``'s motion, then from t0 a hover with attitude wander (plus ``steer`` of thx, thy), landing by T."""
    t_land = T - 6.0
    # arm and spool up past MIN_THR (200) on the ground, take off at ~520, descend, disarm
    thr = Steps(0.0, [(t0, 1.5, 380.0), (t0 + 1.5, 1.0, 140.0), (t_land, 2.0, -140.0), (t_land + 3.0, 1.0, -380.0)])
    thr_wander = Sines.random(rng, 22.0, 0.2, 1.5, 5)
    air = Steps(0.0, [(t0 + 2.0, 0.4, 1.0), (t_land + 2.3, 0.3, -1.0)])
    climb = _vertical_acc([_lift(t0 + 3.0, 1.0, 2.0, t_land + 1.0)])
    fly = Steps(0.0, [(t0 + 2.0, 2.5, 1.0), (t_land, 2.3, -1.0)])  # the wander fades in and out
    wander = [Sines.random(rng, 2.0 * DEG, 0.08, 1.5, 6) for _ in range(2)]
    yaw_w = Sines.random(rng, 12.0 * DEG, 0.02, 0.2, 3)

    def mix(base, i):
        return lambda t: base(t) * (1 - fly(t)) + fly(t) * (wander[i](t) + steer[i](t))

    return Kinematics(
        thx=mix(ground.thx, 0),
        thy=mix(ground.thy, 1),
        yaw=lambda t: ground.yaw(t) + yaw_gain * fly(t) * yaw_w(t) + yaw_extra(t),
        lin_acc_mg=climb if ground.lin_acc_mg is None else _plus(ground.lin_acc_mg, climb),
        lever_m=ground.lever_m,
        lever_weight=ground.lever_weight,
        airborne=air,
        thr=lambda t: thr(t) + air(t) * thr_wander(t),
    )


@_scenario("hover", 40.0, 16.0)
def _hover(T: float, rng, t0: float = 4.0) -> Kinematics:
    """take-off (throttle ramp past 200), hover at throttle 450-550 with motor vibration and small attitude wander,
    landing"""
    return _take_off(_bench(T, rng), t0, T, rng)


@_scenario("freefall", 10.0, 7.5)
def _freefall(T: float, rng) -> Kinematics:
    """held in the hand, dropped (0.5 s free fall: acc ≈ 0), caught (≈ 4 g), lifted back; every 7 s; throttle 0"""
    axes = [Steps(v) for v in _at_rest(rng)]
    t_pick = 3.0
    drops = np.arange(5.0, T - 2.0 + 1e-9, 7.0)
    fall_s, catch_s = 0.5, 0.25
    peak = 2 * (G_MPS2 * fall_s) / catch_s * MG_PER_MPS2  # Hann pulse with area v = g · fall_s
    heights = [_lift(t_pick, 0.4, 1.0)]
    for td in drops:
        # tumbles a little while falling, the catch leaves it tilted, the hand levels it and lifts it back
        for axis, d in zip(axes, rng.normal(0, 12.0, 2) * DEG):
            axis.move(td, fall_s + catch_s, d)
            axis.move(td + 1.5, 1.0, -d)
        heights.append(_lift(td + 3.5, 1.84, 2.0))
    w_hand, hand = _hand_held(rng, t_pick, None)

    def falling(t):
        out = np.zeros(np.shape(t), bool)
        for td in drops:
            out |= (t >= td) & (t < td + fall_s)
        return out

    def lin_acc(t):
        a = _vertical_acc(heights)(t)
        a[falling(t), 2] = -1000.0
        for td in drops:  # the catch
            u = (t - td - fall_s) / catch_s
            c = (u >= 0) & (u < 1)
            a[c, 2] += peak * 0.5 * (1 - np.cos(2 * np.pi * u[c]))
        return a

    # the hand lets go while it falls
    return _held(axes, hand, lin_acc_mg=lin_acc, lever_weight=lambda t: w_hand(t) * (1 - falling(t)))


@_scenario("demo", 60.0, 40.0)
def _demo(T: float, rng) -> Kinematics:
    """hand tilts on the bench, then a short hover"""
    t_hover = max(T * 0.5, 20.0)
    return _take_off(_hand_tilts(t_hover - 1.0, rng), t_hover + 1.0, T, rng)


#: the firmware's stick scaling (rc.c): gELE/gAIL of ±RC_FULLSCALE = ±30° target pitch/roll; a gRUD beyond
#: ±EULER_Z_TH turns the yaw target by 60°·SENSOR_SAMPLING_TIME per AHRS step
_YAW_STICK_RADPS = 60.0 * C.DT_S * DEG * C.AHRS_RATE_HZ


def _lagged(moves: list[tuple[float, float, float]], scale: float, lag_s: float, dur_s: float) -> Steps:
    """The drone's response to stick moves: the same moves, ``lag_s`` later, over ``dur_s``, times ``scale``."""
    out = Steps()
    for t0, _, delta in moves:
        out.move(t0 + lag_s, dur_s, delta * scale)
    return out


@_scenario("flight", 30.0, 27.0)
def _flight(T: float, rng, t0: float = 5.0) -> Kinematics:
    """armed by the remote, take-off, hover, stick moves (nose down, roll right, turn right), landing, disarmed"""
    ground = _bench(T, rng)
    ele, ail, rud = Steps(), Steps(), Steps()
    t, hold = t0 + 5.0, 1.6
    for stick, value in ((ele, 700.0), (ail, -700.0), (rud, -900.0)):
        if t + hold + 1.2 > T - 7.0:
            break
        stick.move(t, 0.3, value)
        stick.move(t + 0.3 + hold, 0.3, -value)
        t += 0.6 + hold + 1.2
    k = C.MAX_TILT_DEG * DEG / C.RC_FULLSCALE
    resp_x = _lagged(ele.moves, -k * 0.95, 0.1, 0.5)  # euler_rc.thx = -gELE·k
    resp_y = _lagged(ail.moves, -k * 0.95, 0.1, 0.5)  # euler_rc.thy = -gAIL·k
    yaw_rate = Steps()
    for t_m, _, delta in rud.moves:  # gRUD < -600: the yaw target turns right (clockwise)
        yaw_rate.move(t_m + 0.15, 0.4, np.sign(delta) * _YAW_STICK_RADPS * 0.95)
    # it holds its heading: the yaw wander is a tenth of a hover's
    kin = _take_off(ground, t0, T, rng, (resp_x, resp_y), 0.1, yaw_rate.integral)
    kin.sticks = lambda t: np.stack([ail(t), ele(t), rud(t)], axis=-1)
    kin.armed = _between(t0 - 1.0, T - 1.5)
    return kin


#: the preflight check's guided hand moves, in order: (name, axis 0 thx / 1 thy / 2 yaw, signed angle, rad)
PREFLIGHT_MOVES = (("tilt right", 1, 25.0 * DEG), ("nose up", 0, 25.0 * DEG), ("turn right", 2, -90.0 * DEG))
#: the idle throttle of the preflight scenario: just above MIN_THR, so the armed firmware drives the motors
PREFLIGHT_IDLE_THR = 210.0


@_scenario("preflight", 32.0, 30.0)
def _preflight(T: float, rng) -> Kinematics:
    """the preflight check's hand moves: armed with the throttle at idle (props off), picked up, tilt right, nose up,
    turn right, put down, disarmed"""
    axes = [Steps(v) for v in _at_rest(rng)]
    t_arm, t_pick = 3.5, 6.0
    t = t_pick + 2.0
    for _, axis, angle in PREFLIGHT_MOVES:
        move = 1.5 if axis == 2 else 1.0
        axes[axis].move(t, move, angle)
        axes[axis].move(t + move + 2.0, move, -angle)
        t += 2 * move + 2.0 + 1.5
    t_put = t + 0.5
    w, hand = _hand_held(rng, t_pick, t_put)
    thr = Steps(0.0, [(t_arm + 0.5, 0.5, PREFLIGHT_IDLE_THR), (t_put + 1.0, 0.5, -PREFLIGHT_IDLE_THR)])
    return _held(
        axes,
        hand,
        lin_acc_mg=_vertical_acc([_lift(t_pick, 0.15, 1.0, t_put)]),
        lever_weight=w,
        thr=thr,
        sticks=lambda t: np.zeros((len(np.atleast_1d(t)), 3)),
        armed=_between(t_arm, t_put + 2.0),
    )


def scenario(name: str, otherwise: str) -> Scenario:
    """The built-in scenario ``name``; else an error naming them and ``otherwise`` (e.g. "or {broad} TRIAL.npz")."""
    if name not in SCENARIOS:
        raise ParamError(f"unknown scenario {name!r}; built-in: {', '.join(SCENARIOS)} ({otherwise})", "broad")
    return SCENARIOS[name]

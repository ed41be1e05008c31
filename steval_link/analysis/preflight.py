"""The preflight wiring check (``steval preflight``): guided hand moves checked against the firmware's own chain.

Props off, armed at idle throttle or with the motors off, the user makes three moves (:data:`MOVES`), each out,
hold, back: tilt right (roll: ``thy`` > 0), nose up (pitch: ``thx`` > 0), turn right (gyro z < 0). Each is found in
the gyro and checked link by link: the sensor's axis and sign, then ``thx``/``thy``; the controller (``s1``, ``s2``
push back); each motor against the mixer, and that each output carries its own mixer line (a swapped motor order is
named). Spin directions cannot be seen in the data: the report says what the mixer expects. At rest acc z ≈ +1 g."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from steval_link import constants as C
from steval_link.analysis.flight_control import MOTORS, expected_motor_pwm, mixer_matrix, mixer_pwm


@dataclass(frozen=True)
class Move:
    name: str
    instruction: str  #: what the user is told
    axis: int  #: 0 x (pitch), 1 y (roll), 2 z (yaw): the firmware axis it turns about
    sign: int  #: +1 / -1: the sign of the rotation about that axis


#: the guided moves, in order
MOVES: tuple[Move, ...] = (
    Move(
        "tilt right", "tilt the drone to the right (right side down) by about 25°, hold 2 s, bring it back level", 1, +1
    ),
    Move("nose up", "lift the nose by about 25°, hold 2 s, bring it back level", 0, +1),
    Move(
        "turn right",
        "turn the drone to the right (clockwise seen from above) by about 90°, hold 2 s, turn it back",
        2,
        -1,
    ),
)

_AXIS_NAMES = ("x (pitch)", "y (roll)", "z (yaw)")
_ANGLE_NAMES = ("pitch thx", "roll thy", "yaw thz")
#: a burst of rotation: the gyro's magnitude above this (dps, smoothed over ~0.1 s)
_BURST_DPS = 12.0
#: a move turns the drone at least this much (deg, integrated gyro)
_MIN_MOVE_DEG = 10.0
#: a motor's change during a hold counts from this many PWM counts
_MIN_MOTOR_DELTA = 3.0


@dataclass
class PreflightReport:
    """What the check found: ``lines`` (plain sentences, per move, motor and axis), ``problems`` (one sentence each)."""

    source: str
    lines: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.problems

    def text(self) -> str:
        n = len(self.problems)
        verdict = "PASS: every check is OK." if self.passed else f"FAIL: {n} problem{'s' if n > 1 else ''}:"
        return "\n".join([*self.lines, "", verdict] + [f"  - {p}" for p in self.problems])


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    return x if n <= 1 or len(x) < n else np.convolve(x, np.ones(n) / n, mode="same")


def _bursts(t_s: np.ndarray, gyro_dps: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """(start, end, integrated rotation deg (3,)) of each burst of rotation, in order."""
    idx = np.flatnonzero(_smooth(np.linalg.norm(gyro_dps, axis=1), 16) > _BURST_DPS)
    if len(idx) == 0:
        return []
    dt = np.clip(np.diff(t_s, prepend=t_s[0]), 0.0, 0.05)
    out = []
    for run in np.split(idx, np.flatnonzero(np.diff(t_s[idx]) > 0.25) + 1):  # gaps under 0.25 s merged
        a, b = run[0], run[-1] + 1
        rot = (gyro_dps[a:b] * dt[a:b, None]).sum(axis=0)
        if np.linalg.norm(rot) >= _MIN_MOVE_DEG:
            out.append((a, b, rot))
    return out


def _pair_moves(bursts):
    """Consecutive (out, back) bursts whose rotations are opposite: [(out, back), ...] in order."""
    pairs = []
    i = 0
    while i + 1 < len(bursts):
        a, b = bursts[i], bursts[i + 1]
        if float(np.dot(a[2], b[2])) < 0:
            pairs.append((a, b))
            i += 2
        else:
            i += 1
    return pairs


def _fmt(v: float) -> str:
    return f"{v:+.1f}°"


def check_preflight(tel, source: str = "") -> PreflightReport:
    """Run the check on a decoded stream (:class:`~steval_link.link.telemetry.Telemetry`)."""
    rep = PreflightReport(source)
    att = tel.attitude
    if len(att) < 200:
        rep.problems.append("the stream holds fewer than 200 attitude frames; record the whole guided sequence")
        return rep
    gyro = att.gyro_mdps.astype(np.float64) / 1000.0
    fc = getattr(tel, "fc", None)
    has_fc = fc is not None and len(fc) > 0
    _check_rest(rep, att, gyro)
    motors_on_any = _check_arming(rep, fc) if has_fc else False
    if not has_fc:
        rep.lines.append(
            "No flight-control frames in this stream (a firmware before protocol v2, or fc_every 0): "
            "only the sensors are checked."
        )
    if not _check_moves(rep, att, gyro, fc if has_fc else None):
        return rep
    rep.lines.append("")
    if has_fc:
        _check_outputs(rep, fc, att, motors_on_any)
    rep.lines.append(
        "Spin directions (from the mixer's yaw signs; check by eye, props off): "
        + "; ".join(f"{m.label} {m.spin}" for m in MOTORS)
        + ", seen from above. A prop on the wrong motor or upside down "
        "makes the drone spin or flip at take-off even when this check passes."
    )
    return rep


def _check_rest(rep: PreflightReport, att, gyro: np.ndarray) -> None:
    """At rest (the still rows of the first quarter) the accelerometer must read about +1 g on z."""
    still = _smooth(np.linalg.norm(gyro, axis=1), 16) < 3.0
    rest = np.flatnonzero(still[: max(len(still) // 4, 1)])
    rest = rest if len(rest) else np.arange(min(100, len(att)))
    acc_rest = att.acc_mg[rest].mean(axis=0)
    if acc_rest[2] > 700:
        rep.lines.append(f"At rest: the accelerometer reads {acc_rest[2]:+.0f} mg on z (z up): OK.")
    else:
        rep.problems.append(
            f"At rest the accelerometer reads {acc_rest[2]:+.0f} mg on z instead of about +1000 mg: "
            "the board is mounted upside down or its z axis is reversed."
        )


def _check_arming(rep: PreflightReport, fc) -> bool:
    """Say whether the drone was armed and the motors ran; returns whether they ran."""
    armed = (fc.fc_flags & 1).astype(bool)
    motors_on = armed & (fc.rc[:, 3] >= C.MIN_THR)
    armed_any, motors_on_any = bool(armed.any()), bool(motors_on.any())
    every = int(np.max(fc.fc_every)) if len(fc.fc_every) else 0
    state = (
        "armed, throttle at idle (motors running)"
        if motors_on_any
        else "armed, throttle below MIN_THR (motors off)"
        if armed_any
        else "not armed (motors off)"
    )
    rep.lines.append(f"Flight-control frames: {len(fc)} (one every {every} steps); the drone was {state}.")
    return motors_on_any


def _check_moves(rep: PreflightReport, att, gyro: np.ndarray, fc) -> bool:
    """Find the guided moves in the gyro and check each (sensor, then controller when ``fc``); False: not them."""
    pairs = _pair_moves(_bursts(att.t_fw_s, gyro))
    if len(pairs) < len(MOVES):
        rep.problems.append(
            f"found {len(pairs)} of the {len(MOVES)} guided moves (each: out, hold, back) in the "
            "gyro; make each move slowly (about 1 s), by at least 20°, and hold it 2 s"
        )
    axes = [int(np.argmax(np.abs(rot))) for (_, _, rot), _ in pairs[: len(MOVES)]]
    if len(axes) == len(MOVES) and len(set(axes)) < len(axes):
        names = ", ".join(_AXIS_NAMES[a] for a in axes)
        rep.problems.append(
            f"the first three moves turned about {names}: not the guided sequence (tilt right, nose "
            "up, turn right: three different axes, even when they are swapped); record it again "
            "with steval preflight, live"
        )
        return False
    for k, mv in enumerate(MOVES):
        rep.lines += ["", f"Move {k + 1}, {mv.name} ({mv.instruction}):"]
        if k >= len(pairs):
            rep.lines.append("  not found in the stream.")
            continue
        (a0, a1, rot), (b0, _, _) = pairs[k]
        _check_sensor(rep, mv, rot, att, a0, a1, b0)
        if fc is not None:
            _check_controller(rep, mv, fc, att, a0, a1, b0, att.step)
    return True


def _axis_turned(values: np.ndarray, axis: int, sign: int) -> tuple[int, str]:
    """The dominant axis of ``values`` and "ok", "reversed" (the other way) or "swapped" (another axis)."""
    dom = int(np.argmax(np.abs(values)))
    if dom != axis:
        return dom, "swapped"
    return dom, "ok" if np.sign(values[dom]) == sign else "reversed"


def _check_sensor(rep: PreflightReport, mv: Move, rot: np.ndarray, att, a0: int, a1: int, b0: int) -> None:
    """The gyro's rotation during the move, then the firmware's angles during the hold (an attitude problem is
    named on its own only when the gyro was right: else it is the same fault, seen twice)."""
    n_problems = len(rep.problems)
    dom, turned = _axis_turned(rot, mv.axis, mv.sign)
    got = ", ".join(f"{n[0]} {_fmt(v)}" for n, v in zip(_AXIS_NAMES, rot))
    exp_dir = "+" if mv.sign > 0 else "-"
    if turned == "ok":
        rep.lines.append(f"  gyro: OK, turned about {_AXIS_NAMES[mv.axis]} {_fmt(rot[dom])} (x/y/z: {got}).")
    elif turned == "reversed":
        rep.problems.append(
            f"{mv.name}: the gyro turned about {_AXIS_NAMES[mv.axis]} with the wrong sign "
            f"({_fmt(rot[dom])}, expected {exp_dir}): the sensor's {_AXIS_NAMES[mv.axis][0]} axis is "
            "reversed (board mounted turned, or a wrong COORDINATE_SYSTEM in config_drone.h)."
        )
        rep.lines.append(f"  gyro: REVERSED {_AXIS_NAMES[mv.axis]} ({got}).")
    else:
        rep.problems.append(
            f"{mv.name}: the gyro turned about {_AXIS_NAMES[dom]} ({_fmt(rot[dom])}) instead of "
            f"{_AXIS_NAMES[mv.axis]}: the sensor's axes are swapped (board mounted turned by 90°, "
            "or a wrong COORDINATE_SYSTEM in config_drone.h)."
        )
        rep.lines.append(f"  gyro: SWAPPED axis, turned about {_AXIS_NAMES[dom]} ({got}).")
    if mv.axis < 2:
        # the attitude (accelerometer + AHRS): before the move vs the middle of the hold
        pre = slice(max(a0 - 30, 0), a0)
        hold = slice(a1 + (b0 - a1) // 4, a1 + 3 * (b0 - a1) // 4 + 1)
        ang = np.stack([att.thx_rad, att.thy_rad], axis=1).astype(np.float64)
        d = np.degrees(ang[hold].mean(axis=0) - ang[pre].mean(axis=0))
        ddom, turned = _axis_turned(d, mv.axis, mv.sign)
        txt = f"pitch thx {_fmt(d[0])}, roll thy {_fmt(d[1])}"
        gyro_ok = len(rep.problems) == n_problems
        if turned == "ok":
            rep.lines.append(f"  attitude: OK, the firmware's {_ANGLE_NAMES[mv.axis]} moved {_fmt(d[ddom])} ({txt}).")
        elif not gyro_ok:
            rep.lines.append(
                f"  attitude: follows the gyro's fault ({txt}); the firmware's motors would push the "
                "drone over instead of levelling it."
            )
        else:
            rep.problems.append(
                f"{mv.name}: the firmware's {_ANGLE_NAMES[mv.axis]} moved the wrong way "
                f"({_fmt(d[ddom])}): it believes the drone tilted the other way; its motors would "
                "push the drone over instead of levelling it."
                if turned == "reversed"
                else f"{mv.name}: the firmware's {_ANGLE_NAMES[ddom]} moved ({_fmt(d[ddom])}) instead of "
                f"its {_ANGLE_NAMES[mv.axis]}: pitch and roll are swapped."
            )
            rep.lines.append(f"  attitude: {turned.upper()} ({txt}).")


def _fc_window(fc, steps: np.ndarray, a: int, b: int) -> np.ndarray:
    """Flight-control rows whose step lies in the attitude rows [a, b)."""
    if b <= a:
        return np.zeros(0, np.int64)
    return np.flatnonzero((fc.step >= steps[a]) & (fc.step < steps[min(b, len(steps) - 1)]))


def _check_controller(rep: PreflightReport, mv: Move, fc, att, a0: int, a1: int, b0: int, steps) -> None:
    pre = _fc_window(fc, steps, max(a0 - 160, 0), a0)
    # yaw while turning: below MIN_THR the firmware resets its yaw angle and target, so only the rate loop sees it
    if mv.axis == 2:
        hold = _fc_window(fc, steps, a0, a1)
    else:
        hold = _fc_window(fc, steps, a1 + (b0 - a1) // 4, a1 + 3 * (b0 - a1) // 4 + 1)
    if len(hold) == 0:
        rep.lines.append("  controller: no flight-control frame during the hold (hold the move longer).")
        return
    ax = mv.axis
    name = "xyz"[ax]
    want = -mv.sign  # the controller must push back
    s1 = float(np.mean(fc.outer_s1_radps[hold, ax]))
    idle_yaw = ax == 2 and not np.all(fc.rc[hold, 3] >= C.MIN_THR)  # the firmware holds yaw and its target at 0
    ok1 = idle_yaw or (np.sign(s1) == want and abs(s1) > 1e-3)
    armed = bool(np.all(fc.fc_flags[hold] & 1))
    line = f"  controller: outer {name}_s1 {s1:+.2f} rad/s"
    if idle_yaw:
        line += " (0 below MIN_THR: the firmware resets its yaw angle and target)"
    if armed:
        ds2 = float(np.mean(fc.inner_s2_pwm[hold, ax]) - (np.mean(fc.inner_s2_pwm[pre, ax]) if len(pre) else 0.0))
        ok2 = np.sign(ds2) == want and abs(ds2) > 1.0
        line += f", inner {name}_s2 {ds2:+.0f}"
    else:
        ok2 = True
        line += " (not armed: the inner loop does not run)"
    back = {0: "nose down", 1: "roll back left", 2: "turn back left"}[ax]
    if ok1 and ok2:
        rep.lines.append(line + f": OK, it asks to {back}.")
    else:
        rep.lines.append(line + ": WRONG direction.")
        rep.problems.append(
            f"{mv.name}: the controller does not ask to {back} ({line.strip()}); the PID gains' "
            "signs or the sensor axis are wrong."
        )
    # motors during the hold
    mp = fc.motor_pwm
    on = armed and np.all(fc.rc[hold, 3] >= C.MIN_THR)
    mix = mixer_matrix()[:, ax] * want  # expected sign of each motor's change
    if not on:
        ups = [m.label for m, s in zip(MOTORS, mix) if s > 0]
        rep.lines.append(
            f"  motors: off (the firmware zeroes them while disarmed or below MIN_THR "
            f"{C.MIN_THR}); the mixer would speed up {' and '.join(ups)}."
        )
        return
    dm = mp[hold].mean(axis=0) - (mp[pre].mean(axis=0) if len(pre) else 0.0)
    wrong = []
    for m, d, s in zip(MOTORS, dm, mix):
        verb = "speeds up" if s > 0 else "slows down"
        if np.sign(d) == s and abs(d) >= _MIN_MOTOR_DELTA:
            rep.lines.append(f"  {m.label}: OK, {verb} ({d:+.0f}).")
        else:
            must = "speed up" if s > 0 else "slow down"
            rep.lines.append(f"  {m.label}: WRONG, changed {d:+.0f}; the mixer says it must {must}.")
            wrong.append(f"{m.label} changed {d:+.0f} instead of {'speeding up' if s > 0 else 'slowing down'}")
    if wrong:
        rep.problems.append(f"{mv.name}: " + "; ".join(wrong) + ".")


def _check_outputs(rep: PreflightReport, fc, att, motors_on_any: bool) -> None:
    armed = (fc.fc_flags & 1).astype(bool)
    # the throttle the TIM9 ISR mixed with: gTHR as ahrs_fusion_ag read it this step (the main loop sets the new
    # gTHR after the AHRS step); the frame's own gTHR where the step's attitude row is missing
    thr = fc.rc[:, 3].copy()
    j = np.clip(np.searchsorted(att.step, fc.step), 0, len(att) - 1)
    same = att.step[j] == fc.step
    thr[same] = att.thr[j[same]]
    on = armed & (thr >= C.MIN_THR)
    if not motors_on_any:
        rep.lines.append(
            "Motor outputs: not checked, the motors were off the whole time (arm and raise the "
            f"throttle just above MIN_THR {C.MIN_THR}, props off, to check them)."
        )
        return
    mp = fc.motor_pwm[on].astype(np.float32)
    lines = mixer_pwm(thr[on], fc.inner_s2_pwm[on])
    # residual of output i against mixer line j
    res = np.abs(mp[:, :, None] - lines[:, None, :]).mean(axis=0)  # (4 outputs, 4 lines)
    best = np.argmin(res, axis=1)
    exact = float(np.mean(np.all(mp == expected_motor_pwm(thr[on], fc.inner_s2_pwm[on], armed[on]), axis=1)))
    if np.all(best == np.arange(4)):
        rep.lines.append(
            f"Motor outputs: OK, each output carries its own mixer line ({exact:.0%} of the "
            f"{len(mp)} frames with the motors on bit for bit)."
        )
        return
    done = set()
    for i, j in enumerate(best):
        mi, mj = MOTORS[i], MOTORS[j]
        if i == j:
            rep.lines.append(f"Motor output {i + 1}: OK.")
            continue
        rep.lines.append(f"Motor output {mi.number}: WRONG, carries {mj.label}'s command.")
        if i in done:
            continue
        if best[j] == i:  # a pair swapped
            done.update((i, j))
            rep.problems.append(
                f"motor order: outputs {mi.number} and {mj.number} are swapped: output {mi.number} (TIM4 channel "
                f"{mi.number}, the {mi.position} motor's plug) carries the command of {mj.label} and output "
                f"{mj.number} that of {mi.label}, so these two motors push the wrong way for pitch and yaw and the "
                "drone flips or spins at take-off. Fix the mixer lines (motorN_pwm = ...) in flight_control.c or "
                "the motor order of the build."
            )
        else:
            done.add(i)
            rep.problems.append(
                f"motor order: output {mi.number} (TIM4 channel {mi.number}, the {mi.position} "
                f"motor's plug) carries the command of {mj.label}. Fix the mixer lines in "
                "flight_control.c or the motor order of the build."
            )

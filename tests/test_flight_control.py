"""The firmware's flight control on the host (mixer, motor places, outer-loop P) and the emulated remote's sticks."""

from __future__ import annotations

import numpy as np
import pytest

from steval_link import constants as C
from steval_link.analysis.flight_control import MOTORS, expected_motor_pwm, mixer_pwm, motor_thr, outer_p
from steval_link.emulation import motion as M
from steval_link.emulation.runner import MOUNTS, ScenarioMotion, joydata_bytes
from steval_link.errors import UserError


def test_motor_places_and_spin_follow_the_mixer_signs():
    # flight_control.c: motor1 = thr - x - y + z, motor2 = thr + x - y - z, motor3 = thr + x + y + z,
    # motor4 = thr - x + y - z; +x (nose up) needs the front, +y (right side down) the left side, +z (turn
    # counter-clockwise) the clockwise props
    assert [(m.position, m.spin) for m in MOTORS] == [
        ("right rear", "clockwise"), ("right front", "counter-clockwise"),
        ("left front", "clockwise"), ("left rear", "counter-clockwise")]


def test_mixer_is_the_firmwares_float32_arithmetic():
    thr = np.array([208, 520, 0], np.int16)
    s2 = np.array([[1.5, -2.25, 3.125], [-800.0, 800.0, 12.5], [0.1, 0.2, 0.3]], np.float32)
    out = mixer_pwm(thr, s2)
    mt = np.trunc(np.float32(0.05) * thr.astype(np.float32) + np.float32(633.333)).astype(np.float32)
    assert motor_thr(thr).tolist() == mt.tolist() == [643.0, 659.0, 633.0]
    x, y, z = s2[:, 0], s2[:, 1], s2[:, 2]
    ref = np.stack([((mt - x) - y) + z, ((mt + x) - y) - z, ((mt + x) + y) + z, ((mt - x) + y) - z], axis=1)
    assert out.dtype == np.float32 and out.tobytes() == ref.astype(np.float32).tobytes()
    exp = expected_motor_pwm(thr, s2, [True, False, True])
    assert exp[0].tolist() == out[0].tolist() and not exp[1].any() and not exp[2].any()  # disarmed, thr < MIN_THR


def test_outer_p_is_kp1_times_the_error():
    rc = np.array([[0.1, -0.2, 0.0]], np.float32)
    ang = np.array([[0.05, 0.1, -0.3]], np.float32)
    p = outer_p(rc, ang)
    assert p.tolist() == (np.array(C.OUTER_KP, np.float32) * (rc - ang)).tolist()


def test_joydata_is_the_inverse_of_main_c():
    b = joydata_bytes(thr=520, ail=-702, ele=702, rud=-910, armed=True)
    j2, j3, j4, j5, _, j7 = b
    assert (j2 - 128) * -13 == -910 and j3 * 13 == 520 and (j4 - 128) * -13 == -702 and (j5 - 128) * 13 == 702
    assert j7 & 0x04 and not joydata_bytes(0, 0, 0, 0, False)[5]
    assert joydata_bytes(0, 0, 0, 0, False)[0] == 128  # centred sticks


def test_flight_scenario_arms_and_moves_the_sticks():
    motion = ScenarioMotion("flight", 30.0, seed=1)
    ticks = np.arange(0, int(29.0 * C.ISR_RATE_HZ), 50)
    rem = [motion.remote(int(k)) for k in ticks]
    armed = np.array([r[2] for r in rem])
    sticks = np.array([r[1] for r in rem])
    thr = np.array([r[0] for r in rem])
    assert armed.any() and not armed[0] and not armed[-1]
    assert sticks[:, 1].max() >= 650 and sticks[:, 0].min() <= -650 and sticks[:, 2].min() <= -850
    assert thr.max() > 450  # hovering


def test_mount_fault_turns_what_the_board_reads():
    ok = ScenarioMotion("hand-tilts", 20.0, seed=2)
    bad = ScenarioMotion("hand-tilts", 20.0, seed=2, mount="turned-180")
    k = int(12.0 * C.ISR_RATE_HZ)
    a_ok, g_ok = ok.counts(k)
    a_bad, g_bad = bad.counts(k)
    assert not np.array_equal(a_ok, a_bad)
    assert set(MOUNTS) == {"turned-90", "turned-180"}
    with pytest.raises(UserError, match="unknown --mount"):
        ScenarioMotion("bench", 5.0, seed=0, mount="sideways")


def test_preflight_scenario_makes_the_guided_moves_in_order():
    assert [m[0] for m in M.PREFLIGHT_MOVES] == ["tilt right", "nose up", "turn right"]
    motion = ScenarioMotion("preflight", 32.0, seed=1)
    k = int(10.0 * C.ISR_RATE_HZ)
    thr, sticks, armed = motion.remote(k)
    assert armed and thr >= C.MIN_THR and sticks == (0, 0, 0)

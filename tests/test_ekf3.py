"""The course's 3-state Euler-angle EKF (steval_link.estimators.ekf3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.estimator_checks import assert_bad_samples_harmless, assert_run_equals_steps

from steval_link.emulation import broad
from steval_link.estimators.ekf3 import Ekf3
from steval_link.estimators.registry import create
from steval_link.quat import euler_from_quaternion, quaternion_from_euler

RATE = 161.5384615


def test_quaternion_from_euler_round_trips_the_firmware_convention():
    rng = np.random.default_rng(0)
    thx = rng.uniform(-3, 3, 200)
    thy = rng.uniform(-1.5, 1.5, 200)
    thz = rng.uniform(-3, 3, 200)
    q = quaternion_from_euler(thx, thy, thz)
    ex, ey, ez = euler_from_quaternion(q)
    assert np.allclose(ex, thx) and np.allclose(ey, thy) and np.allclose(ez, thz)


def test_static_tilt_converges_to_the_accelerometer_angles():
    thx, thy = 0.3, -0.5
    g = np.array([-math.sin(thy), math.sin(thx) * math.cos(thy), math.cos(thx) * math.cos(thy)]) * 1000.0
    acc = np.tile(g, (1500, 1))
    r = Ekf3().run(acc, np.zeros_like(acc))
    assert r.thx_rad[-1] == pytest.approx(thx, abs=1e-3)
    assert r.thy_rad[-1] == pytest.approx(thy, abs=1e-3)
    assert r.valid.all()


@pytest.mark.parametrize("exact", [True, False])
def test_tracks_a_rotation_with_consistent_gyro_and_gravity(exact):
    n = 4000
    t = np.arange(n) / RATE
    thx = 0.5 * np.sin(2 * np.pi * 0.4 * t)
    thy = 0.3 * np.sin(2 * np.pi * 0.25 * t + 0.5)
    thz = 0.2 * t
    q = quaternion_from_euler(thx, thy, thz)
    dq = broad.quat_multiply(broad.quat_conjugate(q[:-1]), q[1:])
    ang = 2 * np.arctan2(np.linalg.norm(dq[:, 1:], axis=1), dq[:, 0])
    axis = dq[:, 1:] / np.maximum(np.linalg.norm(dq[:, 1:], axis=1, keepdims=True), 1e-15)
    gyro = np.degrees(np.vstack([np.zeros((1, 3)), axis * (ang * RATE)[:, None]])) * 1000.0
    acc = np.stack([-np.sin(thy), np.sin(thx) * np.cos(thy), np.cos(thx) * np.cos(thy)], axis=1) * 1000.0
    rng = np.random.default_rng(1)
    r = Ekf3(exact_propagation=exact).run(acc + rng.normal(0, 2, acc.shape), gyro + rng.normal(0, 75, acc.shape))
    err = broad.inclination_error_rad(r.q_wxyz, q)
    assert broad.rmse_deg(err) < 0.5
    # yaw follows the gyro (no absolute reference), so it stays close over this short run
    assert np.degrees(np.abs(np.angle(np.exp(1j * (r.thz_rad - thz))))).max() < 3.0


def test_acceleration_robustness_is_optional():
    n = 3000
    acc = np.tile([0.0, 0.0, 1000.0], (n, 1))
    acc[1000:1100, 0] = 900.0  # a 0.6 s shove of 0.9 g
    plain = Ekf3().run(acc, np.zeros((n, 3)))
    robust = Ekf3(adaptive=True).run(acc, np.zeros((n, 3)))
    level = np.tile([1.0, 0, 0, 0], (n, 1))
    e_plain = np.degrees(broad.inclination_error_rad(plain.q_wxyz, level)).max()
    e_robust = np.degrees(broad.inclination_error_rad(robust.q_wxyz, level)).max()
    assert e_robust < 0.5 * e_plain


def test_interface_and_registry():
    est = create("ekf3", rate_hz=200.0)
    assert isinstance(est, Ekf3) and est.dt == pytest.approx(0.005)
    acc = np.tile([[100.0, 0.0, 995.0]], (20, 1))
    gyro = np.zeros((20, 3))
    assert_run_equals_steps(est, acc, gyro)
    assert_bad_samples_harmless(est, [([0, 0, 0], [0, 0, 0]), ([np.nan, 0, 1000], [np.nan, 0, 0])])
    with pytest.raises(ValueError):
        Ekf3(rate_hz=-1)

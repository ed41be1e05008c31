"""Accelerometer-only tilt (exercise 8): the firmware's axes and angle names, zero vectors, and the estimator."""

from __future__ import annotations

import numpy as np
import pytest

from steval_link.estimators import registry
from steval_link.estimators.accel_tilt import AccelTilt, accel_tilt, tilt_quaternion
from steval_link.estimators.st_mahony import quaternion_to_euler, run
from steval_link.quat import euler_from_quaternion


def gravity_in_body_mg(q_wxyz) -> np.ndarray:
    """What the accelerometer reads at rest for attitude q: the direction the Mahony filter calls v, in mg."""
    q0, q1, q2, q3 = np.moveaxis(np.asarray(q_wxyz, dtype=np.float64), -1, 0)
    v = np.stack([2 * (q1 * q3 - q0 * q2), 2 * (q0 * q1 + q2 * q3), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3], -1)
    return 1000.0 * v


def test_known_tilts():
    thx, thy, valid = accel_tilt([[0, 0, 1000], [0, 500, 866.0254], [-500, 0, 866.0254], [0, 0, -1000]])
    assert np.allclose(np.degrees(thx), [0, 30, 0, 180], atol=1e-4)
    assert np.allclose(np.degrees(thy), [0, 0, 30, 0], atol=1e-4)
    assert valid.all()


def test_same_angles_as_the_firmware_for_any_attitude():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(2000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    acc = gravity_in_body_mg(q)
    thx, thy, valid = accel_tilt(acc)
    ref_x, ref_y, _ = euler_from_quaternion(q)
    assert valid.all()
    assert np.allclose(thx, ref_x, atol=1e-9) and np.allclose(thy, ref_y, atol=1e-9)
    fw_x, fw_y = quaternion_to_euler(q.astype(np.float32))  # and with the firmware's own float32 conversion
    ok = np.abs(ref_y) < 1.4
    assert np.allclose(thx[ok], fw_x[ok], atol=1e-5) and np.allclose(thy[ok], fw_y[ok], atol=1e-5)


def test_the_firmware_filter_converges_to_the_accelerometer_tilt():
    acc = np.tile(np.float32([-250.0, 400.0, 880.0]), (3000, 1))
    _, thx, thy, _ = run(acc, np.zeros((3000, 3)))  # kp = 10 on the ground
    ax, ay, _ = accel_tilt(acc[-1])
    assert abs(float(thx[-1]) - ax) < 1e-3 and abs(float(thy[-1]) - ay) < 1e-3


def test_zero_and_non_finite_vectors_are_defined_but_invalid():
    thx, thy, valid = accel_tilt([[0.0, 0.0, 0.0], [np.nan, 0.0, 1000.0], [0.0, np.inf, 1.0]])
    assert thx[0] == 0.0 and thy[0] == 0.0 and not valid.any()
    est = AccelTilt().run(np.zeros((4, 3)), np.zeros((4, 3)))
    assert not est.valid.any() and np.isfinite(est.q_wxyz).all() and np.isnan(est.thz_rad).all()


def test_units_do_not_matter_and_dynamic_acceleration_can_be_flagged():
    a = np.array([[120.0, -340.0, 910.0]])
    assert np.allclose(accel_tilt(a)[:2], accel_tilt(a * 9.80665e-3)[:2])
    _, _, valid = accel_tilt([[0, 0, 1000], [0, 0, 1500], [0, 0, 950]], max_dev_mg=100)
    assert valid.tolist() == [True, False, True]


def test_tilt_quaternion_round_trips():
    thx = np.linspace(-3.0, 3.0, 41)
    thy = np.linspace(-1.5, 1.5, 41)
    q = tilt_quaternion(thx, thy)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    rx, ry, rz = euler_from_quaternion(q)
    assert np.allclose(rx, thx) and np.allclose(ry, thy) and np.allclose(rz, 0.0)


def test_estimator_interface():
    est = registry.create("accel", max_dev_mg=200)
    assert est.name == "accel"
    acc = np.array([[0.0, 500.0, 866.0], [0.0, 0.0, 0.0]])
    res = est.run(acc, np.zeros_like(acc))
    assert res.valid.tolist() == [True, False]
    assert np.allclose(est.step(acc[0], [0, 0, 0]), res.q_wxyz[0])
    est.reset()
    with pytest.raises(ValueError):
        est.run(np.zeros((3, 2)), np.zeros((3, 2)))

"""The MEKF (steval_link.estimators.mekf): convergence, bias estimation, tracking, robustness, interface."""

from __future__ import annotations

import numpy as np
import pytest
from support.estimator_checks import assert_bad_samples_harmless, assert_run_equals_steps

from steval_link.emulation import broad
from steval_link.estimators.mekf import Mekf
from steval_link.estimators.registry import create
from steval_link.quat import quaternion_from_euler

RATE = 161.5384615


def _trajectory(n, rate=RATE, amp_rad=0.6, f_hz=0.5):
    """Body → earth attitude swinging about x and y; exact gyro (mdps) and gravity-only acc (mg)."""
    t = np.arange(n) / rate
    thx = amp_rad * np.sin(2 * np.pi * f_hz * t)
    thy = 0.7 * amp_rad * np.sin(2 * np.pi * 0.7 * f_hz * t + 1.0)
    thz = 0.3 * t
    q = quaternion_from_euler(thx, thy, thz)
    # body rate from consecutive quaternions: ω = 2·log(q_k⁻¹ q_{k+1}) / dt, taken at the step's end
    dq = broad.quat_multiply(broad.quat_conjugate(q[:-1]), q[1:])
    ang = 2 * np.arctan2(np.linalg.norm(dq[:, 1:], axis=1), dq[:, 0])
    axis = dq[:, 1:] / np.maximum(np.linalg.norm(dq[:, 1:], axis=1, keepdims=True), 1e-15)
    w = np.vstack([np.zeros((1, 3)), axis * (ang * rate)[:, None]])
    # gravity in the body frame: third row of R(q)
    q0, q1, q2, q3 = q.T
    g = np.stack([2 * (q1 * q3 - q0 * q2), 2 * (q0 * q1 + q2 * q3), q0**2 - q1**2 - q2**2 + q3**2], axis=1)
    return q, np.degrees(w) * 1000.0, g * 1000.0


def test_static_tilt_converges_to_the_accelerometer():
    acc = np.tile([[-300.0, 200.0, 933.0]], (800, 1))
    r = Mekf(latency_s=0.0).run(acc, np.zeros_like(acc))
    q = r.q_wxyz[-1]
    g = np.array(
        [
            2 * (q[1] * q[3] - q[0] * q[2]),
            2 * (q[0] * q[1] + q[2] * q[3]),
            q[0] ** 2 - q[1] ** 2 - q[2] ** 2 + q[3] ** 2,
        ]
    )
    assert np.allclose(g, acc[0] / np.linalg.norm(acc[0]), atol=1e-3)
    assert r.valid.all()


def test_tracks_a_swinging_motion_with_bias_and_noise():
    n = 6000
    q_true, gyro, acc = _trajectory(n)
    rng = np.random.default_rng(0)
    bias = np.array([300.0, -200.0, 100.0])  # mdps
    gyro_m = gyro + bias + rng.normal(0, 60, gyro.shape)
    acc_m = acc + rng.normal(0, 2, acc.shape)
    est = Mekf(latency_s=0.0)
    r = est.run(acc_m, gyro_m)
    err = broad.inclination_error_rad(r.q_wxyz, q_true)
    assert broad.rmse_deg(err[n // 2 :]) < 0.5
    # the horizontal bias components are observable; the estimate approaches them
    assert np.linalg.norm(est.bias_mdps - bias) < np.linalg.norm(bias)
    # without the bias states the 0.3 dps bias costs far more accuracy
    no_bias = Mekf(latency_s=0.0, estimate_bias=False).run(acc_m, gyro_m)
    err_nb = broad.inclination_error_rad(no_bias.q_wxyz, q_true)
    assert broad.rmse_deg(err_nb[n // 2 :]) > 3 * broad.rmse_deg(err[n // 2 :])


def test_clean_motion_is_tracked_exactly():
    q_true, gyro, acc = _trajectory(3000)
    r = Mekf(latency_s=0.0).run(acc, gyro)
    assert np.degrees(broad.inclination_error_rad(r.q_wxyz, q_true)).max() < 0.01


def test_linear_acceleration_that_averages_out_does_not_tilt_the_estimate():
    n = 8000
    t = np.arange(n) / RATE
    acc = np.zeros((n, 3))
    acc[:, 2] = 1000.0
    acc[:, 0] = 500.0 * np.sign(np.sin(2 * np.pi * 1.0 * t))  # ±0.5 g shaking along x, level body
    r = Mekf(latency_s=0.0).run(acc, np.zeros((n, 3)))
    err = broad.inclination_error_rad(r.q_wxyz, np.tile([1.0, 0, 0, 0], (n, 1)))
    assert np.degrees(err[int(4 * RATE) :]).max() < 5.0  # after the start-up (warm-up mean over τ = 3 s)
    assert np.degrees(err[n // 2 :]).max() < 1.0 and np.degrees(err[-1]) < 0.3
    # the direct (body-frame) MEKF is pulled around by it
    r_direct = Mekf(latency_s=0.0, acc_tau_s=0.0).run(acc, np.zeros((n, 3)))
    err_d = broad.inclination_error_rad(r_direct.q_wxyz, np.tile([1.0, 0, 0, 0], (n, 1)))
    assert np.degrees(err_d[n // 2 :]).max() > 3 * np.degrees(err[n // 2 :]).max()


def test_latency_compensation_predicts_along_the_rate():
    acc = np.tile([[0.0, 0.0, 1000.0]], (3, 1))
    gyro = np.tile([[0.0, 0.0, 90000.0]], (3, 1))  # 90 dps about z
    a = Mekf(latency_s=0.0).run(acc, gyro).q_wxyz[-1]
    b = Mekf(latency_s=0.01).run(acc, gyro).q_wxyz[-1]
    d = broad.quat_multiply(broad.quat_conjugate(a), b)
    assert 2 * np.degrees(np.arctan2(np.linalg.norm(d[1:]), d[0])) == pytest.approx(0.9, rel=1e-3)


def test_interface_reset_step_run_and_bad_samples():
    est = create("mekf")
    acc = np.tile([[0.0, 0.0, 1000.0]], (10, 1))
    gyro = np.zeros((10, 3))
    assert_run_equals_steps(est, acc, gyro)
    # NaN or zero inputs do not poison the state
    assert_bad_samples_harmless(est, [([np.nan, 0, 0], [0, 0, 0]), ([0, 0, 0], [np.nan, 0, 0])])
    with pytest.raises(ValueError):
        Mekf(rate_hz=0)


def _butterworth2_reference(x: np.ndarray, fc_hz: float, fs_hz: float) -> np.ndarray:
    """2nd-order Butterworth low-pass of the columns of x, designed and run independently of mekf: analog poles
    Ωc·e^{±j3π/4} (Ωc pre-warped), bilinear map, double zero at z = −1, unit DC gain, transposed direct form II
    from rest. The output starts in steady state at x[0] (superposition: x[0] + response to x − x[0])."""
    wc = 2 * fs_hz * np.tan(np.pi * fc_hz / fs_hz)
    s = wc * np.exp(1j * 3 * np.pi / 4)
    z = (1 + s / (2 * fs_hz)) / (1 - s / (2 * fs_hz))
    a = np.real(np.poly([z, np.conj(z)]))  # 1, a1, a2
    b = np.array([1.0, 2.0, 1.0]) * abs(1 - z) ** 2 / 4.0  # (1 + z⁻¹)², DC gain 1: |1 − z|² = 1 + a1 + a2
    u = x - x[0]
    y = np.empty_like(u)
    s1 = np.zeros(x.shape[1])
    s2 = np.zeros(x.shape[1])
    for k in range(u.shape[0]):
        y[k] = b[0] * u[k] + s1
        s1 = b[1] * u[k] - a[1] * y[k] + s2
        s2 = b[2] * u[k] - a[2] * y[k]
    return x[0] + y


@pytest.mark.parametrize("native", [False, True])
def test_low_pass_of_C_is_the_butterworth_of_its_history(native):
    """LP(C) in the bias Jacobian is the documented Butterworth of the past C values (regression: the low-pass
    once kept a view of C, which the prediction updates in place, so its x1/x2 history read the current C)."""
    from steval_link.estimators import mekf as mekf_mod

    if native and not mekf_mod.NATIVE_AVAILABLE:
        pytest.skip("native EKF loop (_ekf_native) not built")
    tau = 0.5
    q_true, gyro, acc = _trajectory(1200)
    gyro = gyro + np.array([300.0, -200.0, 100.0])
    ref = Mekf(acc_tau_s=tau, latency_s=0.0)
    cum, lp = [], []
    for a, g in zip(acc, gyro):
        ref.step(a, g)
        if ref._cum_lp.ready:  # fed once per step from the end of the accelerometer low-pass' warm-up on
            cum.append(ref._cum_rs.ravel().copy())
            lp.append(ref._cum_lp.y1.copy())
    cum, lp = np.array(cum), np.array(lp)
    assert 800 < len(cum) < 1200 and np.ptp(cum, axis=0).max() > 1.0  # C moved a lot while filtered
    want = _butterworth2_reference(cum, np.sqrt(2) / (2 * np.pi * tau), RATE)
    # rounding, amplified by the poles near z = 1, leaves ≈ 1e-10 (|C| ≤ 6); the aliased history was off by 6e-3
    np.testing.assert_allclose(lp, want, rtol=0, atol=1e-9)
    # the C loop (run in two pieces, state carried between them) ends with the same low-pass memory
    est = Mekf(acc_tau_s=tau, latency_s=0.0)
    est.run(acc[:500], gyro[:500], native=native)
    est.run(acc[500:], gyro[500:], native=native)
    np.testing.assert_allclose(est._cum_lp.y1, want[-1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(est._cum_lp.x1, cum[-1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(est._cum_lp.x2, cum[-2], rtol=0, atol=1e-9)

"""The LSM6DSL model and the firmware's ISR pipeline (steval_link.emulation.sensor_model)."""

from __future__ import annotations

import numpy as np
import pytest

from steval_link import constants as C
from steval_link.emulation import sensor_model as sm

F32 = np.float32


def _iir_reference(x_int):
    """Independent scalar port of the ISR's IIR lines (float32 each operation, C order, state from zero)."""
    a1, a2, b0, b1, b2 = (
        F32(v)
        for v in (
            0.94280904158206336,
            -0.33333333333333343,
            0.09763107293781749,
            0.19526214587563498,
            0.09763107293781749,
        )
    )
    x1 = x2 = y1 = y2 = F32(0)
    out = []
    for v in x_int:
        x = F32(int(v))
        y = F32(F32(F32(F32(b0 * x) + F32(b1 * x1)) + F32(b2 * x2)) + F32(a1 * y1))
        y = F32(y + F32(a2 * y2))
        x2, x1 = x1, x
        y2, y1 = y1, y
        out.append(y)
    return np.array(out, dtype=F32)


def test_gyro_iir_bit_exact_against_scalar_reference():
    rng = np.random.default_rng(1)
    g = rng.integers(-200000, 200000, size=(600, 3)).astype(np.int32)
    y = sm.gyro_iir(g)
    assert y.dtype == F32
    for j in range(3):
        ref = _iir_reference(g[:, j])
        assert np.array_equal(y[:, j].view(np.int32), ref.view(np.int32))


def test_gyro_iir_chunks_equal_whole_and_dc_gain_one():
    rng = np.random.default_rng(2)
    g = rng.integers(-5000, 5000, size=(300, 3))
    whole = sm.gyro_iir(g)
    st = sm.IirState()
    parts = np.concatenate([sm.gyro_iir(g[:7], st), sm.gyro_iir(g[7:8], st), sm.gyro_iir(g[8:], st)])
    assert np.array_equal(whole, parts)
    const = sm.gyro_iir(np.full((400, 3), 7000))
    assert np.allclose(const[-1], 7000, rtol=1e-5)


def test_iir_frequency_response_is_a_100hz_butterworth_at_800hz():
    h, gain_db, _, gd = sm.iir_frequency_response([0.0, 100.0, 300.0], fs_hz=800.0)
    assert abs(h[0]) == pytest.approx(1.0, abs=1e-6)
    assert gain_db[1] == pytest.approx(-3.01, abs=0.05)
    assert gain_db[2] < -20
    # group delay at low frequency ≈ 1.7 samples; the published latency adds half a 416 Hz period
    _, _, _, gd_tick = sm.iir_frequency_response([0.0])
    assert sm.GYRO_LATENCY_S == pytest.approx(gd_tick[0] + 0.5 / 416.0)
    assert 0.002 < gd_tick[0] < 0.0025


def test_fifo_average_is_float32_sum_times_double_fifth():
    rng = np.random.default_rng(3)
    fifo = rng.normal(0, 3000, size=(2000, 5, 3)).astype(F32)
    got = sm.fifo_average(fifo)
    s = np.zeros((2000, 3), F32)
    for i in range(5):
        s = (s + fifo[:, i]).astype(F32)
    ref = np.array([[F32(float(v) * (1.0 / 5)) for v in row] for row in s], dtype=F32)
    assert np.array_equal(got, ref)
    # and it is not the float32 product with 0.2f (the firmware multiplies in double)
    assert not np.array_equal(got, s * F32(0.2))


def test_quantisation_like_the_st_driver():
    acc = sm.quantise([[1000.0, -1000.0, 5000.0], [0.05, -0.2, -5000.0]], sm.ACC_SENSITIVITY_MG)
    # 1000 mg → raw 8197 → 8197·0.122f = 1000.03 → 1000; truncation toward zero; ±4 g saturation (raw ±32767/8)
    assert acc.tolist() == [[1000, -1000, 3997], [0, 0, -3997]]
    gyro = sm.quantise([[36.0, -106.0, 2.5e6]], sm.GYRO_SENSITIVITY_MDPS)  # nearest LSB, saturation at raw 32767
    assert gyro.tolist() == [[70, -140, 32767 * 70]]
    assert gyro.dtype == np.int32 and acc.dtype == np.int32


def test_calibration_and_offset_removal():
    acc = np.tile([[13, -7, 1021]], (800, 1))
    gyro = np.tile([[-201, 55, 3]], (800, 1))
    acc[0, 0] += 799  # sum 13·800 + 799 → ·0.00125 = 13.99875 → 13 (truncation)
    a_off, g_off = sm.calibrate_offsets(acc, gyro)
    assert a_off.tolist() == [13, -7, 1021] and g_off.tolist() == [-201, 55, 3]
    a, g = sm.remove_offsets(acc[1:2], gyro[1:2], a_off, g_off)
    assert a.tolist() == [[0, 0, 1000]] and g.tolist() == [[0, 0, 0]]


def test_run_isr_timeline_and_steady_state():
    t = 1599 + 5 * 200 + 3
    acc = np.tile([[30, -20, 1010]], (t, 1))
    gyro = np.tile([[1400, 0, -700]], (t, 1))
    out = sm.run_isr(acc, gyro)
    assert out.first_tick == 1599
    assert out.acc_ahrs_mg.shape == (200, 3) and out.gyro_ahrs_mdps.shape == (200, 3)
    assert np.all(np.diff(out.step_tick) == 5) and out.step_tick[0] == 1599 + 4
    assert np.array_equal(out.acc_ahrs_mg[-1], np.array([0, 0, 1000], F32))
    assert np.all(out.gyro_ahrs_mdps[-1] == 0)  # a constant rate during calibration is taken as bias
    # without calibration: default offsets (0, 0, 1000) leave the readings as they are
    out2 = sm.run_isr(acc[:50], gyro[:50], calibrate=False)
    acc2, gyro2 = out2.acc_ahrs_mg, out2.gyro_ahrs_mdps
    assert acc2.shape == (10, 3) and np.allclose(acc2[-1], [30, -20, 1010])
    assert np.allclose(gyro2[-1], [1400, 0, -700], rtol=1e-3)
    with pytest.raises(ValueError):
        sm.run_isr(acc[:100], gyro[:100])


def test_lsm6dsl_read_is_seeded_and_noisy_as_configured():
    n = 20000
    acc = np.tile([0.0, 0.0, 1000.0], (n, 1))
    gyro = np.zeros((n, 3))
    s = sm.Lsm6dsl(acc_noise_mg=2.0, gyro_noise_mdps=75.0, gyro_bias_mdps=(700.0, 0.0, 0.0))
    a1, g1 = s.read(acc, gyro, rng=5)
    a2, g2 = s.read(acc, gyro, rng=np.random.default_rng(5))
    assert np.array_equal(a1, a2) and np.array_equal(g1, g2)
    assert np.std(a1[:, 2]) == pytest.approx(2.0, rel=0.15)
    assert np.mean(g1[:, 0]) == pytest.approx(700, abs=5)
    assert np.std(g1[:, 1]) == pytest.approx(np.sqrt(75.0**2 + 70**2 / 12), rel=0.1)
    assert np.all(g1 % 70 == 0)  # 70 mdps steps
    # gyro noise held per 416 Hz sample when tick times are given
    t = np.arange(n) / C.ISR_RATE_HZ
    _, g3 = s.read(acc, gyro, rng=5, t_tick_s=t)
    idx = np.floor(t * 416.0 + 1e-9).astype(int)
    same = idx[1:] == idx[:-1]
    assert np.all(g3[1:][same] == g3[:-1][same])


def test_resample_to_tick_linear_and_hold():
    t = np.arange(0, 2.0, 1 / 285.714)
    x = np.stack([3 * t, -t], axis=1)
    tt, y = sm.resample_to_tick(t, x)
    assert tt[1] == pytest.approx(1 / C.ISR_RATE_HZ)
    assert np.allclose(y[:, 0], 3 * tt) and y.shape == (tt.shape[0], 2)
    _, yh = sm.resample_to_tick(t, x, hold_hz=416.0)
    assert np.allclose(yh[:, 0], 3 * np.floor(tt * 416.0 + 1e-9) / 416.0)
    assert np.all(yh[:, 0] <= y[:, 0] + 1e-12)


def test_isr_yaw_integrates_and_resets_below_min_thr():
    gz = np.full(1615, 100000.0, dtype=F32)  # 100 dps for 2 s of ticks
    thr = np.r_[np.full(800, 0), np.full(815, 450)]
    yaw = sm.isr_yaw_rad(gz, thr)
    assert np.all(yaw[:800] == 0)
    assert float(yaw[-1]) == pytest.approx(np.radians(100) * 815 * 0.00125, rel=1e-4)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_pipeline_matches_the_conformance_vectors_inputs(shared_dir):
    """broad_02.csv's inputs were made by an emulated STEVAL pipeline; ours must agree in scale, offset and lag."""
    from steval_link.emulation import broad

    trial = broad.load_trial(shared_dir / "datasets" / "broad" / "02_undisturbed_slow_rotation_B.npz")
    view = broad.steval_view(trial)
    rows = np.genfromtxt(shared_dir / "conformance" / "st-fcu-170120" / "broad_02.csv", delimiter=",", skip_header=2)
    acc_c, gyro_c = rows[:, 2:5], rows[:, 5:8]
    m = view.acc_mg.shape[0]
    lag = acc_c.shape[0] - m  # the vectors start earlier; both end with the trial
    assert 0 < lag < 400
    d_acc = acc_c[lag:] - view.acc_mg
    d_gyro = gyro_c[lag:] - view.gyro_mdps
    # constant calibration offsets differ by a few mg / mdps; what remains is rounding
    assert np.all(np.abs(d_acc.mean(axis=0)) < 5)
    assert np.all(d_acc.std(axis=0) < 0.5)
    assert np.all(np.abs(d_gyro.mean(axis=0)) < 40)
    assert np.all(d_gyro.std(axis=0) < 2.0)


def test_the_gyro_latency_stated_in_constants_is_the_sensor_models():
    from steval_link import constants

    assert constants.GYRO_LATENCY_S == pytest.approx(sm.GYRO_LATENCY_S, rel=1e-12)

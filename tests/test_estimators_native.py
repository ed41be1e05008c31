"""The C loops of Ekf3.run and Mekf.run (steval_link.estimators._ekf_native) against the Python reference.

Both paths must give the same attitude (to rounding: numpy's small matrix products go through BLAS, whose summation
order differs) for every option, on synthetic motion with bad samples and on BROAD trials through the STEVAL
pipeline model, and must leave the filter in the same state so ``step()`` continues after ``run()``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from steval_link.emulation import broad
from steval_link.estimators import ekf3, mekf
from steval_link.estimators.ekf3 import Ekf3
from steval_link.estimators.mekf import Mekf
from steval_link.quat import quaternion_from_euler

RATE = 161.5384615
TOL_RAD = 1e-9
#: steps of synthetic motion per option set: 18.6 s at 161.5 Hz, the rest, the swing's build-up and 14 s of motion
#: (the Python reference steps one sample at a time; the whole BROAD trials run in the slow tests)
SYNTHETIC_STEPS = 3000

needs_native = pytest.mark.skipif(
    not (ekf3.NATIVE_AVAILABLE and mekf.NATIVE_AVAILABLE), reason="native EKF loops (_ekf_native) not built"
)

EKF3_OPTIONS = [
    {},
    {"exact_propagation": False},
    {"adaptive": True, "norm_gain": 3.0},
    {"adaptive": True, "exact_propagation": False, "acc_motion_mg": 0.0, "gyro_noise_mdps": 300.0},
    {"rate_hz": 285.7, "process_noise_dps_rthz": 0.5},
]

MEKF_OPTIONS = [
    {},
    {"latency_s": 0.0},
    {"acc_tau_s": 0.0},
    {"acc_tau_s": 0.0, "norm_gain": 2.0, "latency_s": 0.01},
    {"norm_gain": 1.5},
    {"estimate_bias": False},
    {"estimate_bias": False, "acc_tau_s": 0.0, "norm_gain": 1.0},
    {"reject_mg": 150.0, "acc_tau_s": 1.0},
    {"acc_tau_s": 0.002},  # warm-up of 0 steps: the low-pass starts from its first sample
    {"rate_hz": 285.7, "init_bias_mdps": 20.0, "bias_rw_mdps_per_sqrt_s": 3.0, "gyro_noise_mdps_rthz": 30.0},
]


def _motion(n: int, seed: int = 0, rate: float = RATE, bad_samples: bool = True):
    """Hand-held-like motion in firmware units: (acc_mg, gyro_mdps) float32 (N, 3).

    Swinging tilt up to ≈ 40°, yaw drift, a 0.2 g linear acceleration in the earth frame, 2 s of rest first, gyro
    bias 300 mdps and noise, accelerometer noise; with ``bad_samples`` also a zero accelerometer before the first
    valid one, NaN gyro and accelerometer samples, zero and 2.5 g accelerometer spikes.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    env = np.clip((t - 2.0) / 2.0, 0.0, 1.0)
    thx = env * 0.7 * np.sin(2 * np.pi * 0.37 * t)
    thy = env * 0.5 * np.sin(2 * np.pi * 0.23 * t + 1.0)
    thz = env * 0.4 * t
    q = quaternion_from_euler(thx, thy, thz)
    dq = broad.quat_multiply(broad.quat_conjugate(q[:-1]), q[1:])
    ang = 2 * np.arctan2(np.linalg.norm(dq[:, 1:], axis=1), dq[:, 0])
    axis = dq[:, 1:] / np.maximum(np.linalg.norm(dq[:, 1:], axis=1, keepdims=True), 1e-15)
    w = np.vstack([np.zeros((1, 3)), axis * (ang * rate)[:, None]])
    gyro = np.degrees(w) * 1000.0 + [300.0, -200.0, 150.0] + rng.normal(0, 75, (n, 3))
    lin_earth = (
        env[:, None]
        * 0.2
        * np.stack(
            [np.sin(2 * np.pi * 0.9 * t), np.cos(2 * np.pi * 0.6 * t), 0.5 * np.sin(2 * np.pi * 1.3 * t)], axis=1
        )
    )
    f_earth = lin_earth + [0.0, 0.0, 1.0]  # specific force, g
    acc = _rotate(broad.quat_conjugate(q), f_earth) * 1000.0 + rng.normal(0, 3, (n, 3))
    if bad_samples:
        acc[:3] = 0.0
        gyro[rng.integers(10, n, 5)] = np.nan
        acc[rng.integers(10, n, 5)] = np.nan
        acc[rng.integers(10, n, 5)] = 0.0
        acc[rng.integers(10, n, 5)] *= 2.5
    return acc.astype(np.float32), gyro.astype(np.float32)


def _rotate(q_wxyz, v):
    """v (…, 3) rotated by the unit quaternions q (N, 4): q ⊗ (0, v) ⊗ q*."""
    v = np.broadcast_to(v, q_wxyz[..., 1:].shape)
    p = np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)
    return broad.quat_multiply(broad.quat_multiply(q_wxyz, p), broad.quat_conjugate(q_wxyz))[..., 1:]


def _wrapped(a, b):
    return np.abs(np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b)))))


def _assert_same(r_py, r_c, tol=TOL_RAD):
    assert r_py.q_wxyz.shape == r_c.q_wxyz.shape
    np.testing.assert_array_equal(r_py.valid, r_c.valid)
    ok = r_py.valid
    assert np.abs(r_py.q_wxyz[ok] - r_c.q_wxyz[ok]).max(initial=0.0) <= tol
    for k in ("thx_rad", "thy_rad", "thz_rad"):
        assert _wrapped(getattr(r_py, k)[ok], getattr(r_c, k)[ok]).max(initial=0.0) <= tol, k


def _assert_same_state(a, b, tol=1e-9):
    if isinstance(a, Ekf3):
        assert a._initialised == b._initialised
        assert np.abs(_wrapped(a.x, b.x)).max() <= tol
        assert np.abs(a.P - b.P).max() <= tol * max(1.0, np.abs(a.P).max())
    else:
        assert a._initialised == b._initialised
        assert np.abs(np.array(a.qs) - np.array(b.qs)).max() <= tol
        assert np.abs(np.array(a.qc) - np.array(b.qc)).max() <= tol
        assert np.abs(a.b - b.b).max() <= tol
        assert np.abs(a.P - b.P).max() <= tol * max(1.0, np.abs(a.P).max())


@needs_native
@pytest.mark.parametrize("options", EKF3_OPTIONS, ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()) or "default")
def test_ekf3_native_equals_python_on_synthetic_motion(options):
    n = SYNTHETIC_STEPS
    acc, gyro = _motion(n, rate=options.get("rate_hz", RATE))
    py, c = Ekf3(**options), Ekf3(**options)
    r_py = py.run(acc, gyro, native=False)
    r_c = c.run(acc, gyro, native=True)
    assert r_c.valid.sum() > n - 100  # the comparison covers the motion, not a stuck filter
    _assert_same(r_py, r_c)
    _assert_same_state(py, c)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_native
@pytest.mark.parametrize("options", MEKF_OPTIONS, ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()) or "default")
def test_mekf_native_equals_python_on_synthetic_motion(options):
    acc, gyro = _motion(SYNTHETIC_STEPS, seed=1, rate=options.get("rate_hz", RATE))
    py, c = Mekf(**options), Mekf(**options)
    r_py = py.run(acc, gyro, native=False)
    r_c = c.run(acc, gyro, native=True)
    # valid from the first accelerometer sample within reject_mg of 1 g (the motion's third): the tilt is set there
    assert r_c.valid[10:].all() and np.array_equal(r_c.valid, r_py.valid)
    _assert_same(r_py, r_c)
    _assert_same_state(py, c)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_native
def test_ekf3_through_gimbal_lock_and_upside_down():
    """A tumble about y (θ through ±90°, cos θ clamped) and a start upside down."""
    n = 3000
    t = np.arange(n) / RATE
    thy = 2.0 * np.sin(2 * np.pi * 0.2 * t)  # beyond ±90°
    thx = 0.3 * np.sin(2 * np.pi * 0.5 * t) + math.pi  # upside down
    q = quaternion_from_euler(thx, thy, 0.1 * t)
    dq = broad.quat_multiply(broad.quat_conjugate(q[:-1]), q[1:])
    ang = 2 * np.arctan2(np.linalg.norm(dq[:, 1:], axis=1), dq[:, 0])
    axis = dq[:, 1:] / np.maximum(np.linalg.norm(dq[:, 1:], axis=1, keepdims=True), 1e-15)
    gyro = np.degrees(np.vstack([np.zeros((1, 3)), axis * (ang * RATE)[:, None]])) * 1000.0
    acc = _rotate(broad.quat_conjugate(q), np.array([0.0, 0.0, 1000.0]))
    for options in ({}, {"exact_propagation": False}):
        r_py = Ekf3(**options).run(acc, gyro, native=False)
        r_c = Ekf3(**options).run(acc, gyro, native=True)
        # the Euler-angle state is ill-conditioned at gimbal lock: rounding differences grow there, so compare
        # the attitude (quaternion up to sign) rather than the angles
        dot = np.abs(np.sum(r_py.q_wxyz * r_c.q_wxyz, axis=1))
        assert np.all(1.0 - dot <= 1e-12)


@needs_native
@pytest.mark.parametrize("options", [{}, {"estimate_bias": False}, {"acc_tau_s": 0.0}, {"norm_gain": 1.0}])
def test_mekf_upside_down_start(options):
    acc, gyro = _motion(1500, seed=3, bad_samples=False)
    acc = acc * np.float32([1, -1, -1])  # rotated 180° about x
    gyro = gyro * np.float32([1, -1, -1])
    acc[0] = [0.0, 0.0, -1000.0]  # exactly inverted: the tilt quaternion's special case
    r_py = Mekf(**options).run(acc, gyro, native=False)
    r_c = Mekf(**options).run(acc, gyro, native=True)
    _assert_same(r_py, r_c)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_native
@pytest.mark.parametrize(
    "cls, options",
    [
        (Ekf3, {}),
        (Ekf3, {"exact_propagation": False}),
        (Mekf, {}),
        (Mekf, {"norm_gain": 1.0}),
        (Mekf, {"acc_tau_s": 0.0}),
        (Mekf, {"estimate_bias": False}),
    ],
)
def test_step_continues_after_native_run_and_run_after_step(cls, options):
    """run() leaves the same state as the Python steps: step() after run(), run() after step(), chunked runs."""
    acc, gyro = _motion(3000, seed=2)  # the chunks below end at 200, 2500, 2600 and the end
    ref = cls(**options)
    q_ref = ref.run(acc, gyro, native=False).q_wxyz

    # native run in chunks (the first inside the low-pass warm-up), then Python steps, then native again
    est = cls(**options)
    parts = [
        est.run(acc[:200], gyro[:200], native=True).q_wxyz,
        est.run(acc[200:2500], gyro[200:2500], native=True).q_wxyz,
        np.array([est.step(a, g) for a, g in zip(acc[2500:2600], gyro[2500:2600])]),
        est.run(acc[2600:], gyro[2600:], native=True).q_wxyz,
    ]
    q = np.vstack(parts)
    ok = np.isfinite(q_ref).all(axis=1)
    np.testing.assert_array_equal(ok, np.isfinite(q).all(axis=1))
    assert np.abs(q_ref[ok] - q[ok]).max() <= TOL_RAD
    _assert_same_state(ref, est)

    # and reset() after a native run returns to the power-up state
    est.reset()
    np.testing.assert_allclose(est.run(acc[:300], gyro[:300], native=True).q_wxyz, q_ref[:300], atol=TOL_RAD)


def test_python_fallback_when_the_extension_is_missing(monkeypatch):
    """Without the extension run() uses the Python steps; native=True says the loop is not built."""
    acc, gyro = _motion(400, seed=4)
    want_e = Ekf3().run(acc, gyro, native=False)
    want_m = Mekf().run(acc, gyro, native=False)
    for mod in (ekf3, mekf):
        monkeypatch.setattr(mod, "_native", None)
        monkeypatch.setattr(mod, "NATIVE_AVAILABLE", False)
    got_e = Ekf3().run(acc, gyro)
    got_m = Mekf().run(acc, gyro)
    np.testing.assert_array_equal(got_e.q_wxyz, want_e.q_wxyz)
    np.testing.assert_array_equal(got_m.q_wxyz, want_m.q_wxyz)
    with pytest.raises(RuntimeError, match="not built"):
        Ekf3().run(acc, gyro, native=True)
    with pytest.raises(RuntimeError, match="not built"):
        Mekf().run(acc, gyro, native=True)


@needs_native
def test_default_run_is_native_and_matches_the_registry_estimators():
    from steval_link.estimators.registry import create

    acc, gyro = _motion(1000, seed=5)
    for name, cls in (("ekf3", Ekf3), ("mekf", Mekf)):
        r_default = create(name).run(acc, gyro)
        r_native = cls().run(acc, gyro, native=True)
        np.testing.assert_array_equal(r_default.q_wxyz, r_native.q_wxyz)


def _broad_trials(shared_dir):
    paths = sorted((shared_dir / "datasets" / "broad").glob("*.npz"))
    if not paths:
        pytest.skip("no BROAD trials in ../shared/datasets/broad")
    return paths


@needs_native
@pytest.mark.slow
def test_native_equals_python_on_broad_trials(shared_dir):
    """Every BROAD trial through the STEVAL pipeline model, default options (as in the accuracy benchmark)."""
    n_max = 6000  # ≈ 37 s of each trial keeps the Python reference quick
    for path in _broad_trials(shared_dir):
        view = broad.steval_view(broad.load_trial(path))
        acc, gyro = view.acc_mg[:n_max], view.gyro_mdps[:n_max]
        for cls in (Ekf3, Mekf):
            py, c = cls(rate_hz=view.rate_hz), cls(rate_hz=view.rate_hz)
            r_py = py.run(acc, gyro, native=False)
            r_c = c.run(acc, gyro, native=True)
            _assert_same(r_py, r_c)
            _assert_same_state(py, c)


@pytest.fixture(scope="module")
def translation_view(shared_dir):
    """A whole BROAD trial through the STEVAL pipeline: fast translation (the hardest for the filters) if present."""
    paths = [p for p in _broad_trials(shared_dir) if "fast_translation" in p.name] or _broad_trials(shared_dir)
    return broad.steval_view(broad.load_trial(paths[0]))


@needs_native
@pytest.mark.parametrize(
    "cls, options",
    [
        (Ekf3, {"adaptive": True}),
        (Ekf3, {"exact_propagation": False}),
        (Mekf, {"latency_s": 0.0, "acc_tau_s": 0.0}),
        (Mekf, {"norm_gain": 1.0, "reject_mg": 300.0}),
    ],
)
@pytest.mark.slow
def test_native_equals_python_on_a_whole_broad_trial(translation_view, cls, options):
    """A whole trial with other option sets."""
    view = translation_view
    r_py = cls(rate_hz=view.rate_hz, **options).run(view.acc_mg, view.gyro_mdps, native=False)
    r_c = cls(rate_hz=view.rate_hz, **options).run(view.acc_mg, view.gyro_mdps, native=True)
    _assert_same(r_py, r_c)

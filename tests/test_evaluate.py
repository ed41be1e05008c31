"""BROAD loading and metrics (steval_link.emulation.broad), the evaluation (steval_link.analysis.evaluate) and
``steval evaluate``."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.analysis import evaluate as ev
from steval_link.emulation import broad
from steval_link.errors import UserError
from steval_link.estimators.st_mahony import StMahony
from steval_link.quat import quaternion_from_euler

BROAD_TRIALS = ("02_undisturbed_slow_rotation_B", "24_disturbed_tapping_A")


def _steval_here(monkeypatch, capsys, *args):
    """``steval ARGS`` in this process (no interpreter start-up): the same returncode, stdout and stderr."""
    code, out, err = run_cli(monkeypatch, capsys, *args)
    return SimpleNamespace(returncode=code, stdout=out, stderr=err)


# --- metric -------------------------------------------------------------------------------------------------------


def test_inclination_error_ignores_heading_offsets_and_measures_tilt():
    rng = np.random.default_rng(0)
    q_true = broad.quat_normalize(rng.normal(size=(500, 4)))
    yaw = rng.uniform(-3, 3, 500)
    q_yaw = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)  # about the earth's z
    q_est = broad.quat_multiply(q_yaw, q_true)
    assert np.allclose(broad.inclination_error_rad(q_est, q_true), 0, atol=1e-6)
    assert np.allclose(broad.heading_error_rad(q_est, q_true), np.abs(yaw), atol=1e-6)
    tilt = 0.1
    q_tilt = np.tile([np.cos(tilt / 2), np.sin(tilt / 2), 0, 0], (500, 1))  # 0.1 rad about the earth's x
    q_est2 = broad.quat_multiply(q_tilt, q_est)
    assert np.allclose(broad.inclination_error_rad(q_est2, q_true), tilt, atol=1e-6)
    # any norm and sign of the estimate are fine (the firmware's |q| ≈ 0.998)
    assert np.allclose(broad.inclination_error_rad(-0.998 * q_est2, q_true), tilt, atol=1e-6)


def test_the_firmware_quaternion_is_body_to_earth_like_broad():
    """A tilted drone at rest: the Mahony replica's q, scored against the body → earth truth, has ~0 error."""
    thx, thy = 0.4, -0.25
    g = np.array([-math.sin(thy), math.sin(thx) * math.cos(thy), math.cos(thx) * math.cos(thy)]) * 1000.0
    acc = np.tile(g, (600, 1)).astype(np.float32)
    est = StMahony().run(acc, np.zeros_like(acc), np.zeros(600, dtype=np.int64))  # ground mode converges fast
    q_true = quaternion_from_euler(thx, thy, 0.0)
    err = broad.inclination_error_rad(est.q_wxyz[-1].astype(np.float64), q_true)
    assert np.degrees(err) < 0.05
    # its conjugate (earth → body) would be wrong by the full tilt
    wrong = broad.inclination_error_rad(broad.quat_conjugate(est.q_wxyz[-1].astype(np.float64)), q_true)
    assert np.degrees(wrong) > 20


def test_rmse_ignores_nan_and_uses_the_mask():
    e = np.radians([1.0, np.nan, 3.0, 100.0])
    assert broad.rmse_deg(e, [True, True, True, False]) == pytest.approx(math.sqrt(5.0))
    assert math.isnan(broad.rmse_deg(e, [False, True, False, False]))


def test_interpolate_quat_takes_the_short_way_and_marks_outside():
    t = np.array([0.0, 1.0])
    q = np.array([[1.0, 0, 0, 0], [-math.cos(0.05), 0, 0, -math.sin(0.05)]])  # same as +0.1 rad about z, sign flipped
    out = broad.interpolate_quat(t, q, np.array([0.5, 2.0]))
    assert np.allclose(np.abs(out[0]), [math.cos(0.025), 0, 0, math.sin(0.025)], atol=1e-9)
    assert np.isnan(out[1]).all()


# --- loading ------------------------------------------------------------------------------------------------------


def test_load_trial_errors_are_one_sentence(tmp_path):
    with pytest.raises(UserError, match="no such file"):
        broad.load_trial(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip at all")
    with pytest.raises(UserError, match="cannot read"):
        broad.load_trial(bad)
    partial = tmp_path / "partial.npz"
    np.savez(partial, acc=np.zeros((5, 3)), gyr=np.zeros((5, 3)))
    with pytest.raises(UserError, match="without quat, movement, fs"):
        broad.load_trial(partial)
    shapes = tmp_path / "shapes.npz"
    np.savez(
        shapes, acc=np.zeros((5, 3)), gyr=np.zeros((5, 2)), quat=np.zeros((5, 4)), movement=np.ones(5, bool), fs=100.0
    )
    with pytest.raises(UserError, match="malformed"):
        broad.load_trial(shapes)


def _synthetic_trial(path, n=3000, fs=285.714):
    """A short BROAD-format trial: rest, then a slow swing; exact data."""
    t = np.arange(n) / fs
    thx = np.where(t > 3, 0.3 * np.sin(2 * np.pi * 0.5 * (t - 3)), 0.0)
    q = quaternion_from_euler(thx, 0 * t, 0 * t)
    wx = np.where(t > 3, 0.3 * 2 * np.pi * 0.5 * np.cos(2 * np.pi * 0.5 * (t - 3)), 0.0)
    acc = np.stack([0 * t, np.sin(thx), np.cos(thx)], axis=1) * 9.81
    gyr = np.stack([wx, 0 * t, 0 * t], axis=1)
    np.savez(
        path,
        acc=acc.astype(np.float32),
        gyr=gyr.astype(np.float32),
        quat=q.astype(np.float32),
        movement=t > 3,
        fs=np.float64(fs),
    )
    return path


def test_steval_view_of_a_synthetic_trial(tmp_path):
    trial = broad.load_trial(_synthetic_trial(tmp_path / "99_synthetic.npz"))
    v = broad.steval_view(trial)
    assert v.rate_hz == pytest.approx(161.538, abs=1e-3)
    assert v.acc_mg.dtype == np.float32 and v.acc_mg.shape == v.gyro_mdps.shape
    assert v.t_s[0] == pytest.approx(1601 * 52 * 2000 / 84e6, abs=1e-9)  # ticks 1599..1603: the middle one
    at_rest = ~v.movement
    assert np.allclose(v.acc_mg[at_rest][:50], [0, 0, 1000], atol=1.0)
    r = ev.evaluate_view(v, ev.default_specs(v.rate_hz, only=["mekf", "accel"]), trial.name)
    assert set(r.rmse_deg) == {"mekf", "accel"}
    assert r.rmse_deg["mekf"] < 0.5 and r.rmse_deg["accel"] < 1.0
    nv = broad.own_rate_view(trial)
    assert nv.rate_hz == pytest.approx(285.714) and nv.acc_mg.shape == (3000, 3)


def test_default_specs_selection():
    labels = [s.label for s in ev.default_specs(161.5)]
    assert labels[:5] == ["st-mahony-flight", "st-mahony-ground", "accel", "ekf3", "mekf"]
    both = ev.default_specs(161.5, only=["st-mahony"])
    assert [(s.label, s.thr) for s in both] == [("st-mahony-flight", 450), ("st-mahony-ground", 0)]
    own = ev.default_specs(285.7, own_rate=True, only=["st-mahony-flight", "mekf"])
    assert own[0].options == {"dt_s": 1 / 285.7} and own[1].options["latency_s"] == 0.0
    with pytest.raises(UserError, match="unknown estimator"):
        ev.default_specs(161.5, only=["kalman"])


# --- the command ----------------------------------------------------------------------------------------------------


@pytest.mark.slow  # two whole BROAD trials through five estimators: ≈ 2 s of CPU
def test_cli_evaluate_on_shared_broad_trials(shared_dir, tmp_path, monkeypatch, capsys):
    paths = [str(shared_dir / "datasets" / "broad" / f"{name}.npz") for name in BROAD_TRIALS]
    res = _steval_here(monkeypatch, capsys, "evaluate", *paths, "--json")
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    expected = {"st-mahony-flight", "st-mahony-ground", "accel", "ekf3", "mekf"}
    assert expected <= set(report["estimators"])
    assert [t["trial"] for t in report["trials"]] == list(BROAD_TRIALS)
    for t in report["trials"]:
        for k in report["estimators"]:
            v = t["rmse_deg"][k]
            assert v is not None and math.isfinite(v) and 0 < v < 90
        # the averaged-acc MEKF beats accelerometer-only tilt and the firmware's flight-mode filter
        assert t["rmse_deg"]["mekf"] < t["rmse_deg"]["accel"]
        assert t["rmse_deg"]["mekf"] < t["rmse_deg"]["st-mahony-flight"]
    assert set(report["mean_rmse_deg"]) == set(report["estimators"])


def test_cli_evaluate_own_rate_table_and_directory(shared_dir, tmp_path, monkeypatch, capsys):
    d = tmp_path / "trials"
    d.mkdir()
    _synthetic_trial(d / "98_synthetic.npz")
    res = _steval_here(
        monkeypatch, capsys, "evaluate", str(d), "--estimators", "st-mahony-flight,accel,mekf", "--own-rate"
    )
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert "st-mahony-flight" in lines[1] and "mekf" in lines[1]
    assert lines[2].startswith("98_synthetic")
    assert len(lines[2].split()) == 4


def test_cli_evaluate_bad_input_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    missing = _steval_here(monkeypatch, capsys, "evaluate", str(tmp_path / "nope.npz"))
    assert missing.returncode == 2 and missing.stderr.count("\n") == 1 and "no such file" in missing.stderr
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"garbage")
    res = _steval_here(monkeypatch, capsys, "evaluate", str(bad))
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    res = _steval_here(monkeypatch, capsys, "evaluate", str(empty))
    assert res.returncode == 2 and "no .npz" in res.stderr
    res = _steval_here(monkeypatch, capsys, "evaluate", str(bad), "--estimators", "kalman")
    assert res.returncode == 2 and "unknown estimator" in res.stderr


def test_evaluate_capture_with_truth_sidecar(tmp_path, monkeypatch, capsys):
    from steval_link.link.capture import demo_capture_path
    from steval_link.link.load import load_telemetry

    cap = demo_capture_path()
    tel = load_telemetry(cap)
    att = tel.attitude
    local = tmp_path / "demo.stv"
    local.write_bytes(cap.read_bytes())
    # ground truth = the firmware's own estimate: its error is zero, the replica (same thr) is bit-exact too
    q = broad.quat_normalize(np.asarray(att.q_wxyz, dtype=np.float64))
    np.savez(ev.truth_sidecar_path(local), step=np.asarray(att.step), quat=q)
    r = ev.evaluate_capture(local, ev.default_specs(161.5, only=["accel", "mekf"]))
    assert r.rmse_deg["firmware"] == pytest.approx(0.0, abs=1e-3)
    assert math.isfinite(r.rmse_deg["mekf"]) and math.isfinite(r.rmse_deg["accel"])
    res = _steval_here(monkeypatch, capsys, "evaluate", str(local), "--estimators", "accel", "--json")
    assert res.returncode == 0, res.stderr
    rep = json.loads(res.stdout)
    assert rep["trials"][0]["rmse_deg"]["firmware"] == pytest.approx(0.0, abs=1e-3)
    (tmp_path / "other.stv").write_bytes(cap.read_bytes())
    res = _steval_here(monkeypatch, capsys, "evaluate", str(tmp_path / "other.stv"))
    assert res.returncode == 2 and "truth.npz" in res.stderr


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_plot_evaluation(tmp_path):
    pytest.importorskip("matplotlib")
    trial = broad.load_trial(_synthetic_trial(tmp_path / "97_synthetic.npz"))
    r = ev.evaluate_view(broad.steval_view(trial), ev.default_specs(161.5, only=["accel", "mekf"]), trial.name)
    out = ev.plot_evaluation([r], tmp_path / "eval.png")
    assert out.stat().st_size > 10_000
    assert "97_synthetic" in ev.format_table([r])


def test_vqf_adapter_units_frames_and_interface():
    pytest.importorskip("vqf")
    from steval_link.estimators.registry import create

    thx, thy = 0.2, 0.35
    g = np.array([-math.sin(thy), math.sin(thx) * math.cos(thy), math.cos(thx) * math.cos(thy)]) * 1000.0
    acc = np.tile(g, (3000, 1))
    gyro = np.zeros_like(acc)
    est = create("vqf")
    r = est.run(acc, gyro)
    assert np.degrees(broad.inclination_error_rad(r.q_wxyz[-1], quaternion_from_euler(thx, thy, 0.0))) < 0.1
    est.reset()
    steps = np.array([est.step(a, w) for a, w in zip(acc[:30], gyro[:30])])
    assert np.allclose(steps, create("vqf").run(acc[:30], gyro[:30]).q_wxyz)
    # 90 dps about z predicted 10 ms ahead: 0.9° further
    spin = np.tile([0.0, 0.0, 90000.0], (5, 1))
    a = create("vqf").run(acc[:5], spin).q_wxyz[-1]
    b = create("vqf", latency_s=0.01).run(acc[:5], spin).q_wxyz[-1]
    d = broad.quat_multiply(broad.quat_conjugate(a), b)
    assert 2 * np.degrees(np.arctan2(np.linalg.norm(d[1:]), d[0])) == pytest.approx(0.9, rel=1e-3)


def test_cli_sensor_noise_is_seeded(tmp_path, monkeypatch, capsys):
    trial = _synthetic_trial(tmp_path / "96_synthetic.npz")
    args = ["evaluate", str(trial), "-e", "accel", "--json"]
    a = json.loads(_steval_here(monkeypatch, capsys, *args, "--sensor-noise", "--seed", "4").stdout)
    b = json.loads(_steval_here(monkeypatch, capsys, *args, "--sensor-noise", "--seed", "4").stdout)
    c = json.loads(_steval_here(monkeypatch, capsys, *args).stdout)
    assert a["trials"][0]["rmse_deg"] == b["trials"][0]["rmse_deg"]
    assert a["sensor_noise"] and not c["sensor_noise"]
    assert a["trials"][0]["rmse_deg"]["accel"] > c["trials"][0]["rmse_deg"]["accel"]


def test_the_table_rounds_each_figure_once():
    """28.308501° is 28.309 in the table (the JSON keeps 28.3085): no second rounding of a rounded value."""
    res = ev.TrialResult(
        "02_a", 161.5, np.arange(10) / 161.5, np.ones(10, bool), {"ekf3": 28.308501}, {"ekf3": np.zeros(10)}, {}
    )
    row = [ln for ln in ev.format_table([res]).splitlines() if ln.startswith("02_a")][0]
    assert row.split()[-1] == "28.309"
    assert ev.summary([res])["trials"][0]["rmse_deg"]["ekf3"] == 28.3085

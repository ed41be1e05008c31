"""``steval simulate`` (UMaine Lab 5 simulator): the baseline bit for bit through the CLI, options, noise, errors."""

from __future__ import annotations

import csv
import importlib.util
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.emulation.lab5 import run_simulation
from steval_link.estimators.conformance import load_conformance_csv
from steval_link.estimators.st_mahony import MahonySettings, bits_equal, run

BASELINE = Path(__file__).resolve().parents[1] / ".." / "shared" / "conformance" / "st-fcu-170120" / "lab5_baseline.csv"
needs_baseline = pytest.mark.skipif(not BASELINE.is_file(), reason="shared conformance vectors (../shared) not present")


def parse_csv(text: str) -> dict[str, np.ndarray]:
    rows = list(csv.DictReader(io.StringIO(text)))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


@needs_baseline
def test_baseline_csv_output_is_bit_exact_with_the_firmware(monkeypatch, capsys):
    v = load_conformance_csv(BASELINE)
    code, out, err = run_cli(
        monkeypatch, capsys, "simulate", "--gyro", 1000, 2000, 4000, "--acc", 0, 0, 0, "--csv", "-"
    )
    assert code == 0
    cols = parse_csv(out)
    assert len(cols["iteration"]) == len(v) == 100
    for i, name in enumerate(("q0", "q1", "q2", "q3")):
        assert bits_equal(cols[name].astype(np.float32), v.q_wxyz[:, i]).all(), name
    assert bits_equal(cols["eax_rad"].astype(np.float32), v.thx_rad).all()
    assert bits_equal(cols["eay_rad"].astype(np.float32), v.thy_rad).all()
    assert bits_equal(cols["gyro_z_mdps"].astype(np.float32), v.gyro_mdps[:, 2]).all()
    assert "eax = thx  pitch" in err  # the summary goes to stderr when the CSV goes to stdout


@needs_baseline
def test_baseline_defaults_json_and_printed_angles(monkeypatch, capsys):
    v = load_conformance_csv(BASELINE)
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "--json")  # defaults are the Lab 5 baseline
    assert code == 0
    doc = json.loads(out)
    q = np.array([r["q_wxyz"] for r in doc["rows"]], dtype=np.float32)
    assert bits_equal(q, v.q_wxyz).all()
    assert np.float32(doc["final"]["eay_rad"]) == v.thy_rad[-1]
    code, out, _ = run_cli(monkeypatch, capsys, "simulate")
    assert code == 0
    text = {line.split(":")[0].strip(): line for line in out.splitlines()}
    pitch = text["eax = thx  pitch (about x)"]
    assert f"{math.degrees(float(v.thx_rad[-1])):+.6f} deg" in pitch
    assert f"{float(v.thx_rad[-1]):+.9g} rad" in pitch
    assert "eay = thy  roll  (about y)" in text and "eaz = thz  yaw   (about z)" in text


def test_options_reach_the_filter(monkeypatch, capsys, tmp_path):
    out_csv = tmp_path / "run.csv"
    args = [
        "simulate",
        "--acc",
        100,
        300,
        900,
        "--gyro",
        0,
        0,
        0,
        "-n",
        60,
        "--ki",
        1.0,
        "--kp",
        2.0,
        "--throttle",
        450,
        "--dt",
        0.00619,
        "--csv",
        out_csv,
    ]
    code, out, _ = run_cli(monkeypatch, capsys, *args)
    assert code == 0 and "KI 1" in out and "kp 2" in out
    cols = parse_csv(out_csv.read_text())
    acc = np.tile(np.float32([100, 300, 900]), (60, 1))
    q, thx, _, _ = run(
        acc,
        np.zeros((60, 3)),
        np.full(60, 450),
        settings=MahonySettings(ki=1.0, kp_ground=2.0, kp_flight=2.0, dt_s=0.00619),
    )
    assert bits_equal(cols["q2"].astype(np.float32), q[:, 2]).all()
    assert bits_equal(cols["eax_rad"].astype(np.float32), thx).all()


def test_no_correction_integrates_the_gyro_only(monkeypatch, capsys):
    code, out, _ = run_cli(
        monkeypatch,
        capsys,
        "simulate",
        "--gyro",
        10000,
        0,
        0,
        "--acc",
        0,
        1000,
        0,
        "--no-correction",
        "--variant",
        "221117",
        "-n",
        160,
        "--json",
    )
    assert code == 0
    doc = json.loads(out)
    assert abs(doc["final"]["eax_deg"] - 10.0 * 160 * 0.00625) < 0.02  # 10 dps for 1 s, acc ignored
    assert doc["settings"]["correction"] is False


def test_noise_is_seeded_and_has_the_typical_size():
    a = run_simulation(iterations=3000, gyro_noise_mdps=75.0, acc_noise_mg=2.0, seed=42)
    b = run_simulation(iterations=3000, gyro_noise_mdps=75.0, acc_noise_mg=2.0, seed=42)
    c = run_simulation(iterations=3000, gyro_noise_mdps=75.0, acc_noise_mg=2.0, seed=43)
    assert bits_equal(a.q_wxyz, b.q_wxyz).all() and not bits_equal(a.q_wxyz, c.q_wxyz).all()
    assert abs(np.std(a.gyro_mdps[:, 0]) - 75.0) < 5.0 and abs(np.std(a.acc_mg[:, 2]) - 2.0) < 0.15
    unseeded = run_simulation(iterations=5, gyro_noise_mdps=75.0)
    assert unseeded.seed is not None  # drawn and recorded so the run can be repeated
    quiet = run_simulation(iterations=5)
    assert quiet.seed is None and (quiet.gyro_mdps == np.float32([1000, 2000, 4000])).all()


def test_noise_flags(monkeypatch, capsys):
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "--noise", "--seed", 1, "-n", 3000, "--json")
    doc = json.loads(out)
    assert doc["gyro_noise_mdps"] == 75.0 and doc["acc_noise_mg"] == 2.0 and doc["seed"] == 1
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "--gyro-noise", "on", "--acc-noise", "0.5", "--json")
    doc = json.loads(out)
    assert doc["gyro_noise_mdps"] == 75.0 and doc["acc_noise_mg"] == 0.5


def test_other_estimators_by_name(monkeypatch, capsys):
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "-e", "accel", "--acc", 0, 500, 866, "--json")
    assert code == 0
    doc = json.loads(out)
    assert abs(doc["final"]["eax_deg"] - 30.0) < 0.01 and doc["final"]["eaz_rad"] is None  # no yaw from gravity


@pytest.mark.parametrize(
    "args, message",
    [
        (["-e", "nope"], "unknown estimator"),
        (["-n", "-1"], "--iterations"),
        (["-e", "accel", "--ki", "1"], "does not take"),
        (["--gyro-noise", "loud"], "--gyro-noise"),
        (["--acc-noise", "-3"], "--acc-noise"),
        (["--throttle", "40000"], "int16"),
        (["--dt", "0"], "--dt"),
        (["--json", "--csv", "-"], "stdout"),
        (["--csv", "/nonexistent-dir/x.csv"], "cannot write"),
    ],
)
def test_bad_options_are_one_line_user_errors(monkeypatch, capsys, args, message):
    code, out, err = run_cli(monkeypatch, capsys, "simulate", *args)
    assert code == 2 and message in err and err.startswith("steval: error:")
    assert len(err.strip().splitlines()) == 1


def test_rrd_logging_boundary(monkeypatch, capsys, tmp_path):
    rrd = tmp_path / "sim.rrd"
    code, out, err = run_cli(monkeypatch, capsys, "simulate", "-n", 20, "--rrd", rrd)
    try:
        has_logger = importlib.util.find_spec("steval_viewer.simulate_log") is not None
    except ImportError:
        has_logger = False
    if has_logger:
        assert code == 0 and rrd.is_file() and rrd.stat().st_size > 0
    else:
        assert code == 2 and "steval_viewer.simulate_log" in err


def test_run_simulation_result_arrays():
    res = run_simulation(gyro_mdps=(0, 0, 0), acc_mg=(0, 0, 1000), iterations=10, throttle=300)
    assert res.q_wxyz.shape == (10, 4) and res.eax_rad.dtype == np.float32
    assert np.allclose(res.t_s, (np.arange(10) + 1) * 0.00625)
    assert res.final_angles_rad() == (0.0, 0.0, 0.0) and res.valid.all()
    assert run_simulation(iterations=0).iterations == 0
    with pytest.raises(ValueError):
        run_simulation(gyro_mdps=(1, 2))


def _angle_lines(out: str) -> list[str]:
    return [line for line in out.splitlines() if line.strip().startswith(("eax", "eay", "eaz"))]


def test_zero_acc_says_correction_and_ki_are_inactive(monkeypatch, capsys):
    """The Lab 5 baseline has acc = 0: the firmware's error term is 0, so exercises 4 and 5 change nothing there,
    and the output says so (instead of leaving students to wonder why --ki 1 prints the same numbers)."""
    code, base, _ = run_cli(monkeypatch, capsys, "simulate")
    assert code == 0 and "acc is 0: correction and KI inactive" in base
    for option in ("--ki", "1"), ("--no-correction",):
        code, out, _ = run_cli(monkeypatch, capsys, "simulate", *option)
        assert code == 0 and "acc is 0: correction and KI inactive" in out
        assert _angle_lines(out) == _angle_lines(base)


README_EXERCISE = ("--acc", "0", "0", "1000", "--throttle", "500", "-n", "1000")


def _pitch_deg(out: str) -> float:
    line = next(x for x in out.splitlines() if x.strip().startswith("eax"))
    return float(line.split(":")[1].split()[0])


def test_readme_command_shows_exercises_4_and_5():
    readme = (Path(__file__).resolve().parents[1] / "docs" / "tutorials" / "umaine-lab5.md").read_text(encoding="utf-8")
    assert "steval simulate " + " ".join(README_EXERCISE) in readme


def test_exercises_4_and_5_change_the_angles_with_gravity(monkeypatch, capsys):
    code, base, _ = run_cli(monkeypatch, capsys, "simulate", *README_EXERCISE)
    assert code == 0 and "acc is 0" not in base
    _, ki1, _ = run_cli(monkeypatch, capsys, "simulate", *README_EXERCISE, "--ki", "1")
    _, free, _ = run_cli(monkeypatch, capsys, "simulate", *README_EXERCISE, "--no-correction")
    # KI 1 removes the gyro-bias offset kp 0.4 leaves; without correction the gyro integrates freely
    assert abs(_pitch_deg(base)) > 1.0 and abs(_pitch_deg(ki1)) < 0.2
    assert abs(_pitch_deg(free)) > 5.0


@pytest.mark.parametrize("estimator", ["ekf3", "mekf"])
def test_ekfs_with_zero_acc_flag_every_row_instead_of_claiming_level(monkeypatch, capsys, estimator):
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "-e", estimator, "-n", 20)
    assert code == 0
    assert "acc is 0" in out and "flagged invalid" in out and "does not integrate the gyro" in out
    assert all("n/a" in line for line in _angle_lines(out))
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "-e", estimator, "-n", 20, "--json")
    doc = json.loads(out)
    assert not any(row["valid"] for row in doc["rows"])
    # with gravity from the first sample on, every row is valid
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "-e", estimator, "-n", 20, "--acc", 0, 0, 1000, "--json")
    assert all(row["valid"] for row in json.loads(out)["rows"])

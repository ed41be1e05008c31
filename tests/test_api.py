"""The Python API for notebooks (``import steval_link as sl``), and the docs' exercise 9 example run as written."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import steval_link as sl
from steval_link.errors import UserError
from steval_link.estimators.plugins import PluginError

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "recordings" / "demo.stv"
BROAD = ROOT.parent / "shared" / "datasets" / "broad"
TRIAL = BROAD / "02_undisturbed_slow_rotation_B.npz"
needs_broad = pytest.mark.skipif(
    not TRIAL.is_file() and os.environ.get("CI") != "true", reason="BROAD trials (../shared) not present"
)


def readme_python_block() -> str:
    text = (ROOT / "docs" / "tutorials" / "eth-lecture4.md").read_text(encoding="utf-8")
    section = text.split("## Exercise 9", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_the_readme_exercise_9_example_runs_as_written(tmp_path, monkeypatch):
    code = readme_python_block()
    assert len(code.strip().splitlines()) <= 10  # "about eight lines"
    (tmp_path / "recordings").symlink_to(ROOT / "recordings")
    monkeypatch.chdir(tmp_path)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.close("all")
    exec(compile(code, "eth-lecture4.md", "exec"), {})
    png = tmp_path / "roll_pitch.png"
    assert png.stat().st_size > 10_000
    lines = plt.gcf().axes[0].get_lines()
    cap = sl.open_capture(DEMO)
    assert [ln.get_label() for ln in lines] == [
        "roll (thy), firmware",
        "pitch (thx), firmware",
        "roll, accelerometer only",
        "pitch, accelerometer only",
    ]
    x, y = lines[1].get_data()
    assert np.array_equal(x, cap.attitude.t_fw_s) and np.allclose(y, np.degrees(cap.attitude.thx_rad), equal_nan=True)
    plt.close("all")


def test_import_is_cheap_and_lazy():
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, steval_link; print(sorted(m for m in sys.modules if m.startswith(('numpy', 'steval_link.'))))",
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert out.strip() == "[]"
    assert "open_capture" in dir(sl) and sl.__version__


def test_open_capture_gives_arrays_with_units_in_their_names():
    cap = sl.open_capture(DEMO)
    a = cap.attitude
    assert len(cap) == len(a.t_fw_s) == a.acc_mg.shape[0] > 9000
    assert a.acc_mg.shape[1] == 3 and a.q_wxyz.shape[1] == 4 and np.all(np.diff(a.t_fw_s) > 0)
    assert abs(np.median(a.acc_mg[:, 2]) - 1000) < 100  # z up: +1 g at rest, in mg
    assert len(cap.status) > 0 and "demo.stv" in repr(cap)
    with pytest.raises(UserError, match="no-such.stv"):
        sl.open_capture("no-such.stv")


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_to_pandas_has_the_export_columns_or_says_how_to_get_pandas(monkeypatch):
    cap = sl.open_capture(DEMO)
    pd = pytest.importorskip("pandas")
    df = cap.to_pandas()
    assert isinstance(df, pd.DataFrame) and len(df) == len(cap)
    assert {"t_fw_s", "acc_x_mg", "gyro_z_mdps", "thx_pitch_rad", "thy_roll_rad"} <= set(df.columns)
    assert np.array_equal(df["thx_pitch_rad"].to_numpy(), cap.attitude.thx_rad, equal_nan=True)
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(ImportError, match="needs pandas, which is not installed: pip install pandas"):
        cap.to_pandas()


STUDENT = textwrap.dedent("""
    import numpy as np

    class Gravity:
        def __init__(self, gain=0.05):
            self.gain = gain
            self.reset()

        def reset(self):
            self.g = None

        def step(self, acc_mg, gyro_mdps, thr=0):
            a = np.asarray(acc_mg) / np.linalg.norm(acc_mg)
            self.g = a if self.g is None else (1 - self.gain) * self.g + self.gain * a
            g = self.g / np.linalg.norm(self.g)
            thx, thy = np.arctan2(g[1], g[2]), np.arctan2(-g[0], np.hypot(g[1], g[2]))
            return np.array([np.cos(thx / 2) * np.cos(thy / 2), np.sin(thx / 2) * np.cos(thy / 2),
                             np.cos(thx / 2) * np.sin(thy / 2), -np.sin(thx / 2) * np.sin(thy / 2)])
""")


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_run_estimator_takes_a_name_a_reference_or_an_object(tmp_path, monkeypatch):
    (tmp_path / "gravity.py").write_text(STUDENT)
    monkeypatch.syspath_prepend(str(tmp_path))
    from gravity import Gravity

    cap = sl.open_capture(DEMO)
    by_name = sl.run_estimator("accel", cap)
    assert by_name.thx_rad.shape == (len(cap),) and by_name.valid.all()
    obj = Gravity(gain=1.0)
    obj.g = np.array([1.0, 0.0, 0.0])  # a used object: run_estimator runs a fresh copy from reset()
    by_object = sl.run_estimator(obj, cap)
    assert np.allclose(by_object.thx_rad, by_name.thx_rad, atol=1e-9)
    assert obj.g.tolist() == [1.0, 0.0, 0.0]
    by_ref = sl.run_estimator(f"{tmp_path / 'gravity.py'}:Gravity(gain=1.0)", DEMO)
    assert np.array_equal(by_ref.q_wxyz, by_object.q_wxyz)
    slow = sl.run_estimator(Gravity(gain=0.01), cap)
    assert not np.allclose(slow.thx_rad, by_name.thx_rad)


def test_run_estimator_of_a_failing_object_names_its_line(tmp_path, monkeypatch):
    (tmp_path / "gravity.py").write_text(STUDENT)
    monkeypatch.syspath_prepend(str(tmp_path))
    from gravity import Gravity

    with pytest.raises(PluginError, match=r"estimator Gravity failed in gravity.py, line 14, in step: TypeError"):
        sl.run_estimator(Gravity(gain="strong"), DEMO)
    with pytest.raises(TypeError, match="has no step"):
        sl.run_estimator(object(), DEMO)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_broad
def test_evaluate_scores_names_references_and_objects_against_ground_truth(tmp_path, monkeypatch):
    (tmp_path / "gravity.py").write_text(STUDENT)
    monkeypatch.syspath_prepend(str(tmp_path))
    from gravity import Gravity

    scores = sl.evaluate(TRIAL, ["st-mahony-flight", "ekf3", Gravity(), Gravity(gain=0.5)])
    means = scores.mean_rmse_deg
    assert list(means) == ["st-mahony-flight", "ekf3", "Gravity(gain=0.05)", "Gravity(gain=0.5)"]
    assert means["st-mahony-flight"] == pytest.approx(0.914, abs=0.001)  # the docs' accuracy table
    assert means["Gravity(gain=0.05)"] != means["Gravity(gain=0.5)"]
    assert scores.rmse_deg[TRIAL.stem] == means
    assert "inclination RMSE" in scores.table()


@needs_broad
def test_a_bad_argument_names_the_parameter_in_the_api_and_the_flag_in_the_cli(monkeypatch, capsys):
    from support.cli import run_cli

    with pytest.raises(UserError) as exc:
        sl.evaluate(TRIAL, ",")
    assert str(exc.value) == "estimators= selects no estimator" and "--" not in str(exc.value)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", TRIAL, "--estimators", ",")
    assert (code, out, err) == (2, "", "steval: error: --estimators selects no estimator\n")
    with pytest.raises(UserError, match=r"^max_seconds= must be a positive number of seconds, got -1"):
        sl.evaluate(TRIAL, "accel", max_seconds=-1)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", TRIAL, "-e", "accel", "--max-seconds", "-1")
    assert code == 2 and err == "steval: error: --max-seconds must be a positive number of seconds, got -1.0\n"

"""``steval estimator new`` writes a working 3-state EKF; ``steval estimator check`` finds what is wrong with an
estimator and scores it next to ST-Mahony and VQF."""

from __future__ import annotations

import json
import os
import textwrap
from pathlib import Path

import pytest
from support.cli import run_cli

from steval_link.analysis import estimator_check as ec

ROOT = Path(__file__).resolve().parents[1]
BROAD = ROOT.parent / "shared" / "datasets" / "broad"
FAST_ROTATION = BROAD / "07_undisturbed_fast_rotation_B.npz"
needs_broad = pytest.mark.skipif(
    not FAST_ROTATION.is_file() and os.environ.get("CI") != "true", reason="BROAD trials (../shared) not present"
)


def new_starter(tmp_path, monkeypatch, capsys, *extra: str) -> Path:
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(monkeypatch, capsys, "estimator", "new", "my_ekf.py", *extra)
    assert code == 0, err
    return tmp_path / "my_ekf.py"


def test_new_writes_a_starter_and_never_overwrites_without_force(tmp_path, monkeypatch, capsys):
    f = new_starter(tmp_path, monkeypatch, capsys)
    text = f.read_text()
    for marker in ("Step 1: collect a(k), g(k)", "Step 2: prediction", "Step 3: update", "q_gyro", "r_acc", "p0"):
        assert marker in text
    f.write_text(text + "\n# my edits\n")
    code, out, err = run_cli(monkeypatch, capsys, "estimator", "new", "my_ekf.py")
    assert code == 2 and err.strip() == ("steval: error: my_ekf.py already exists (use --force to overwrite)")
    assert f.read_text().endswith("# my edits\n")
    code, out, err = run_cli(monkeypatch, capsys, "estimator", "new", "my_ekf.py", "--force", "--class", "Kalman3")
    assert code == 0 and "class Kalman3" in f.read_text() and "MyEkf" not in f.read_text()
    code, out, err = run_cli(monkeypatch, capsys, "estimator", "new", "notes.txt")
    assert code == 2 and len(err.strip().splitlines()) == 1 and not (tmp_path / "notes.txt").exists()


@pytest.mark.slow  # a pure-Python EKF through every check and every bundled capture: ≈ 5 s of CPU
def test_the_starter_passes_every_check_and_is_scored_on_the_bundled_captures(tmp_path, monkeypatch, capsys):
    new_starter(tmp_path, monkeypatch, capsys)
    code, out, err = run_cli(monkeypatch, capsys, "estimator", "check", "my_ekf.py:MyEkf", "--no-broad", "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["ok"] and report["estimator"] == "MyEkf"
    assert [c["name"] for c in report["checks"]] == [
        "shapes",
        "at rest",
        "pitch sign",
        "roll sign",
        "turn",
        "invalid input",
        "determinism",
        "speed",
    ]
    assert report["steps_per_s"] > ec.LIVE_MIN_STEPS_PER_S
    demo = next(c for c in report["captures"] if c["capture"] == "demo.stv")
    assert set(demo["vs_firmware_deg"]) >= {"MyEkf", "st-mahony", "ekf3"}
    assert demo["vs_firmware_deg"]["st-mahony"] == 0.0  # the replica from power-up is the firmware
    assert 0.1 < demo["vs_firmware_deg"]["MyEkf"] < 10.0
    assert report["broad"] is None


BROKEN = {
    # pitch read with the wrong sign: a units/axes mistake the tilt checks must name
    "pitch sign": ("thx = -math.atan2(ay, az)", "FAIL  pitch sign"),
    # degrees instead of radians
    "at rest": ("thx = math.atan2(ay, az) + 0.05", "FAIL  at rest"),
}

TILT_TEMPLATE = """
import math
import numpy as np


class Tilt:
    def reset(self):
        pass

    def step(self, acc_mg, gyro_mdps, thr=0):
        ax, ay, az = acc_mg
        {line}
        thy = math.atan2(-ax, math.hypot(ay, az))
        hx, hy = thx / 2, thy / 2
        return np.array([math.cos(hx) * math.cos(hy), math.sin(hx) * math.cos(hy), math.cos(hx) * math.sin(hy),
                         -math.sin(hx) * math.sin(hy)])
"""


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@pytest.mark.parametrize("case", sorted(BROKEN))
def test_check_names_what_is_wrong_and_exits_1(case, tmp_path, monkeypatch, capsys):
    line, expected = BROKEN[case]
    (tmp_path / "tilt.py").write_text(TILT_TEMPLATE.format(line=line))
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(monkeypatch, capsys, "estimator", "check", "tilt.py:Tilt", "--no-broad")
    assert code == 1, err
    assert expected in out and "PASS  shapes" in out and "bundled captures" in out


def interface(tmp_path, source: str, cls: str) -> dict:
    (tmp_path / "est.py").write_text(textwrap.dedent(source))
    checks, rate, trace = ec.interface_checks(str(tmp_path / "est.py") + ":" + cls)
    return {c.name: c for c in checks} | {"_trace": trace}


def test_check_finds_state_poisoned_by_invalid_input(tmp_path):
    res = interface(
        tmp_path,
        """
        import numpy as np
        class Poisoned:
            def reset(self): self.g = np.array([0.0, 0.0, 1.0])
            def __init__(self): self.reset()
            def step(self, a, g, thr=0):
                self.g = 0.9 * self.g + 0.1 * np.asarray(a) / np.linalg.norm(a)  # free fall: 0 / 0 forever
                return np.array([1.0, 0.0, 0.0, 0.0]) * np.sign(self.g.sum())
        """,
        "Poisoned",
    )
    assert not res["invalid input"].ok and "NO finite estimate" in res["invalid input"].detail
    assert res["shapes"].ok


def test_check_finds_nondeterminism_and_a_reset_that_forgets(tmp_path):
    res = interface(
        tmp_path,
        """
        import random
        import numpy as np
        class Dice:
            def reset(self): pass
            def step(self, a, g, thr=0): return np.array([1.0, random.random() * 1e-3, 0.0, 0.0])
        """,
        "Dice",
    )
    assert not res["determinism"].ok and "two fresh instances" in res["determinism"].detail
    res = interface(
        tmp_path,
        """
        import numpy as np
        class Sticky:
            def __init__(self): self.n = 0
            def reset(self): pass
            def step(self, a, g, thr=0):
                self.n += 1
                return np.array([1.0, 0.0, 0.0, 0.0]) if self.n < 500 else np.array([0.0, 1.0, 0.0, 0.0])
        """,
        "Sticky",
    )
    assert not res["determinism"].ok and "reset()" in res["determinism"].detail


def test_check_finds_a_non_unit_quaternion_and_a_slow_filter(tmp_path, monkeypatch):
    res = interface(
        tmp_path,
        """
        import numpy as np
        class Long:
            def reset(self): pass
            def step(self, a, g, thr=0): return np.array([2.0, 0.0, 0.0, 0.0])
        """,
        "Long",
    )
    assert not res["shapes"].ok and "not a unit quaternion" in res["shapes"].detail
    monkeypatch.setattr(ec, "LIVE_MIN_STEPS_PER_S", 1e12)
    res = interface(
        tmp_path,
        "import numpy as np\nclass Q:\n    def reset(self): pass\n"
        "    def step(self, a, g, thr=0): return np.array([1.0, 0, 0, 0])\n",
        "Q",
    )
    assert not res["speed"].ok and "steps/s" in res["speed"].detail


def test_check_of_a_raising_estimator_shows_its_traceback_once_and_scores_nothing(tmp_path, monkeypatch, capsys):
    (tmp_path / "boom.py").write_text(
        "class Boom:\n    def reset(self): pass\n    def step(self, a, g, thr=0):\n        return a[3]\n"
    )
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(monkeypatch, capsys, "estimator", "check", "boom.py:Boom", "--no-broad")
    assert code == 1
    assert err.count("Traceback (your code):") == 1 and 'boom.py", line 4, in step' in err
    assert "FAIL  shapes" in out and "boom.py, line 4, in step: IndexError" in out
    assert "bundled captures" not in out and "not scored" in out


def test_check_of_a_missing_file_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(monkeypatch, capsys, "estimator", "check", "nothing.py:X")
    assert code == 2 and err.strip() == "steval: error: estimator file nothing.py not found" and out == ""


@pytest.mark.slow  # two BROAD trials through the pipeline model and five estimators: ≈ 4 s of CPU
@needs_broad
def test_one_gain_changed_moves_the_broad_score(tmp_path, monkeypatch, capsys):
    f = new_starter(tmp_path, monkeypatch, capsys)
    (base,) = ec.broad_scores(f"{f}:MyEkf", [FAST_ROTATION])
    (tuned,) = ec.broad_scores(f"{f}:MyEkf(r_acc=1e-4)", [FAST_ROTATION])
    # the starter beats the firmware's filter on fast rotation; a gain changed moves its score, not the others'
    assert base.rmse_deg["MyEkf"] < base.rmse_deg["st-mahony-flight"]
    assert abs(tuned.rmse_deg["MyEkf(r_acc=0.0001)"] - base.rmse_deg["MyEkf"]) > 0.1  # one label per variant
    assert tuned.rmse_deg["st-mahony-flight"] == base.rmse_deg["st-mahony-flight"]
    assert "vqf" in base.rmse_deg and "ekf3" in base.rmse_deg


@needs_broad
@pytest.mark.slow  # the BROAD pipeline model and the bundled captures: about half a minute
def test_check_with_broad_prints_the_table_next_to_st_mahony_and_vqf(tmp_path, monkeypatch, capsys):
    new_starter(tmp_path, monkeypatch, capsys)
    code, out, err = run_cli(
        monkeypatch, capsys, "estimator", "check", "my_ekf.py:MyEkf", "--broad", str(FAST_ROTATION)
    )
    assert code == 0, err
    head = next(line for line in out.splitlines() if line.startswith("trial"))
    assert head.split()[1:] == ["MyEkf", "st-mahony-flight", "ekf3", "vqf"]
    row = next(line for line in out.splitlines() if line.startswith("07_"))
    values = [float(v) for v in row.split()[1:]]
    assert len(values) == 4 and values[0] < values[1]

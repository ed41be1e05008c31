"""Coverage is part of every score (issue #31): an estimator that gives up half-way is marked, never ranked, and
its mean is not a plain number; labels carry the options; ``-e A -e B`` equals ``-e A,B``; the table as CSV and
Markdown."""

from __future__ import annotations

import json
import textwrap

import numpy as np
import pytest
from support.cli import run_cli

import steval_link as sl
from steval_link.analysis import evaluate as ev
from steval_link.analysis.firmware_eval import cut_trial
from steval_link.analysis.report import coverage_of
from steval_link.emulation import broad
from steval_link.errors import UserError

#: ekf3 that returns NaN from its step ``after`` on (a diverged EKF), as a student's file would hold it
GIVES_UP = textwrap.dedent("""
    import numpy as np
    from steval_link.estimators.ekf3 import Ekf3

    class Ekf:
        def __init__(self, after=9000, rate_hz=161.5):
            self.after = after
            self.inner = Ekf3(rate_hz=rate_hz)
            self.reset()

        def reset(self):
            self.inner.reset()
            self.k = 0

        def step(self, acc_mg, gyro_mdps, thr=0):
            q = self.inner.step(acc_mg, gyro_mdps, thr)
            self.k += 1
            return np.full(4, np.nan) if self.k > self.after else q
""")


@pytest.fixture()
def trial(shared_dir):
    return shared_dir / "datasets" / "broad" / "02_undisturbed_slow_rotation_B.npz"


@pytest.fixture()
def mine(tmp_path):
    p = tmp_path / "mine.py"
    p.write_text(GIVES_UP)
    return p


def test_coverage_of_counts_scored_rows_and_finds_where_it_stopped():
    ok = np.ones(10, bool)
    ok[6:] = False
    scored = np.ones(10, bool)
    scored[:2] = False
    c = coverage_of(ok, scored, np.arange(100, 110), np.linspace(0, 0.9, 10))
    assert (c.scored_rows, c.covered_rows, c.diverged_at_step) == (8, 4, 106)
    assert c.scored_fraction == 0.5 and c.diverged_at_s == pytest.approx(0.6)
    assert c.cell("1.234") == "1.234 (50 %)" and not c.complete
    # a gap in the middle is not a divergence; a non-finite tail with no scored row in it is not one either
    ok2 = np.ones(10, bool)
    ok2[3] = False
    ok2[9] = False
    scored2 = np.ones(10, bool)
    scored2[9] = False
    assert coverage_of(ok2, scored2).diverged_at_step is None
    none = coverage_of(np.zeros(10, bool), np.ones(10, bool))
    assert none.covered_rows == 0 and none.cell("—") == "no score" and "not finite on any" in none.why
    assert coverage_of(np.ones(5, bool), np.zeros(5, bool)).why == "no movement row with ground truth"


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_a_filter_that_gives_up_is_marked_in_table_json_and_plot(trial, mine, tmp_path, monkeypatch, capsys):
    quit_early, to_the_end = f"{mine}:Ekf(after=9000)", f"{mine}:Ekf(after=100000)"
    png, csv_out, md = tmp_path / "e.png", tmp_path / "e.csv", tmp_path / "e.md"
    args = ["evaluate", trial, "--max-seconds", "90", "-e", f"{quit_early},{to_the_end}", "-e", "accel"]
    code, out, err = run_cli(monkeypatch, capsys, *args, "--json", "--plot", png, "--csv", csv_out, "--markdown", md)
    assert code == 0, err
    rep = json.loads(out)
    a, b = "Ekf(after=9000)", "Ekf(after=100000)"
    assert rep["estimators"] == [a, b, "accel"]  # both variants, options in the labels, and the repeated -e
    (t,) = rep["trials"]
    assert 0 < t["scored_fraction"][a] < 1 and t["scored_fraction"][b] == 1.0 and t["scored_fraction"]["accel"] == 1
    assert t["diverged_at_step"][a] == 9000 and t["diverged_at_step"][b] is None
    assert t["diverged_at_s"][a] > 0
    assert rep["incomplete"] == [a]
    assert rep["mean_rmse_deg"][a] is None and rep["mean_rmse_deg"][b] is not None
    assert png.stat().st_size > 10_000
    # the CSV and the Markdown hold the table the text prints, the incomplete cell marked
    rows = csv_out.read_text().splitlines()
    assert rows[0] == f"trial,{a},{b},accel" and "%)" in rows[1].split(",")[1]
    assert "| trial |" in md.read_text() and "diverged at step 9000" in md.read_text()
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 0, err
    row = next(line for line in out.splitlines() if line.startswith("02_"))
    pct = int(round(100 * t["scored_fraction"][a] - 0.5))
    assert f"({pct} %)" in row
    assert f"{a} on {t['trial']}: scored on {pct} % of the" in out and "diverged at step 9000" in out


@pytest.mark.slow
def test_the_api_keeps_both_variants_and_their_coverage(trial, mine):
    scores = sl.evaluate(trial, [f"{mine}:Ekf(after=8000)", f"{mine}:Ekf(after=100000)"])
    (res,) = scores.results
    assert list(res.coverage) == ["Ekf(after=8000)", "Ekf(after=100000)"]
    assert res.coverage["Ekf(after=8000)"].diverged_at_step == 8000
    assert res.coverage["Ekf(after=100000)"].complete
    assert scores.mean_rmse_deg["Ekf(after=8000)"] is None and scores.incomplete == ["Ekf(after=8000)"]
    (fractions,) = scores.scored_fraction.values()
    assert 0 < fractions["Ekf(after=8000)"] < 1 and fractions["Ekf(after=100000)"] == 1.0
    assert list(scores.diverged_at_step.values())[0]["Ekf(after=8000)"] == 8000
    with pytest.raises(UserError, match="chosen twice"):
        sl.evaluate(trial, [f"{mine}:Ekf(after=5)", f"{mine}:Ekf(after=5)"])


def test_two_identical_labels_exit_2(trial, mine, monkeypatch, capsys):
    code, out, err = run_cli(
        monkeypatch, capsys, "evaluate", trial, "-e", f"{mine}:Ekf(after=5)", "-e", f"accel,{mine}:Ekf(after=5)"
    )
    assert code == 2 and "chosen twice" in err and err.count("\n") == 1
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", trial, "-e", "ekf3", "-e", "ekf3")
    assert code == 2 and "estimator ekf3 is chosen twice" in err


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_a_never_finite_estimator_says_why(trial, mine, monkeypatch, capsys):
    code, out, err = run_cli(
        monkeypatch, capsys, "evaluate", trial, "--max-seconds", "60", "-e", f"{mine}:Ekf(after=0)", "-e", "accel"
    )
    assert code == 0, err
    assert "no score" in out and "Ekf(after=0) on 02_undisturbed_slow_rotation_B: no score: its estimate is" in out


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_table_rows_mark_means_of_incomplete_estimators(trial, mine):
    view_specs = ev.default_specs(161.5, only=[f"{mine}:Ekf(after=5000)", "accel"])
    cut = cut_trial(broad.load_trial(trial), 60.0)
    r1 = ev.evaluate_view(broad.steval_view(cut), view_specs, cut.name)
    header, rows = ev.table_rows([r1, r1])
    assert header == ["trial", "Ekf(after=5000)", "accel"]
    mean = next(r for r in rows if r[0] == "mean")
    assert mean[1] == "incomplete" and mean[2].replace(".", "").isdigit()
    pytest.importorskip("matplotlib")
    fig = ev.evaluation_figure([r1])
    bars, detail = fig.axes[0], fig.axes[1]
    labels = bars.get_legend_handles_labels()[1]
    assert labels == ["Ekf(after=5000) (incomplete: not ranked)", "accel"]
    f = r1.coverage["Ekf(after=5000)"].scored_fraction
    assert f"{int(f * 100)} %" in [t.get_text() for t in bars.texts]
    line = next(ln for ln in detail.get_lines() if ln.get_label().startswith("Ekf(after=5000)"))
    y = np.asarray(line.get_ydata(), float)
    assert np.isnan(y[5000:]).all() and np.isfinite(y[4000:5000]).any()  # a gap from the step it gave up, never 0


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_compares_truth_section_gives_each_trace_its_coverage(mine, tmp_path, monkeypatch, capsys):
    """A synthesised capture re-written with truth chunks (the firmware's own attitude as truth): a filter that
    gives up at step 500 is marked in compare's truth section, the firmware covers every scored row."""
    from steval_link.link.capture import CaptureWriter, read_capture
    from steval_link.link.load import load_telemetry
    from steval_link.quat import quaternion_from_euler

    syn = tmp_path / "syn.stv"
    code, _, err = run_cli(monkeypatch, capsys, "synth", "--scenario", "hand-tilts", "--duration", "12", "--out", syn)
    assert code == 0, err
    att = load_telemetry(syn).attitude
    q_true = quaternion_from_euler(np.asarray(att.thx_rad, np.float64), np.asarray(att.thy_rad, np.float64), 0.0)
    out = tmp_path / "with-truth.stv"
    with CaptureWriter(out, port="emulated:synth", baud=115200) as w:
        w.write(read_capture(syn).data, 1.0)
        w.write_truth(att.step, att.t_fw_s, q_true, np.ones(len(att.step), bool), 1.0)
    code, stdout, err = run_cli(monkeypatch, capsys, "compare", out, "-e", f"{mine}:Ekf(after=500)", "--json")
    assert code == 0, err
    truth = json.loads(stdout)["truth"]
    label = "Ekf(after=500)"
    assert truth["scored_fraction"]["firmware"] == 1.0
    assert truth["scored_fraction"][label] == pytest.approx(500 / len(att.step), abs=1e-3)
    assert truth["diverged_at_step"][label] == int(att.step[500]) and truth["diverged_at_step"]["firmware"] is None
    code, stdout, err = run_cli(monkeypatch, capsys, "compare", out, "-e", f"{mine}:Ekf(after=500)")
    assert code == 0, err
    row = next(line for line in stdout.splitlines() if line.strip().startswith(label) and "%)" in line)
    assert f"diverged at step {int(att.step[500])}" in row
    # evaluate of the same capture: the firmware's own estimate and the estimator, each with its coverage
    code, stdout, err = run_cli(monkeypatch, capsys, "evaluate", out, "-e", f"{mine}:Ekf(after=500)", "--json")
    assert code == 0, err
    (t,) = json.loads(stdout)["trials"]
    assert t["scored_fraction"]["firmware"] == 1.0 and t["diverged_at_step"][label] == int(att.step[500])
    assert t["diverged_at_s"][label] == pytest.approx(float(att.t_fw_s[500]), abs=1e-3)

"""Long jobs show a progress bar on a terminal (stderr), and nothing when stderr is not a terminal or with --json."""

from __future__ import annotations

import json

import pytest

from conftest import run_cli, run_cli_tty

BAR = "━"  # rich's bar segments


@pytest.fixture(scope="module")
def long_capture(tmp_path_factory):
    """Ten minutes of emulated flight (≈ 97 000 attitude frames): synth, replay, export, compare take seconds."""
    out = tmp_path_factory.mktemp("progress") / "long.stv"
    code, stdout, term = run_cli_tty("synth", "--scenario", "demo", "--duration", "600", "--out", out)
    assert code == 0, term
    return out, term


def test_synth_shows_a_bar_on_a_terminal(long_capture):
    _, term = long_capture
    assert BAR in term and "synth" in term and "%" in term
    assert "ISR pipeline" in term or "link and TX queue" in term  # the stages show as they pass


def test_replay_to_rrd_shows_a_bar_through_loading_estimators_and_logging(long_capture, tmp_path):
    cap, _ = long_capture
    code, stdout, term = run_cli_tty("replay", cap, "--rrd", tmp_path / "long.rrd")
    assert code == 0, term
    assert BAR in term and "replay" in term
    assert "frames:" in stdout  # the summary itself stays on stdout, untouched


def test_export_and_compare_show_a_bar(long_capture, tmp_path):
    cap, _ = long_capture
    code, stdout, term = run_cli_tty("export", cap, "--csv", tmp_path / "long.csv")
    assert code == 0 and BAR in term and "export" in term, term
    code, stdout, term = run_cli_tty("compare", cap, "--plot", tmp_path / "long.png")
    assert code == 0 and BAR in term and "compare" in term, term


def test_json_and_pipes_get_no_bar(long_capture, monkeypatch, capsys, tmp_path):
    cap, _ = long_capture
    code, stdout, term = run_cli_tty("replay", cap, "--rrd", tmp_path / "a.rrd", "--json")
    assert code == 0 and BAR not in term
    assert json.loads(stdout)["frames"]["attitude"] > 30000
    code, stdout, term = run_cli_tty("compare", cap, "-e", "ekf3,mekf", "--json")
    assert code == 0 and BAR not in term
    rrd = tmp_path / "b.rrd"
    code, out, err = run_cli(monkeypatch, capsys, "replay", cap, "--rrd", rrd)  # stderr: a pipe
    assert code == 0 and BAR not in err
    assert err.splitlines() == [f"steval: Rerun recording written to {rrd} (open it with: rerun {rrd})"]


def test_evaluate_shows_a_bar(shared_dir, tmp_path):
    trials = shared_dir / "datasets" / "broad"
    code, stdout, term = run_cli_tty("evaluate", trials, "-e", "accel,ekf3")
    assert code == 0 and BAR in term and "evaluate" in term, term
    code, stdout, term = run_cli_tty("evaluate", trials, "-e", "accel,ekf3", "--json")
    assert code == 0 and BAR not in term and json.loads(stdout)

"""One AHRS step cost (ETH exercise 6, issue #31): computed once from the status frames, the same figure and words in
``replay``, ``compare`` and their ``--json``; the unit said as it is."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.analysis.link_stats import DWT_CYCLES, EMULATED_INSTRUCTIONS, step_cost
from steval_link.link.capture import demo_capture_path, read_capture
from steval_link.link.load import load_telemetry


def test_replay_and_compare_give_one_step_cost_for_demo(monkeypatch, capsys):
    demo = demo_capture_path()
    code, out, err = run_cli(monkeypatch, capsys, "replay", demo, "--json")
    assert code == 0, err
    from_replay = json.loads(out)["ahrs_step_cost"]
    code, out, err = run_cli(monkeypatch, capsys, "compare", demo, "-e", "accel", "--json")
    assert code == 0, err
    assert json.loads(out)["ahrs_step_cost"] == from_replay
    assert from_replay["unit"] == EMULATED_INSTRUCTIONS and from_replay["mean_us"] is None  # instructions: no time
    assert from_replay["steps"] > 5000 and from_replay["median"] <= from_replay["max"]
    # the text outputs say it in the same words
    _, replay_text, _ = run_cli(monkeypatch, capsys, "replay", demo)
    _, compare_text, _ = run_cli(monkeypatch, capsys, "compare", demo, "-e", "accel")
    (line,) = [ln for ln in replay_text.splitlines() if ln.startswith("AHRS step cost:")]
    assert line in compare_text.splitlines()
    assert f"mean {from_replay['mean']:.1f}, max {from_replay['max']} emulated instructions" in line


def test_the_step_cost_is_the_weighted_status_windows():
    tel = load_telemetry(demo_capture_path())
    s = tel.status
    have = (s.cyc_n > 0) & (s.cyc_mean > 0)
    cost = step_cost(tel)
    w = s.cyc_n[have].astype(float)
    assert cost.mean == np.sum(s.cyc_mean[have] * w) / np.sum(w)
    assert cost.max == s.cyc_max[have].max() and cost.steps == int(w.sum())
    assert s.cyc_mean[have].min() <= cost.median <= s.cyc_mean[have].max()


def test_a_drones_capture_is_dwt_cycles_with_its_time(tmp_path, monkeypatch, capsys):
    raw = tmp_path / "drone.bin"  # the same bytes as a raw dump from a port: no header says emulated
    raw.write_bytes(read_capture(demo_capture_path()).data)
    code, out, err = run_cli(monkeypatch, capsys, "replay", raw, "--json")
    assert code == 0, err
    cost = json.loads(out)["ahrs_step_cost"]
    assert cost["unit"] == DWT_CYCLES and cost["mean_us"] == round(cost["mean"] / 84e6 * 1e6, 2)
    _, text, _ = run_cli(monkeypatch, capsys, "replay", raw)
    assert "DWT cycles over" in text and "µs mean at 84 MHz" in text


@pytest.mark.slow
def test_emulate_summary_says_the_step_cost_replay_says(reference_elf, tmp_path, monkeypatch, capsys):
    out = tmp_path / "emu.stv"
    args = ["emulate", reference_elf, "--scenario", "bench", "--duration", "8", "--out", out, "--no-view"]
    code, stdout, stderr = run_cli(monkeypatch, capsys, *args, "-e", "accel", "-e", "ekf3")
    assert code == 0, stderr
    (cost,) = [ln for ln in stdout.splitlines() if ln.startswith("AHRS step cost:")]
    assert "emulated instructions over" in cost and "µs" not in cost
    assert not any(ln.startswith("instructions per AHRS step") for ln in stdout.splitlines())
    code, text, err = run_cli(monkeypatch, capsys, "replay", out, "-e", "accel,ekf3")
    assert code == 0, err
    assert cost in text.splitlines()
    # each -e estimator summarised, by emulate as by replay of its capture
    mine = [ln for ln in stdout.splitlines() if ln.startswith("estimator ")]
    assert [ln.split(":")[0] for ln in mine] == ["estimator accel", "estimator ekf3"]
    assert all(ln in text.splitlines() for ln in mine) and "RMS difference from the firmware: pitch" in mine[1]


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_a_live_replay_of_an_emulated_capture_keeps_its_unit(tmp_path, monkeypatch, capsys):
    """``steval live replay://demo.stv`` records a new capture: its step cost is still emulated instructions."""
    out = tmp_path / "again.stv"
    url = f"replay://{demo_capture_path()}?speed=50"
    code, text, err = run_cli(monkeypatch, capsys, "live", "-p", url, "--no-view", "--out", out, "-e", "none")
    assert code == 0, err
    code, again, err = run_cli(monkeypatch, capsys, "replay", out, "--json")
    assert code == 0, err
    code, first, err = run_cli(monkeypatch, capsys, "replay", demo_capture_path(), "--json")
    assert json.loads(again)["ahrs_step_cost"] == json.loads(first)["ahrs_step_cost"]
    assert json.loads(again)["ahrs_step_cost"]["unit"] == EMULATED_INSTRUCTIONS

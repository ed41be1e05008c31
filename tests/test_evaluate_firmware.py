"""``steval evaluate --firmware``: a firmware's own attitude scored against ground truth on the emulated board; the
truth chunks T of an emulated capture and ``steval compare``'s truth section."""

from __future__ import annotations

import json
import shutil
import struct
import warnings
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.cli import run_cli, run_cli_tty

from steval_link.analysis.firmware_eval import cut_trial, firmware_labels
from steval_link.constants import TICK_PERIOD_S as TICK_S
from steval_link.emulation import broad
from steval_link.emulation.broad import BroadTrial, StepTruth, score_euler, truth_at_trial_time
from steval_link.errors import UserError
from steval_link.link.capture import (
    CHUNK_TRUTH,
    TRUTH_ROWS_PER_CHUNK,
    CaptureTruncatedWarning,
    CaptureWriter,
    capture_truth,
    read_capture,
)
from steval_link.quat import quaternion_from_euler

try:
    from support import firmware as S
except ImportError:  # pragma: no cover - the support package always exists in this repo
    S = None

TRIAL = "07_undisturbed_fast_rotation_B.npz"
#: seconds of the trial the end-to-end tests use: its movement starts at 26.5 s
CUT_S = 32.0


def _trial(n: int = 2000, fs: float = 100.0) -> BroadTrial:
    t = np.arange(n) / fs
    q = quaternion_from_euler(0.3 * np.sin(t), 0.2 * np.cos(t), 0.1 * t)
    q[50:60] = np.nan  # occluded markers
    mov = t > 5.0
    return BroadTrial("synthetic", fs, np.zeros((n, 3)), np.zeros((n, 3)), q, mov)


# --- truth chunk T ------------------------------------------------------------------------------------------------


def test_truth_chunks_round_trip_next_to_the_serial_bytes(tmp_path):
    rng = np.random.default_rng(1)
    m = TRUTH_ROWS_PER_CHUNK + 17  # two chunks
    step = np.arange(m)
    t_s = 3.0 + step / 161.5
    q = rng.normal(size=(m, 4))
    q[5] = np.nan
    mov = rng.random(m) > 0.5
    path = tmp_path / "c.stv"
    with CaptureWriter(path, port="emulated:x.elf", baud=115200) as w:
        w.write(b"\xaa\x55serial", 0.5)
        w.write_truth(step[:10], t_s[:10], q[:10], mov[:10], 0.6)
        w.write(b"more", 0.7)
        w.write_truth(step[10:], t_s[10:], q[10:], mov[10:], 0.8)
    cap = read_capture(path)
    assert cap.data == b"\xaa\x55serialmore" and not cap.truncated
    assert len(cap.chunks[CHUNK_TRUTH]) == 3
    tr = capture_truth(cap.chunks)
    assert np.array_equal(tr.step, step) and np.array_equal(tr.t_s, t_s) and np.array_equal(tr.movement, mov)
    assert np.array_equal(tr.q_wxyz, q, equal_nan=True)


def test_capture_without_truth_has_none(tmp_path):
    path = tmp_path / "c.stv"
    with CaptureWriter(path, port="/dev/ttyUSB0", baud=115200) as w:
        w.write(b"abc", 0.1)
    assert capture_truth(read_capture(path).chunks) is None


def test_unknown_chunk_type_is_kept_not_damage(tmp_path):
    """A newer writer's chunk type (intact CRC) is no damage: no warning, the bytes around it intact."""
    path = tmp_path / "c.stv"
    with CaptureWriter(path, port="/dev/ttyUSB0", baud=115200) as w:
        w.write(b"first", 0.1)
    head = struct.pack("<BId", ord("Z"), 3, 0.2) + b"new"
    with open(path, "ab") as f:
        f.write(head + struct.pack("<I", zlib.crc32(head)))
        d = struct.pack("<BId", ord("D"), 4, 0.3) + b"last"
        f.write(d + struct.pack("<I", zlib.crc32(d)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", CaptureTruncatedWarning)
        cap = read_capture(path)
    assert cap.data == b"firstlast" and not cap.truncated and not cap.events
    assert cap.chunks[ord("Z")] == [(0.2, b"new")]


# --- alignment ------------------------------------------------------------------------------------------------------


def test_truth_at_trial_time_interpolates_inside_and_is_nan_outside():
    tr = _trial()
    t = np.array([-0.01, 0.0, 0.5, 0.555, 10.004, tr.t_s[-1], tr.t_s[-1] + 0.01])
    q, mov = truth_at_trial_time(tr, t)
    assert np.isnan(q[[0, 2, 3, 6]]).all()  # before, occluded (samples 50-59), after
    assert np.allclose(q[1], tr.quat_wxyz[0]) and np.allclose(q[5], tr.quat_wxyz[-1])
    mid = truth_at_trial_time(tr, [10.005])[0][0]
    assert broad.inclination_error_rad(mid, tr.quat_wxyz[1000])[()] < 0.01
    assert mov.tolist() == [False, False, False, False, True, True, False]


class _FakeEmu:
    """What StepTruth uses of an Emulation: the trial, the step observers and the motion time base."""

    def __init__(self, trial, first_tick_s: float, k0: int) -> None:
        self.motion = SimpleNamespace(trial=trial, first_tick_s=first_tick_s)
        self.step_start_observers = []
        self.k0 = k0
        self.k = 0

    def tick_index(self, mark=None) -> int:
        return self.k

    def trial_time_s(self, k):
        return np.asarray(k) * TICK_S - self.motion.first_tick_s

    def tick_time_s(self, k):
        return self.motion.first_tick_s + (np.asarray(k) - self.k0) * TICK_S


def test_step_truth_takes_the_middle_tick_of_each_window():
    tr = _trial()
    k0 = 830
    first = k0 * TICK_S - 0.0004  # the first TIM9 update 0.4 ms before its tick's nominal time
    emu = _FakeEmu(tr, first, k0)
    st = StepTruth(emu)
    last = k0 + 1602 + 5 * np.arange(400)  # the firmware's AHRS steps: every 5th tick after calibration
    for k in last:
        emu.k = int(k)
        for ob in emu.step_start_observers:
            ob(None)
    rows = st.take()
    assert rows.step.tolist() == list(range(400))
    t_mid = (last - 2) * TICK_S - first  # trial time of the middle tick
    assert np.allclose(rows.t_trial_s, t_mid)
    assert rows.t_trial_s[0] == pytest.approx(1600 * TICK_S + 0.0004)  # ≈ 1.98 s: after the 2 s calibration
    assert np.allclose(rows.t_s, first + (last - 2 - k0) * TICK_S)  # emulated time of that tick
    q, mov = truth_at_trial_time(tr, t_mid)
    assert np.array_equal(rows.q_wxyz, q, equal_nan=True) and np.array_equal(rows.movement, mov)
    assert len(st.take()) == 0  # taken once


def test_score_euler_is_the_inclination_rmse_of_thx_thy():
    tr = _trial()
    thx, thy = 0.3 * np.sin(tr.t_s), 0.2 * np.cos(tr.t_s)
    err, rmse = score_euler(thx, thy, tr.quat_wxyz, tr.movement)
    assert np.nanmax(err) < 1e-6 and rmse < 1e-4  # yaw does not count (acos near 1: ~1e-8 rad)
    err, rmse = score_euler(thx + np.radians(2.0), thy, tr.quat_wxyz, tr.movement)
    assert rmse == pytest.approx(2.0, abs=0.05)  # about the body x axis: ≈ 2° of inclination (cos thy)


def test_labels_tell_same_named_files_apart(tmp_path):
    a, b, c = tmp_path / "stock" / "fw.elf", tmp_path / "lab" / "fw.elf", tmp_path / "lab" / "other.elf"
    assert firmware_labels([a, b, c]) == ["fw:stock/fw.elf", "fw:lab/fw.elf", "fw:other.elf"]
    with pytest.raises(UserError, match="twice"):
        firmware_labels([a, tmp_path / "stock" / ".." / "stock" / "fw.elf"])


def test_cut_trial_keeps_the_first_seconds():
    tr = _trial()
    cut = cut_trial(tr, 3.0)
    assert cut.t_s[-1] == pytest.approx(3.0) and cut_trial(tr, 100.0) is tr and cut_trial(tr, None) is tr


def test_bad_firmware_is_one_line(monkeypatch, capsys, tmp_path, shared_dir):
    trial = shared_dir / "datasets" / "broad" / TRIAL
    bad = tmp_path / "fw.elf"
    bad.write_bytes(b"not an elf at all")
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--firmware", bad, trial)
    assert code == 2 and out == "" and err.count("\n") == 1 and "not an ELF" in err
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--firmware", tmp_path / "none.elf", trial)
    assert code == 2 and err.count("\n") == 1
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", "--max-seconds", "-1", trial)
    assert code == 2 and "--max-seconds" in err


# --- end to end with the reference firmware (slow; the toolchain builds it) -----------------------------------------


def _reference_builds(tmp_path: Path) -> tuple[Path, Path]:
    """The reference firmware twice, under one file name in two folders: default, and KI = 1 without correction."""
    if S is None or not hasattr(S, "build_reference"):
        pytest.skip("tests/support/firmware.py has no build_reference (the reference firmware) yet")
    why = S.missing()
    if why:
        pytest.skip(why)
    out = []
    for name, options in (("stock", ()), ("lab", ("AHRS_KI=1.0f", "NO_CORRECTION=1"))):
        elf = Path(S.build_reference(tmp_path / f"build-{name}", *options))
        dest = tmp_path / name / "firmware.elf"
        dest.parent.mkdir()
        shutil.copy(elf, dest)
        out.append(dest)
    return out[0], out[1]


@pytest.mark.slow
def test_evaluate_two_firmwares_with_the_same_name(monkeypatch, capsys, tmp_path, shared_dir):
    stock, lab = _reference_builds(tmp_path)
    trial = shared_dir / "datasets" / "broad" / TRIAL
    code, out, err = run_cli(
        monkeypatch,
        capsys,
        "evaluate",
        "-e",
        "st-mahony-ground",
        "--firmware",
        stock,
        "--firmware",
        lab,
        "--max-seconds",
        CUT_S,
        trial,
        "--json",
    )
    assert code == 0, err
    rep = json.loads(out)
    fws = {f["firmware"]: f for f in rep["firmware"]}
    assert set(fws) == {"fw:stock/firmware.elf", "fw:lab/firmware.elf"}
    assert rep["estimators"] == ["st-mahony-ground", "fw:stock/firmware.elf", "fw:lab/firmware.elf"]
    s, lab_ = fws["fw:stock/firmware.elf"], fws["fw:lab/firmware.elf"]
    for f in (s, lab_):
        assert f["rmse_deg"] is not None and f["rmse_deg"] > 0 and f["movement_steps"] > 500
        assert f["instructions_per_step"]["median"] > 500
        assert rep["trials"][0]["rmse_deg"][f["firmware"]] == f["rmse_deg"]
    assert abs(s["rmse_deg"] - lab_["rmse_deg"]) > 1.0  # KI 1 without correction drifts off
    assert lab_["replica_settings"]["ki"] == pytest.approx(1.0) and lab_["replica_settings"]["correction"] is False
    # the default build is ST's filter: the bit-exact replica on its own inputs scores the same
    assert s["replica_steps"] > 0 and s["replica_bit_exact_steps"] == s["replica_steps"]
    assert s["replica_rmse_deg"] == s["rmse_deg"]
    # and near the Python replica on the modelled pipeline (same trial, same alignment; inputs modelled apart)
    assert s["rmse_deg"] == pytest.approx(rep["trials"][0]["rmse_deg"]["st-mahony-ground"], rel=0.15)

    # the plain view on a terminal (no movement in 3 s yet: the lines are what counts here), with its progress bar
    code, out, term = run_cli_tty(
        "evaluate", "-e", "accel", "--firmware", stock, "--firmware", lab, "--max-seconds", "3", trial
    )
    assert code == 0, term
    assert "evaluate" in term and "%" in term and "(emulated)" in term
    lines = [ln for ln in out.splitlines() if ln.startswith(TRIAL[:-4]) and "fw:" in ln and "instr/step" in ln]
    assert len(lines) == 2 and "fw:stock/firmware.elf" in lines[0] and "fw:lab/firmware.elf" in lines[1]


@pytest.mark.slow
def test_emulated_capture_keeps_its_truth_for_compare(monkeypatch, capsys, tmp_path, shared_dir):
    stock, _ = _reference_builds(tmp_path)
    trial = shared_dir / "datasets" / "broad" / TRIAL
    cap = tmp_path / "run.stv"
    code, out, err = run_cli(
        monkeypatch,
        capsys,
        "emulate",
        stock,
        "--broad",
        trial,
        "--duration",
        CUT_S,
        "--out",
        cap,
        "--no-view",
        "-e",
        "none",
        "--no-prompt",
    )
    assert code == 0, err
    tr = capture_truth(read_capture(cap).chunks)
    assert tr is not None and len(tr) > 4000 and tr.movement.any()
    assert np.all(np.diff(tr.step) == 1) and tr.step[0] == 0
    assert 2.9 < tr.t_s[0] < 3.1  # the first step's middle tick: ≈ 3 s after power-up (1 s delay + 2 s calibration)
    code, out, err = run_cli(monkeypatch, capsys, "compare", cap, "-e", "ekf3", "--json")
    assert code == 0, err
    rep = json.loads(out)
    truth = rep["truth"]
    assert truth["movement_steps"] > 500
    r = truth["rmse_deg"]
    assert r["firmware"] > 0 and r["ekf3"] > 0
    assert r["st-mahony-replica"] == r["firmware"]  # the bit-exact replica, scored the same way
    # evaluate of the capture reads the same truth (no sidecar needed)
    code, out, err = run_cli(monkeypatch, capsys, "evaluate", cap, "-e", "ekf3", "--json")
    assert code == 0, err
    ev = json.loads(out)["trials"][0]["rmse_deg"]
    assert ev["ekf3"] > 0 and ev["firmware"] == pytest.approx(r["firmware"], abs=0.05)  # q vs thx/thy: ~0.01°


# --- compare's truth section and the evaluate table, without an ELF -------------------------------------------------


def test_compare_scores_the_truth_a_capture_keeps(monkeypatch, capsys, tmp_path):
    """A synthesised capture (Python drone, bit-exact replica) re-written with truth chunks: the truth is the firmware's
    own attitude turned 1.5° about x on the movement steps, so the firmware and the replica score exactly that."""
    syn = tmp_path / "syn.stv"
    code, _, err = run_cli(monkeypatch, capsys, "synth", "--scenario", "hand-tilts", "--duration", "12", "--out", syn)
    assert code == 0, err
    cap = read_capture(syn)
    from steval_link.link.load import load_telemetry

    att = load_telemetry(syn).attitude
    mov = (np.arange(len(att.step)) % 3) != 0
    tilt = np.where(mov, np.radians(1.5), 0.0)
    q_true = quaternion_from_euler(
        np.asarray(att.thx_rad, np.float64) + tilt, np.asarray(att.thy_rad, np.float64), 0.7
    )  # a heading offset does not count
    out = tmp_path / "with-truth.stv"
    with CaptureWriter(out, port="emulated:synth", baud=115200) as w:
        w.write(cap.data, 1.0)
        w.write_truth(att.step, att.t_fw_s, q_true, mov, 1.0)
    code, stdout, err = run_cli(monkeypatch, capsys, "compare", out, "-e", "accel", "--json")
    assert code == 0, err
    truth = json.loads(stdout)["truth"]
    assert truth["steps_matched"] == len(att.step) and truth["movement_steps"] == int(mov.sum())
    r = truth["rmse_deg"]
    assert r["firmware"] == pytest.approx(1.5, abs=0.05) and r["st-mahony-replica"] == r["firmware"]
    assert r["accel"] > 0
    code, stdout, err = run_cli(monkeypatch, capsys, "compare", out, "-e", "accel")
    assert code == 0 and "against the ground truth the capture keeps" in stdout
    # no truth chunk, no section
    code, stdout, err = run_cli(monkeypatch, capsys, "compare", syn, "-e", "accel", "--json")
    assert code == 0 and "truth" not in json.loads(stdout)


def _fake_firmware(label: str, trial: str, rmse_offset_deg: float):
    from steval_link.analysis.firmware_eval import FirmwareResult
    from steval_link.emulation.broad import TruthRows

    m = 300
    t = 2.0 + np.arange(m) / 161.5
    q_true = quaternion_from_euler(0.2 * np.sin(t), 0.0, 0.0)
    mov = t > 2.5
    thx, thy = 0.2 * np.sin(t) + np.radians(rmse_offset_deg), np.zeros(m)  # level in roll: the error is the offset
    err, rmse = score_euler(thx, thy, q_true, mov)
    truth = TruthRows(np.arange(m), t + 1.0, t, q_true, mov)
    return FirmwareResult(
        label,
        f"/x/{label}",
        trial,
        "frames",
        truth,
        thx.astype(np.float32),
        thy.astype(np.float32),
        err,
        rmse,
        np.full(m, 4400),
        replica_rmse_deg=rmse,
        replica_bit_exact=m,
        replica_steps=m,
    )


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_table_has_a_column_and_one_line_per_firmware_per_trial(tmp_path):
    from steval_link.analysis import evaluate as ev

    results = []
    for name in ("02_a", "07_b"):
        res = ev.TrialResult(
            name, 161.5, np.arange(10) / 161.5, np.ones(10, bool), {"ekf3": 1.0}, {"ekf3": np.zeros(10)}, {"ekf3": 1e5}
        )
        ev.add_firmware(res, _fake_firmware("fw:stock/a.elf", name, 2.0))
        ev.add_firmware(res, _fake_firmware("fw:lab/a.elf", name, 5.0))
        results.append(res)
    text = ev.format_table(results)
    assert "fw:stock/a.elf" in text.splitlines()[1] and "fw:lab/a.elf" in text.splitlines()[1]
    lines = [ln for ln in text.splitlines() if "instr/step" in ln]
    assert len(lines) == 4 and lines[0].startswith("02_a") and "fw:stock/a.elf  2.000" in lines[0]
    assert "4400 instr/step" in lines[1] and "bit-exact 300/300" in lines[1]
    assert "s wall" in lines[0] and "wall_s" in ev.summary(results)["firmware"][0]  # each firmware's wall time
    s = ev.summary(results)
    assert [f["firmware"] for f in s["firmware"]] == ["fw:stock/a.elf", "fw:lab/a.elf"] * 2
    assert s["trials"][1]["rmse_deg"]["fw:lab/a.elf"] == pytest.approx(5.0, abs=1e-3)
    assert s["mean_rmse_deg"]["fw:stock/a.elf"] == pytest.approx(2.0, abs=1e-3)
    json.dumps(s, allow_nan=False)
    pytest.importorskip("matplotlib")
    png = ev.plot_evaluation(results, tmp_path / "e.png")
    assert png.stat().st_size > 10_000

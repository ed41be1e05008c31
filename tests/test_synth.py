"""``steval synth``: emulated captures decode cleanly, follow the firmware's timing and link rules, and carry status
snapshots that seed the filter replica to bit-exactness; deterministic; Python and C encoders give the same bytes."""

from __future__ import annotations

import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest

from steval_link import constants as C
from steval_link.cli import main
from steval_link.emulation import sensor_model as sm
from steval_link.emulation.fw_link import STATUS_EVERY_STEPS, boot_lines
from steval_link.emulation.scenarios import SCENARIOS
from steval_link.emulation.synth import SynthOptions, synthesize, write_output
from steval_link.errors import UserError
from steval_link.estimators.firmware_replay import replay_firmware
from steval_link.estimators.st_mahony import MahonySettings, MahonyState, bits_equal, quaternion_to_euler
from steval_link.estimators.st_mahony import run as mahony_run
from steval_link.link import protocol as P
from steval_link.link.capture import read_capture
from steval_link.link.decoder import decode_bytes
from steval_link.link.load import load_telemetry

ROOT = Path(__file__).resolve().parents[1]


def decode(res):
    return decode_bytes(res.data, (res.chunk_offsets, res.chunk_times_s), baud=res.header["baud"])


@pytest.fixture(scope="module")
def runs():
    """A few emulations shared by the tests (each well under a second)."""
    return {
        "hover": synthesize(SynthOptions("hover", duration_s=20, seed=7)),
        "join": synthesize(SynthOptions("hover", duration_s=10, join_at_s=12.37, drop_rate=0.02, seed=8)),
        "text": synthesize(SynthOptions("hover", duration_s=20, seed=7, text_mode=True)),
    }


# ---- determinism ------------------------------------------------------------------------------------------------


def test_same_seed_same_bytes_different_seed_different_bytes(tmp_path):
    opts = SynthOptions("hand-tilts", duration_s=9, seed=3, join_at_s=1.5, drop_rate=0.05)
    a, b = synthesize(opts), synthesize(opts)
    assert a.data == b.data
    assert np.array_equal(a.chunk_offsets, b.chunk_offsets) and np.array_equal(a.chunk_times_s, b.chunk_times_s)
    write_output(a, tmp_path / "a.stv")
    write_output(b, tmp_path / "b.stv")
    assert (tmp_path / "a.stv").read_bytes() == (tmp_path / "b.stv").read_bytes()
    c = synthesize(SynthOptions("hand-tilts", duration_s=9, seed=4, join_at_s=1.5, drop_rate=0.05))
    assert c.data != a.data
    hdr = read_capture(tmp_path / "a.stv").header
    assert hdr["start_time_utc"].startswith("2026-01-01T00:00:01.5")  # fixed epoch + join, never the wall clock
    assert hdr["extra"]["emulated"] is True
    assert hdr["extra"]["command"] == opts.command()


# ---- every scenario ---------------------------------------------------------------------------------------------


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_scenario_decodes_cleanly_at_the_firmware_rate(name):
    dur = SCENARIOS[name].min_duration_s + 2.0  # the first step comes ≈ 2.985 s after power-up
    res = synthesize(SynthOptions(name, duration_s=dur, seed=1))
    tel = decode(res)
    st = tel.stats
    assert st.crc_failures == 0 and st.seq_gaps == 0 and st.unknown_frames == 0
    a = tel.attitude
    # the AHRS starts after ST's 1 s HAL_Delay and the 2 s power-up calibration (as the real firmware under
    # emulation: 2.985 s); step counter from 0; one frame per step at 161.5 Hz
    assert a.step[0] == 0 and np.array_equal(a.step, np.arange(len(a)))
    assert len(a) == res.counts["attitude"] and 0 <= len(res.attitude) - len(a) <= 2  # the last may be cut off
    assert 2.97 < a.t_fw_s[0] < 3.0
    dt = np.diff(a.t_fw_s)
    assert abs(np.median(dt) - 1 / C.AHRS_RATE_HZ) < 2e-6
    assert dt.min() > 0.0045 and dt.max() < 0.008  # main-loop latency jitter only
    assert abs((len(a) - 1) / (a.t_fw_s[-1] - a.t_fw_s[0]) - C.AHRS_RATE_HZ) < 0.05
    assert len(a) == pytest.approx((dur - (a.t_fw_s[0])) * C.AHRS_RATE_HZ, abs=3)
    # status after every 162nd step (~1 Hz), right after that step's attitude frame
    s = tel.status
    assert np.array_equal(s.step, np.arange(STATUS_EVERY_STEPS - 1, a.step[-1] + 1, STATUS_EVERY_STEPS)[: len(s)])
    assert len(s) >= (len(a) // STATUS_EVERY_STEPS) - 1
    assert np.allclose(np.diff(s.t_fw_s), STATUS_EVERY_STEPS / C.AHRS_RATE_HZ, atol=1e-3)
    assert np.all(s.cyc_n == STATUS_EVERY_STEPS) and np.all(s.cpu_hz == 84_000_000) and np.all(s.baud == 115200)
    assert np.all((s.cyc_min > 2000) & (s.cyc_min <= s.cyc_mean) & (s.cyc_mean <= s.cyc_max) & (s.cyc_max < 10000))
    for j, step in enumerate(s.step):
        row = int(np.searchsorted(a.step, step))
        assert s.t_us[j] == a.t_us[row]
        assert bits_equal(s.q_wxyz[j], a.q_wxyz[row]).all()  # snapshot after the step = the step's ahrs.q
    # the boot banner as text frames, before the first attitude frame
    banner = [line for _, line in boot_lines(np.random.default_rng(0))]
    assert len(tel.text) == len(banner) == res.counts["text"] and tel.text[-1][0] < a.t_host_s[0]
    for (_, got), want in zip(tel.text, banner):
        assert got == want or (got.startswith("BoardMAC = c0:8c:") and want.startswith("BoardMAC = "))
    assert tel.text[0][1].startswith("STEVAL-FCU001V1 FW rev.1.0")
    # the firmware replica from power-up is bit-exact on every step
    rep = replay_firmware(tel)
    assert rep.seeds[0].source == "power-up" and rep.n_seeded == len(a) and rep.all_exact


def test_status_snapshots_seed_the_port_bit_exact_after_each(runs):
    tel = decode(runs["hover"])
    a, s = tel.attitude, tel.status
    settings = MahonySettings.of_status(s, 0)
    assert len(s) >= 15
    for j in range(len(s)):
        r0 = int(s.step[j]) + 1
        r1 = min(r0 + 2 * STATUS_EVERY_STEPS, len(a))
        state = MahonyState(q_wxyz=s.q_wxyz[j], int_xyz=s.int_xyz[j])
        q, thx, thy, _ = mahony_run(a.acc_mg[r0:r1], a.gyro_mdps[r0:r1], a.thr[r0:r1], settings=settings, state=state)
        assert bits_equal(q, a.q_wxyz[r0:r1]).all(), f"status {j}"
        assert bits_equal(thx, a.thx_rad[r0:r1]).all() and bits_equal(thy, a.thy_rad[r0:r1]).all()
    assert np.any(s.int_xyz != 0)  # the integral terms are live (KI 0.1)


def test_hover_throttle_kp_switch_thz_and_vibration(runs):
    res = runs["hover"]
    a = decode(res).attitude
    thr = a.thr.astype(int)
    assert thr.min() == 0 and thr[0] == 0
    flying = thr >= C.MIN_THR
    assert flying.any() and not flying[:200].any() and not flying[-100:].any()
    core = thr[np.flatnonzero(flying)[0] + 600 : np.flatnonzero(flying)[-1] - 600]
    assert 440 <= np.percentile(core, 5) and np.percentile(core, 95) <= 560
    # thz: 0 while throttle < MIN_THR (ISR reset), integrating in flight
    assert np.all(a.thz_rad[~flying] == 0)
    assert np.abs(a.thz_rad[flying]).max() > 0.02
    # motor vibration: the acc spread in flight is far above the bench noise before take-off
    ground = slice(0, 300)
    air = np.flatnonzero(flying)[800:1600]
    assert a.acc_mg[air, 0].std() > 3 * a.acc_mg[ground, 0].std()


def test_motion_truth_matches_the_firmware_attitude_on_hand_tilts():
    res = synthesize(SynthOptions("hand-tilts", duration_s=30, seed=2))
    a = decode(res).attitude
    prof = res.profile
    # true pitch/roll at each step's tick, relative to the calibration attitude (the firmware's level)
    tick = (np.searchsorted(prof.t_s, res.step_t_s) - 1)[a.step]
    thx_true, thy_true = (np.asarray(v, np.float64) for v in quaternion_to_euler(prof.q_wxyz[tick].astype(np.float32)))
    cal = slice(sm.CALIBRATION_SKIP_TICKS, sm.CALIBRATION_SKIP_TICKS + sm.CALIBRATION_TICKS)
    x0, y0 = (np.mean(np.asarray(v, np.float64)) for v in quaternion_to_euler(prof.q_wxyz[cal].astype(np.float32)))
    ex = np.degrees(a.thx_rad - (thx_true - x0))
    ey = np.degrees(a.thy_rad - (thy_true - y0))
    assert np.degrees(np.abs(thx_true).max()) > 25 and np.degrees(np.abs(thy_true).max()) > 25
    assert np.sqrt(np.mean(ex**2)) < 3.0 and np.sqrt(np.mean(ey**2)) < 3.0


def test_freefall_reads_zero_g_then_saturates_on_the_catch():
    res = synthesize(SynthOptions("freefall", duration_s=9, seed=1))
    a = decode(res).attitude
    norm = np.linalg.norm(a.acc_mg.astype(np.float64), axis=1)
    falling = norm < 100
    assert 60 <= falling.sum() <= 85  # ≈ 0.5 s at 161.5 Hz
    raw_z = res.profile.acc_mg[:, 2]
    assert raw_z.max() > 4000  # the catch exceeds the ±4 g range: the sensor saturates
    assert a.acc_mg[:, 2].max() > 3500


# ---- mid-flight join, drops -------------------------------------------------------------------------------------


def test_join_mid_frame_seeds_from_the_first_status(runs):
    res = runs["join"]
    assert res.data[:2] != P.SYNC  # the capture starts inside a frame
    tel = decode(res)
    a = tel.attitude
    assert tel.stats.crc_failures == 0 and 0 < a.offset[0] < P.STATUS_FRAME_SIZE
    assert a.step[0] > 12 * C.AHRS_RATE_HZ - 3 * C.AHRS_RATE_HZ  # mid-flight (steps start ≈ 2.985 s after power-up)
    assert a.t_host_s[0] < 0.02 and np.all(np.diff(a.t_host_s) >= 0)
    rep = replay_firmware(tel)
    assert rep.seeds[0].source == "status"
    assert rep.seeds[0].step - 1 in set(tel.status.step.tolist())  # from the step after a snapshot
    assert not rep.seeded[: rep.seeds[0].row].any()
    assert rep.all_exact and rep.n_seeded > len(a) // 3


def test_drop_rate_gaps_match_tx_dropped(runs):
    tel = decode(runs["join"])
    a, s = tel.attitude, tel.status
    assert tel.stats.seq_gaps > 0
    # every step the firmware made and the capture lacks, between the first frame and each status, was dropped
    for j in range(1, len(s)):
        lo, hi = int(s.step[j - 1]), int(s.step[j])
        have = np.count_nonzero((a.step > lo) & (a.step <= hi))
        assert s.tx_dropped[j] - s.tx_dropped[j - 1] == (hi - lo) - have
    assert s.tx_dropped[0] > 0  # cumulative since boot: the drops before the join are counted too


def test_too_low_baud_overflows_the_queue_but_status_frames_get_through():
    # 8.5 s: the last status frame (step 809, at 7.99 s) has time to leave the backed-up queue
    res = synthesize(SynthOptions("bench", duration_s=8.5, baud=57600, seed=1))
    tel = decode(res)
    s = tel.status
    assert tel.stats.crc_failures == 0 and tel.stats.frames_missing > 0.3 * len(tel.attitude)
    assert len(s) == len(res.status) and np.all(s.baud == 57600)  # none dropped: they have the reserve
    last = int(s.step[-1])
    assert s.tx_dropped[-1] == (last + 1) - np.count_nonzero(tel.attitude.step <= last)
    assert np.all(s.queue_peak > 1500)


# ---- variants, text mode, throttle ------------------------------------------------------------------------------


def test_firmware_variants_are_reported_and_replayed_bit_exact():
    res = synthesize(SynthOptions("hand-tilts", duration_s=10, ki=1.0, correction=False, seed=5))
    tel = decode(res)
    s = tel.status
    assert np.all(s.ki == np.float32(1.0)) and np.all(s.flags & P.FLAG_NO_CORRECTION)
    assert np.all(s.int_xyz == 0)  # no correction: the integrals never move
    rep = replay_firmware(tel)
    assert rep.all_exact and not rep.seeds[0].settings.correction


def test_text_mode_lines(runs):
    res = runs["text"]
    assert b"\xa5\x5a" not in res.data
    tel = decode(res)
    a, s = tel.attitude, tel.status
    assert tel.stats.crc_failures == 0 and not a.exact.any()
    assert np.all(a.step % 16 == 0) and a.step[0] == 0 and np.all(np.diff(a.step) == 16)
    assert len(s) >= 15 and np.all(s.flags & P.FLAG_TEXT_MODE) and np.allclose(s.ki, 0.1)
    # same seed, binary build: the $ATT values are the firmware's values rounded toward zero
    b = runs["hover"].attitude
    rows = a.step.astype(int)
    assert np.array_equal(a.acc_mg, np.trunc(b["acc_mg"][rows]))
    assert np.array_equal(a.gyro_mdps, np.trunc(b["gyro_mdps"][rows]))
    thx, _ = quaternion_to_euler(b["q_wxyz"][rows])
    mdeg = np.trunc(np.nan_to_num((thx * np.float32(57295.78)).astype(np.float32)))
    assert np.allclose(a.thx_rad, mdeg * np.pi / 180000, atol=1e-12)
    assert np.array_equal(a.t_us // 1000, (b["t_us"][rows] // 1000))


def test_throttle_override():
    res = synthesize(SynthOptions("bench", duration_s=6, throttle="0:0,3:0,3.5:300", seed=1))
    a = decode(res).attitude
    late = a.t_fw_s > 3.6
    assert np.all(np.abs(a.thr[late].astype(int) - 300) <= 1) and np.all(a.thr[a.t_fw_s < 2.9] == 0)
    assert np.any(a.thz_rad[late] != 0)
    with pytest.raises(UserError):
        synthesize(SynthOptions("bench", duration_s=6, throttle="fast"))


def test_broad_trial(shared_dir):
    trial = shared_dir / "datasets" / "broad" / "02_undisturbed_slow_rotation_B.npz"
    res = synthesize(SynthOptions(str(trial), duration_s=6, seed=1))
    tel = decode(res)
    assert res.profile.measured and tel.stats.crc_failures == 0
    assert res.header["port"] == "synth:02_undisturbed_slow_rotation_B"
    assert replay_firmware(tel).all_exact
    with pytest.raises(UserError):
        synthesize(SynthOptions(str(trial), duration_s=10_000))


# ---- encoders ---------------------------------------------------------------------------------------------------


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@pytest.mark.skipif(shutil.which("make") is None or shutil.which("gcc") is None, reason="needs make and gcc")
def test_c_encoder_gives_the_python_bytes(tmp_path, host_build):
    exe = host_build / "stv_encode"
    for opts in (
        SynthOptions("demo", duration_s=40, seed=1),
        SynthOptions("hover", duration_s=8, join_at_s=9, drop_rate=0.05, seed=2, baud=921600),
    ):
        py = synthesize(opts)
        c = synthesize(SynthOptions(**{**opts.__dict__, "encoder": "c", "c_encoder": str(exe)}))
        assert len(py.data) > 50_000 and c.data == py.data
        assert np.array_equal(c.chunk_times_s, py.chunk_times_s)
    with pytest.raises(UserError, match="make -C firmware_patch host"):
        synthesize(SynthOptions("bench", duration_s=4, encoder="c", c_encoder=str(tmp_path / "missing")))


# ---- CLI --------------------------------------------------------------------------------------------------------


def run_cli(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_cli_writes_capture_and_raw(tmp_path, capsys):
    out = tmp_path / "x.stv"
    code, stdout, _ = run_cli(["synth", "--scenario", "bench", "--duration", "5", "--out", str(out)], capsys)
    assert code == 0 and "wrote" in stdout and out.is_file()
    tel = load_telemetry(out)
    assert tel.source["kind"] == "stv" and len(tel.attitude) > 250
    raw = tmp_path / "x.bin"
    code, _, _ = run_cli(["synth", "-s", "bench", "--duration", "5", "-o", str(raw)], capsys)
    assert code == 0 and raw.read_bytes() == read_capture(out).data
    code, _, err = run_cli(["synth", "-s", "bench", "--duration", "4", "-o", str(out)], capsys)
    assert code == 2 and "exists" in err and len(err.strip().splitlines()) == 1
    code, stdout, _ = run_cli(["synth", "--list"], capsys)
    assert code == 0 and all(name in stdout for name in SCENARIOS)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_the_former_throttle_option_still_runs_a_recorded_command(tmp_path, capsys):
    """Captures made before keep ``--throttle 0:0,...`` in their header command: it runs as --throttle-schedule."""
    out = {flag: tmp_path / f"{flag.strip('-')}.stv" for flag in ("--throttle", "--throttle-schedule")}
    for flag, path in out.items():
        args = ["synth", "-s", "bench", "--duration", "4", flag, "0:0,2:300", "--out", str(path)]
        assert run_cli(args, capsys)[0] == 0
    assert read_capture(out["--throttle"]).data == read_capture(out["--throttle-schedule"]).data


def test_a_setting_not_given_is_left_out_of_the_header_command():
    """An option the user did not give (None) is not written as ``--commands None``: the command runs again."""
    from steval_link.cli.checks import command_line

    line = command_line(["steval", "emulate", "fw.elf"], {"seed": 0, "commands": None, "tick_start_ms": None})
    assert line == "steval emulate fw.elf --seed 0"


def test_the_capture_header_command_repeats_the_capture(tmp_path, capsys):
    """The CLI writes the command line into the header; run again, it gives the same bytes."""
    out = tmp_path / "a.stv"
    args = [
        "synth",
        "-s",
        "bench",
        "--duration",
        "4",
        "--ki",
        "1",
        "--no-correction",
        "--throttle-schedule",
        "0:0,2:300",
    ]
    assert run_cli([*args, "--vibration", "gyro-x:47:2000", "--out", str(out)], capsys)[0] == 0
    command = read_capture(out).header["extra"]["command"]
    words = shlex.split(command)
    assert words[:2] == ["steval", "synth"] and "--throttle-schedule" in words and "--no-correction" in words
    again = tmp_path / "b.stv"
    assert run_cli([*words[1:], "--out", str(again)], capsys)[0] == 0
    assert read_capture(again).data == read_capture(out).data


@pytest.mark.parametrize(
    "args, words",
    [
        (["--scenario", "nope"], "unknown scenario"),
        (["--scenario", "missing_trial.npz"], "no such file"),
        (["--scenario", "bench", "--duration", "-1"], "--duration"),
        (["--scenario", "bench", "--duration", "1"], "at least"),
        (["--scenario", "bench", "--drop-rate", "1.5"], "--drop-rate"),
        (["--scenario", "bench", "--baud", "12"], "--baud"),
        (["--scenario", "bench", "--join-at", "-3"], "--join-at"),
        (["--scenario", "bench", "--encoder", "rust"], "--encoder"),
        (["--scenario", "bench", "--text-mode", "--encoder", "c"], "--text-mode"),
        (["--scenario", "bench", "--throttle-schedule", "1:2:3"], "--throttle-schedule"),
        (["--scenario", "bench", "--ki", "nan"], "--ki"),
    ],
)
def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys, args, words):
    code, _, err = run_cli(["synth", *args, "--out", str(tmp_path / "y.stv")], capsys)
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "y.stv").exists()


def test_the_default_c_encoder_is_this_trees_host_build():
    from pathlib import Path

    from steval_link.emulation.synth import default_c_encoder

    root = Path(__file__).resolve().parents[1]
    assert default_c_encoder() == root / "firmware_patch" / "host" / "stv_encode"

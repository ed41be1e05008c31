"""The firmware's flight control on the host (mixer, motor places, outer-loop P) and the emulated remote's sticks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link import constants as C
from steval_link.analysis.flight_control import MOTORS, expected_motor_pwm, mixer_pwm, motor_thr, outer_p
from steval_link.analysis.preflight import check_preflight
from steval_link.emulation.runner import MOUNTS, ScenarioMotion, joydata_bytes
from steval_link.emulation.scenarios import PREFLIGHT_MOVES
from steval_link.errors import UserError
from steval_link.link import protocol as P
from steval_link.link.decoder import decode_bytes
from steval_link.link.load import load_telemetry


def test_motor_places_and_spin_follow_the_mixer_signs():
    # flight_control.c: motor1 = thr - x - y + z, motor2 = thr + x - y - z, motor3 = thr + x + y + z,
    # motor4 = thr - x + y - z; +x (nose up) needs the front, +y (right side down) the left side, +z (turn
    # counter-clockwise) the clockwise props
    assert [(m.position, m.spin) for m in MOTORS] == [
        ("right rear", "clockwise"),
        ("right front", "counter-clockwise"),
        ("left front", "clockwise"),
        ("left rear", "counter-clockwise"),
    ]


def test_mixer_is_the_firmwares_float32_arithmetic():
    thr = np.array([208, 520, 0], np.int16)
    s2 = np.array([[1.5, -2.25, 3.125], [-800.0, 800.0, 12.5], [0.1, 0.2, 0.3]], np.float32)
    out = mixer_pwm(thr, s2)
    mt = np.trunc(np.float32(0.05) * thr.astype(np.float32) + np.float32(633.333)).astype(np.float32)
    assert motor_thr(thr).tolist() == mt.tolist() == [643.0, 659.0, 633.0]
    x, y, z = s2[:, 0], s2[:, 1], s2[:, 2]
    ref = np.stack([((mt - x) - y) + z, ((mt + x) - y) - z, ((mt + x) + y) + z, ((mt - x) + y) - z], axis=1)
    assert out.dtype == np.float32 and out.tobytes() == ref.astype(np.float32).tobytes()
    exp = expected_motor_pwm(thr, s2, [True, False, True])
    assert exp[0].tolist() == out[0].tolist() and not exp[1].any() and not exp[2].any()  # disarmed, thr < MIN_THR


def test_outer_p_is_kp1_times_the_error():
    rc = np.array([[0.1, -0.2, 0.0]], np.float32)
    ang = np.array([[0.05, 0.1, -0.3]], np.float32)
    p = outer_p(rc, ang)
    assert p.tolist() == (np.array(C.OUTER_KP, np.float32) * (rc - ang)).tolist()


def test_joydata_is_the_inverse_of_main_c():
    b = joydata_bytes(thr=520, ail=-702, ele=702, rud=-910, armed=True)
    j2, j3, j4, j5, _, j7 = b
    assert (j2 - 128) * -13 == -910 and j3 * 13 == 520 and (j4 - 128) * -13 == -702 and (j5 - 128) * 13 == 702
    assert j7 & 0x04 and not joydata_bytes(0, 0, 0, 0, False)[5]
    assert joydata_bytes(0, 0, 0, 0, False)[0] == 128  # centred sticks


def test_flight_scenario_arms_and_moves_the_sticks():
    motion = ScenarioMotion("flight", 30.0, seed=1)
    ticks = np.arange(0, int(29.0 * C.ISR_RATE_HZ), 50)
    rem = [motion.remote(int(k)) for k in ticks]
    armed = np.array([r[2] for r in rem])
    sticks = np.array([r[1] for r in rem])
    thr = np.array([r[0] for r in rem])
    assert armed.any() and not armed[0] and not armed[-1]
    assert sticks[:, 1].max() >= 650 and sticks[:, 0].min() <= -650 and sticks[:, 2].min() <= -850
    assert thr.max() > 450  # hovering


def test_mount_fault_turns_what_the_board_reads():
    ok = ScenarioMotion("hand-tilts", 20.0, seed=2)
    bad = ScenarioMotion("hand-tilts", 20.0, seed=2, mount="turned-180")
    k = int(12.0 * C.ISR_RATE_HZ)
    a_ok, g_ok = ok.counts(k)
    a_bad, g_bad = bad.counts(k)
    assert not np.array_equal(a_ok, a_bad)
    assert set(MOUNTS) == {"turned-90", "turned-180"}
    with pytest.raises(UserError, match="unknown mount="):
        ScenarioMotion("bench", 5.0, seed=0, mount="sideways")


def test_preflight_scenario_makes_the_guided_moves_in_order():
    assert [m[0] for m in PREFLIGHT_MOVES] == ["tilt right", "nose up", "turn right"]
    motion = ScenarioMotion("preflight", 32.0, seed=1)
    k = int(10.0 * C.ISR_RATE_HZ)
    thr, sticks, armed = motion.remote(k)
    assert armed and thr >= C.MIN_THR and sticks == (0, 0, 0)


# ---- the bundled captures of the real firmware under emulation (recordings/make_recordings.sh) -------------------

REC = Path(__file__).resolve().parents[1] / "recordings"


@pytest.fixture(scope="module")
def flight():
    return load_telemetry(REC / "flight.stv")


def _att_rows(tel):
    a, fc = tel.attitude, tel.fc
    j = np.searchsorted(a.step, fc.step)
    assert np.array_equal(a.step[j], fc.step)  # every FC frame follows the attitude frame of its step
    return j


def test_flight_capture_has_fc_frames_at_the_budgeted_rate(flight):
    fc = flight.fc
    assert len(fc) > 150 and np.all(fc.fc_every == 23) and np.all(flight.status.fc_every == 23)
    assert np.all(np.diff(fc.step) == 23)
    assert flight.stats.crc_failures == 0 and flight.stats.frames_missing == 0
    # the whole stream within 90 % of 115200 baud: bytes of the frames over the firmware time they span
    span = flight.attitude.t_fw_s[-1] - flight.attitude.t_fw_s[0]
    nbytes = (
        len(flight.attitude) * P.ATTITUDE_FRAME_SIZE
        + len(flight.status) * P.STATUS_FRAME_SIZE
        + len(fc) * P.FLIGHT_FRAME_SIZE
    )
    assert nbytes * 10 / span / 115200 <= 0.90
    assert fc.armed.any() and (fc.rc[:, 3] >= C.MIN_THR).any()
    assert (fc.rc[:, 1] == 702).any() and (fc.rc[:, 0] == -702).any() and (fc.rc[:, 2] <= -600).any()
    assert np.all((fc.vbat_v == 0) | (np.abs(fc.vbat_v - 3.9) < 0.01))


def test_flight_targets_are_rc_c_of_the_sticks(flight):
    fc = flight.fc
    # GetTargetEulerAngle: euler_rc.thx = -t1 * max_pitch_rad / RC_FULLSCALE (float32, t1 = gELE clamped)
    max_rad = np.float32(np.float32(3.141592654) * np.float32(30)) / np.float32(180.0)
    for axis, stick in ((0, 1), (1, 0)):
        t1 = np.clip(fc.rc[:, stick].astype(np.int32), -1800, 1800)
        want = (np.float32(1) * (-t1).astype(np.float32) * max_rad) / np.float32(1800)
        assert fc.euler_rc_rad[:, axis].tobytes() == want.astype(np.float32).tobytes()
    yaw = fc.euler_rc_rad[:, 2]
    assert yaw.min() < -1.0  # the rudder held beyond ±600 turned the yaw target (60°/s)


def test_flight_pid_terms_and_motors_are_the_firmwares_own_code(flight):
    """Acceptance: the outer loop's s1 is P = kp1·(target − angle) of the same step, bit for bit (I = 0); the motor
    PWM is the mixer of the inner outputs s2 and the throttle the ISR used, bit for bit."""
    fc, a = flight.fc, flight.attitude
    j = _att_rows(flight)
    ang = np.stack([a.thx_rad, a.thy_rad, a.thz_rad], axis=1)[j]
    p = outer_p(fc.euler_rc_rad, ang)
    assert p[:, :2].tobytes() == fc.outer_s1_radps[:, :2].tobytes()
    assert np.mean(p[:, 2] == fc.outer_s1_radps[:, 2]) > 0.95  # yaw: thz may move in the ISR before the outer loop
    exp = expected_motor_pwm(a.thr[j], fc.inner_s2_pwm, fc.armed)
    on = fc.armed & (a.thr[j] >= C.MIN_THR)
    assert on.sum() > 100
    assert exp.tobytes() == fc.motor_pwm.tobytes()
    # the motors answer the stick moves as the mixer says: nose-down stick (gELE > 0) → x_s2 < 0 → rear motors up
    assert np.all(np.abs(fc.inner_s2_pwm) <= C.MAX_ADJ)


def test_export_has_the_flight_columns_with_units(flight, tmp_path):
    from steval_link.cli.export import in_degrees, write_csv

    table = flight.attitude_table()
    table.update(flight.flight_columns())
    for name in (
        "target_thx_pitch_rad",
        "outer_s1_y_roll_radps",
        "inner_s2_z_yaw_pwm",
        "motor4_pwm",
        "vbat_v",
        "rc_thr",
        "fc_armed",
        "fc_every",
    ):
        assert name in table
    rows = np.isfinite(table["motor1_pwm"])
    assert rows.sum() == len(flight.fc)
    # the exported columns alone reproduce the mixer: motor = mixer(thr of the row, inner s2)
    s2 = np.stack([table[f"inner_s2_{n}_pwm"] for n in ("x_pitch", "y_roll", "z_yaw")], axis=1)[rows]
    motors = np.stack([table[f"motor{i}_pwm"] for i in range(1, 5)], axis=1)[rows]
    exp = expected_motor_pwm(table["thr"][rows], s2, table["fc_armed"][rows] > 0)
    assert exp.tobytes() == motors.astype(np.float32).tobytes()
    write_csv(in_degrees(table), tmp_path / "f.csv")
    header = (tmp_path / "f.csv").read_text().splitlines()[0].split(",")
    assert "target_thx_pitch_deg" in header and "motor1_pwm" in header


def test_viewer_logs_the_firmwares_values(flight, monkeypatch):
    from steval_viewer import flight_log

    sent = {}
    monkeypatch.setattr(flight_log, "send_scalars", lambda rec, path, times, v, valid=None: sent.update({path: v}))
    monkeypatch.setattr(flight_log, "send_arrows", lambda *a, **k: None)
    n = flight_log.log_flight_control(None, flight)
    fc = flight.fc
    assert n == len(fc)
    assert np.array_equal(sent["fc/motor_pwm"], fc.motor_pwm.astype(np.float64))
    assert np.array_equal(sent["fc/inner_s2_pwm"], fc.inner_s2_pwm.astype(np.float64))
    assert np.array_equal(sent["fc/pitch_thx_deg/target"], np.degrees(fc.euler_rc_rad[:, 0].astype(np.float64)))
    # P and I of the outer loop: P = s1 and I = 0 bit for bit for pitch and roll
    assert np.array_equal(sent["fc/outer_roll_y_radps/p"], sent["fc/outer_roll_y_radps/s1"])
    assert not np.any(sent["fc/outer_pitch_x_radps/i"])


def test_replay_rrd_has_the_flight_control_view(monkeypatch, capsys, tmp_path):
    """``steval replay flight.stv --rrd``: the flight-control entities, the tab's views and the motors' arrows."""
    from steval_viewer.rrd_check import blueprint_views, read_rrd, static_values

    out = tmp_path / "f.rrd"
    code, _, err = run_cli(monkeypatch, capsys, "replay", REC / "flight.stv", "--rrd", out, "-e", "none")
    assert code == 0, err
    info = read_rrd(out)
    n = len(load_telemetry(REC / "flight.stv").fc)
    for path in (
        "fc/motor_pwm",
        "fc/inner_s2_pwm",
        "fc/pitch_thx_deg/target",
        "fc/outer_roll_y_radps/p",
        "fc/outer_roll_y_radps/i",
        "world/drone/firmware/motors/m1",
    ):
        assert info.samples.get(path) == n, path
    views = blueprint_views(out)
    assert "pitch thx vs target (deg)" in views and "roll thy vs target (deg)" in views
    assert "motors (of 2000)" in views
    assert static_values(out, "world/drone/firmware/motors/m1")


def test_live_pipeline_hands_flight_frames_to_the_viewer():
    """The live path (steval live / emulate): each flight-control frame reaches the viewer after its step's
    attitude frame; a viewer without log_flight (an older LiveViewer) is simply not given them."""
    from support.viewers import NullViewer

    from steval_link.link.capture import read_capture
    from steval_link.live.pipeline import LivePipeline

    class Viewer(NullViewer):
        def __init__(self):
            self.steps, self.flight = [], []

        def log_batch(self, batch):
            self.steps += [int(s) for s in batch.attitude.step]

        def log_flight(self, frame, t):
            assert self.steps and self.steps[-1] >= frame.step  # its attitude frame came first
            self.flight.append(frame)

    viewer = Viewer()
    pipe = LivePipeline([], viewer=viewer)
    data = read_capture(REC / "flight.stv").data
    for i in range(0, len(data), 4096):
        pipe.feed([(data[i : i + 4096], float(i))])
    pipe.flush_view()
    fc = load_telemetry(REC / "flight.stv").fc
    assert [f.step for f in viewer.flight] == fc.step.tolist()
    assert np.array([f.motor_pwm for f in viewer.flight], np.float32).tobytes() == fc.motor_pwm.tobytes()


# ---- preflight --------------------------------------------------------------------------------------------------


def test_preflight_passes_the_clean_capture():
    rep = check_preflight(load_telemetry(REC / "preflight_ok.stv"))
    assert rep.passed, rep.problems
    text = rep.text()
    assert "motor 1 (right rear): OK, speeds up" in text and "Motor outputs: OK" in text
    assert text.count(": OK") >= 3 * 2 + 12


def test_preflight_names_the_swapped_motors():
    rep = check_preflight(load_telemetry(REC / "preflight_swapped_motors.stv"))
    assert not rep.passed
    assert any("outputs 3 and 4 are swapped" in p for p in rep.problems)
    assert not any("gyro" in p or "sensor" in p for p in rep.problems)  # the sensors are fine


def test_cli_preflight_exit_codes(monkeypatch, capsys):
    code, out, _ = run_cli(monkeypatch, capsys, "preflight", REC / "preflight_ok.stv")
    assert code == 0 and "PASS" in out
    code, out, _ = run_cli(monkeypatch, capsys, "preflight", REC / "preflight_swapped_motors.stv")
    assert code == 1 and "FAIL" in out and "outputs 3 and 4 are swapped" in out
    code, _, err = run_cli(monkeypatch, capsys, "preflight")
    assert code == 2 and err.startswith("steval: error:")


# ---- the reference firmware under emulation: its flight control, injected faults, the baud rate's N -----------------


def _emulated(elf, tmp_path, name, **kw):
    from steval_link.emulation.runner import Emulation, EmulationOptions
    from steval_link.link.capture import encode_capture

    emu = Emulation(EmulationOptions(elf=elf, **kw))
    path = tmp_path / name
    path.write_bytes(encode_capture({"source": "test"}, list(emu.chunks())))
    return load_telemetry(path)


@pytest.fixture(scope="module")
def fw_elf(reference_elf):
    from support import firmware as S

    return S, reference_elf


@pytest.fixture(scope="module")
def ref_flight(fw_elf, tmp_path_factory):
    """The flight scenario on the reference firmware (its own flight controller)."""
    _, elf = fw_elf
    return _emulated(elf, tmp_path_factory.mktemp("flight"), "flight.stv", scenario="flight", duration_s=27.0, seed=1)


@pytest.mark.slow
def test_reference_flight_frames_are_the_hosts_arithmetic(ref_flight):
    """The reference's flight control has ST's structure, so the host's checks hold on its frames: targets from the
    sticks (rc.c's formula), outer s1 = P bit for bit (I = 0), the motors = the mixer of s2 bit for bit."""
    fc, a = ref_flight.fc, ref_flight.attitude
    assert len(fc) > 150 and np.all(fc.fc_every == 23) and fc.armed.any()
    max_rad = np.float32(np.float32(3.141592654) * np.float32(30)) / np.float32(180.0)
    for axis, stick in ((0, 1), (1, 0)):
        t1 = np.clip(fc.rc[:, stick].astype(np.int32), -1800, 1800)
        want = (np.float32(1) * (-t1).astype(np.float32) * max_rad) / np.float32(1800)
        assert fc.euler_rc_rad[:, axis].tobytes() == want.astype(np.float32).tobytes()
    assert fc.euler_rc_rad[:, 2].min() < -1.0  # the rudder turned the yaw target
    j = _att_rows(ref_flight)
    ang = np.stack([a.thx_rad, a.thy_rad, a.thz_rad], axis=1)[j]
    p = outer_p(fc.euler_rc_rad, ang)
    assert p[:, :2].tobytes() == fc.outer_s1_radps[:, :2].tobytes()
    on = fc.armed & (a.thr[j] >= C.MIN_THR)
    assert on.sum() > 100
    assert expected_motor_pwm(a.thr[j], fc.inner_s2_pwm, fc.armed).tobytes() == fc.motor_pwm.tobytes()
    assert np.all(np.abs(fc.inner_s2_pwm) <= C.MAX_ADJ) and np.all(np.abs(fc.vbat_v - 3.9) < 0.01)


@pytest.mark.slow
def test_preflight_on_the_reference_and_its_swapped_motors_build(fw_elf, tmp_path):
    """steval preflight passes the reference firmware's preflight moves and names outputs 3 and 4 of a build whose
    mixer drives them swapped (SWAP_MOTORS=34)."""
    S, elf = fw_elf
    ok = check_preflight(_emulated(elf, tmp_path, "ok.stv", scenario="preflight", duration_s=30.0, seed=1))
    assert ok.passed, ok.problems
    swapped = S.build_reference(tmp_path / "sw", "SWAP_MOTORS=34")
    bad = check_preflight(_emulated(swapped, tmp_path, "sw.stv", scenario="preflight", duration_s=30.0, seed=1))
    assert not bad.passed and any("outputs 3 and 4 are swapped" in p for p in bad.problems)


@pytest.mark.slow
@pytest.mark.parametrize("mount, words", [("turned-90", "axes are swapped"), ("turned-180", "reversed")])
def test_preflight_names_a_board_mounted_turned(fw_elf, tmp_path, mount, words):
    """The sensor fault as a real one happens: the board mounted turned on the frame (the same readings as a
    wrong COORDINATE_SYSTEM in config_drone.h); the motion and the firmware are unchanged."""
    _, elf = fw_elf
    tel = _emulated(elf, tmp_path, f"{mount}.stv", scenario="preflight", duration_s=30.0, seed=2, mount=mount)
    rep = check_preflight(tel)
    assert not rep.passed
    moved = [p for p in rep.problems if p.startswith(("tilt right", "nose up"))]
    assert any("tilt right" in p and words in p for p in moved) and any("nose up" in p and words in p for p in moved)
    assert not any(p.startswith("turn right") and "gyro" in p for p in rep.problems)  # z is right


@pytest.mark.slow
def test_fc_every_step_at_460800_baud(fw_elf, tmp_path):
    S, _ = fw_elf
    elf = S.build_reference(tmp_path / "b", "BAUD=460800")
    tel = _emulated(elf, tmp_path, "fast.stv", scenario="bench", duration_s=6.0, seed=1)
    assert len(tel.fc) >= len(tel.attitude) - 1 and np.all(tel.fc.fc_every == 1)
    assert np.all(tel.status.fc_every == 1) and np.all(np.diff(tel.fc.step) == 1)


def test_preflight_refuses_a_capture_that_is_not_the_guided_sequence():
    rep = check_preflight(load_telemetry(REC / "demo.stv"))  # hand tilts: pitch, pitch, roll, ...
    assert not rep.passed and "not the guided sequence" in rep.problems[0]


@pytest.mark.slow
def test_cli_preflight_live_on_a_port(tmp_path):
    """``steval preflight --port``: prompts the moves on stderr while recording the port (here a pty replaying the
    clean capture at the line's rate), then checks what it recorded."""
    from support.ptyfeed import PtyFeeder, StevalProcess

    from steval_link.link.capture import read_capture

    data = read_capture(REC / "preflight_ok.stv").data
    out = tmp_path / "pre.stv"
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = StevalProcess(["preflight", "--port", str(feeder.link), "--out", str(out)], cwd=tmp_path)
        assert proc.wait_line("reading ", 60.0) is not None, proc.stderr
        feeder.start()
        rc = proc.finish(timeout_s=120)
    assert rc == 0, (proc.stdout, proc.stderr)
    assert "1/3 TILT RIGHT" in proc.stderr and "3/3 TURN RIGHT" in proc.stderr
    assert "PASS" in proc.stdout and out.is_file()


def test_a_scenario_too_short_for_its_moves_is_one_sentence():
    with pytest.raises(UserError, match="needs duration_s= of at least 27 s"):
        ScenarioMotion("flight", 10.0, seed=0)


@pytest.mark.slow
def test_frame_motors_are_what_tim4_drives(fw_elf):
    """When the firmware builds a flight-control frame, TIM4's CCR1..4 (the motor pins) hold its motor_pwm as
    set_motor_pwm writes it: truncated, clamped to 0..1900 (one ISR run wrote both)."""
    from steval_link.emulation.runner import Emulation, EmulationOptions

    _, elf = fw_elf
    emu = Emulation(EmulationOptions(elf=elf, scenario="flight", duration_s=27.0, seed=1))
    addr = emu.elf.addr("motor_pwm")
    seen = []
    emu.board.probe(
        emu.elf.addr("stv_fw_flight"),
        lambda b: seen.append((np.frombuffer(b.ram_read(addr, 16), "<f4").copy(), emu.motor_ccr())),
    )
    chunks = list(emu.chunks())
    assert len(seen) > 150
    pwm = np.array([p for p, _ in seen])
    ccr = np.array([c for _, c in seen])
    want = np.where(pwm >= C.MOTOR_MAX_PWM, C.MOTOR_MAX_PWM, np.where(pwm <= 0, 0, np.trunc(pwm)))
    assert np.array_equal(ccr, want.astype(np.int64)) and ccr.max() > 600
    tel = decode_bytes(b"".join(d for d, _ in chunks))
    assert tel.fc.motor_pwm.tobytes() == pwm.astype(np.float32).tobytes()  # the frames carry exactly these

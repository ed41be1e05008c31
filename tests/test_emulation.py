"""Firmware in the loop: the reference firmware (firmware_patch/reference, ``make reference``) runs on the emulated
STM32F401 board; its USART1 bytes are checked end to end: frames, boot lines, status cadence, the Python replica
bit-exact from power-up, the sensor pipeline bit-exact with sensor_model, lab variants, and the errors a broken
firmware gets.

Skips cleanly without arm-none-eabi-gcc, newlib-nano or unicorn (a user's fresh clone); in CI (CI=true) they fail.
"""

from __future__ import annotations

import signal
import struct
import time

import numpy as np
import pytest
from support import firmware as S

from steval_link.emulation import sensor_model as sm
from steval_link.estimators.firmware_replay import replay_firmware
from steval_link.link.capture import encode_capture
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AttitudeFrame, StatusFrame, TextFrame
from steval_link.link.load import load_telemetry

WHY = S.missing()
pytestmark = pytest.mark.skipif(WHY is not None, reason=WHY or "")

BANNER = "steval-link reference firmware (not ST's): the STEVAL loop for tests and teaching"
BOOT_LINES = [
    BANNER,
    "LSM6DSL ready: acc +-4 g, gyro +-2000 dps",
    "calibrating the offsets for 2 s: keep the drone still",
]


@pytest.fixture(scope="session")
def fw_default(reference_elf):
    return reference_elf


@pytest.fixture(scope="session")
def fw_lab(tmp_path_factory):
    """Lab exercises 4 + 5 at 921600 baud."""
    return S.build_reference(tmp_path_factory.mktemp("fw-lab"), "AHRS_KI=1.0f", "NO_CORRECTION=1", "BAUD=921600")


def emulate(elf, scenario="bench", duration_s=5.0, seed=0, **kw):
    from steval_link.emulation.runner import Emulation, EmulationOptions

    emu = Emulation(EmulationOptions(elf=elf, scenario=scenario, duration_s=duration_s, seed=seed, **kw))
    chunks = list(emu.chunks())
    return emu, chunks


def decode(chunks):
    dec = StreamDecoder()
    frames = []
    for data, _t in chunks:
        frames += dec.feed(data)
    frames += dec.finish()
    return dec.stats, frames


def port_check(chunks, tmp_path, name="emu.stv"):
    """The capture of the run, through load_telemetry and the seeded replica (what `steval compare` does)."""
    from steval_link.analysis.compare import compare_replica

    path = tmp_path / name
    path.write_bytes(encode_capture({"source": "test"}, chunks))
    tel = load_telemetry(path)
    rep, _replay, _rows = compare_replica(tel)
    return rep


@pytest.fixture(scope="session")
def default_run(fw_default):
    """2000+ AHRS steps of hand tilts from power-up (15.5 s emulated), with the LSM6DSL samples the firmware read."""
    return emulate(fw_default, "hand-tilts", duration_s=15.5, seed=3, log_samples=20000)


@pytest.mark.slow
def test_default_build_end_to_end(default_run, tmp_path):
    emu, chunks = default_run
    stats, frames = decode(chunks)
    att = [f for f in frames if isinstance(f, AttitudeFrame)]
    sta = [f for f in frames if isinstance(f, StatusFrame)]
    txt = [f.text for f in frames if isinstance(f, TextFrame)]
    assert stats.crc_failures == 0 and stats.seq_gaps == 0 and stats.frames_missing == 0 and stats.seq_resets == 0
    assert len(att) >= 2000
    assert [f.seq for f in att] == list(range(len(att)))
    # boot log lines arrive as text frames, before the first attitude frame
    for line in BOOT_LINES:
        assert line in txt
    first_att = frames.index(att[0])
    assert all(isinstance(f, TextFrame) for f in frames[:first_att])
    # a status frame after every 162nd step, with the step it follows and the firmware's constants
    assert [s.step for s in sta] == [162 * k - 1 for k in range(1, len(sta) + 1)]
    assert len(sta) == len(att) // 162
    s0 = sta[0]
    assert s0.baud == 115200 and s0.cpu_hz == 84_000_000 and s0.min_thr == 200 and s0.tx_dropped == 0
    assert np.float32(s0.ki) == np.float32(0.1) and s0.cyc_n == 162
    # the DWT window the firmware reports = the emulator's instruction count (plus interrupts that land in it)
    rep = emu.report()
    assert 3800 < min(rep.step_instructions) <= max(rep.step_instructions) < 6500
    assert s0.cyc_min >= min(rep.step_instructions) and s0.cyc_max < 8000
    # boot timing: TIM9 starts after the 1 s sensor delay (ST's timing); the first step 1604 ticks later
    assert 0.99 < rep.tim9_start_s < 1.02
    assert 2.97 < rep.first_attitude_s < 3.0
    assert abs(att[0].t_us / 1e6 - rep.first_attitude_s) < 0.01
    # the Python replica, seeded at power-up, bit-exact on every step
    port = port_check(chunks, tmp_path)
    assert port.seeds[0]["source"] == "power-up"
    assert port.all_exact and port.bit_exact == port.rows == len(att)


@pytest.mark.slow
def test_firmware_isr_equals_sensor_model(default_run):
    """acc_ahrs/gyro_ahrs the firmware computed (frames) = sensor_model's ISR pipeline on the same driver
    readings (the LSM6DSL samples the emulated sensor served, scaled as ST's driver does)."""
    emu, chunks = default_run
    _stats, frames = decode(chunks)
    att = [f for f in frames if isinstance(f, AttitudeFrame)]
    ticks, acc, gyro = emu.bus.served_driver_readings()
    # the ISR reads nothing in ticks 1-800, then once per tick (consecutive samples)
    assert np.all(np.diff(ticks) == 1)
    # (the first ISR call comes at once: HAL's EGR.UG in TIM_Base_SetConfig leaves UIF set, as on the chip)
    skipped = np.zeros((sm.CALIBRATION_SKIP_TICKS, 3), np.int32)  # never read: run_isr ignores them
    isr = sm.run_isr(np.concatenate([skipped, acc]), np.concatenate([skipped, gyro]))
    n = min(len(att), len(isr.acc_ahrs_mg))
    assert n >= 2000
    fw_acc = np.array([f.acc_mg for f in att[:n]], np.float32)
    fw_gyro = np.array([f.gyro_mdps for f in att[:n]], np.float32)
    assert fw_acc.view(np.uint32).tolist() == isr.acc_ahrs_mg[:n].view(np.uint32).tolist()
    assert fw_gyro.view(np.uint32).tolist() == isr.gyro_ahrs_mdps[:n].view(np.uint32).tolist()


@pytest.mark.slow
def test_synth_agrees_with_the_reference_firmware(default_run):
    """steval synth's emulated timing (it models ST's release) against the reference firmware's under emulation,
    same scenario and length: first step time, status cadence, DWT window (cyc_*). (The boot lines differ: synth
    prints ST's, the reference its own.)"""
    from steval_link.emulation.synth import SynthOptions, synthesize

    emu, chunks = default_run
    _stats, frames = decode(chunks)
    fw_att = [f for f in frames if isinstance(f, AttitudeFrame)]
    fw_sta = [f for f in frames if isinstance(f, StatusFrame)]
    res = synthesize(SynthOptions("hand-tilts", duration_s=15.5, seed=3))
    dec = StreamDecoder()
    sy = dec.feed(res.data) + dec.finish()
    sy_att = [f for f in sy if isinstance(f, AttitudeFrame)]
    sy_sta = [f for f in sy if isinstance(f, StatusFrame)]
    # boot: the first AHRS step at ≈ 2.985 s (1 s sensor delay + 2 s calibration), within a millisecond
    assert abs(sy_att[0].t_us - fw_att[0].t_us) < 1000
    assert abs(len(sy_att) - len(fw_att)) <= 2
    # status after every 162nd step, as many, at the same times within a millisecond
    assert [s.step for s in sy_sta] == [s.step for s in fw_sta]
    assert all(abs(a.t_us - b.t_us) < 1000 for a, b in zip(sy_sta, fw_sta))
    # the DWT window of ahrs_fusion_ag + QuaternionToEuler (the reference's C at -O0 like ST's): at rest (the first
    # second) synth's mean is within 3 % of the firmware's; tilted, the soft-float atan2/asin take longer (up to
    # ≈ 5300), which synth's constant does not model: within 25 % there
    assert abs(sy_sta[0].cyc_mean - fw_sta[0].cyc_mean) < 0.03 * fw_sta[0].cyc_mean
    for a, b in zip(sy_sta, fw_sta):
        assert abs(a.cyc_mean - b.cyc_mean) < 0.25 * b.cyc_mean


@pytest.mark.slow
def test_lab_variant_ki1_nocorrection_921600(fw_lab, tmp_path):
    emu, chunks = emulate(fw_lab, "hand-tilts", duration_s=6.0, seed=1)
    stats, frames = decode(chunks)
    att = [f for f in frames if isinstance(f, AttitudeFrame)]
    sta = [f for f in frames if isinstance(f, StatusFrame)]
    assert stats.crc_failures == 0 and stats.seq_gaps == 0 and len(att) > 400
    assert sta[0].baud == 921600 and np.float32(sta[0].ki) == np.float32(1.0) and sta[0].flags & 1
    port = port_check(chunks, tmp_path)
    assert port.all_exact and port.bit_exact == port.rows == len(att)
    assert port.settings["correction"] is False


@pytest.mark.slow
def test_diverge_build_reproduces_the_refactor_bug(tmp_path):
    """AHRS_DIVERGE=1 (halfT scales only the last term of the quaternion update): the filter leaves the unit sphere
    within a few steps; protocol v2 keeps those CRC-valid frames and flags their values (values_bad)."""
    elf = S.build_reference(tmp_path / "b", "AHRS_DIVERGE=1")
    emu, chunks = emulate(elf, "bench", duration_s=4.0)
    stats, frames = decode(chunks)
    att = [f for f in frames if isinstance(f, AttitudeFrame)]
    assert emu.report().ahrs_steps > 150 and stats.crc_failures == 0
    assert stats.implausible == 0 and stats.values_bad > 100 and len(att) == stats.attitude > 150
    assert any(not np.all(np.isfinite(f.q_wxyz)) or np.max(np.abs(f.q_wxyz)) > 2 for f in att)
    assert abs(np.linalg.norm(att[1].q_wxyz) - 1.0) > 0.05  # |q| 1.08 after the second step


@pytest.mark.slow
def test_text_mode_build(tmp_path):
    elf = S.build_reference(tmp_path / "b", "TEXT_MODE=1")
    emu, chunks = emulate(elf, "bench", duration_s=4.5)
    text = b"".join(d for d, _ in chunks).decode("ascii")
    assert BANNER in text
    att = [ln for ln in text.splitlines() if ln.startswith("$ATT,")]
    assert len(att) >= 12  # one line per 16 steps after 2.985 s
    stats, frames = decode(chunks)
    assert stats.crc_failures == 0


@pytest.mark.slow
def test_throttle_race_frame_carries_the_throttle_the_filter_used(fw_default, tmp_path):
    """An interrupt (ST's REMOCON_PWM TIM2 capture) can change gTHR between stv_fw_step_begin and the filter's read.
    Emulate exactly that (gTHR := 520 at ahrs_fusion_ag's entry on every 3rd step, after the snapshot): the
    frames must carry 520 there, so the replica (kp 0.4 on those steps) stays bit-exact."""
    from steval_link.emulation.runner import Emulation, EmulationOptions

    emu = Emulation(EmulationOptions(elf=fw_default, scenario="bench", duration_s=4.5))
    gthr = emu.elf.addr("gTHR")
    calls = [0]

    def rc_interrupt(board):
        calls[0] += 1
        if calls[0] % 3 == 0:
            board.ram_write(gthr, (520).to_bytes(2, "little"))

    emu.board.probe(emu.elf.addr("ahrs_fusion_ag"), rc_interrupt)
    chunks = list(emu.chunks())
    _stats, frames = decode(chunks)
    att = [f for f in frames if isinstance(f, AttitudeFrame)]
    assert len(att) > 200
    assert [f.thr for f in att[:9]] == [0, 0, 520] * 3
    port = port_check(chunks, tmp_path)
    assert port.all_exact and port.bit_exact == port.rows == len(att)


@pytest.mark.slow
def test_python_counter_fallback_gives_the_same_payloads(fw_default):
    """Without the C counter (_icount not built) the board counts at block granularity in Python: the same frames
    (acc, gyro, q, thr, seq), only times and instruction counts are approximate."""
    from steval_link.emulation.board import Board
    from steval_link.emulation.runner import Emulation, EmulationOptions

    def run(native):
        emu = Emulation(EmulationOptions(elf=fw_default, scenario="hand-tilts", duration_s=4.5, seed=2))
        if native is False:
            emu.board = Board(emu.elf, emu.bus, native=False)
            emu.board.tick_observers.append(emu._on_tick)
            emu._install_step_probes()
        _stats, frames = decode(list(emu.chunks()))
        return emu.board.native, [f for f in frames if isinstance(f, AttitudeFrame)]

    native_c, a = run(None)
    native_py, b = run(False)
    assert native_py is False and len(a) == len(b) > 200
    key = lambda f: (f.seq, f.thr, f.acc_mg, f.gyro_mdps, f.q_wxyz, f.thz_rad)  # noqa: E731
    assert [key(f) for f in a] == [key(f) for f in b]


@pytest.mark.slow
def test_idle_skipping_changes_no_payload(fw_default, tmp_path):
    """Jumping the clock over the main loop's sleep (wfi: the speed-up) against a build whose main loop polls and
    never sleeps, run without skipping: the same frames and boot lines, the same instructions per AHRS step,
    t_us within a microsecond."""
    from steval_link.emulation.runner import Emulation, EmulationOptions

    def run(elf, skip):
        emu = Emulation(EmulationOptions(elf=elf, scenario="hand-tilts", duration_s=3.3, seed=2, skip_idle=skip))
        _stats, frames = decode(list(emu.chunks()))
        return (
            emu.report(),
            [f for f in frames if isinstance(f, AttitudeFrame)],
            [f.text for f in frames if isinstance(f, TextFrame)],
        )

    r1, a1, t1 = run(fw_default, True)
    r2, a2, t2 = run(S.build_reference(tmp_path / "poll", "SLEEP=0"), False)
    assert r1.skipped_instructions > 20 * r1.instructions and r2.skipped_instructions == 0
    key = lambda f: (f.seq, f.thr, f.acc_mg, f.gyro_mdps, f.q_wxyz, f.thz_rad)  # noqa: E731
    assert len(a1) == len(a2) > 40 and [key(f) for f in a1] == [key(f) for f in a2] and t1 == t2
    assert max(abs(x.t_us - y.t_us) for x, y in zip(a1, a2)) <= 1
    assert r1.step_instructions == r2.step_instructions


def _patched_elf(elf, tmp_path, func: str, code: bytes):
    """A copy of the ELF with the first bytes of ``func`` replaced by Thumb ``code``."""
    from steval_link.emulation.elf import Elf

    e = Elf(elf)
    addr = e.addr(func)
    data = bytearray(elf.read_bytes())
    (phoff,) = struct.unpack_from("<I", data, 28)
    phentsize, phnum = struct.unpack_from("<HH", data, 42)
    for i in range(phnum):
        _t, off, _v, paddr, filesz, *_ = struct.unpack_from("<8I", data, phoff + i * phentsize)
        if paddr <= addr < paddr + filesz:
            data[off + addr - paddr : off + addr - paddr + len(code)] = code
            out = tmp_path / f"{func}.elf"
            out.write_bytes(bytes(data))
            return out
    raise AssertionError(f"{func} not in a loaded segment")


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_unmodelled_hardware_names_function_and_address(fw_default, tmp_path):
    """A firmware that writes to the USB OTG block (not modelled): one line naming the function and address."""
    from steval_link.emulation.board import UnmodelledHardware

    # movs r0, #0x50; lsls r0, r0, #24; str r0, [r0]; bx lr   (write to 0x50000000)
    elf = _patched_elf(fw_default, tmp_path, "hw_gpio_init", bytes.fromhex("5020 0006 0060 7047"))
    with pytest.raises(UnmodelledHardware) as exc:
        emulate(elf, duration_s=1.0)
    msg = str(exc.value)
    assert "\n" not in msg and "hw_gpio_init" in msg and "0x50000000" in msg and "write" in msg


def test_watchdog_names_where_the_firmware_is_stuck(fw_default, tmp_path):
    """An endless loop (b .) before anything is printed: the watchdog stops the run and says where."""
    from steval_link.emulation.board import FirmwareStuck

    elf = _patched_elf(fw_default, tmp_path, "hw_gpio_init", bytes.fromhex("fee7"))
    with pytest.raises(FirmwareStuck) as exc:
        emulate(elf, duration_s=10.0, watchdog_s=0.3)
    assert "hw_gpio_init" in str(exc.value)


def test_cli_emulate_writes_a_capture_that_compare_finds_bit_exact(fw_default, tmp_path, monkeypatch, capsys):
    """The user's path: `steval emulate ELF --out X.stv --no-view`, then `steval compare X.stv`."""
    from support.cli import run_cli

    out = tmp_path / "emu.stv"
    code, stdout, stderr = run_cli(
        monkeypatch, capsys, "emulate", fw_default, "--scenario", "bench", "--duration", "4", "--out", out, "--no-view"
    )
    assert code == 0, stderr
    assert out.stat().st_size > 5000
    assert "firmware DWT window" in stdout + stderr  # the step cost itself: tests/test_step_cost.py
    code, stdout, stderr = run_cli(monkeypatch, capsys, "compare", out)
    assert code == 0, stderr
    assert "bit-exact" in stdout


def test_cli_emulate_bad_elf_is_one_line(tmp_path, monkeypatch, capsys):
    from support.cli import run_cli

    bad = tmp_path / "x.elf"
    bad.write_bytes(b"not an elf")
    code, _out, err = run_cli(monkeypatch, capsys, "emulate", bad, "--no-view", "--duration", "1")
    assert code == 2 and err.startswith("steval: error:") and err.count("\n") == 1


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["INT", "TERM", "HUP"])
def test_cli_emulate_stops_cleanly_on_one_signal_and_keeps_the_capture(fw_default, tmp_path, sig):
    """Ctrl-C (or SIGTERM, SIGHUP) once during `steval emulate`: it stops at the next round, says so, and the
    capture holds every frame emulated until then, bit-exact with the replica."""
    from support.ptyfeed import StevalProcess

    out = tmp_path / "emu.stv"
    proc = StevalProcess(
        ["emulate", str(fw_default), "--scenario", "hover", "--duration", "120", "--out", str(out), "--no-view"],
        cwd=tmp_path,
    )
    assert proc.wait_line("emulating ", 120) is not None, proc.stderr
    time.sleep(5.0)  # past the boot (first frame at 2.985 s of emulated time)
    rc = proc.finish(timeout_s=60, sig=sig)
    assert rc == 0, proc.stderr
    assert "Traceback" not in proc.stderr and "stopped: " in proc.stdout
    tel = load_telemetry(out)
    assert len(tel.attitude) > 100 and tel.stats.crc_failures == 0
    assert replay_firmware(tel).all_exact


# ---- the viewer paths of `steval emulate` -------------------------------------------------------------------------


@pytest.mark.slow  # 5 s of emulated firmware (unicorn) logged to Rerun: 1.6 to 3.3 s here
def test_cli_emulate_to_rrd_headless(fw_default, tmp_path, monkeypatch, capsys):
    """`steval emulate ELF --rrd X.rrd`: the emulated stream logged as a live session is (every attitude frame, the
    flight-control entities, the blueprint)."""
    from support.cli import run_cli

    from steval_viewer import entities as ent
    from steval_viewer.rrd_check import read_rrd

    out = tmp_path / "emu.rrd"
    code, _stdout, stderr = run_cli(
        monkeypatch,
        capsys,
        "emulate",
        fw_default,
        "--scenario",
        "bench",
        "--duration",
        "5",
        "--rrd",
        out,
        "-e",
        "none",
        "--out",
        tmp_path / "emu.stv",
    )
    assert code == 0, stderr
    info = read_rrd(out)
    assert info.has_blueprint
    steps = info.samples[ent.pitch_path("firmware")]
    assert 300 < steps < 340  # 161.5 steps/s from 2.985 s
    assert info.samples.get("fc/motor_pwm", 0) >= steps // 23 - 1


@pytest.mark.slow
def test_cli_emulate_spawns_the_viewer_with_the_stream(fw_default, tmp_path):
    """`steval emulate ELF --spawn` on a virtual display: the real Rerun viewer opens, gets every attitude step,
    stays open when the emulation ends."""
    from support.cli import run_steval
    from support.xdisplay import rerun_processes, viewer_port, viewer_recording, virtual_display

    from steval_viewer import entities as ent

    with virtual_display() as display, viewer_port() as port:
        done = run_steval(
            ["emulate", fw_default, "--scenario", "bench", "--duration", "4", "--spawn", "--grpc-port", port]
            + ["-e", "none"],
            env=display.env,
            cwd=tmp_path,
            timeout=180,
        )
        assert done.returncode == 0, done.stderr
        rec = viewer_recording(f"rerun+http://127.0.0.1:{port}/proxy", timeline="ahrs_step", end=160, timeout_s=60)
        assert "/" + ent.pitch_path("firmware") in rec.entities
        assert rerun_processes(port), "the spawned viewer should stay open after the emulation"

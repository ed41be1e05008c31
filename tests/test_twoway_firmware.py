"""The two-way link on the reference firmware (firmware_patch/reference, our link modules) under emulation: commands
reach it through the emulated USART1 RX, and the replica follows every change bit for bit.

- The runtime filter settings keep the stock arithmetic: the shared conformance vectors (computed from ST's
  released binary), fed to the reference firmware's own ``ahrs_fusion_ag`` step by step, come out bit for bit
  (and with KI 1 / no correction set in ``stv_filter``, bit for bit the replica with those settings).
- KI, the correction and a filter reset changed mid-stream: every step bit-exact in ``replay_firmware``, the live
  replica and ``steval compare``; each change announced by an EVENT status naming its step; the capture holds the
  commands sent (``H`` chunks).
- Corrupted, cut and foreign bytes on RX are ignored and counted (the acks' ``rx_bad``); nothing else is applied.
- With the throttle up a filter change is refused, the ack says why, and nothing changes.

Skips cleanly without arm-none-eabi-gcc or unicorn (the conformance tests without ../shared); CI has all.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from support import firmware as S

from steval_link.estimators.conformance import load_conformance_csv
from steval_link.estimators.firmware_replay import replay_firmware
from steval_link.estimators.st_mahony import MahonySettings, bits_equal, run
from steval_link.link import protocol as P
from steval_link.link.capture import encode_capture, read_capture
from steval_link.link.commands import Command, CommandChannel, parse_command
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AckFrame, AttitudeFrame, CommandFrame, StatusFrame
from steval_link.link.load import load_telemetry

WHY = S.missing()
pytestmark = [pytest.mark.skipif(WHY is not None, reason=WHY or ""), pytest.mark.slow]

CONFORMANCE = S.ROOT.parent / "shared" / "conformance" / "st-fcu-170120"
FIRST_STEP_S = 2.985  # emulated time of the first AHRS step (boot)
STEP_S = 0.00619


@pytest.fixture(scope="module")
def fw(reference_elf):
    return reference_elf


def _emulation(elf, scenario="hand-tilts", duration_s=6.0, **kw):
    from steval_link.emulation.runner import Emulation, EmulationOptions

    return Emulation(EmulationOptions(elf=elf, scenario=scenario, duration_s=duration_s, seed=2, **kw))


def _frames(chunks):
    dec = StreamDecoder()
    out = []
    for data, _t in chunks:
        out += dec.feed(data)
    return dec, out


# ---- the stock arithmetic, runtime settings ------------------------------------------------------------------


def _through_firmware(elf, vec, rows: int, ki: float | None = None, correction: int | None = None):
    """Feed the first ``rows`` vector inputs to the firmware's own ahrs_fusion_ag (at its entry, in its RAM),
    and read back ahrs.q and the Euler angles it sends (at stv_fw_step_end's entry)."""
    emu = _emulation(elf, "bench", FIRST_STEP_S + (rows + 3) * STEP_S)
    b, e = emu.board, emu.elf
    R = b.regs.R
    g_thr = e.addr("gTHR")
    filt = e.addr("stv_filter")
    k = {"in": 0, "out": 0}
    q = np.full((rows, 4), np.nan, np.float32)
    eul = np.full((rows, 2), np.nan, np.float32)

    def on_fusion(board):
        i = k["in"]
        if i == 0 and (ki is not None or correction is not None):
            # stv_filter = {kp_ground, kp_flight, ki, min_thr (i16), correction (u8)}: set as a command would
            if ki is not None:
                board.ram_write(filt + 8, struct.pack("<f", ki))
            if correction is not None:
                board.ram_write(filt + 14, bytes([correction]))
        if i < rows:
            board.ram_write(board.reg(R[0]), vec.acc_mg[i].astype("<f4").tobytes())
            board.ram_write(board.reg(R[1]), vec.gyro_mdps[i].astype("<f4").tobytes())
            board.ram_write(g_thr, struct.pack("<h", int(vec.thr[i])))
        k["in"] = i + 1

    def on_end(board):
        i = k["out"]
        if i < rows:
            q[i] = np.frombuffer(board.ram_read(board.reg(R[2]), 16), "<f4")
            eul[i] = np.frombuffer(board.ram_read(board.reg(R[3]), 8), "<f4")
        k["out"] = i + 1

    b.probe(e.addr("ahrs_fusion_ag"), on_fusion)
    b.probe(e.addr("stv_fw_step_end"), on_end)
    emu.run()
    assert k["out"] >= rows, f"only {k['out']} AHRS steps ran"
    return q, eul


@pytest.mark.parametrize("name,rows", [("throttle_switch.csv", 900), ("edge_cases.csv", 700), ("broad_02.csv", 600)])
def test_conformance_vectors_through_the_firmware(fw, name, rows):
    """The reference's ahrs.c (settings read from stv_filter) computes exactly what ST's released binary computes."""
    if not (CONFORMANCE / name).is_file():
        pytest.skip("shared conformance vectors not present")
    vec = load_conformance_csv(CONFORMANCE / name)
    rows = min(rows, len(vec))
    q, eul = _through_firmware(fw, vec, rows)
    assert bits_equal(q, vec.q_wxyz[:rows]).all()
    assert bits_equal(eul[:, 0], vec.thx_rad[:rows]).all() and bits_equal(eul[:, 1], vec.thy_rad[:rows]).all()


def test_runtime_ki_and_no_correction_are_the_port_with_those_settings(fw):
    """KI 1 and no correction set at runtime = the port with those settings (= the lab builds' arithmetic)."""
    vec = load_conformance_csv(CONFORMANCE / "throttle_switch.csv") if CONFORMANCE.is_dir() else None
    if vec is None:
        pytest.skip("shared conformance vectors not present")
    rows = 600
    for ki, corr in ((1.0, 1), (0.1, 0)):
        q, eul = _through_firmware(fw, vec, rows, ki=ki, correction=corr)
        pq, pthx, pthy, _ = run(
            vec.acc_mg[:rows],
            vec.gyro_mdps[:rows],
            vec.thr[:rows],
            settings=MahonySettings(ki=ki, correction=bool(corr)),
        )
        assert bits_equal(q, pq).all() and bits_equal(eul[:, 0], pthx).all() and bits_equal(eul[:, 1], pthy).all()
        assert not bits_equal(q, vec.q_wxyz[:rows]).all()  # the settings did change the result


# ---- changes mid-stream ----------------------------------------------------------------------------------------

SCRIPT = [
    (3.6, "status"),
    (4.2, "set ki 1.0"),
    (5.5, "correction off"),
    (6.6, "reset"),
    (7.4, "correction on"),
    (8.0, "set kp_ground 2.5"),
    (8.6, "set min_thr 150"),
]


def _scripted_run(elf, script, duration_s, **kw):
    emu = _emulation(elf, duration_s=duration_s, **kw)
    channel = CommandChannel(lambda b: None, first_seq=100)
    sent = {}
    for t, text in script:
        s = channel.next_frame(parse_command(text) if isinstance(text, str) else text)
        emu.send_at(s.frame, t)
        sent[s.cmd_seq] = s.command
    chunks, host = [], []
    for data, t in emu.chunks():
        host += emu.take_host_bytes()
        chunks.append((data, t))
    host += emu.take_host_bytes()
    return emu, chunks, host, sent


@pytest.fixture(scope="module")
def changes_run(fw):
    return _scripted_run(fw, SCRIPT, 9.6)


def test_changes_mid_stream_are_followed_bit_exact(changes_run, tmp_path):
    emu, chunks, host, sent = changes_run
    dec, frames = _frames(chunks)
    assert dec.stats.crc_failures == 0 and dec.stats.frames_missing == 0
    acks = [f for f in frames if isinstance(f, AckFrame)]
    assert [a.cmd_seq for a in acks] == sorted(sent)  # one ack per command, in order
    assert all(a.result == P.ACK_ACCEPTED for a in acks)
    assert [a.rx_ok for a in acks] == list(range(1, len(sent) + 1)) and all(a.rx_bad == 0 for a in acks)
    events = [f for f in frames if isinstance(f, StatusFrame) and f.flags & P.FLAG_EVENT]
    assert len(events) == len(sent)
    att_steps = [f.seq for f in frames if isinstance(f, AttitudeFrame)]
    for ack, ev in zip(acks, events):
        assert ev.step == ack.step - 1  # the status names the last step done; the change applies from the next
    # each change is in the status frames: ki 1 from the 2nd command, correction off (flags bit 0), reset, ...
    assert events[0].ki == np.float32(0.1) and events[1].ki == np.float32(1.0)
    assert events[2].flags & P.FLAG_NO_CORRECTION and not events[4].flags & P.FLAG_NO_CORRECTION
    assert tuple(events[3].q_wxyz) == (1.0, 0.0, 0.0, 0.0) and tuple(events[3].int_xyz) == (0.0, 0.0, 0.0)
    assert events[5].kp_ground == np.float32(2.5) and events[6].min_thr == 150
    assert [e.param_gen for e in events] == [0, 1, 2, 3, 4, 5, 6]
    assert len(att_steps) > 900

    # the capture tells the whole story: the bytes sent (H chunks) and received
    path = tmp_path / "changes.stv"
    from steval_link.link.capture import CaptureWriter

    with CaptureWriter(path, port="emulated", baud=115200) as w:
        hi = 0
        for data, t in chunks:
            while hi < len(host) and host[hi][1] <= t:
                w.write_host(*host[hi])
                hi += 1
            w.write(data, t)
    cap = read_capture(path)
    assert b"".join(h.data for h in cap.host) == b"".join(s for s, _ in host)
    cmd_dec = StreamDecoder()
    cmds = [f for f in cmd_dec.feed(b"".join(h.data for h in cap.host)) if isinstance(f, CommandFrame)]
    assert [c.cmd_seq for c in cmds] == sorted(sent)

    # replay_firmware and the compare path: every step bit-exact across every change
    tel = load_telemetry(path)
    rep = replay_firmware(tel)
    assert rep.all_exact and rep.n_seeded == len(tel.attitude.step), (rep.first_mismatch, rep.n_seeded)
    # without following the EVENT snapshots the port would not be bit-exact after the first change
    from steval_link.analysis.compare import compare_replica

    crep, _replay, _rows = compare_replica(tel)
    assert crep.bit_exact == crep.seeded == len(tel.attitude.step)


def test_live_port_follows_every_change(changes_run):
    from steval_link.live.pipeline import LivePipeline

    emu, chunks, host, sent = changes_run
    pipe = LivePipeline(["st-mahony"])
    hi = 0
    for data, t in chunks:
        while hi < len(host) and host[hi][1] <= t:
            pipe.feed_host(host[hi][0], host[hi][1])
            hi += 1
        pipe.feed([(data, t)])
    port = pipe.mahony
    assert port.describe() == "replica bit-exact", port.describe()
    notes = list(pipe.notes)
    assert any(n.startswith("set ki 1: accepted, applies from step") for n in notes), notes
    assert any(n.startswith("correction off: accepted") for n in notes), notes


def test_corrupted_commands_are_ignored_and_counted(fw):
    """Noise, a corrupted, a cut and a foreign frame on RX: none applied, each bad candidate counted in rx_bad;
    the valid command after them is applied."""
    emu = _emulation(fw, duration_s=5.6)
    good = Command(P.CMD_SET_PARAM, P.PARAM_KI, 1.0)
    corrupted = bytearray(good.encode(7))
    corrupted[9] ^= 0x10  # the value's bits: CRC fails
    cut = good.encode(8)[:13]
    foreign = P.encode_ack(cmd_seq=1, cmd=1, result=0, step=0)  # a valid frame of another type
    v1 = bytearray(good.encode(9))
    v1[2] = (1 << 4) | P.TYPE_COMMAND  # protocol version 1: no such command
    rng = np.random.default_rng(5)
    noise = rng.integers(0, 256, 300, dtype=np.uint8).tobytes().replace(b"\xa5\x5a", b"\xa5\x00")
    emu.send_at(noise + bytes(corrupted) + cut + foreign + bytes(v1), 3.5)
    emu.send_at(Command(P.CMD_REQUEST_STATUS).encode(10), 4.3)
    emu.send_at(good.encode(11), 4.8)
    chunks = list(emu.chunks())
    _dec, frames = _frames(chunks)
    acks = [f for f in frames if isinstance(f, AckFrame)]
    assert [a.cmd_seq for a in acks] == [10, 11]
    assert acks[0].rx_ok == 1 and acks[0].rx_bad >= 4  # corrupted, cut (seen when the next header came), foreign, v1
    status = [f for f in frames if isinstance(f, StatusFrame) and f.flags & P.FLAG_EVENT]
    assert status[0].ki == np.float32(0.1) and status[0].param_gen == 0  # nothing applied by the bad bytes
    assert status[1].ki == np.float32(1.0) and status[1].param_gen == 1
    sent_bytes = b"".join(d for d, _ in emu.take_host_bytes())
    assert emu.board.usart1.rx_received == len(sent_bytes) and emu.board.usart1.rx_overruns == 0


def test_filter_changes_are_refused_while_the_motors_may_spin(fw, tmp_path):
    """Throttle at MIN_THR or above, or armed (the remote's arming bit: rc_enable_motor): a filter change or reset is
    refused (ack result 1, the ARMED flag set), a status request is still answered; once the throttle is down and
    the drone disarmed, the change applies."""
    script = [
        (4.0, "set ki 1.0"),
        (4.3, "reset"),
        (4.6, "status"),
        (5.5, "set ki 1.0"),
        (5.6, "status"),
        (6.2, "set ki 1.0"),
    ]
    emu = _emulation(fw, duration_s=6.8, throttle="0:0,3.7:0,3.8:300,5.0:300,5.1:0")
    joy, connected = emu.elf.addr("joydata"), emu.elf.by_name["connected"]
    armed_seen = []

    def arm(board):  # the BLE remote's arming button from 5.2 s to 5.8 s (throttle 0)
        t = board.now / 84e6
        if 5.2 <= t < 5.8:
            board.ram_write(joy + 7, b"\x04")
            board.ram_write(connected.addr, (1).to_bytes(max(connected.size, 1), "little"))
            armed_seen.append(int.from_bytes(board.ram_read(emu.elf.addr("rc_enable_motor"), 4), "little"))
        elif t >= 5.8:
            board.ram_write(joy + 7, b"\x00")

    emu.board.tick_observers.append(arm)
    channel = CommandChannel(lambda b: None, first_seq=1)
    for t, text in script:
        emu.send_at(channel.next_frame(parse_command(text)).frame, t)
    chunks = list(emu.chunks())
    assert 1 in armed_seen  # the firmware did arm
    _dec, frames = _frames(chunks)
    acks = [f for f in frames if isinstance(f, AckFrame)]
    assert [a.result for a in acks] == [
        P.ACK_REFUSED_ARMED,
        P.ACK_REFUSED_ARMED,
        P.ACK_ACCEPTED,
        P.ACK_REFUSED_ARMED,
        P.ACK_ACCEPTED,
        P.ACK_ACCEPTED,
    ]
    events = [f for f in frames if isinstance(f, StatusFrame) and f.flags & P.FLAG_EVENT]
    assert len(events) == 3
    for ev in events[:2]:  # throttle up, then armed: the motors may spin, nothing changed
        assert ev.flags & P.FLAG_ARMED and ev.ki == np.float32(0.1) and ev.param_gen == 0
    assert not events[2].flags & P.FLAG_ARMED and events[2].ki == np.float32(1.0) and events[2].param_gen == 1
    path = tmp_path / "refused.stv"
    path.write_bytes(encode_capture({"source": "test"}, chunks))
    assert replay_firmware(load_telemetry(path)).all_exact


def test_mode_switch_at_runtime(fw):
    """SET_MODE text: the ack still binary, then $ATT/$STA lines; SET_MODE binary: frames again."""
    emu, chunks, host, sent = _scripted_run(fw, [(3.6, "mode text"), (4.6, "mode binary")], 5.4)
    data = b"".join(d for d, _ in chunks)
    assert b"$ATT," in data and b"$STA," in data and b"#ACK " in data
    _dec, frames = _frames(chunks)
    acks = [f for f in frames if isinstance(f, AckFrame)]
    assert acks and acks[0].result == P.ACK_ACCEPTED
    att = [f for f in frames if isinstance(f, AttitudeFrame)]
    assert att[-1].t_us > 4.7e6 - 2.985e6  # binary frames again after the switch back
    from steval_link.link.commands import ack_of_text
    from steval_link.link.frames import TextFrame

    text_acks = [ack_of_text(f.text) for f in frames if isinstance(f, TextFrame) and f.text.startswith("#ACK")]
    assert len(text_acks) == 1 and text_acks[0].cmd == P.CMD_SET_MODE and text_acks[0].result == P.ACK_ACCEPTED


def test_cli_emulate_with_a_command_script_then_compare(fw, tmp_path, monkeypatch, capsys):
    """The user's path: steval emulate --commands, then steval compare: bit-exact, the changes listed."""
    from support.cli import run_cli

    script = tmp_path / "cmds.txt"
    script.write_text("# time (s) command\n3.6 set ki 1.0\n4.4 correction off\n")
    out = tmp_path / "live.stv"
    code, stdout, stderr = run_cli(
        monkeypatch,
        capsys,
        "emulate",
        fw,
        "--scenario",
        "hand-tilts",
        "--duration",
        "5.2",
        "--commands",
        script,
        "--out",
        out,
        "--no-view",
    )
    assert code == 0, stderr
    assert "set ki 1: accepted, applies from step" in stderr and "correction off: accepted" in stderr
    cap = read_capture(out)
    assert cap.host and cap.header["format_version"] == 2
    code, stdout, stderr = run_cli(monkeypatch, capsys, "compare", out)
    assert code == 0, stderr
    assert "bit-exact on every step" in stdout
    assert "ki 0.1 → 1" in stdout and "correction on → off" in stdout


def test_instruction_cost_of_the_command_check_is_tiny(fw):
    """With no command on RX, the command check after each step costs a few instructions (measured)."""
    emu = _emulation(fw, "bench", 3.6)
    b, e = emu.board, emu.elf
    counts = []
    start = {}

    def enter(board):
        start["n"] = board.instructions_now()
        start["lr"] = board.reg(board.regs.LR) & ~1

    def next_entry(board):
        start["c"] = board.instructions_now()

    b.probe(e.addr("stv_cmd_next"), next_entry)

    def after_next(board):
        if "c" in start:
            counts.append(board.instructions_now() - start.pop("c"))

    # the instruction after the call: stv_cmd_next returns to stv_fw_step_end; probe its return address once seen
    seen = set()

    def on_next(board):
        lr = board.reg(board.regs.LR) & ~1
        if lr not in seen:
            seen.add(lr)
            b.probe(lr, after_next)

    b.probe(e.addr("stv_cmd_next"), on_next)
    emu.run()
    assert counts, "stv_cmd_next never ran"
    assert max(counts) <= 40, counts[:10]

"""Protocol v2 (issue #16): CRC-32 frames, the plausibility gate, the new frame types, and v1 captures decoding
exactly as before."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from support.streams import stream_decode

from steval_link.analysis.compare import compare_capture
from steval_link.analysis.summary import format_summary, summarize
from steval_link.emulation.line_damage import damage, long_stream, payload_records, score
from steval_link.link import protocol as P
from steval_link.link.decoder import decode_bytes
from steval_link.link.frames import AckFrame, AttitudeFrame, CommandFrame, FlightFrame
from steval_link.link.load import load_telemetry
from steval_link.link.plausibility import PlausibilityGate

ROOT = Path(__file__).resolve().parents[1]
V1 = ROOT / "tests" / "data" / "v1"
PERIOD_US = 6190.476


def att(seq: int, t_us: int | None = None, acc=(0.0, 0.0, 1000.0)) -> bytes:
    t_us = int(seq * PERIOD_US) if t_us is None else t_us
    return P.encode_attitude(
        t_us=t_us, acc_mg=acc, gyro_mdps=[1, 2, 3], q_wxyz=[0.9983, 0, 0, 0], thz_rad=0, seq=seq, thr=0
    )


# ---------------------------------------------------------------------------------------------- v1 as before


# Decoded by the v1 decoder (commit 012847d) before protocol v2: the stats and a hash of the attitude rows.
V1_BEFORE = {
    "freefall.stv": (
        dict(
            frames_ok=1160,
            attitude=1133,
            status=6,
            text=21,
            crc_failures=0,
            bytes_skipped=12,
            seq_gaps=0,
            frames_missing=0,
            seq_resets=0,
            unknown_frames=0,
            bytes_total=67157,
        ),
        "c84b3c4019120fe8",
    ),
    "midflight_drops.stv": (
        dict(
            frames_ok=3235,
            attitude=3215,
            status=20,
            text=0,
            crc_failures=0,
            bytes_skipped=45,
            seq_gaps=10,
            frames_missing=14,
            seq_resets=0,
            unknown_frames=0,
            bytes_total=188395,
        ),
        "138e273339ea531c",
    ),
}


@pytest.mark.parametrize("name", sorted(V1_BEFORE))
def test_v1_captures_decode_exactly_as_before(name):
    tel = load_telemetry(V1 / name)
    stats, digest = V1_BEFORE[name]
    got = tel.stats.as_dict()
    assert {k: got[k] for k in stats} == stats
    assert got["v1_frames"] == stats["frames_ok"] and got["implausible"] == 0
    a = tel.attitude
    assert (
        hashlib.sha256(a.q_wxyz.tobytes() + a.acc_mg.tobytes() + a.step.tobytes() + a.t_us.tobytes()).hexdigest()[:16]
        == digest
    )
    # bit-exact comparisons unchanged
    replica = compare_capture(tel, estimators=()).replica
    assert replica.all_exact and replica.bit_exact == replica.seeded > 0
    # the replay summary states v1's known limit; a v2 capture does not carry that line
    text = "\n".join(format_summary(summarize(tel)))
    assert "protocol v1" in text and "65 536" in text
    assert "protocol v1" not in "\n".join(format_summary(summarize(load_telemetry(ROOT / "recordings/demo.stv"))))


def test_bundled_recordings_are_v2_and_bit_exact():
    tel = load_telemetry(ROOT / "recordings" / "demo.stv")
    assert tel.stats.v1_frames == 0 and tel.stats.implausible == 0 and tel.stats.attitude == 9210
    assert (tel.status.fw_version == [2, 0]).all()
    assert compare_capture(tel, estimators=()).replica.all_exact


# ---------------------------------------------------------------------------------------------- fuzzing


@pytest.fixture(scope="module")
def demo_payloads():
    return payload_records(load_telemetry(ROOT / "recordings" / "demo.stv"))


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@pytest.mark.parametrize("seed", [11, 12, 13])
def test_loose_wire_fuzz_gives_no_fake_frame_and_recovers_most(demo_payloads, seed):
    """The fast, derandomised version of benchmarks/bench_fuzz.py (which runs >= 10^7 frames with fresh seeds)."""
    att_rec, sta_rec = demo_payloads
    data, payloads = long_stream(att_rec, sta_rec, 20_000, start_rep=seed)
    hurt, counts = damage(data, np.random.default_rng(seed))
    assert counts.flips and counts.cuts and counts.bursts
    tel = decode_bytes(hurt)
    sc, fakes = score(payloads, tel)
    assert sc.fake == 0, fakes[:3]
    assert sc.recovered_ratio >= 0.93
    # the incremental decoder hands out the same frames
    frames, stats = stream_decode(hurt, 997)
    assert stats.as_dict() == tel.stats.as_dict()
    assert [f.offset for f in frames if isinstance(f, AttitudeFrame)] == tel.attitude.offset.tolist()


def test_a_crc16_collision_cannot_pass_in_a_v2_stream():
    """v1's weak check is not a back door: once v2 frames were seen, a v1 frame (here a genuine one) is refused."""
    v1 = P.encode_frame(P.TYPE_ATTITUDE, att(5)[4:56], version=1)
    data = att(3) + att(4) + v1 + att(6)
    tel = decode_bytes(data)
    assert tel.attitude.seq.tolist() == [3, 4, 6] and tel.stats.v1_frames == 0
    frames, _ = stream_decode(data, 7)
    assert [f.seq for f in frames] == [3, 4, 6]


# ---------------------------------------------------------------------------------------------- plausibility


def test_impossible_values_are_held_back_on_v1_and_kept_flagged_on_v2():
    bad = [
        att(10, acc=(3.3e28, 0, 1000)),
        att(11, acc=(np.nan, 0, 1000)),
        P.encode_attitude(
            t_us=int(12 * PERIOD_US),
            acc_mg=[0, 0, 1000],
            gyro_mdps=[0, 0, 0],
            q_wxyz=[7.0, 0, 0, 0],
            thz_rad=0,
            seq=12,
            thr=0,
        ),
    ]
    frames_v2 = [att(i) for i in range(10)] + bad + [att(i) for i in range(13, 20)]
    # protocol v1 (CRC-16): the values guard the weak check, the three frames are held back
    data = b"".join(P.encode_frame(P.TYPE_ATTITUDE, f[4:56], version=1) for f in frames_v2)
    tel = decode_bytes(data)
    assert tel.attitude.seq.tolist() == list(range(10)) + list(range(13, 20))
    assert tel.stats.implausible == 3 and tel.stats.crc_failures == 0 and tel.stats.values_bad == 0
    frames, stats = stream_decode(data, 13)
    assert stats.as_dict() == tel.stats.as_dict()
    # protocol v2 (CRC-32): what the firmware sent is kept and flagged (issue #24)
    data = b"".join(frames_v2)
    tel = decode_bytes(data)
    assert tel.attitude.seq.tolist() == list(range(20))
    assert tel.attitude.values_bad.tolist() == [False] * 10 + [True] * 3 + [False] * 7
    assert tel.stats.implausible == 0 and tel.stats.values_bad == 3
    frames, stats = stream_decode(data, 13)
    assert stats.as_dict() == tel.stats.as_dict()


def test_out_of_sequence_frame_is_held_back_a_restart_is_followed():
    seqs = list(range(100, 110))
    data = b"".join(att(s) for s in seqs)
    data += att(40000, t_us=123)  # a CRC-valid frame from nowhere: seq and time do not continue
    data += b"".join(att(s) for s in range(110, 120))
    # firmware restart: seq and time start again; three frames that fit each other are the new timeline
    data += b"".join(att(s, t_us=2_000 + int(s * PERIOD_US)) for s in range(0, 6))
    tel = decode_bytes(data)
    assert tel.attitude.seq.tolist() == list(range(100, 120)) + list(range(6))
    assert tel.stats.implausible == 1 and tel.stats.seq_resets == 1
    frames, stats = stream_decode(data, 50)
    assert [f.seq for f in frames] == tel.attitude.seq.tolist() and stats.as_dict() == tel.stats.as_dict()


def test_status_must_fit_the_attitude_before_it():
    data = att(200) + P.encode_status(step=200, t_us=int(200 * PERIOD_US), q_wxyz=[1, 0, 0, 0], int_xyz=[0, 0, 0])
    data += att(201) + P.encode_status(step=9_000_000, t_us=5, q_wxyz=[1, 0, 0, 0], int_xyz=[0, 0, 0])
    data += att(202)
    tel = decode_bytes(data)
    assert tel.status.step.tolist() == [200] and tel.stats.implausible == 1


def test_gate_allows_skipped_steps_and_long_gaps_within_the_window():
    g = PlausibilityGate()
    assert g.offer(0, 10, int(10 * PERIOD_US), True, "a") == ["a"]
    # the main loop late by one tick period: d = 1 but almost two periods passed
    assert g.offer(0, 11, int(12 * PERIOD_US), True, "b") == ["b"]
    # 5000 steps lost on the link: still the same timeline
    assert g.offer(0, 5011, int(5012 * PERIOD_US), True, "c") == ["c"]
    # time going backwards is not
    assert g.offer(0, 5012, int(100 * PERIOD_US), True, "d") == []


# ---------------------------------------------------------------------------------------------- new frames


def test_flight_ack_and_command_frames_decode_in_both_decoders():
    fc = P.encode_flight(
        step=77,
        euler_rc_rad=[0.1, -0.2, 0.3],
        rc=[-5, 6, 7, 400],
        outer_s1=[1, 2, 3],
        inner_s2=[4, 5, 6],
        motor_pwm=[700, 710, 720, 730],
        vbat_v=3.9,
        fc_flags=3,
        fc_every=23,
    )
    ack = P.encode_ack(cmd_seq=9, cmd=P.CMD_SET_PARAM, result=P.ACK_REFUSED_ARMED, step=78, rx_ok=4, rx_bad=2)
    cmd = P.encode_command(cmd_seq=9, cmd=P.CMD_SET_PARAM, param=P.PARAM_KI, value=1.0)
    data = att(77) + fc + ack + cmd + att(78)
    frames, stats = stream_decode(data, 5)
    kinds = [type(f) for f in frames]
    assert kinds == [AttitudeFrame, FlightFrame, AckFrame, CommandFrame, AttitudeFrame]
    f = frames[1]
    assert (f.step, f.rc, f.motor_pwm, f.fc_flags, f.fc_every) == (77, (-5, 6, 7, 400), (700, 710, 720, 730), 3, 23)
    assert np.float32(f.vbat_v) == np.float32(3.9) and frames[2].result == P.ACK_REFUSED_ARMED
    assert (frames[3].cmd, frames[3].param, frames[3].value) == (P.CMD_SET_PARAM, P.PARAM_KI, 1.0)
    tel = decode_bytes(data)
    assert tel.stats.as_dict() == stats.as_dict() and (stats.flight, stats.ack, stats.command) == (1, 1, 1)
    assert tel.flight["step"].tolist() == [77] and tel.flight["rc"][0].tolist() == [-5, 6, 7, 400]
    assert tel.acks["cmd_seq"].tolist() == [9] and tel.commands["value"].tolist() == [1.0]

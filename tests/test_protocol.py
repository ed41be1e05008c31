"""protocol.py against PROTOCOL.md: sizes, offsets, CRC, encoder byte layout."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from steval_link.link import protocol as P


def test_crc_check_values():
    assert P.crc32(b"123456789") == 0xCBF43926  # CRC-32/ISO-HDLC check value (v2)
    assert P.crc16(b"123456789") == 0x29B1  # CRC-16/CCITT-FALSE check value (v1)


def test_attitude_payload_offsets_match_protocol_table():
    offs = {name: P.ATTITUDE_DTYPE.fields[name][1] for name in P.ATTITUDE_DTYPE.names}
    assert offs == {"t_us": 0, "acc_mg": 4, "gyro_mdps": 16, "q_wxyz": 28, "thz_rad": 44, "seq": 48, "thr": 50}
    assert P.ATTITUDE_FRAME_SIZE == 60 and P.ATTITUDE_FRAME_SIZE_V1 == 58


def test_status_payload_offsets_match_protocol_table():
    offs = {name: P.STATUS_DTYPE.fields[name][1] for name in P.STATUS_DTYPE.names}
    assert offs == {
        "step": 0,
        "t_us": 4,
        "q_wxyz": 8,
        "int_xyz": 24,
        "kp_ground": 36,
        "kp_flight": 40,
        "ki": 44,
        "dt_s": 48,
        "cyc_min": 52,
        "cyc_mean": 56,
        "cyc_max": 60,
        "cpu_hz": 64,
        "tx_dropped": 68,
        "baud": 72,
        "cyc_n": 76,
        "min_thr": 78,
        "flags": 80,
        "queue_peak": 82,
        "fw_version": 84,
        "fc_every": 86,
        "param_gen": 87,
    }
    assert P.STATUS_FRAME_SIZE == 96 and P.STATUS_FRAME_SIZE_V1 == 94


def test_flight_ack_command_offsets_match_protocol_table():
    def offs(dt):
        return {name: dt.fields[name][1] for name in dt.names}

    assert offs(P.FLIGHT_DTYPE) == {
        "step": 0,
        "euler_rc_rad": 4,
        "rc": 16,
        "outer_s1": 24,
        "inner_s2": 36,
        "motor_pwm": 48,
        "vbat_v": 64,
        "fc_flags": 68,
        "fc_every": 70,
        "reserved": 71,
    }
    assert offs(P.ACK_DTYPE) == {"cmd_seq": 0, "cmd": 2, "result": 3, "step": 4, "rx_ok": 8, "rx_bad": 10}
    assert offs(P.COMMAND_DTYPE) == {"cmd_seq": 0, "cmd": 2, "param": 3, "value": 4, "reserved": 8}
    assert (P.FLIGHT_FRAME_SIZE, P.ACK_FRAME_SIZE, P.COMMAND_FRAME_SIZE) == (80, 20, 20)


def test_attitude_frame_bytes():
    f = P.encode_attitude(
        t_us=0x01020304, acc_mg=[1, 2, 3], gyro_mdps=[4, 5, 6], q_wxyz=[1, 0, 0, 0], thz_rad=0.5, seq=0x1234, thr=-2
    )
    assert f[:4] == b"\xa5\x5a\x21\x34"
    assert f[4:8] == b"\x04\x03\x02\x01"  # little-endian
    assert struct.unpack_from("<3f", f, 8) == (1.0, 2.0, 3.0)
    assert struct.unpack_from("<Hh", f, 4 + 48) == (0x1234, -2)
    assert len(f) == 60 and struct.unpack_from("<I", f, 56)[0] == P.crc32(f[2:56])
    v1 = P.encode_frame(P.TYPE_ATTITUDE, f[4:56], version=1)
    assert v1[2] == 0x11 and len(v1) == 58 and struct.unpack_from("<H", v1, 56)[0] == P.crc16(v1[2:56])


def test_encode_attitude_block_equals_single_frames():
    rng = np.random.default_rng(0)
    rec = np.zeros(50, P.ATTITUDE_DTYPE)
    rec["acc_mg"] = rng.normal(size=(50, 3))
    rec["seq"] = np.arange(50)
    single = b"".join(
        P.encode_attitude(
            t_us=int(r["t_us"]),
            acc_mg=r["acc_mg"],
            gyro_mdps=r["gyro_mdps"],
            q_wxyz=r["q_wxyz"],
            thz_rad=r["thz_rad"],
            seq=int(r["seq"]),
            thr=int(r["thr"]),
        )
        for r in rec
    )
    assert P.encode_attitude_block(rec) == single
    v1 = P.encode_attitude_block(rec, version=1)
    assert v1 == b"".join(P.encode_frame(P.TYPE_ATTITUDE, r.tobytes(), version=1) for r in rec)


def test_text_frames_split_at_255_bytes():
    data = P.encode_text("x" * 600)
    assert len(data) == 3 * 8 + 600
    assert data[3] == 255 and data[2] == 0x23
    with pytest.raises(ValueError):
        P.encode_frame(P.TYPE_TEXT, b"y" * 256)

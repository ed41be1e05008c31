"""StreamDecoder and decode_bytes on real bytes: frames, counters, resync, bounded memory, bulk == stream."""

from __future__ import annotations

import numpy as np
import pytest
from support.streams import StreamBuilder, frame_keys, stream_decode

from steval_link.link import protocol as P
from steval_link.link.decoder import StreamDecoder, decode_bytes
from steval_link.link.frames import AttitudeFrame, StatusFrame, TextFrame
from steval_link.link.telemetry import telemetry_from_frames

FS = P.ATTITUDE_FRAME_SIZE  # 60 bytes in protocol v2


def assert_bulk_equals_stream(data: bytes):
    frames, stats = stream_decode(data, 97)
    tel = decode_bytes(data)
    assert tel.stats.as_dict() == stats.as_dict()
    ref = telemetry_from_frames(frames, stats)
    for name in (
        "step",
        "seq",
        "t_us",
        "t_fw_s",
        "acc_mg",
        "gyro_mdps",
        "thr",
        "q_wxyz",
        "thz_rad",
        "thx_rad",
        "thy_rad",
        "exact",
        "offset",
    ):
        np.testing.assert_array_equal(getattr(tel.attitude, name), getattr(ref.attitude, name), err_msg=name)
    for name in ("step", "t_us", "ki", "cyc_mean", "offset", "exact", "t_fw_s"):
        np.testing.assert_array_equal(getattr(tel.status, name), getattr(ref.status, name), err_msg=name)
    assert [t for _, t in tel.text] == [t for _, t in ref.text]
    return tel, frames, stats


def test_clean_stream_all_frame_kinds(stream: StreamBuilder):
    stream.text("STEVAL-FCU001V1 boot")
    stream.flight(500, text_every=200)
    data = stream.bytes()
    frames, stats = stream_decode(data)
    sent = [k for k, _, _ in stream.sent]
    assert [type(f).__name__[0].lower() for f in frames] == [k[0] for k in sent]
    assert stats.frames_ok == len(stream.sent)
    assert stats.attitude == 500 and stats.status == 3 and stats.text == 3
    assert stats.bytes_skipped == 0 and stats.crc_failures == 0 and stats.seq_gaps == 0
    assert stats.bytes_total == len(data)
    # offsets are the stream positions of each frame
    pos = 0
    for f, (_, fb, _) in zip(frames, stream.sent):
        assert f.offset == pos and f.nbytes == len(fb)
        pos += len(fb)
    assert isinstance(frames[0], TextFrame) and frames[0].text == "STEVAL-FCU001V1 boot"


def test_attitude_fields_are_exact_bits():
    acc = np.array([1.5e-7, -3.25, 1000.0001], np.float32)
    gyro = np.array([np.float32(np.pi), -0.0, 12345.678], np.float32)
    q = np.array([0.99830001, 0.0123, -0.0456, 0.0789], np.float32)
    data = P.encode_attitude(
        t_us=4294967295, acc_mg=acc, gyro_mdps=gyro, q_wxyz=q, thz_rad=np.float32(-1.25), seq=65535, thr=-32768
    )
    (f,) = StreamDecoder().feed(data)
    assert isinstance(f, AttitudeFrame) and f.exact
    assert np.array_equal(np.array(f.acc_mg, np.float32).view(np.uint32), acc.view(np.uint32))
    assert np.array_equal(np.array(f.gyro_mdps, np.float32).view(np.uint32), gyro.view(np.uint32))
    assert np.array_equal(np.array(f.q_wxyz, np.float32), q)
    assert (f.t_us, f.seq, f.thr, f.thz_rad) == (4294967295, 65535, -32768, -1.25)
    tel = decode_bytes(data)
    assert tel.attitude.acc_mg.tobytes() == acc.tobytes() and tel.attitude.q_wxyz.tobytes() == q.tobytes()


def test_status_fields():
    data = P.encode_status(
        step=123456,
        t_us=99,
        q_wxyz=[1, 0, 0, 0],
        int_xyz=[0.5, -0.25, 0],
        ki=1.0,
        cyc_min=1,
        cyc_mean=2,
        cyc_max=3,
        cyc_n=161,
        tx_dropped=7,
        baud=921600,
        flags=3,
        queue_peak=300,
        fw_version=(2, 1),
        fc_every=23,
        param_gen=4,
    )
    (f,) = StreamDecoder().feed(data)
    assert isinstance(f, StatusFrame)
    assert (
        f.step,
        f.t_us,
        f.ki,
        f.cyc_n,
        f.tx_dropped,
        f.baud,
        f.flags,
        f.queue_peak,
        f.fw_version,
        f.fc_every,
        f.param_gen,
    ) == (123456, 99, 1.0, 161, 7, 921600, 3, 300, (2, 1), 23, 4)
    assert f.int_xyz == (0.5, -0.25, 0.0) and f.kp_ground == 10.0 and f.min_thr == 200
    tel = decode_bytes(data)
    assert tel.status.step[0] == 123456 and tel.status.fw_version[0].tolist() == [2, 1]


@pytest.mark.parametrize("chunk", [1, 2, 3, 59, 60, 61, 1000, 10**6])
def test_any_chunking_gives_same_frames(stream: StreamBuilder, chunk: int):
    stream.flight(300, text_every=50)
    data = stream.bytes()
    ref, ref_stats = stream_decode(data, len(data))
    frames, stats = stream_decode(data, chunk)
    assert frame_keys(frames) == frame_keys(ref)
    assert stats == ref_stats


def test_mid_stream_start_resyncs_within_one_frame(stream: StreamBuilder):
    stream.flight(100, status_every=0)
    data = stream.bytes()
    for cut in (1, 13, FS - 1, FS + 30):
        frames, stats = stream_decode(data[cut:], 7)
        first_full = -(-cut // FS)
        assert [f.seq for f in frames] == list(range(first_full, 100))
        assert stats.bytes_skipped == first_full * FS - cut


def test_corrupted_frame_is_dropped_and_counted(stream: StreamBuilder):
    stream.flight(50, status_every=0)
    data = bytearray(stream.bytes())
    data[10 * FS + 20] ^= 0x04  # payload bit flip in frame 10
    data[20 * FS + 57] ^= 0x80  # CRC bit flip in frame 20
    frames, stats = stream_decode(bytes(data), 5)
    assert [f.seq for f in frames] == [i for i in range(50) if i not in (10, 20)]
    assert stats.crc_failures == 2
    assert stats.seq_gaps == 2 and stats.frames_missing == 2
    assert stats.bytes_skipped == 2 * FS
    assert_bulk_equals_stream(bytes(data))


def test_frame_inside_damaged_frame_is_recovered(stream: StreamBuilder):
    """A frame whose bytes start inside the remains of a truncated frame is still found (discard one byte)."""
    stream.flight(10, status_every=0)
    data = stream.bytes()
    damaged = data[: 3 * FS + 30] + data[4 * FS :]  # frame 3 cut short, frame 4 follows directly
    frames, stats = stream_decode(damaged, 11)
    assert [f.seq for f in frames] == [0, 1, 2, 4, 5, 6, 7, 8, 9]
    assert stats.crc_failures == 1  # the truncated frame's header claims 52 bytes, its CRC fails
    assert stats.seq_gaps == 1 and stats.frames_missing == 1


def test_garbage_never_accumulates_and_yields_nothing():
    rng = np.random.default_rng(5)
    garbage = rng.integers(0, 256, 1_000_000, dtype=np.uint8).tobytes()
    sd = StreamDecoder()
    peak = 0
    got = []
    for i in range(0, len(garbage), 4096):
        got += sd.feed(garbage[i : i + 4096])
        peak = max(peak, sd.pending_bytes)
    got += sd.finish()
    assert peak <= 512
    assert not [f for f in got if not isinstance(f, TextFrame)]
    assert sd.stats.bytes_skipped + sum(f.nbytes for f in got) == len(garbage)


def test_pending_is_bounded_for_long_text_without_newline():
    sd = StreamDecoder()
    sd.feed(b"\n")
    for _ in range(100):
        sd.feed(b"x" * 100)
        assert sd.pending_bytes <= 512
    assert sd.finish() == []


def test_seq_wrap_gap_and_restart(make_stream):
    b = make_stream(2)
    for s in list(range(65530, 65536)) + list(range(0, 5)) + [9, 10]:  # wrap, then 4 missing
        b.attitude(s)
    for s in range(0, 3):  # firmware restart: three frames that fit each other are taken as the new timeline
        b.attitude(s, t_us=1000 + 6190 * s)
    data = b.bytes()
    tel, frames, stats = assert_bulk_equals_stream(data)
    assert (stats.seq_gaps, stats.frames_missing, stats.seq_resets) == (1, 4, 1)
    steps = tel.attitude.step.tolist()
    assert steps[:13] == list(range(65530, 65541)) + [65545, 65546]
    assert steps[13:] == [0, 1, 2]


def test_status_anchors_absolute_step(make_stream):
    b = make_stream(3)
    base = 3 * 65536 + 100
    for s in range(base, base + 400):
        b.attitude(s)
        if s == base + 250:
            b.status(s)
    tel, _, _ = assert_bulk_equals_stream(b.bytes())
    assert tel.attitude.step.tolist() == list(range(base, base + 400))
    assert tel.status.step.tolist() == [base + 250]


def test_firmware_time_unwraps_at_2_32_us(make_stream):
    b = make_stream(4)
    t0 = P.T_US_MODULUS - 3 * 6192
    for i in range(8):
        b.attitude(i, t_us=(t0 + i * 6192) % P.T_US_MODULUS)
    tel, _, _ = assert_bulk_equals_stream(b.bytes())
    dt = np.diff(tel.attitude.t_fw_s)
    np.testing.assert_allclose(dt, 0.006192, atol=1e-9)
    assert tel.attitude.t_fw_s[-1] > P.T_US_MODULUS / 1e6


def test_unknown_type_bad_version_and_v1_after_v2_are_skipped(stream: StreamBuilder):
    stream.attitude(0)
    future = P.encode_frame(7, b"\x01\x02\x03")  # version 2, type 7: CRC-valid, unknown
    stream.parts.append(future)
    v3 = bytearray(stream.attitude(1))
    stream.parts.pop()
    v3[2] = 0x31  # version 3 does not exist
    stream.parts.append(bytes(v3))
    v1 = P.encode_frame(P.TYPE_ATTITUDE, bytes(v3[4:56]), version=1)  # a valid v1 frame inside a v2 stream
    stream.parts.append(v1)
    stream.attitude(2)
    data = stream.bytes()
    tel, frames, stats = assert_bulk_equals_stream(data)
    assert [f.seq for f in frames] == [0, 2]
    assert stats.unknown_frames == 1 and stats.crc_failures == 0 and stats.v1_frames == 0
    assert stats.bytes_skipped == len(future) + len(v3) + len(v1)


def test_sync_bytes_inside_payload_are_harmless():
    acc = np.frombuffer(b"\xa5\x5a\x21\x34" * 3, np.float32)  # payload holds a fake header
    frames = b"".join(
        P.encode_attitude(t_us=6190 * i, acc_mg=acc, gyro_mdps=acc, q_wxyz=[1, 0, 0, 0], thz_rad=0, seq=i, thr=0)
        for i in range(20)
    )
    tel, got, stats = assert_bulk_equals_stream(frames)
    assert [f.seq for f in got] == list(range(20))
    assert stats.bytes_skipped == 0
    # and when a frame before it is damaged, the fake headers are rejected, the next real frame found
    damaged = bytearray(frames)
    damaged[3] = 0x00
    tel, got, stats = assert_bulk_equals_stream(bytes(damaged))
    assert [f.seq for f in got] == list(range(1, 20))


def test_bulk_equals_stream_on_damaged_mixed_input(make_stream):
    b = make_stream(6)
    b.log_line("boot banner")
    for i in range(400):
        b.attitude(i)
        if i % 100 == 99:
            b.status(i)
        if i % 37 == 0:
            b.att_line(i)
        if i % 91 == 0:
            b.log_line(f"plain log {i}")
    data = bytearray(b.bytes())
    rng = np.random.default_rng(9)
    for pos in rng.integers(0, len(data), 40):
        data[pos] ^= 1 << int(rng.integers(8))
    data[5000:5000] = rng.integers(0, 256, 300, dtype=np.uint8).tobytes()
    del data[9000:9100]
    assert_bulk_equals_stream(bytes(data))


def test_host_times_from_chunks(stream: StreamBuilder):
    stream.flight(10, status_every=0)
    data = stream.bytes()
    offs = np.array([0, 2 * FS, 300], np.int64)  # chunks end after frames 1, mid frame 5, at the end
    times = np.array([1.0, 2.0, 3.0])
    tel = decode_bytes(data, (offs, times))
    last = tel.attitude.offset + FS - 1
    expect = np.where(last < 2 * FS, 1.0, np.where(last < 300, 2.0, 3.0))
    np.testing.assert_array_equal(tel.attitude.t_host_s, expect)
    tel_b = decode_bytes(data, (offs, times), baud=115200)
    # the frame completed last in chunk 0 gets the chunk's time; earlier ones are earlier by 10 bit times/byte
    assert tel_b.attitude.t_host_s[1] == 1.0
    assert tel_b.attitude.t_host_s[0] == pytest.approx(1.0 - FS * 10 / 115200)
    assert np.all(np.diff(tel_b.attitude.t_host_s) >= 0)


def test_firmware_euler_angles_for_binary_rows(stream: StreamBuilder):
    from steval_link.estimators.st_mahony import quaternion_to_euler

    stream.flight(20, status_every=0)
    tel = decode_bytes(stream.bytes())
    thx, thy = quaternion_to_euler(tel.attitude.q_wxyz)
    assert tel.attitude.thx_rad.tobytes() == thx.tobytes() and tel.attitude.thy_rad.tobytes() == thy.tobytes()


def test_attitude_table_columns(stream: StreamBuilder):
    stream.flight(30)
    tel = decode_bytes(stream.bytes())
    table = tel.attitude_table()
    assert all(np.ndim(c) == 1 and len(c) == 30 for c in table.values())
    for name in ("t_fw_s", "acc_x_mg", "gyro_z_mdps", "q_w", "thx_pitch_rad", "thy_roll_rad", "thz_yaw_rad"):
        assert name in table
    np.testing.assert_array_equal(table["acc_y_mg"], tel.attitude.acc_mg[:, 1])


def test_empty_input():
    tel = decode_bytes(b"")
    assert len(tel.attitude) == 0 and tel.stats.bytes_total == 0
    sd = StreamDecoder()
    assert sd.feed(b"") == [] and sd.finish() == []

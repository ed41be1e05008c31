"""Host tests of the firmware patch's C core (firmware_patch/src, built with the host gcc).

The C encoder and TX queue run on real bytes and the Python side decodes them: frames from C carry exactly the
float bits Python put in, the queue drops and counts instead of blocking, sequence number, timestamp and the
cycle counter wrap correctly, and ``host/stv_encode`` (which makes the bundled recordings) is byte-for-byte
``steval_link.link.protocol``'s encoder.
"""

from __future__ import annotations

import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from support.streams import stream_decode

from steval_link import constants as C
from steval_link.link import protocol as P
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AttitudeFrame, StatusFrame, TextFrame
from steval_link.link.textmode import parse_sentence

ROOT = Path(__file__).resolve().parents[1]
FW = ROOT / "firmware_patch"

pytestmark = pytest.mark.skipif(
    shutil.which("make") is None or shutil.which("gcc") is None, reason="needs make and gcc for the host build"
)


# ---- helpers ----------------------------------------------------------------------------------------------


def strict_split(data: bytes) -> list[tuple[int, bytes]]:
    """Split a stream that must consist of valid binary frames only, back to back (type, payload)."""
    out, p = [], 0
    while p < len(data):
        assert data[p : p + 2] == P.SYNC, f"no sync at byte {p}"
        vt, ln = data[p + 2], data[p + 3]
        assert vt >> 4 == P.VERSION
        end = p + 4 + ln
        crc = struct.unpack_from("<I", data, end)[0]
        assert crc == P.crc32(data[p + 2 : end]), f"bad CRC at byte {p}"
        out.append((vt & 0x0F, data[p + 4 : end]))
        p = end + P.CRC_SIZE
    return out


def decode_all(data: bytes) -> tuple[list, object]:
    """The project's decoder on the C link's output. The host runs feed the link made-up cycle counts and values, not
    the AHRS rhythm, so the plausibility gate (tested on its own) is off here: this checks the framing."""
    return stream_decode(data, 977, plausibility=False)  # odd chunking: frames straddle feed() calls


def random_f32_bits(rng: np.random.Generator, n: int) -> np.ndarray:
    """float32 values with arbitrary bit patterns plus the special ones (NaNs with payloads, inf, -0, denormals)."""
    bits = rng.integers(0, 1 << 32, n, dtype=np.uint64).astype(np.uint32)
    special = np.array(
        [0x7FC00001, 0x7F800001, 0xFFFFFFFF, 0x7F800000, 0xFF800000, 0x80000000, 0x00000001, 0x007FFFFF, 0x3F800000],
        dtype=np.uint32,
    )
    bits[: min(n, len(special))] = special[: min(n, len(special))]
    return bits.view(np.float32)


# ---- C self-test ------------------------------------------------------------------------------------------


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_c_selftest(host_build):
    """CRC (slice-by-4 == bitwise, aligned and not), queue full/drop/wrap of 2^32 indices, µs accumulation, logs."""
    r = subprocess.run([host_build / "test_stv", "selftest"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("ok ")


# ---- stv_encode: C encoder == Python encoder ------------------------------------------------------------------


def make_requests(rng: np.random.Generator, n: int) -> tuple[bytes, bytes]:
    """Random frame requests and the frames steval_link.link.protocol makes of them."""
    req, exp = bytearray(), bytearray()
    for i in range(n):
        kind = i % 5
        if kind < 3:
            rec = np.zeros((), P.ATTITUDE_DTYPE)
            rec["t_us"] = rng.integers(0, 1 << 32)
            rec["acc_mg"] = random_f32_bits(rng, 3)
            rec["gyro_mdps"] = random_f32_bits(rng, 3)
            rec["q_wxyz"] = random_f32_bits(rng, 4)
            rec["thz_rad"] = random_f32_bits(rng, 1)[0]
            rec["seq"] = rng.integers(0, 1 << 16)
            rec["thr"] = rng.integers(-32768, 32768)
            payload = rec.tobytes()
            exp += P.encode_attitude(
                t_us=int(rec["t_us"]),
                acc_mg=rec["acc_mg"],
                gyro_mdps=rec["gyro_mdps"],
                q_wxyz=rec["q_wxyz"],
                thz_rad=rec["thz_rad"],
                seq=int(rec["seq"]),
                thr=int(rec["thr"]),
            )
        elif kind == 3:
            payload = rng.integers(0, 256, P.STATUS_PAYLOAD_SIZE, dtype=np.uint8).tobytes()
            rec = np.frombuffer(payload, P.STATUS_DTYPE)[0]
            exp += P.encode_status(
                step=int(rec["step"]),
                t_us=int(rec["t_us"]),
                q_wxyz=rec["q_wxyz"],
                int_xyz=rec["int_xyz"],
                kp_ground=rec["kp_ground"],
                kp_flight=rec["kp_flight"],
                ki=rec["ki"],
                dt_s=rec["dt_s"],
                cyc_min=int(rec["cyc_min"]),
                cyc_mean=int(rec["cyc_mean"]),
                cyc_max=int(rec["cyc_max"]),
                cyc_n=int(rec["cyc_n"]),
                cpu_hz=int(rec["cpu_hz"]),
                tx_dropped=int(rec["tx_dropped"]),
                baud=int(rec["baud"]),
                min_thr=int(rec["min_thr"]),
                flags=int(rec["flags"]),
                queue_peak=int(rec["queue_peak"]),
                fw_version=tuple(int(x) for x in rec["fw_version"]),
                fc_every=int(rec["fc_every"]),
                param_gen=int(rec["param_gen"]),
            )
            req += bytes([P.TYPE_STATUS, len(payload)]) + payload
            continue
        else:
            n_chars = int(rng.choice([1, 7, 80, 254, 255]))
            text = "".join(rng.choice(list("abcXYZ 09:;,.-_°µ")) for _ in range(n_chars))
            payload = text.encode("utf-8")[:255]
            exp += P.encode_frame(P.TYPE_TEXT, payload)
            req += bytes([P.TYPE_TEXT, len(payload)]) + payload
            continue
        req += bytes([P.TYPE_ATTITUDE, len(payload)]) + payload
    return bytes(req), bytes(exp)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_stv_encode_equals_python_encoder(host_build):
    rng = np.random.default_rng(20240601)
    req, exp = make_requests(rng, 3000)  # > 64 KiB of input: requests straddle stv_encode's read buffer
    assert len(req) > 1 << 16
    r = subprocess.run([host_build / "stv_encode"], input=req, capture_output=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout == exp


def test_stv_encode_float_bits_survive_decoding(host_build):
    """Frames from C decode in Python to the very float bits that went in (NaN payloads, -0, denormals)."""
    rng = np.random.default_rng(7)
    recs = np.zeros(64, P.ATTITUDE_DTYPE)
    recs["t_us"] = rng.integers(0, 1 << 32, 64)
    recs["acc_mg"] = random_f32_bits(rng, 192).reshape(64, 3)
    recs["gyro_mdps"] = random_f32_bits(rng, 192).reshape(64, 3)
    recs["q_wxyz"] = random_f32_bits(rng, 256).reshape(64, 4)
    recs["thz_rad"] = random_f32_bits(rng, 64)
    recs["seq"] = np.arange(64)
    recs["thr"] = rng.integers(-32768, 32768, 64)
    req = b"".join(bytes([1, 52]) + r.tobytes() for r in recs)
    out = subprocess.run([host_build / "stv_encode"], input=req, capture_output=True, check=True).stdout
    frames = strict_split(out)
    got = np.frombuffer(b"".join(p for _, p in frames), P.ATTITUDE_DTYPE)
    assert got.tobytes() == recs.tobytes()  # bit-exact, field by field
    decoded, stats = decode_all(out)
    assert stats.attitude == 64 and stats.bytes_skipped == 0
    for f, r in zip(decoded, recs):
        assert np.array(f.acc_mg, np.float32).view(np.uint32).tolist() == r["acc_mg"].view(np.uint32).tolist() or (
            np.isnan(r["acc_mg"]).any()  # Python floats keep NaN-ness; exact NaN payload bits are checked above
        )


@pytest.mark.parametrize(
    "req, message",
    [
        (bytes([9, 0]), "unknown frame type 9"),
        (bytes([1, 51]) + bytes(51), "needs a 52-byte payload"),
        (bytes([2, 52]) + bytes(52), "needs a 88-byte payload"),
        (bytes([1, 52]) + bytes(20), "ends inside the request"),
    ],
)
def test_stv_encode_bad_input_is_one_clear_line(host_build, req, message):
    good = bytes([3, 2]) + b"ok"
    r = subprocess.run([host_build / "stv_encode"], input=good + req, capture_output=True)
    assert r.returncode == 2
    assert message in r.stderr.decode()
    assert len(r.stderr.decode().strip().splitlines()) == 1
    assert r.stdout == P.encode_text("ok")  # frames before the bad request are already out


# ---- the link core, driven like the firmware main loop ---------------------------------------------------------


def cmd_config(
    *,
    text_mode=0,
    decimation=16,
    status_every=162,
    cpu_hz=84_000_000,
    baud=115200,
    ki=0.1,
    flags=0,
    cyc0=0,
    t_us0=0,
    step0=0,
) -> bytes:
    return b"C" + struct.pack(
        "<BIIIIfHIII", text_mode, decimation, status_every, cpu_hz, baud, ki, flags, cyc0, t_us0, step0
    )


def cmd_step(c0, c1, thr, acc, gyro, q, eul, sq, si) -> bytes:
    return (
        b"S"
        + struct.pack("<IIh", c0 % (1 << 32), c1 % (1 << 32), thr)
        + np.concatenate([acc, gyro, q, eul, sq, si]).astype(np.float32).tobytes()
    )


def cmd_drain(n) -> bytes:
    return b"D" + struct.pack("<I", n)


def cmd_log(text: bytes) -> bytes:
    return b"L" + struct.pack("<H", len(text)) + text


def run_link(host_build: Path, commands: bytes) -> tuple[bytes, dict[str, int]]:
    r = subprocess.run([host_build / "test_stv", "link"], input=commands, capture_output=True, check=True)
    info = dict(kv.split("=") for kv in r.stderr.decode().split())
    return r.stdout, {k: int(v) for k, v in info.items()}


class Steps:
    """Deterministic AHRS step inputs and cycle counter readings (6.19 ms steps, jittered, 84 MHz)."""

    def __init__(self, n, cyc0, seed=1):
        rng = np.random.default_rng(seed)
        self.acc = random_f32_bits(rng, n * 3).reshape(n, 3)
        self.gyro = random_f32_bits(rng, n * 3).reshape(n, 3)
        self.q = random_f32_bits(rng, n * 4).reshape(n, 4)
        self.eul = rng.normal(0, 1, (n, 3)).astype(np.float32)
        self.sq = random_f32_bits(rng, n * 4).reshape(n, 4)
        self.si = random_f32_bits(rng, n * 3).reshape(n, 3)
        self.thr = rng.integers(-300, 1500, n)
        period = rng.integers(519_000, 521_000, n)
        self.begin = cyc0 + np.concatenate([[7], np.cumsum(period)[:-1] + 7]).astype(np.int64)
        self.cycles = rng.integers(3000, 9000, n)
        self.end = self.begin + self.cycles

    def command(self, i) -> bytes:
        return cmd_step(
            int(self.begin[i]),
            int(self.end[i]),
            int(self.thr[i]),
            self.acc[i],
            self.gyro[i],
            self.q[i],
            self.eul[i],
            self.sq[i],
            self.si[i],
        )


def bits(x) -> list[int]:
    return np.asarray(x, np.float32).view(np.uint32).tolist()


def test_link_stream_wraps_seq_time_and_cycle_counter(host_build):
    """seq 65535 -> 0, t_us 2^32 -> 0 and CYCCNT 2^32 -> 0 inside one stream; every value bit-exact."""
    n, every = 400, 50
    cyc0, t0, step0 = (1 << 32) - 1_000_000, (1 << 32) - 1_000_000, 65_400
    s = Steps(n, cyc0)
    cmds = cmd_config(status_every=every, cyc0=cyc0, t_us0=t0, step0=step0, ki=1.0, flags=1)
    for i in range(n):
        cmds += s.command(i) + cmd_drain(80)
    out, info = run_link(host_build, cmds)
    assert info["dropped"] == 0
    frames = strict_split(out)  # nothing but valid frames
    att = [np.frombuffer(p, P.ATTITUDE_DTYPE)[0] for t, p in frames if t == P.TYPE_ATTITUDE]
    sta = [(k, np.frombuffer(p, P.STATUS_DTYPE)[0]) for k, (t, p) in enumerate(frames) if t == P.TYPE_STATUS]
    assert len(att) == n and len(sta) == n // every

    # firmware time: floor(cycles since init / 84) µs, from t_us0, modulo 2^32
    t_expect = (t0 + (s.begin - cyc0) // 84) % (1 << 32)
    assert [int(a["t_us"]) for a in att] == t_expect.tolist()
    assert any(int(a["t_us"]) < t0 for a in att)  # t_us wrapped
    assert [int(a["seq"]) for a in att] == [(step0 + i) % 65536 for i in range(n)]
    for i, a in enumerate(att):
        assert bits(a["acc_mg"]) == bits(s.acc[i]) and bits(a["gyro_mdps"]) == bits(s.gyro[i])
        assert bits(a["q_wxyz"]) == bits(s.q[i]) and bits(a["thz_rad"]) == bits(s.eul[i, 2])
        assert int(a["thr"]) == s.thr[i]

    for j, (k, st) in enumerate(sta):
        last = (j + 1) * every - 1  # the status follows the attitude frame of the step it describes
        assert frames[k - 1][0] == P.TYPE_ATTITUDE and int(att[last]["seq"]) == (step0 + last) % 65536
        assert int(st["step"]) == step0 + last and int(st["t_us"]) == int(att[last]["t_us"])
        assert bits(st["q_wxyz"]) == bits(s.sq[last]) and bits(st["int_xyz"]) == bits(s.si[last])
        cyc = s.cycles[last + 1 - every : last + 1]
        assert (int(st["cyc_min"]), int(st["cyc_mean"]), int(st["cyc_max"]), int(st["cyc_n"])) == (
            cyc.min(),
            cyc.sum() // every,
            cyc.max(),
            every,
        )
        assert (float(st["ki"]), int(st["flags"]), int(st["baud"]), int(st["cpu_hz"])) == (1.0, 1, 115200, 84_000_000)
        assert (float(st["kp_ground"]), float(st["kp_flight"]), int(st["min_thr"])) == (10.0, np.float32(0.4), 200)
        assert float(st["dt_s"]) == np.float32(0.00625) and st["fw_version"].tolist() == [2, 0]
        assert int(st["tx_dropped"]) == 0 and 0 < int(st["queue_peak"]) < 2048

    decoded, stats = decode_all(out)  # the project's decoder agrees
    assert stats.attitude == n and stats.status == n // every and stats.bytes_skipped == 0 and stats.seq_gaps == 0


def test_link_full_queue_drops_and_counts_without_blocking(host_build):
    """No UART draining for 100 steps: what fits is queued whole, the rest is dropped and reported.

    Attitude frames leave room for one status frame (96 bytes) so the drop count still gets out.
    """
    s = Steps(150, 0)
    cmds = cmd_config(status_every=50)
    for i in range(100):
        cmds += s.command(i)  # never drained
    cmds += cmd_drain(1 << 20)
    for i in range(100, 150):
        cmds += s.command(i) + cmd_drain(1 << 20)
    out, info = run_link(host_build, cmds)
    frames = strict_split(out)  # dropped frames never leave a partial frame behind
    # 2048-byte queue: attitude frames while 60 + 96 bytes stay free -> 32 frames (1920 bytes)
    seqs = [int(np.frombuffer(p, P.ATTITUDE_DTYPE)[0]["seq"]) for t, p in frames if t == P.TYPE_ATTITUDE]
    assert seqs == list(range(32)) + list(range(100, 150))
    sta = [np.frombuffer(p, P.STATUS_DTYPE)[0] for t, p in frames if t == P.TYPE_STATUS]
    # the status after step 49 uses the reserve (reporting 17 drops so far); the one after step 99 finds no room
    assert [int(x["step"]) for x in sta] == [49, 149]
    assert int(sta[0]["tx_dropped"]) == 49 - 31 and int(sta[0]["queue_peak"]) == 32 * 60
    assert int(sta[1]["tx_dropped"]) == 69 and info["dropped"] == 69  # attitude 32..99 and status 99
    assert int(sta[1]["queue_peak"]) == 32 * 60 + 96  # still waiting when the previous status was taken
    decoded, stats = decode_all(out)
    assert stats.seq_gaps == 1 and stats.frames_missing == 68 and stats.bytes_skipped == 0


@pytest.mark.parametrize("baud, expect_drops", [(115200, False), (57600, True)])
def test_link_uart_model(host_build, baud, expect_drops):
    """UART draining baud/10 bytes/s between 161.5 Hz steps, with log lines: 115200 keeps up, 57600 drops."""
    n = 1500
    s = Steps(n, 0)
    per_step = baud / 10 / C.AHRS_RATE_HZ
    cmds, sent = cmd_config(status_every=162, baud=baud), 0.0
    for i in range(n):
        cmds += s.command(i)
        if i % 300 == 0:
            cmds += cmd_log(b"log line %d\r\n" % i)
        target = (i + 1) * per_step
        cmds += cmd_drain(int(target) - int(sent))
        sent = int(target)
    out, info = run_link(host_build, cmds)
    decoded, stats = decode_all(out)
    assert stats.bytes_skipped == 0 and stats.crc_failures == 0
    texts = [f.text for f in decoded if isinstance(f, TextFrame)]
    status = [f for f in decoded if isinstance(f, StatusFrame)]
    if expect_drops:
        assert info["dropped"] > 0 and stats.frames_missing > 0
        assert status and status[-1].tx_dropped > 0
    else:
        assert info["dropped"] == 0 and stats.attitude == n and stats.seq_gaps == 0
        assert texts == [f"log line {i}" for i in range(0, n, 300)]
        assert max(f.queue_peak for f in status) < 300  # the queue never fills at 82 % load


def test_link_text_mode_lines(host_build):
    """Text mode: decimated $ATT lines and $STA lines with valid checksums; log lines stay plain lines."""
    n, dec, every = 64, 4, 20
    s = Steps(n, 0)
    s.acc = np.array([[-12.9, 3.5, 1000.7]] * n, np.float32)
    s.gyro = np.array([[1e10, -1e10, np.nan]] * n, np.float32)  # saturate / NaN -> 0, never UB
    cmds = cmd_config(text_mode=1, decimation=dec, status_every=every, ki=0.1)
    cmds += cmd_log(b"$not a record\n")
    for i in range(n):
        cmds += s.command(i) + cmd_drain(1 << 20)
    out, info = run_link(host_build, cmds)
    lines = out.split(b"\r\n")
    assert lines[-1] == b""
    lines = lines[:-1]
    assert lines[0] == b"#not a record"
    att = [parse_sentence(ln) for ln in lines if ln.startswith(b"$ATT")]
    sta = [parse_sentence(ln) for ln in lines if ln.startswith(b"$STA")]
    assert len(att) == n // dec and len(sta) == n // every
    rad2mdeg = np.float32(57295.78)
    for f in att:
        assert isinstance(f, AttitudeFrame)
        i = f.step
        assert i % dec == 0
        assert f.acc_mg == (-12.0, 3.0, 1000.0) and f.gyro_mdps == (2147483647.0, -2147483648.0, 0.0)
        assert f.t_us == (int(s.begin[i]) // 84) // 1000 * 1000
        assert f.thr == s.thr[i]
        mdeg = [int(np.trunc(np.float32(v) * rad2mdeg)) for v in s.eul[i]]
        assert round(f.thx_rad / (np.pi / 180000)) == mdeg[0] and round(f.thy_rad / (np.pi / 180000)) == mdeg[1]
    for k, f in enumerate(sta):
        assert isinstance(f, StatusFrame) and f.step == (k + 1) * every - 1
        assert f.flags == P.FLAG_TEXT_MODE and f.ki == 0.1 and f.cyc_n == every
    decoded, stats = decode_all(out)
    assert stats.crc_failures == 0 and stats.attitude == n // dec and stats.status == n // every


# ---- bundled recordings are C-encoder output --------------------------------------------------------------------


def bundled_recordings() -> list[Path]:
    """The bundled serial captures (BLE captures carry ST's notifications, no frames of ours)."""
    from steval_link.link.ble_payloads import is_ble_source
    from steval_link.link.load import read_recording

    rec = ROOT / "recordings"
    return (
        sorted(p for p in rec.glob("*") if p.suffix in (".stv", ".bin") and not is_ble_source(read_recording(p)))
        if rec.is_dir()
        else []
    )


@pytest.mark.parametrize("path", bundled_recordings() or [None], ids=lambda p: p.name if p else "none")
def test_bundled_recording_frames_are_c_encoder_output(host_build, path):
    """Every valid binary frame of every bundled capture is exactly what stv_encode (the C encoder) makes of its
    payload: the recordings double as C -> Python conformance fixtures."""
    if path is None:
        pytest.skip("no bundled captures in recordings/ yet")
    from steval_link.link.load import read_recording

    data = read_recording(path).data
    dec = StreamDecoder()
    frames = dec.feed(data) + dec.finish()
    spans = [data[f.offset : f.offset + f.nbytes] for f in frames if getattr(f, "exact", True) and f.nbytes]
    binary = [s for s in spans if s[:2] == P.SYNC]
    if not binary:
        pytest.skip(f"{path.name} holds no binary frames (text mode)")
    req = b"".join(bytes([s[2] & 0x0F, s[3]]) + s[4 : -P.CRC_SIZE] for s in binary)
    out = subprocess.run([host_build / "stv_encode"], input=req, capture_output=True, check=True).stdout
    assert out == b"".join(binary)

"""Property tests (hypothesis, deterministic): chunking invariance, and damage never yields a frame that was not
sent while every intact frame after the damage is recovered; the bulk decoder agrees with the stream decoder."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from steval_link.link import protocol as P
from steval_link.link.decoder import StreamDecoder, decode_bytes
from steval_link.link.frames import TextFrame
from steval_link.link.text_telemetry import looks_like_text
from steval_link.link.textmode import format_att, format_sta

FUZZ = settings(
    derandomize=True,
    max_examples=80,
    deadline=None,
    suppress_health_check=list(HealthCheck),  # results must not depend on machine load
    database=None,  # the same examples on every machine and run
    phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink],  # no slow "explain" phase
)

f32_bits = st.integers(0, 2**32 - 1).map(lambda b: np.array([b], np.uint32).view(np.float32)[0])


@st.composite
def frames(draw):
    """One encoded frame or text-mode line (bytes), of any kind."""
    kind = draw(st.sampled_from(["att", "att", "att", "att", "status", "text", "att_line", "sta_line"]))
    step = draw(st.integers(0, 2**32 - 1))
    if kind == "att":
        v = [draw(f32_bits) for _ in range(11)]
        return P.encode_attitude(
            t_us=draw(st.integers(0, 2**32 - 1)),
            acc_mg=v[0:3],
            gyro_mdps=v[3:6],
            q_wxyz=v[6:10],
            thz_rad=v[10],
            seq=step,
            thr=draw(st.integers(-32768, 32767)),
        )
    if kind == "status":
        return P.encode_status(
            step=step,
            t_us=draw(st.integers(0, 2**32 - 1)),
            q_wxyz=[1, 0, 0, 0],
            int_xyz=[draw(f32_bits), 0, 0],
            tx_dropped=draw(st.integers(0, 2**32 - 1)),
        )
    if kind == "text":
        return P.encode_text(
            draw(st.text(st.characters(min_codepoint=32, max_codepoint=0x2FF), min_size=1, max_size=300))
        )
    ints = st.integers(-(10**6), 10**6)
    if kind == "att_line":
        return format_att(
            step=step,
            t_ms=draw(st.integers(0, 4294967)),
            thr=draw(st.integers(-32768, 32767)),
            thx_mdeg=draw(ints),
            thy_mdeg=draw(ints),
            thz_mdeg=draw(ints),
            acc_mg=[draw(ints) for _ in range(3)],
            gyro_mdps=[draw(ints) for _ in range(3)],
        )
    return format_sta(
        step=step,
        t_ms=draw(st.integers(0, 4294967)),
        cyc_min=1,
        cyc_mean=2,
        cyc_max=3,
        cyc_n=4,
        tx_dropped=draw(st.integers(0, 1000)),
        flags=4,
        ki_micro=draw(st.integers(0, 10**7)),
    )


def decode(data: bytes, cuts: list[int]):
    """The framing alone: random frames carry random values, so the plausibility gate is off here (it has its own
    tests in test_plausibility.py)."""
    sd = StreamDecoder(plausibility=False)
    out = []
    pos = 0
    for c in sorted(set(cuts)):
        out += sd.feed(data[pos:c])
        pos = c
    out += sd.feed(data[pos:])
    out += sd.finish()
    return out, sd.stats


def frame_bytes(data: bytes, frames) -> list[tuple[int, bytes]]:
    return [(f.offset, data[f.offset : f.offset + f.nbytes]) for f in frames]


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@FUZZ
@given(st.lists(frames(), min_size=1, max_size=25), st.data())
def test_random_chunking_gives_identical_frames(sent, data):
    stream = b"".join(sent)
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=40))
    whole, whole_stats = decode(stream, [])
    got, stats = decode(stream, cuts)
    assert frame_bytes(stream, got) == frame_bytes(stream, whole)
    assert [type(f) for f in got] == [type(f) for f in whole]
    assert stats == whole_stats
    # every frame sent is decoded exactly once
    assert [b for _, b in frame_bytes(stream, got)] == sent


# plain lines without digits (lines of numbers are text telemetry, tested in test_text_telemetry.py)
log_lines = (
    st.text(
        st.characters(min_codepoint=32, max_codepoint=0x2FF, exclude_characters="$0123456789"), min_size=1, max_size=80
    )
    .filter(str.isprintable)
    .map(lambda s: s.encode("utf-8") + (b"\r\n" if len(s) % 2 else b"\n"))
)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@FUZZ
@given(st.lists(st.one_of(frames(), log_lines), min_size=1, max_size=25), st.data())
def test_chunking_invariance_with_plain_log_lines(sent, data):
    """Plain lines (no checksum) are accepted only right after a handed-out frame, and only when they read as text
    (``looks_like_text``; the others are counted in ``text_dropped``); chunking never matters."""
    stream = b"".join(sent)
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=40))
    whole, whole_stats = decode(stream, [])
    got, stats = decode(stream, cuts)
    assert frame_bytes(stream, got) == frame_bytes(stream, whole) and stats == whole_stats
    tel = decode_bytes(stream, plausibility=False)
    assert tel.stats.as_dict() == stats.as_dict()
    assert [t for _, t in tel.text] == [f.text for f in got if isinstance(f, TextFrame)]
    # everything is decoded except a plain line at the very start (nothing before it proves it is whole)
    expect = sent[1:] if sent[0][:1] not in (b"\xa5", b"$") else sent
    expect = [b for b in expect if b[:1] in (b"\xa5", b"$") or looks_like_text(b.decode().rstrip("\r\n"))]
    assert [b for _, b in frame_bytes(stream, got)] == expect


@st.composite
def damaged_stream(draw):
    """(sent frames, damaged stream, intact frames' (new offset, bytes))."""
    sent = draw(st.lists(frames(), min_size=2, max_size=20))
    out = bytearray()
    intact: list[tuple[int, bytes]] = []
    for fb in sent:
        if draw(st.integers(0, 9)) < 3:  # garbage between frames
            out += draw(st.binary(min_size=1, max_size=30))
        op = draw(st.sampled_from(["none", "none", "flip", "delete", "insert", "truncate"]))
        if op == "none":
            intact.append((len(out), fb))
            out += fb
            continue
        b = bytearray(fb)
        i = draw(st.integers(0, len(b) - 1))
        if op == "flip":
            b[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "delete":
            del b[i : i + draw(st.integers(1, 8))]
        elif op == "insert":
            b[max(i, 1) : max(i, 1)] = draw(st.binary(min_size=1, max_size=8))
        else:
            del b[max(i, 1) :]
        out += b
    return sent, bytes(out), intact


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@FUZZ
@given(damaged_stream(), st.data())
def test_damage_never_yields_unsent_frames_and_recovers_intact_ones(case, data):
    sent, stream, intact = case
    cuts = data.draw(st.lists(st.integers(0, len(stream)), max_size=10))
    got, stats = decode(stream, cuts)
    sent_set = {b.rstrip(b"\r\n") for b in sent}  # "\r" is optional before a text line's "\n"
    decoded = frame_bytes(stream, got)
    for f, (off, b) in zip(got, decoded):
        if isinstance(f, TextFrame) and stream[off] not in (0xA5, 0x24):
            continue  # a plain log line has no checksum (none is sent here; see test below)
        line = b.rstrip(b"\r\n")
        if stream[off] == 0x24 and line not in sent_set and any(_xor_blind(line, s) for s in sent_set):
            continue  # bytes deleted whose XOR is 0 (two equal characters): a text checksum cannot see that
        assert line in sent_set, f"decoded a frame that was not sent at {off}: {b!r}"
    got_set = set(decoded)
    for off, b in intact:
        assert (off, b) in got_set, f"intact frame at {off} not recovered"
    assert stats.bytes_total == len(stream)
    assert stats.bytes_skipped + stats.blank_bytes + sum(len(b) for _, b in decoded) == len(stream)


def _xor_blind(line: bytes, sent: bytes) -> bool:
    """``line`` is ``sent`` with some bytes deleted whose XOR is 0 (an XOR checksum still holds)."""
    if len(line) >= len(sent):
        return False
    i, x = 0, 0
    for c in sent:
        if i < len(line) and line[i] == c:
            i += 1
        else:
            x ^= c
    return i == len(line) and x == 0


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@FUZZ
@given(damaged_stream())
def test_bulk_decoder_equals_stream_decoder_on_damaged_input(case):
    _, stream, _ = case
    got, stats = decode(stream, [])
    tel = decode_bytes(stream, plausibility=False)
    assert tel.stats.as_dict() == stats.as_dict()
    att_off = [f.offset for f in got if type(f).__name__ == "AttitudeFrame"]
    assert tel.attitude.offset.tolist() == att_off
    assert tel.status.offset.tolist() == [f.offset for f in got if type(f).__name__ == "StatusFrame"]
    assert [t for _, t in tel.text] == [f.text for f in got if isinstance(f, TextFrame)]


@FUZZ
@given(st.binary(max_size=3000))
def test_random_bytes_never_yield_binary_frames(garbage):
    got, stats = decode(garbage, [len(garbage) // 3])
    for f in got:
        # a random frame would need a matching CRC-16 (or checksum and fields): the odds are negligible
        assert isinstance(f, TextFrame) and garbage[f.offset] != 0xA5
    assert stats.bytes_skipped + sum(f.nbytes for f in got) == len(garbage)

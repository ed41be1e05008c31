"""Text mode: $ATT/$STA lines, checksums, plain log lines, mixed with binary frames."""

from __future__ import annotations

import math

import numpy as np
from support.streams import StreamBuilder

from steval_link.link.decoder import StreamDecoder, decode_bytes
from steval_link.link.frames import AttitudeFrame, StatusFrame, TextFrame
from steval_link.link.textmode import checksum, format_att, format_sta, parse_sentence


def decode_all(data: bytes, chunk: int = 13):
    sd = StreamDecoder()
    out = []
    for i in range(0, len(data), chunk):
        out += sd.feed(data[i : i + chunk])
    return out + sd.finish(), sd.stats


ATT = format_att(
    step=70000,
    t_ms=433,
    thr=150,
    thx_mdeg=-1500,
    thy_mdeg=2250,
    thz_mdeg=90000,
    acc_mg=[12, -7, 998],
    gyro_mdps=[-350, 0, 70],
)


def test_checksum_and_format():
    assert checksum(b"GPGLL,5300.97914,N,00259.98174,E,125926,A") == 0x28  # a well-known NMEA sentence
    assert ATT.startswith(b"$ATT,70000,433,150,-1500,2250,90000,12,-7,998,-350,0,70*") and ATT.endswith(b"\r\n")
    body = ATT[1 : ATT.index(b"*")]
    assert int(ATT[ATT.index(b"*") + 1 : -2], 16) == checksum(body)
    assert format_att(
        step=1, t_ms=0, thr=0, thx_mdeg=-1.9, thy_mdeg=1.9, thz_mdeg=0, acc_mg=[0, 0, 0], gyro_mdps=[0, 0, 0]
    ).startswith(b"$ATT,1,0,0,-1,1,")  # rounded toward zero


def test_parse_att_line_units():
    f = parse_sentence(ATT.rstrip(b"\r\n"))
    assert isinstance(f, AttitudeFrame) and not f.exact
    assert f.step == 70000 and f.seq == 70000 % 65536 and f.t_us == 433000 and f.thr == 150
    assert math.isclose(f.thx_rad, math.radians(-1.5)) and math.isclose(f.thy_rad, math.radians(2.25))
    assert math.isclose(f.thz_rad, math.pi / 2)
    assert f.acc_mg == (12.0, -7.0, 998.0) and f.gyro_mdps == (-350.0, 0.0, 70.0)
    assert all(math.isnan(x) for x in f.q_wxyz)


def test_parse_sta_line():
    line = format_sta(
        step=5, t_ms=31, cyc_min=1, cyc_mean=2, cyc_max=3, cyc_n=161, tx_dropped=4, flags=4, ki_micro=1_000_000
    )
    f = parse_sentence(line.rstrip(b"\r\n"))
    assert isinstance(f, StatusFrame) and not f.exact
    assert (f.step, f.t_us, f.cyc_min, f.cyc_mean, f.cyc_max, f.cyc_n, f.tx_dropped, f.flags) == (
        5,
        31000,
        1,
        2,
        3,
        161,
        4,
        4,
    )
    assert f.ki == 1.0 and math.isnan(f.kp_ground)


def test_bad_checksum_or_fields_are_crc_failures():
    bad_sum = ATT.replace(b"*", b"*0")[:-4] + b"\r\n"
    flipped = ATT.replace(b"998", b"999")  # checksum no longer matches
    short = b"$ATT,1,2,3*" + b"%02X" % checksum(b"ATT,1,2,3") + b"\r\n"  # right checksum, wrong field count
    frames, stats = decode_all(b"\n" + flipped + short + bad_sum + ATT)
    assert [type(f) for f in frames] == [AttitudeFrame]
    assert stats.crc_failures == 3
    assert stats.bytes_skipped == 1 + len(flipped) + len(short) + len(bad_sum)


def test_text_log_stream(make_stream):
    b: StreamBuilder = make_stream(1)
    b.log_line("STEVAL-FCU001V1 text mode")  # the very first line: the decoder cannot know it is whole
    for i in range(0, 800, 16):
        b.att_line(i)
        if i % 160 == 0:
            b.sta_line(i)
            b.log_line(f"note {i} — ünïcode ok")
    data = b.bytes()
    frames, stats = decode_all(data, 5)
    atts = [f for f in frames if isinstance(f, AttitudeFrame)]
    assert [f.step for f in atts] == list(range(0, 800, 16))
    assert stats.status == 5 and stats.crc_failures == 0
    texts = [f.text for f in frames if isinstance(f, TextFrame)]
    assert texts == [f"note {i} — ünïcode ok" for i in range(0, 800, 160)]
    assert stats.bytes_skipped == len(b"STEVAL-FCU001V1 text mode\r\n")
    tel = decode_bytes(data)
    assert tel.stats.as_dict() == stats.as_dict()
    assert tel.attitude.step.tolist() == list(range(0, 800, 16)) and not tel.attitude.exact.any()
    assert np.isnan(tel.attitude.q_wxyz).all()
    assert tel.attitude.thx_rad.dtype == np.float32


def test_mid_line_start_is_skipped():
    frames, stats = decode_all(ATT[10:] + ATT + b"plain line\n" + ATT)
    assert [type(f).__name__ for f in frames] == ["AttitudeFrame", "TextFrame", "AttitudeFrame"]
    assert stats.bytes_skipped == len(ATT) - 10 and stats.crc_failures == 0


def test_text_and_binary_mixed_in_one_stream(make_stream):
    b: StreamBuilder = make_stream(2)
    for i in range(100):
        b.attitude(i)
    b.log_line("switching to text mode")
    for i in range(100, 200, 16):
        b.att_line(i)
    for i in range(200, 300):
        b.attitude(i)
    data = b.bytes()
    frames, stats = decode_all(data, 29)
    assert len(frames) == len(b.sent)
    assert [f.text for f in frames if isinstance(f, TextFrame)] == ["switching to text mode"]
    tel = decode_bytes(data)
    assert tel.stats.as_dict() == stats.as_dict()
    assert tel.attitude.exact.sum() == 200 and (~tel.attitude.exact).sum() == 7


def test_control_bytes_break_a_line_and_resync_at_next_line():
    junk = b"\n$ATT,1,2\x00garbage" + b"\x01\x02 more\n"
    frames, stats = decode_all(junk + ATT + b"log after\r\n")
    assert [type(f).__name__ for f in frames] == ["AttitudeFrame", "TextFrame"]
    assert frames[1].text == "log after"

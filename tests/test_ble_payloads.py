"""The BLE payload decoder (steval_link.link.ble_payloads).

Tests on hand-made payloads (layouts, tick wrap, drops, the uniform estimator grid), and on the bundled BLE capture
of ST's stock firmware (recordings/ble_demo.stv: its notifications as ST's release sends them, recorded under
emulation): decoded across the tick's wrap, at the AHRS rate, with notifications dropped on the way (host side).
"""

from __future__ import annotations

import json
import shlex
import struct
from pathlib import Path

import numpy as np
import pytest
from support.ble import held_rows, telemetry_of_records

from steval_link.link import ble_payloads as B
from steval_link.link import ble_telemetry as BC
from steval_link.link.capture import read_capture
from steval_link.link.load import load_telemetry

# -- hand-made payloads ---------------------------------------------------------------------------------------------


def motion(tick, acc=(0, 0, 1000), gyro_centi=(0, 0, 0), mag=(0, 0, 0)) -> bytes:
    return struct.pack("<H3h3h3h", tick & 0xFFFF, *acc, *gyro_centi, *mag)


def test_layouts_and_units():
    dec = B.BleDecoder()
    m = dec.feed(B.CHAR_MOTION, motion(7, (-12, 34, 1001), (-5, 123, -32768), (1, -2, 3)), 0.5)
    assert isinstance(m, B.BleMotionFrame) and m.tick == 7 and m.acc_mg == (-12, 34, 1001) and m.t_host_s == 0.5
    assert m.gyro_mdps == (-500, 12300, -3276800)  # mdps/100 on the wire
    assert m.mag_mgauss == (1, -2, 3) and not m.repeat
    e = dec.feed(B.CHAR_ENV, struct.pack("<HiHhh", 9, 101325, 1000, -55, -620), 0.6)
    assert (e.tick, e.pressure_hpa, e.battery_pct, e.temperature_c, e.rssi_dbm) == (9, 1013.25, 100.0, -5.5, -62.0)
    a = dec.feed(B.CHAR_ARMING, b"\x0a\x00\x01", 0.7)
    assert (a.tick, a.armed) == (10, True)
    for cid, n in ((B.CHAR_MOTION, 20), (B.CHAR_ENV, 12), (B.CHAR_ARMING, 3)):
        with pytest.raises(B.BadPayload):
            B.unpack_payload(cid, bytes(n - 1))
        assert dec.feed(cid, bytes(n - 1), 1.0) is None  # the decoder counts it and goes on
    assert dec.bad_payloads == 3 and dec.feed(99, b"x", 1.0) is None and dec.unknown == 1
    assert dec.counts["motion"] == 2 and dec.feed(B.CHAR_MOTION, motion(7), 1.1).repeat is False
    assert dec.feed(B.CHAR_MOTION, motion(7), 1.2).repeat  # the same payload again
    assert B.char_id_of_uuid("00E00000-0001-11E1-AC36-0002A5D5C51B") == B.CHAR_MOTION
    assert B.char_id_of_uuid("00000000-0001-11e1-9ab4-0002a5d5c51b") is None  # the service, not a characteristic


def test_tick_unwrap_across_the_wrap_and_a_long_gap():
    ticks = [65530, 65531, 65533, 65535, 0, 1, 3]
    unwrap = B.TickUnwrapper()
    assert [unwrap(t) for t in ticks] == [65530, 65531, 65533, 65535, 65536, 65537, 65539]
    # a disconnect longer than one wrap period (524.288 s): the host clock says how many wraps passed
    unwrap = B.TickUnwrapper()
    got = [unwrap(t, dt) for t, dt in ((100, None), (101, 0.008), ((101 + 75000) & 0xFFFF, 600.0))]
    assert got == [100, 101, 101 + 75000]
    # the same through the decoder, on one clock for every characteristic
    dec = B.BleDecoder()
    frames = [dec.feed(B.CHAR_MOTION, motion(t), 0.008 * i) for i, t in enumerate(ticks)]
    assert [f.tick for f in frames] == [65530, 65531, 65533, 65535, 65536, 65537, 65539]


def test_a_capture_counts_and_skips_bad_payloads():
    recs = [
        (0.0, B.CHAR_MOTION, motion(1)),
        (0.001, B.CHAR_ENV, bytes(12)),
        (0.002, B.CHAR_ARMING, b"\x01\x00\x00"),
        (0.003, B.CHAR_MOTION, motion(2)[:-1]),
        (0.004, 9, b"xx"),
        (0.005, B.CHAR_STDERR, b"Error\r\n"),
    ]
    tel = telemetry_of_records(recs)
    ble = tel.link
    assert len(ble.samples) == len(tel.attitude) == 1 and ble.bad_payloads == 1 and ble.unknown == 1
    assert ble.counts == {"motion": 2, "environment": 1, "arming": 1, "stdout": 0, "stderr": 1}
    assert tel.text == [(0.005, "[stderr] Error\r\n")]


def steps(n: int, t0_ms: float = 123_456.0) -> list[int]:
    """The ticks of motion notifications sent once per AHRS step (6.19 ms) starting at HAL_GetTick() = t0_ms."""
    t_ms = t0_ms + np.arange(n) * BC.STEP_PERIOD_S * 1e3
    return [int(t) >> 3 for t in t_ms]


def test_nominal_interval_drops_and_uniform_grid():
    ticks = steps(2000)
    recs = [(i * BC.STEP_PERIOD_S, B.CHAR_MOTION, motion(t, acc=(i % 1000, 0, 1000))) for i, t in enumerate(ticks)]
    full = telemetry_of_records(recs).link.cadence
    assert full.interval_s == pytest.approx(BC.STEP_PERIOD_S)
    assert full.dropped == 0
    # drop a block of 40 and 10 scattered notifications
    keep = np.ones(len(recs), bool)
    keep[500:540] = False
    keep[[900, 1100, 1300, 1500, 1600, 1700, 1750, 1800, 1850, 1900]] = False
    tel = telemetry_of_records([r for r, k in zip(recs, keep) if k])
    a, held = tel.attitude, held_rows(tel)
    assert tel.link.cadence.dropped == 50 == tel.link.rows_held
    assert tel.link.dt_s == pytest.approx(BC.STEP_PERIOD_S)
    assert abs(len(a) - 2000) <= 1 and int(held.sum()) == len(a) - len(tel.link.samples)
    # the block is held over: the rows after 499 repeat its sample until 540's arrives
    assert a.acc_mg[499:540, 0].tolist() == [499.0] * 40 or a.acc_mg[500, 0] == 499.0
    assert (np.diff(a.t_fw_s) > 0).all()


# -- the real firmware under emulation ------------------------------------------------------------------------------

WRAP_MS = 1 << 19  # HAL_GetTick() at which the u16 tick (>> 3) wraps


REC = Path(__file__).resolve().parents[1] / "recordings"


@pytest.fixture(scope="module")
def demo():
    """recordings/ble_demo.stv as the one model: its link's facts."""
    return load_telemetry(REC / "ble_demo.stv").link


def test_decoder_on_st_firmwares_notifications_across_the_tick_wrap(demo):
    counts = [demo.counts[k] for k in ("motion", "environment", "arming")]
    assert min(counts) > 5000 and max(counts) - min(counts) <= 1  # (the run may end between two of them)
    assert demo.bad_payloads == 0 and demo.unknown == 0
    # the u16 tick wrapped once (HAL_GetTick started at 494288 ms): unwrapped, it runs on
    tick, t_host = demo.samples["tick"], demo.samples["t_host_s"]
    assert (np.diff(tick) >= 0).all() and tick[-1] >= 1 << 16 > tick[0]
    # the unwrapped tick clock runs with the (emulated) host clock, to the tick's 8 ms resolution
    drift = (tick - tick[0]) * B.TICK_S - (t_host - t_host[0])
    assert np.abs(drift).max() <= 2 * B.TICK_S
    # one notification of each characteristic per AHRS step, none dropped
    assert 1.0 / demo.cadence.interval_s == pytest.approx(161.54, abs=0.05)
    assert demo.cadence.dropped == 0
    # hand tilts: the acceleration's magnitude is about 1 g
    assert abs(float(np.median(np.linalg.norm(demo.samples["acc"], axis=1))) - 1000) < 50


def test_decoder_sees_notifications_dropped_on_the_way(demo):
    s = demo.samples
    keep = np.ones(len(s), bool)
    keep[100:160] = False
    # the whole sample as sent (acc, gyro, mag): two updates within one 8 ms tick differ by their sensor noise
    records = [
        (
            float(t),
            B.CHAR_MOTION,
            motion(int(k) & 0xFFFF, tuple(map(int, a)), tuple(int(round(v / 100)) for v in g), tuple(map(int, m))),
        )
        for t, k, a, g, m, ok in zip(s["t_host_s"], s["tick"], s["acc"], s["gyro"], s["mag"], keep)
        if ok
    ]
    dropped = telemetry_of_records(records)
    assert dropped.link.cadence.dropped == 60
    assert int(held_rows(dropped).sum()) == 60 and abs(len(dropped.attitude) - len(s)) <= 1


def test_replay_of_the_ble_capture(monkeypatch, capsys):
    from support.cli import run_cli

    code, text, err = run_cli(monkeypatch, capsys, "replay", REC / "ble_demo.stv", "--json")
    s = json.loads(text)
    assert code == 0, err
    assert s["kind"] == "ble" and s["tick_wraps"] == 1 and s["motion_dropped_estimate"] == 0 and s["emulated"]
    assert s["notifications"]["motion"] > 5000
    cmd = shlex.split(read_capture(REC / "ble_demo.stv").header["extra"]["command"])
    assert cmd[:2] == ["steval", "emulate"] and "--ble" in cmd


def test_emulate_ble_refuses_rrd(tmp_path, monkeypatch, capsys):
    from support.cli import run_cli

    elf = tmp_path / "x.elf"
    elf.write_bytes(b"\x7fELF")
    code, _, err = run_cli(monkeypatch, capsys, "emulate", elf, "--ble", "--rrd", tmp_path / "x.rrd")
    assert code == 2 and "--ble records a BLE capture only" in err

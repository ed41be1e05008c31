"""The BLE payload decoder (steval_link.link.ble_payloads).

Fast tests on hand-made payloads (layouts, tick wrap, drops, the uniform estimator grid), and slow ones against
ST's stock firmware under emulation: every ``aci_gatt_update_char_value`` the firmware sends through
``hci_send_req`` is read back from the HCI request in the emulated RAM (service handle, char handle, offset,
length, value) and decoded, and the decoded values must equal the arguments the firmware passed to
``AccGyroMag_Update`` / ``Batt_Env_RSSI_Update`` / ``ARMING_Update`` (read at their entry) and its tick
(``HAL_GetTick() >> 3``): the decoder agrees with the firmware's own encoding on every payload, across the tick's
wrap, with notifications dropped on the way (host side) and refused by a congested radio (firmware side).
"""

from __future__ import annotations

import json
import shlex
import struct

import numpy as np
import pytest

from steval_link.link import ble_payloads as B
from steval_link.link.capture import read_capture

# -- hand-made payloads ---------------------------------------------------------------------------------------------


def motion(tick, acc=(0, 0, 1000), gyro_centi=(0, 0, 0), mag=(0, 0, 0)) -> bytes:
    return struct.pack("<H3h3h3h", tick & 0xFFFF, *acc, *gyro_centi, *mag)


def test_layouts_and_units():
    m = B.decode_motion(motion(7, (-12, 34, 1001), (-5, 123, -32768), (1, -2, 3)))
    assert m.tick == 7 and m.acc_mg == (-12, 34, 1001)
    assert m.gyro_mdps == (-500, 12300, -3276800)  # mdps/100 on the wire
    assert m.mag_mgauss == (1, -2, 3)
    e = B.decode_env(struct.pack("<HiHhh", 9, 101325, 1000, -55, -620))
    assert (e.tick, e.pressure_hpa, e.battery_pct, e.temperature_c, e.rssi_dbm) == (9, 1013.25, 100.0, -5.5, -62.0)
    assert B.decode_arming(b"\x05\x00\x01") == (5, True)
    for fn, n in ((B.decode_motion, 20), (B.decode_env, 12), (B.decode_arming, 3)):
        with pytest.raises(B.BadPayload):
            fn(bytes(n - 1))
    assert B.char_id_of_uuid("00E00000-0001-11E1-AC36-0002A5D5C51B") == B.CHAR_MOTION
    assert B.char_id_of_uuid("00000000-0001-11e1-9ab4-0002a5d5c51b") is None  # the service, not a characteristic


def test_tick_unwrap_across_the_wrap_and_a_long_gap():
    ticks = np.array([65530, 65531, 65533, 65535, 0, 1, 3], dtype=np.int64)
    assert B.unwrap_ticks(ticks).tolist() == [65530, 65531, 65533, 65535, 65536, 65537, 65539]
    # a disconnect longer than one wrap period (524.288 s): the host clock says how many wraps passed
    t_host = np.array([0.0, 0.008, 0.008 + 600.0])
    u = B.unwrap_ticks(np.array([100, 101, (101 + 75000) & 0xFFFF]), t_host)
    assert u.tolist() == [100, 101, 101 + 75000]
    unwrap = B.TickUnwrapper()
    assert [unwrap(int(t)) for t in ticks] == B.unwrap_ticks(ticks).tolist()


def test_decode_notifications_counts_and_skips_bad_payloads():
    recs = [(0.0, B.CHAR_MOTION, motion(1)), (0.001, B.CHAR_ENV, bytes(12)), (0.002, B.CHAR_ARMING, b"\x01\x00\x00"),
            (0.003, B.CHAR_MOTION, motion(2)[:-1]), (0.004, 9, b"xx"), (0.005, B.CHAR_STDERR, b"Error\r\n")]
    ble = B.decode_notifications(recs)
    assert len(ble) == 1 and ble.bad_payloads == 1 and ble.unknown == 1
    assert ble.counts == {"motion": 2, "environment": 1, "arming": 1, "stdout": 0, "stderr": 1}
    assert ble.console == [(0.005, "stderr", "Error\r\n")]


def steps(n: int, t0_ms: float = 123_456.0) -> list[int]:
    """The ticks of motion notifications sent once per AHRS step (6.19 ms) starting at HAL_GetTick() = t0_ms."""
    t_ms = t0_ms + np.arange(n) * B.STEP_PERIOD_S * 1e3
    return [int(t) >> 3 for t in t_ms]


def test_nominal_interval_drops_and_uniform_grid():
    ticks = steps(2000)
    recs = [(i * B.STEP_PERIOD_S, B.CHAR_MOTION, motion(t, acc=(i % 1000, 0, 1000))) for i, t in enumerate(ticks)]
    full = B.decode_notifications(recs)
    assert full.interval_s == pytest.approx(B.STEP_PERIOD_S)
    assert full.dropped_estimate() == 0
    # drop a block of 40 and 10 scattered notifications
    keep = np.ones(len(recs), bool)
    keep[500:540] = False
    keep[[900, 1100, 1300, 1500, 1600, 1700, 1750, 1800, 1850, 1900]] = False
    ble = B.decode_notifications([r for r, k in zip(recs, keep) if k])
    assert ble.dropped_estimate() == 50
    u = B.uniform_inputs(ble)
    assert u.dt_s == pytest.approx(B.STEP_PERIOD_S)
    assert abs(len(u.t_s) - 2000) <= 1 and int(u.filled.sum()) == len(u.t_s) - len(ble)
    # the block is held over: the rows after 499 repeat its sample until 540's arrives
    assert u.acc_mg[499:540, 0].tolist() == [499.0] * 40 or u.acc_mg[500, 0] == 499.0
    assert (np.diff(u.t_s) > 0).all()


# -- the real firmware under emulation ------------------------------------------------------------------------------

WRAP_MS = 1 << 19  # HAL_GetTick() at which the u16 tick (>> 3) wraps


@pytest.fixture(scope="module")
def stock_elf(tmp_path_factory):
    from support import firmware as S

    why = S.missing()
    if why:
        pytest.skip(why)
    d = tmp_path_factory.mktemp("stock")
    return S.build(S.st_copy(d, patched=False), d / "b", target="stock")


class FirmwareCalls:
    """Every HCI update the firmware issued, read by the test itself from the request in RAM, each with the
    arguments of the update function that issued it (read at that function's entry) and whether the radio
    accepted it."""

    def __init__(self, emu, nrg):
        b = emu.board
        self.board, self.nrg = b, nrg
        R = b._R
        self.tick_addr = emu.elf.addr("uwTick")
        self.calls: dict[str, int] = {}
        self.hci: list[dict] = []
        self._last: tuple | None = None

        def on(name, read):
            a = emu.elf.addr(name)
            assert a is not None, name

            def entry(board):
                self.calls[name] = self.calls.get(name, 0) + 1
                self._last = (name, read(board), self._tick_ms(), self.calls[name])

            b.probe(a, entry)

        def axes(board, reg):
            return struct.unpack("<3i", bytes(board.uc.mem_read(board.reg(reg), 12)))

        on("AccGyroMag_Update", lambda bd: (axes(bd, R[0]), axes(bd, R[1]), axes(bd, R[2])))
        on("Batt_Env_RSSI_Update", lambda bd: tuple(bd.reg(R[i]) for i in range(4)))
        on("ARMING_Update", lambda bd: bd.reg(R[0]) & 0xFF)
        b.call_observers.setdefault("hci_send_req", []).append(self._on_hci)

    def _tick_ms(self) -> int:
        return self.board.ram_u32(self.tick_addr)

    def _on_hci(self, board, req, *_):
        # the HCI request as the BlueNRG library built it: struct hci_request {u16 ogf, ocf; int event;
        # void *cparam; int clen; void *rparam; int rlen}; the observer runs after the radio model answered
        ogf, ocf, _ev, cparam, clen, _rp, _rl = struct.unpack("<HHiIiIi", bytes(board.uc.mem_read(req, 24)))
        if (ogf, ocf) == (0x3F, 0x0106):  # aci_gatt_update_char_value
            p = bytes(board.uc.mem_read(cparam, clen))
            serv, char, offset, length = struct.unpack_from("<HHBB", p)
            accepted = bool(self.nrg.notifications) and self.nrg.notifications[-1].value == p[6:6 + length] \
                and len(self.nrg.notifications) > sum(h["accepted"] for h in self.hci)
            self.hci.append({"serv": serv, "char": char, "offset": offset, "value": p[6:6 + length],
                             "call": self._last, "accepted": accepted})


def run_firmware(elf, *, duration_s, tick_start_ms=0, bluenrg=None, throttle="0:0,2:0,3:300"):
    from steval_link.emulation.bluenrg import EmulatedBlueNrg
    from steval_link.emulation.runner import Emulation, EmulationOptions

    nrg = bluenrg if bluenrg is not None else EmulatedBlueNrg()
    emu = Emulation(EmulationOptions(elf=elf, scenario="hand-tilts", duration_s=duration_s, seed=7,
                                     throttle=throttle), bluenrg=nrg, tick_start_ms=tick_start_ms)
    calls = FirmwareCalls(emu, nrg)
    emu.run()
    return emu, nrg, calls


def check_against_firmware(nrg, calls) -> B.BleTelemetry:
    """Each accepted update decodes to exactly what the firmware passed in (see the module docstring)."""
    name_of = {B.CHAR_MOTION: "AccGyroMag_Update", B.CHAR_ENV: "Batt_Env_RSSI_Update", B.CHAR_ARMING: "ARMING_Update"}
    # the radio model recorded exactly the updates it accepted, as the test read them from the HCI requests
    assert len(calls.hci) == nrg.updates
    accepted = [h for h in calls.hci if h["accepted"]]
    assert [(h["char"], h["value"]) for h in accepted] == [(n.char_handle, n.value) for n in nrg.notifications]
    records = []
    for h, n in zip(accepted, nrg.notifications):
        if n.char_id not in name_of:
            continue
        name, a, tick_ms, _ = h["call"]
        assert name == name_of[n.char_id] and h["offset"] == 0  # issued by that characteristic's update function
        if n.char_id == B.CHAR_MOTION:
            m = B.decode_motion(n.value)
            acc, gyro, mag = a
            assert m.acc_mg == tuple(np.int16(acc).tolist())
            assert m.gyro_mdps == tuple(int(np.int16(int(g / 100))) * 100 for g in gyro)  # C: truncation to 0
            assert m.mag_mgauss == tuple(np.int16(mag).tolist())
            tick = m.tick
        elif n.char_id == B.CHAR_ENV:
            e = B.decode_env(n.value)
            press, batt, temp, rssi = a
            assert round(e.pressure_hpa * 100) == np.int32(np.uint32(press))
            assert round(e.battery_pct * 10) == batt & 0xFFFF
            assert round(e.temperature_c * 10) == np.int16(np.uint16(temp & 0xFFFF))
            assert round(e.rssi_dbm * 10) == np.int16(np.uint16(rssi & 0xFFFF)) == nrg.rssi_dbm * 10
            tick = e.tick
        else:
            tick, armed = B.decode_arming(n.value)
            assert armed == bool(a)
        # HAL_GetTick() >> 3 in u16, read inside the update function (SysTick may tick once after its entry)
        assert tick in ((tick_ms >> 3) & 0xFFFF, ((tick_ms + 1) >> 3) & 0xFFFF)
        records.append((n.t_sent_s, n.char_id, n.value))
    return B.decode_notifications(records)


@pytest.mark.slow
def test_decoder_agrees_with_the_stock_firmware_across_the_tick_wrap(stock_elf):
    start = WRAP_MS - 4200  # the u16 tick wraps 4.2 s after power-up, while notifications flow
    emu, nrg, calls = run_firmware(stock_elf, duration_s=6.0, tick_start_ms=start)
    ble = check_against_firmware(nrg, calls)
    counts = [ble.counts[k] for k in ("motion", "environment", "arming")]
    assert min(counts) > 300 and max(counts) - min(counts) <= 1  # (the run may end between two of them)
    assert (np.diff(ble.motion_tick) >= 0).all() and ble.motion_tick[-1] >= 1 << 16 > ble.motion_tick[0]
    # the unwrapped tick clock runs with the emulated clock (8 ms resolution)
    t_emul = np.array([n.t_s for n in nrg.notifications if n.char_id == B.CHAR_MOTION])
    drift = (ble.motion_t_fw_s - ble.motion_t_fw_s[0]) - (t_emul - t_emul[0])
    assert np.abs(drift).max() <= 2 * B.TICK_S
    # the measured rate: one notification of each characteristic per AHRS step while connected
    assert 1.0 / ble.interval_s == pytest.approx(161.54, abs=0.05)
    assert ble.dropped_estimate() == 0
    # notifications dropped on the way (host side): the decoder sees the gaps
    keep = np.ones(len(ble), bool)
    keep[100:160] = False
    records = [(float(t), B.CHAR_MOTION, motion(int(k), tuple(map(int, a)))) for t, k, a, ok in
               zip(ble.motion_t_host_s, ble.motion_tick, ble.acc_mg, keep) if ok]
    dropped = B.decode_notifications(records)
    assert dropped.dropped_estimate() == 60
    u = B.uniform_inputs(dropped)
    assert int(u.filled.sum()) == 60 and abs(len(u.t_s) - len(ble)) <= 1


@pytest.mark.slow
@pytest.mark.parametrize("buffers, per_event", [(12, 6), (8, 4)], ids=["mild", "heavy"])
def test_decoder_on_a_congested_link_the_firmware_skips(stock_elf, buffers, per_event):
    from steval_link.emulation.bluenrg import EmulatedBlueNrg

    # the chip holds 12 notifications and the link sends 6 per 12.5 ms connection event (480/s for 485/s
    # offered): now and then an update is refused and ST's code skips the next 30 motion updates; or 8 and 4
    # (320/s): most motion updates are skipped (≈ 64 Hz delivered)
    nrg = EmulatedBlueNrg(buffers=buffers, per_event=per_event)
    emu, nrg, calls = run_firmware(stock_elf, duration_s=7.0, bluenrg=nrg)
    ble = check_against_firmware(nrg, calls)
    assert nrg.refused > 0
    # the firmware's motion updates (one per AHRS step) from the first delivered notification to the last, less
    # those delivered: the truth the decoder estimates from the ticks
    numbers = [h["call"][3] for h in calls.hci
               if h["accepted"] and h["call"] is not None and h["call"][0] == "AccGyroMag_Update"]
    missing = numbers[-1] - numbers[0] + 1 - len(numbers)
    assert missing >= 30 and len(numbers) == ble.counts["motion"]
    # the decoder's estimate of the missing motion notifications from the ticks alone
    assert abs(ble.dropped_estimate() - missing) <= max(3, missing // 20)
    # the estimators' grid: one row per AHRS step from the first notification to the last, drops held
    u = B.uniform_inputs(ble)
    assert abs(len(u.t_s) - (len(ble) + missing)) <= 2 and int((~u.filled).sum()) == len(ble)


@pytest.mark.slow
def test_steval_emulate_ble_records_a_replayable_capture(stock_elf, tmp_path, monkeypatch, capsys):
    """The recipe of recordings/ble_demo.stv, shortened: steval emulate ELF --ble ... then steval replay."""
    from support.cli import run_cli

    out = tmp_path / "ble.stv"
    code, text, err = run_cli(monkeypatch, capsys, "emulate", stock_elf, "--ble", "--scenario", "hand-tilts",
                              "--duration", "5", "--seed", "2", "--tick-start-ms", str(WRAP_MS - 4000), "--out", out)
    assert code == 0, err
    assert "motion notifications: 161.54 Hz" in text and "refused (congestion model) 0" in text
    code, text, err = run_cli(monkeypatch, capsys, "replay", out, "--json")
    s = json.loads(text)
    assert code == 0 and s["kind"] == "ble" and s["tick_wraps"] == 1 and s["motion_dropped_estimate"] == 0
    assert s["notifications"]["motion"] > 300 and s["emulated"]
    cmd = shlex.split(read_capture(out).header["extra"]["command"])
    assert cmd[:3] == ["steval", "emulate", str(stock_elf)] and "--ble" in cmd and str(WRAP_MS - 4000) in cmd
    code, text, err = run_cli(monkeypatch, capsys, "emulate", stock_elf, "--ble", "--rrd", tmp_path / "x.rrd")
    assert code == 2 and "--ble records a BLE capture only" in err

"""``steval compare``: the seeded replica against the firmware, diagnoses, estimator traces, rates, CLI.

Captures are built here from real wire bytes: a "firmware" (the bit-exact replica, verified against ST's binary in
test_st_mahony) runs over smooth synthetic motion, its outputs and status snapshots are encoded with
``steval_link.link.protocol`` and decoded back with ``decode_bytes`` / written as ``.stv`` files.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from steval_link.analysis.compare import angle_diff_rad, compare_capture, format_report
from steval_link.analysis.link_stats import rate_stats
from steval_link.estimators.st_mahony import MahonySettings, MahonyState, run
from steval_link.link import protocol as P
from steval_link.link.capture import CaptureWriter
from steval_link.link.decoder import decode_bytes
from steval_link.link.textmode import format_att, format_sta

PERIOD_US = 6191.9


def motion(n: int, seed: int = 0, burst: tuple[int, int] | None = None):
    """Smooth tilting motion at the AHRS rate: (acc_mg, gyro_mdps, thr) float32/int16; throttle above MIN_THR in
    the middle third (flight gains). ``burst`` = (start, stop) rows of violent gyro noise (firmware NaN rows)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 161.5
    pitch = 0.35 * np.sin(2 * np.pi * 0.4 * t)
    roll = 0.25 * np.sin(2 * np.pi * 0.27 * t + 1.0)
    dp = np.gradient(pitch, t)
    dr = np.gradient(roll, t)
    acc = np.stack([-np.sin(roll), np.sin(pitch) * np.cos(roll), np.cos(pitch) * np.cos(roll)], 1) * 1000.0
    acc += rng.normal(0, 15, (n, 3))
    gyro = np.stack([np.degrees(dp), np.degrees(dr), 5 * np.sin(t)], 1) * 1000.0 + rng.normal(0, 300, (n, 3))
    if burst:
        gyro[burst[0] : burst[1]] = rng.normal(0, 4e6, (burst[1] - burst[0], 3))
    thr = np.where((t > t[-1] / 3) & (t < 2 * t[-1] / 3), 450, 0).astype(np.int16)
    return acc.astype(np.float32), gyro.astype(np.float32), thr


def firmware_run(acc, gyro, thr, settings: MahonySettings, status_steps):
    """The 'firmware': q, thx, thy per step and the filter state right after each step in ``status_steps``."""
    states = {}
    q = np.empty((len(acc), 4), np.float32)
    st = MahonyState()
    k0 = 0
    for k in sorted(set(status_steps)) + [len(acc) - 1]:
        if k < k0:
            continue
        q[k0 : k + 1], _, _, st = run(acc[k0 : k + 1], gyro[k0 : k + 1], thr[k0 : k + 1], settings=settings, state=st)
        states[k] = st
        k0 = k + 1
    return q, states


def capture_bytes(
    n=1500,
    *,
    seed=0,
    fw_settings=None,
    status_settings=None,
    status_every=161,
    drop=(),
    start=0,
    burst=None,
    tx_dropped=0,
    snapshot=None,
):
    """Wire bytes of a capture: attitude frames of steps ``start``..n-1 (minus ``drop``), a status frame after
    every ``status_every``-th step (claiming ``status_settings``, default: the firmware's). ``snapshot``:
    "zero-integrals" reports exInt..ezInt as 0, "one-late" the state after the next step (firmware race)."""
    fw = fw_settings or MahonySettings()
    claimed = status_settings or fw
    acc, gyro, thr = motion(n, seed, burst)
    status_steps = [k for k in range(n) if k % status_every == status_every - 1]
    q, states = firmware_run(acc, gyro, thr, fw, status_steps)
    rec = np.zeros(n, P.ATTITUDE_DTYPE)
    rec["t_us"] = (np.arange(n) * PERIOD_US).astype(np.int64) + 1_000_000
    rec["acc_mg"], rec["gyro_mdps"], rec["q_wxyz"], rec["thr"] = acc, gyro, q, thr
    rec["seq"] = np.arange(n) % P.SEQ_MODULUS
    dropped = set(drop)
    parts = []
    k0 = start
    for k in status_steps + [n - 1]:
        keep = [i for i in range(k0, k + 1) if i not in dropped]
        if keep:
            parts.append(P.encode_attitude_block(rec[keep]))
        if k in states and k in status_steps and k >= start:
            s = states[k]
            if snapshot == "zero-integrals":
                s = MahonyState(q_wxyz=s.q_wxyz)
            elif snapshot == "one-late":
                _, _, _, s = run(acc[k + 1 : k + 2], gyro[k + 1 : k + 2], thr[k + 1 : k + 2], settings=fw, state=s)
            parts.append(
                P.encode_status(
                    step=k,
                    t_us=int(rec["t_us"][k]) + 300,
                    q_wxyz=s.q_wxyz,
                    int_xyz=s.int_xyz,
                    kp_ground=claimed.kp_ground,
                    kp_flight=claimed.kp_flight,
                    ki=claimed.ki,
                    dt_s=claimed.dt_s,
                    min_thr=claimed.min_thr,
                    flags=claimed.flags,
                    cyc_min=4000,
                    cyc_mean=4200,
                    cyc_max=5000,
                    cyc_n=161,
                    tx_dropped=tx_dropped,
                )
            )
        k0 = k + 1
    return b"".join(parts)


def telemetry(**kw):
    return decode_bytes(capture_bytes(**kw), source={"path": "synthetic", "kind": "raw"})


# ------------------------------------------------------------------------------------------------ the port


def test_clean_capture_is_bit_exact_on_every_step():
    tel = telemetry(n=1500)
    r = compare_capture(tel, estimators=("accel",))
    p = r.replica
    assert p.rows == p.seeded == p.bit_exact == 1500 and p.all_exact and p.first_mismatch is None
    assert p.seeds[0]["source"] == "power-up" and not p.diagnosis
    replica = r.trace("st-mahony-replica")
    assert replica.pitch.rms_deg == 0.0 and replica.roll.max_abs_deg == 0.0 and replica.pitch.n == 1500
    text = "\n".join(format_report(r))
    assert "bit-exact on every step" in text and "bit-exact steps 1500 of 1500" in text
    assert "pitch (thx, about x)" in text and "roll (thy, about y)" in text


def test_accel_trace_measures_the_real_difference():
    tel = telemetry(n=1500)
    r = compare_capture(tel, estimators=("accel",))
    acc = r.trace("accel")
    assert acc.available and acc.pitch.n == 1500
    # accel-only tilt is noisy (15 mg noise ≈ 0.9°) but close to the filter on this gentle motion
    assert 0.05 < acc.pitch.rms_deg < 5 and 0.05 < acc.roll.rms_deg < 5
    assert acc.pitch.max_abs_deg >= acc.pitch.rms_deg
    # against the firmware's own numbers
    d = np.degrees(
        angle_diff_rad(
            np.arctan2(tel.attitude.acc_mg[:, 1].astype(float), tel.attitude.acc_mg[:, 2].astype(float)),
            tel.attitude.thx_rad,
        )
    )
    assert acc.pitch.rms_deg == pytest.approx(float(np.sqrt(np.mean(d**2))), rel=1e-9)


def test_missing_estimators_are_reported_not_fatal():
    r = compare_capture(telemetry(n=400), estimators=("no-such-filter", "accel"))
    t = r.trace("no-such-filter")
    assert t is not None and not t.available and "not available" in t.note
    assert "not available" in "\n".join(format_report(r))


def test_ki_mismatch_is_diagnosed_from_the_same_seed():
    # firmware built with AHRS_KI=1 but the status frames still claim the default 0.1
    tel = telemetry(n=1200, fw_settings=MahonySettings(ki=1.0), status_settings=MahonySettings())
    r = compare_capture(tel, estimators=())
    p = r.replica
    assert not p.all_exact and p.first_mismatch is not None
    assert p.first_mismatch["step"] == p.first_mismatch["row"] < 5
    assert p.matching_variant == {"ki": 1.0}
    assert "KI=1" in p.diagnosis[0] and "AHRS_KI=1" in p.diagnosis[0]
    assert p.matching_bit_exact == 1200
    text = "\n".join(format_report(r))
    assert "NOT bit-exact" in text and "first difference: row" in text and "KI=1" in text


def test_the_settings_found_are_a_command_that_makes_the_replica_bit_exact(tmp_path, monkeypatch, capsys):
    """ETH exercise 4 (AHRS_KI=1, status frames unchanged): compare prints the command with the settings it found,
    and that command runs the replica bit-exact."""
    import shlex

    from support.cli import run_cli

    raw = tmp_path / "ki1.bin"
    raw.write_bytes(capture_bytes(n=1200, fw_settings=MahonySettings(ki=1.0), status_settings=MahonySettings()))
    code, out, err = run_cli(monkeypatch, capsys, "compare", raw)
    line = next(x for x in out.splitlines() if x.startswith("to run the replica with them: "))
    args = shlex.split(line.split(": ", 1)[1])
    assert code == 0 and args == ["steval", "compare", str(raw), "--ki", "1"], out
    code, out, err = run_cli(monkeypatch, capsys, *args[1:])
    assert code == 0 and "bit-exact on every step" in out and "to run the replica" not in out, out + err


def test_settings_override_is_diagnosed_against_the_status_frames():
    tel = telemetry(n=800)
    r = compare_capture(tel, estimators=(), settings=MahonySettings(ki=1.0))
    assert not r.replica.all_exact
    assert r.replica.matching_variant in ({"ki": 0.1}, {"defaults": True})
    assert any("status frames report" in d for d in r.replica.diagnosis)


@pytest.mark.parametrize(
    "fw, expect_key",
    [
        (MahonySettings(correction=False), "correction"),
        (MahonySettings(dt_s=1 / 161.5), "dt_s"),
        (MahonySettings(kp_ground=0.4), "kp"),
        (MahonySettings(kp_flight=10.0), "kp"),  # differs only at flight throttle, from row 300 on
    ],
)
def test_other_firmware_variants_are_named(fw, expect_key):
    tel = telemetry(n=900, fw_settings=fw, status_settings=MahonySettings())
    p = compare_capture(tel, estimators=()).replica
    assert p.matching_variant is not None and expect_key in p.matching_variant, p.diagnosis
    assert p.matching_bit_exact == 900


def test_two_changes_at_once_are_found():
    tel = telemetry(n=700, fw_settings=MahonySettings(ki=1.0, variant="ST 221117"), status_settings=MahonySettings())
    p = compare_capture(tel, estimators=()).replica
    assert p.matching_variant in ({"ki": 1.0, "variant": "ST 221117"}, {"ki": 1.0}), p.diagnosis
    assert p.matching_bit_exact == 700
    assert "closest" in p.filter_line()


def test_the_release_is_recognised_from_the_data():
    """A 221117 firmware whose status frames say nothing of it: the replica runs 221117's filter, bit-exact."""
    tel = telemetry(n=900, fw_settings=MahonySettings(variant="221117"), status_settings=MahonySettings())
    r = compare_capture(tel, estimators=())
    p = r.replica
    assert p.all_exact and p.filter == "ST 221117" and p.filter_from == "data"
    assert p.variant_bit_exact["ST 221117"] == 900 > p.variant_bit_exact["ST 170120"]
    assert r.as_dict()["filter"] == "ST 221117"
    assert "ST 221117 (recognised from the data" in "\n".join(format_report(r))


def test_a_forced_variant_is_used_and_said():
    tel = telemetry(n=300, fw_settings=MahonySettings(variant="221117"), status_settings=MahonySettings())
    p = compare_capture(tel, estimators=(), variant="ST 170120").replica
    assert not p.all_exact and p.filter == "ST 170120" and p.variant_bit_exact == {}
    assert (
        p.filter_from == "variant setting"
        and "filter: ST 170120 (from the variant setting): bit-exact on" in p.filter_line()
    )


def test_unknown_variant_is_called_so():
    tel = telemetry(n=700, fw_settings=MahonySettings(ki=0.37, kp_flight=0.9), status_settings=MahonySettings())
    p = compare_capture(tel, estimators=()).replica
    assert p.matching_variant is None and any("unknown firmware variant" in d for d in p.diagnosis)


def test_one_corrupted_input_is_a_one_off_not_a_variant():
    tel = telemetry(n=1000)
    tel.attitude.acc_mg[500, 0] += 40.0  # a frame damaged in a way its CRC did not catch
    p = compare_capture(tel, estimators=()).replica
    assert p.first_mismatch["step"] == 500 and p.matching_variant is None
    assert any("one-off disturbance around step 500" in d for d in p.diagnosis), p.diagnosis
    assert not any("unknown firmware variant" in d for d in p.diagnosis)


def test_slow_link_note():
    tel = telemetry(n=400, tx_dropped=120)
    tel.status.baud[:] = 57600
    r = compare_capture(tel, estimators=())
    assert any("at 57600 baud" in n and "baud needed" in n for n in r.notes)


def test_status_settings_are_used_and_compared_with_defaults():
    s = MahonySettings(ki=1.0, correction=False)
    tel = telemetry(n=600, fw_settings=s)
    r = compare_capture(tel, estimators=())
    assert r.replica.all_exact and r.replica.settings["ki"] == 1.0 and r.replica.settings["correction"] is False
    fs = r.filter_settings
    assert fs["ki"] == 1.0 and fs["differs_from_defaults"]["ki"] == [1.0, pytest.approx(0.1)]
    assert "correction" in fs["differs_from_defaults"]
    assert "differs from defaults" in "\n".join(format_report(r))


# ------------------------------------------------------------------------------------------------ drops, NaN


def test_drops_reseed_from_the_next_snapshot_and_are_reported():
    drop = list(range(400, 420)) + [1000]
    tel = telemetry(n=1500, drop=drop, tx_dropped=3)
    r = compare_capture(tel, estimators=())
    p = r.replica
    assert p.all_exact and p.rows == 1500 - len(drop)
    assert [s["source"] for s in p.seeds] == ["power-up", "status", "status"]
    assert [s["step"] for s in p.seeds] == [0, 483, 1127]  # after the snapshots of steps 482 and 1126
    assert p.seeded == p.bit_exact == p.rows - (483 - 420) - (1127 - 1001)
    rt = r.rates
    assert rt.seq_gaps == 2 and rt.frames_missing == len(drop) and rt.tx_dropped == 3
    text = "\n".join(format_report(r))
    assert "21 frames missing in 2 seq gaps" in text and "snapshot at step 482" in text


def test_bad_snapshot_integrals_are_named():
    tel = telemetry(n=700, start=100, snapshot="zero-integrals")
    p = compare_capture(tel, estimators=()).replica
    assert not p.all_exact and p.first_mismatch["step"] == 161  # seeded after the snapshot of step 160
    assert p.matching_variant is None
    assert any("integral terms" in d for d in p.diagnosis), p.diagnosis


def test_snapshot_race_after_a_gap_is_reported_as_such():
    tel = telemetry(n=900, drop=range(200, 230), snapshot="one-late")
    p = compare_capture(tel, estimators=()).replica
    assert p.seeds[0]["source"] == "power-up" and p.first_mismatch["step"] == 322  # seeded after snapshot 321
    assert any("frames were dropped before that point (seq gap at step 199→230)" in d for d in p.diagnosis)
    assert any("another step" in d for d in p.diagnosis), p.diagnosis
    # joined mid-flight: no gap to blame, the snapshot is still named
    p = compare_capture(telemetry(n=600, start=100, snapshot="one-late"), estimators=()).replica
    assert p.first_mismatch["step"] == 161 and not any("dropped" in d for d in p.diagnosis)
    assert any("another step" in d for d in p.diagnosis)


def test_joined_mid_flight_without_status_cannot_seed():
    tel = telemetry(n=600, start=100, status_every=10_000)
    p = compare_capture(tel, estimators=()).replica
    assert p.seeded == 0 and p.unseeded_reason and "no status frame" in p.unseeded_reason
    assert "not run" in "\n".join(format_report(compare_capture(tel, estimators=())))


def test_firmware_nan_rows_are_counted_and_excluded():
    tel = telemetry(n=1200, burst=(600, 700))
    nan_rows = int(np.isnan(tel.attitude.thy_rad).sum())
    assert nan_rows > 0  # the violent burst drives asin out of range, as on the drone
    r = compare_capture(tel, estimators=("accel",))
    assert r.firmware_nan_roll == nan_rows
    assert r.replica.all_exact  # NaN == NaN bit-wise: the replica makes the same NaNs
    acc = r.trace("accel")
    assert acc.roll.n == 1200 - nan_rows and math.isfinite(acc.roll.rms_deg)
    assert "firmware NaN steps" in "\n".join(format_report(r))
    json.dumps(r.as_dict(), allow_nan=False)


def test_firmware_restart_restarts_the_port_and_keeps_time_increasing():
    data = capture_bytes(n=500) + capture_bytes(
        n=400, seed=2, fw_settings=MahonySettings(ki=1.0), status_settings=MahonySettings()
    )
    tel = decode_bytes(data, source={"path": "restart", "kind": "raw"})
    r = compare_capture(tel, estimators=())
    p = r.replica
    assert [s["source"] for s in p.seeds] == ["power-up", "power-up"] and r.rates.seq_resets == 1
    assert p.bit_exact == 500 and p.first_mismatch["row"] == 500 and p.first_mismatch["step"] == 0
    assert p.matching_variant == {"ki": 1.0}  # reflashed with AHRS_KI=1 after the first run
    assert np.all(np.diff(r.t_rel_s) > 0) and p.first_mismatch["t_rel_s"] == pytest.approx(r.t_rel_s[500])


def test_rate_statistics():
    tel = telemetry(n=1000)
    rt = rate_stats(tel)
    assert rt.period_mean_ms == pytest.approx(6.1919, abs=2e-3)
    assert rt.period_std_ms < 0.001 and rt.period_p99_ms <= 6.193
    assert rt.rate_hz == pytest.approx(161.5, rel=1e-3)
    assert rt.ahrs_cycles_mean == 4200 and rt.ahrs_us("mean") == pytest.approx(50.0)
    assert rt.ahrs_cycles_min == 4000 and rt.ahrs_cycles_max == 5000


def test_angle_differences_wrap():
    d = np.degrees(angle_diff_rad(np.radians([179.0, -179.0, 10.0]), np.radians([-179.0, 179.0, 10.0])))
    assert np.allclose(d, [-2.0, 2.0, 0.0])


# ------------------------------------------------------------------------------------------------ text mode


def text_mode_bytes(n=400):
    acc, gyro, thr = motion(n, seed=3)
    q, _ = firmware_run(acc, gyro, thr, MahonySettings(), [])
    from steval_link.estimators.st_mahony import quaternion_to_euler

    thx, thy = quaternion_to_euler(q)
    out = []
    for k in range(0, n, 2):
        out.append(
            format_att(
                step=k,
                t_ms=int(k * 6.1919),
                thr=int(thr[k]),
                thx_mdeg=int(math.degrees(thx[k]) * 1000),
                thy_mdeg=int(math.degrees(thy[k]) * 1000),
                thz_mdeg=0,
                acc_mg=[int(v) for v in acc[k]],
                gyro_mdps=[int(v) for v in gyro[k]],
            )
        )
    out.append(
        format_sta(
            step=n - 1,
            t_ms=int(n * 6.19),
            cyc_min=1,
            cyc_mean=2,
            cyc_max=3,
            cyc_n=161,
            tx_dropped=0,
            flags=P.FLAG_TEXT_MODE,
            ki_micro=100000,
        )
    )
    return b"".join(out)


def test_text_mode_capture_compares_estimators_only():
    tel = decode_bytes(text_mode_bytes(), source={"path": "log.txt", "kind": "text"})
    assert not tel.attitude.exact.any()
    r = compare_capture(tel, estimators=("accel",))
    assert r.replica is None and r.text_rows == len(tel.attitude)
    assert not r.trace("st-mahony-replica").available
    assert r.trace("accel").available and r.trace("accel").pitch.n == len(tel.attitude)
    text = "\n".join(format_report(r))
    assert "cannot be bit-exact" in text
    json.dumps(r.as_dict(), allow_nan=False)


def test_estimators_on_decimated_text_rows_run_at_the_row_rate():
    tel = decode_bytes(text_mode_bytes(n=1600), source={"path": "log.txt", "kind": "text"})
    r = compare_capture(tel, estimators=("ekf3", "accel"))
    ekf = r.trace("ekf3")
    assert "one row per 2 steps" in ekf.note and not r.trace("accel").note
    # at the right rate the EKF follows the firmware to within a few degrees (at 161.5 Hz it would lag badly)
    assert ekf.pitch.rms_deg < 3 and ekf.roll.rms_deg < 3


# ------------------------------------------------------------------------------------------------ CLI


@pytest.fixture
def stv_file(tmp_path):
    path = tmp_path / "flight.stv"
    data = capture_bytes(n=900, drop=[300])
    with CaptureWriter(path, port="/dev/ttyTEST", baud=115200) as w:
        for i in range(0, len(data), 4096):
            w.write(data[i : i + 4096], t_host_s=i / 11520.0)
    return path


def run_cli(args, capsys):
    from steval_link.cli import main

    with pytest.raises(SystemExit) as exc:
        main(args)
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def test_cli_text_output(stv_file, capsys):
    code, out, err = run_cli(["compare", str(stv_file)], capsys)
    assert code == 0, err
    assert "bit-exact on every step" in out and "pitch (thx, about x)" in out and "accel-only tilt" in out


def test_cli_json_is_machine_output_only(stv_file, capsys):
    code, out, err = run_cli(["compare", str(stv_file), "--json"], capsys)
    assert code == 0, err
    d = json.loads(out)
    assert (
        d["replica"]["all_exact"] is True
        and d["replica"]["bit_exact_steps"] == d["replica"]["seeded_steps"] == 899 - 21
    )
    assert d["rates"]["frames_missing"] == 1 and d["rows"]["attitude"] == 899
    assert {t["name"] for t in d["traces"]} >= {"st-mahony-replica", "accel", "ekf3", "mekf"}


def test_cli_port_disagreement_still_exits_0(tmp_path, capsys):
    path = tmp_path / "ki1.bin"
    path.write_bytes(capture_bytes(n=500, fw_settings=MahonySettings(ki=1.0), status_settings=MahonySettings()))
    code, out, err = run_cli(["compare", str(path), "--estimator", "accel"], capsys)
    assert code == 0 and "NOT bit-exact" in out and "AHRS_KI=1" in out


def test_cli_user_errors_exit_2_with_one_line(tmp_path, capsys):
    code, out, err = run_cli(["compare", str(tmp_path / "nope.stv")], capsys)
    assert code == 2 and err.count("\n") == 1 and err.startswith("steval: error:")
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"hello world, no frames here\x00\x01" * 10)
    code, out, err = run_cli(["compare", str(junk)], capsys)
    assert code == 2 and err.count("\n") == 1
    only_status = tmp_path / "status.bin"
    only_status.write_bytes(P.encode_status(step=5, t_us=0, q_wxyz=[1, 0, 0, 0], int_xyz=[0, 0, 0]))
    code, out, err = run_cli(["compare", str(only_status)], capsys)
    assert code == 2 and "no attitude frames" in err and err.count("\n") == 1
    code, out, err = run_cli(["compare", str(junk), "--estimator", "bogus"], capsys)
    assert code == 2


def test_cycle_counts_of_an_emulated_capture_are_called_instruction_counts(tmp_path):
    from steval_link.analysis.summary import format_summary, summarize
    from steval_link.link.capture import demo_capture_path, read_capture
    from steval_link.link.load import load_telemetry

    demo = load_telemetry(demo_capture_path())  # made by steval emulate: its header says emulated
    assert "emulated instructions over" in "\n".join(format_report(compare_capture(demo)))
    assert "emulated instructions" in "\n".join(format_summary(summarize(demo)))
    # the same bytes recorded from a port (no such header) are a drone's own DWT cycles
    raw = tmp_path / "drone.bin"
    raw.write_bytes(read_capture(demo_capture_path()).data)
    drone = load_telemetry(raw)
    text = "\n".join(format_report(compare_capture(drone)))
    assert "DWT cycles over" in text and "µs mean at 84 MHz" in text and "emulated" not in text

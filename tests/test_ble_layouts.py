"""BLE payloads as they are: a 161.5 Hz stream whose motion values repeat within an 8 ms tick is 161.5 Hz (its
repeats are samples, nothing "polled"); a firmware that sends its Euler angles in the acc fields (as a public 170120
fork does) is said in one sentence, and the euler layout shows them as the firmware's own attitude. The streams
are built from real values: ``recordings/ble_demo.stv``'s notifications, and the attitude of ``recordings/demo.stv``
packed as the fork packs it."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from support.ble import held_rows, telemetry_of_records
from support.cli import run_cli

from steval_link.link import ble_payloads as B
from steval_link.link import ble_telemetry as BC
from steval_link.link.ble_telemetry import EULER_NOTE, link_notes
from steval_link.link.capture import CHUNK_BLE, CaptureWriter
from steval_link.link.load import load_telemetry, read_recording
from steval_link.live.pipeline import LivePipeline

REC = Path(__file__).resolve().parents[1] / "recordings"


def _write(path: Path, recs) -> Path:
    with CaptureWriter(path, port="ble:DRN1110", baud=0, extra={"link": "ble"}) as w:
        for t, cid, payload in recs:
            w.write_chunk(CHUNK_BLE, B.ble_chunk(cid, payload), t)
    return path


def repeated_within_ticks() -> tuple[list, int]:
    """ble_demo's notifications, each motion sample that shares its tick with the one before carrying that one's
    values (a slow-changing or derived signal): (records, samples so changed)."""
    recs = B.ble_records(read_recording(REC / "ble_demo.stv").chunks)
    out, last, changed = [], None, 0
    for t, cid, p in recs:
        if cid == B.CHAR_MOTION:
            if last is not None and last[:2] == p[:2]:
                p, changed = last, changed + 1
            last = p
        out.append((t, cid, p))
    return out, changed


def euler_stream() -> tuple[list, object]:
    """demo.stv's firmware attitude packed as the fork sends it, once per AHRS step: tick, thx thy thz (rad x 1000)
    in the acc fields, the gyro-integrated yaw (mrad) in the gyro fields, mag 0; arriving 20 ms later."""
    a = load_telemetry(REC / "demo.stv").attitude
    recs = []
    for t, x, y, z in zip(a.t_fw_s, a.thx_rad, a.thy_rad, a.thz_rad):
        tick = (int(t * 1000) >> 3) & 0xFFFF
        ang = [int(np.clip(round(float(v) * 1000), -32768, 32767)) for v in (x, y, z)]
        recs.append((float(t) + 0.02, B.CHAR_MOTION, struct.pack("<H3h3h3h", tick, *ang, 0, 0, ang[2] // 100, 0, 0, 0)))
    return recs, a


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_values_repeating_within_a_tick_are_161_5_hz_not_reads(monkeypatch, capsys, tmp_path):
    recs, changed = repeated_within_ticks()
    assert changed > 500  # two samples in one 8 ms tick are common at 161.5 Hz
    tel = telemetry_of_records(recs)
    ble = tel.link
    n_motion = sum(1 for _, c, _ in recs if c == B.CHAR_MOTION)
    assert len(ble.samples) == len(tel.attitude) == n_motion and ble.repeated_reads == 0
    c = ble.cadence
    assert c.kind == BC.STEADY and c.exact and c.rate_hz == pytest.approx(161.54, abs=0.01) and c.dropped == 0
    assert ble.dt_s == pytest.approx(BC.STEP_PERIOD_S) and not held_rows(tel).any()
    code, out, err = run_cli(monkeypatch, capsys, "replay", _write(tmp_path / "rep.stv", recs), "--json")
    s = json.loads(out)
    assert code == 0 and s["motion_cadence"] == BC.STEADY and s["motion_rate_hz"] == 161.54
    assert s["motion_repeated_reads"] == 0 and s["estimator_dt_ms"] == 6.19 and "read" not in s["motion_cadence_text"]
    # live: the same rows from the one pipeline
    pipe = LivePipeline(["accel"])
    items = [(c, p, t) for t, c, p in recs]
    for i in range(0, len(items), 700):
        pipe.feed_ble(items[i : i + 700], final=i + 700 >= len(items))
    lc = pipe.grid.cadence()
    assert lc.kind == BC.STEADY and lc.rate_hz == pytest.approx(161.54, abs=0.01) and pipe.grid.repeats == 0
    assert pipe.health.attitude == n_motion


def test_a_poller_still_reads_as_reads():
    """The repeats of a central that reads the characteristic slower than a tick stay reads of one sample."""
    recs = B.ble_records(read_recording(REC / "ble_demo.stv").chunks)
    motion = [(t, c, p) for t, c, p in recs if c == B.CHAR_MOTION][::5]  # every 31 ms ...
    polled = [r for m in motion for r in (m, (m[0] + 0.004, m[1], m[2]))][:1000]  # ... each read twice
    ble = telemetry_of_records(polled).link
    assert ble.repeated_reads == 500 and len(ble.samples) == 500 and ble.cadence.kind == BC.POLLED


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_euler_in_the_acc_fields_is_said_and_shown_with_the_layout(monkeypatch, capsys, tmp_path):
    recs, a = euler_stream()
    path = _write(tmp_path / "fork.stv", recs)
    code, out, err = run_cli(monkeypatch, capsys, "replay", path, "--json")
    s = json.loads(out)
    assert code == 0 and s["ble_layout"] == "stock" and s["motion_rate_hz"] == 161.54
    assert "not raw sensors" in s["note"] and "not sent over BLE" not in s["note"]
    assert s["note"].count(". ") == 0  # one sentence
    code, out, err = run_cli(monkeypatch, capsys, "replay", path, "--ble-layout", "euler", "--json")
    s = json.loads(out)
    assert code == 0 and s["ble_layout"] == "euler" and "drone's own attitude" in s["note"]
    assert "not sent over BLE" not in s["note"] and "not raw sensors" not in s["note"]
    want = np.degrees(a.thx_rad.astype(np.float64))
    assert s["attitude_deg_range"]["thx"] == pytest.approx([want.min(), want.max()], abs=0.06)
    code, out, err = run_cli(monkeypatch, capsys, "replay", path, "--ble-layout", "nope")
    assert code == 2 and "--ble-layout nope" in err and "euler" in err
    # the one pipeline gives the firmware's attitude rows with the layout (no sensor values, so no estimate)
    pipe = LivePipeline(["st-mahony", "accel"], ble_layout=B.layout_named("euler"))
    pipe.feed_ble([(c, p, t) for t, c, p in recs], final=True)
    assert pipe.health.attitude == len(recs) and pipe.grid.cadence().rate_hz == pytest.approx(161.54, abs=0.01)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_euler_layout_in_rerun_is_the_firmwares_attitude(monkeypatch, capsys, tmp_path):
    from steval_viewer.rrd_check import read_rrd

    recs, a = euler_stream()
    path = _write(tmp_path / "fork.stv", recs)
    rrd = tmp_path / "fork.rrd"
    code, out, err = run_cli(monkeypatch, capsys, "replay", path, "--ble-layout", "euler", "--rrd", rrd)
    assert code == 0, err
    info = read_rrd(rrd)
    n = len(recs)
    assert info.samples["plots/pitch_thx_deg/firmware"] == n and info.samples["plots/roll_thy_deg/firmware"] == n
    assert info.samples["world/drone/firmware"] == n and info.samples.get("plots/acc_mg", 0) == 0  # no sensors sent
    assert "ble/note" in info.static


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_live_ble_with_the_euler_layout_records_it_and_replay_reads_it(monkeypatch, capsys, tmp_path):
    """steval live --ble --ble-layout euler: the one pipeline gives the firmware's attitude rows live, the capture
    header keeps the layout, and a later replay of that capture reads it without the option."""
    import sys

    from support.ble import FakeBleBackend, RecordingViewer, run_until_played

    from steval_link.live.session import LiveOptions, LiveSession, source_for
    from steval_viewer.sink_options import SinkOptions

    recs, a = euler_stream()
    fake = FakeBleBackend([(c, p) for _, c, p in recs[:600]], pace_s=0.0005)
    viewer = RecordingViewer()
    out = tmp_path / "fork.stv"
    opts = LiveOptions(out=out, sinks=SinkOptions(rrd=tmp_path / "x.rrd"), estimators=["accel"])
    session = LiveSession(
        opts,
        source_for("ble:DRN1110", backend=fake, layout="euler"),
        viewer_factory=lambda o, n: viewer,
        stream=sys.stderr,
    )
    run_until_played(session, fake)
    rows = [r.attitude for r in viewer.batches]
    thx = np.concatenate([r.thx_rad for r in rows])
    assert len(thx) == 600 and np.allclose(thx, np.round(a.thx_rad[:600] * 1000) / 1000, atol=1e-6)
    assert not np.isfinite(np.concatenate([r.acc_mg for r in rows])).any()  # no sensor values in this layout
    assert viewer.notes and "drone's own attitude" in viewer.notes[0]
    assert read_recording(out).header["extra"]["ble_layout"] == "euler"
    code, text, err = run_cli(monkeypatch, capsys, "replay", out, "--json")
    assert code == 0 and json.loads(text)["ble_layout"] == "euler"


def test_the_euler_layout_on_sensor_notifications_says_they_look_like_sensors(monkeypatch, capsys):
    """ST's unmodified firmware's notifications read with --ble-layout euler: the note says the acc fields look like
    an accelerometer's; a fork's real angles in that layout get no such sentence."""
    code, out, _ = run_cli(monkeypatch, capsys, "replay", REC / "ble_demo.stv", "--ble-layout", "euler", "--json")
    s = json.loads(out)
    assert code == 0 and "drone's own attitude" in s["note"] and "look like raw sensors" in s["note"]
    fork_acc = telemetry_of_records(euler_stream()[0]).link.samples["acc"]  # the fork's angles, x 1000
    assert link_notes(fork_acc, B.layout_named("euler")) == [EULER_NOTE]

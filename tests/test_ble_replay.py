"""BLE captures: chunk B round trip in capture format 2 (and version 1 files still read), and the user's paths on
the bundled recordings/ble_demo.stv (made from the emulated stock firmware's notifications): steval replay (text,
--json, --rrd), steval export, the README and the recipe."""

from __future__ import annotations

import json
import shlex
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.errors import UserError
from steval_link.link import ble_payloads as B
from steval_link.link import ble_telemetry as BC
from steval_link.link.capture import (
    CHUNK_BLE,
    FORMAT_VERSION,
    CaptureTruncatedWarning,
    CaptureWriter,
    encode_capture,
    read_capture,
)
from steval_link.link.load import load_telemetry

ROOT = Path(__file__).resolve().parents[1]
REC = ROOT / "recordings"
DEMO = REC / "ble_demo.stv"


def notifications(n: int) -> list[tuple[float, int, bytes]]:
    out = []
    for i in range(n):
        t = 3.0 + i * BC.STEP_PERIOD_S
        tick = int((495_000 + t * 1000)) >> 3
        out.append((t, B.CHAR_MOTION, struct.pack("<H3h3h3h", tick & 0xFFFF, i, -i, 1000, 5, -5, 0, 1, 2, 3)))
        out.append((t + 1e-4, B.CHAR_ENV, struct.pack("<HiHhh", tick & 0xFFFF, 101325, 461, 250, -620)))
        out.append((t + 2e-4, B.CHAR_ARMING, struct.pack("<HB", tick & 0xFFFF, i % 2)))
    return out


def test_chunk_b_round_trip_with_serial_bytes_and_events(tmp_path):
    recs = notifications(50)
    path = tmp_path / "b.stv"
    with CaptureWriter(path, port="ble:DRN1110", baud=0, extra={"link": "ble"}, discard_empty=True) as w:
        w.write(b"\xa5\x5a serial bytes too", t_host_s=0.5)
        for i, (t, cid, p) in enumerate(recs):
            if i == 30:
                w.mark_event("disconnect", "BLE link lost", t_host_s=t)
            w.write_chunk(CHUNK_BLE, B.ble_chunk(cid, p), t)
    assert not w.discarded and w.chunks_written == len(recs)
    cap = read_capture(path)
    assert cap.header["format_version"] == FORMAT_VERSION == 2 and not cap.truncated
    assert B.ble_records(cap.chunks) == recs  # exact bytes and times
    assert cap.data == b"\xa5\x5a serial bytes too" and [e.kind for e in cap.events] == ["disconnect"]
    # the same file from encode_capture (offline tools)
    enc = encode_capture(cap.header, [(cap.data, 0.5)], [(CHUNK_BLE, B.ble_chunk(c, p), t) for t, c, p in recs])
    assert B.ble_records(read_capture(path, data=enc).chunks) == recs
    # cut anywhere inside: the notifications before the cut read back, with the usual warning
    raw = path.read_bytes()
    for cut in (len(raw) - 3, len(raw) // 2):
        with pytest.warns(CaptureTruncatedWarning):
            part = read_capture(path, data=raw[:cut])
        got = B.ble_records(part.chunks)
        assert 0 < len(got) < len(recs) and got == recs[: len(got)]
    # a damaged B chunk loses only itself
    i = raw.index(B.ble_chunk(*recs[40][1:]))
    bad = raw[: i + 3] + bytes([raw[i + 3] ^ 0xFF]) + raw[i + 4 :]
    with pytest.warns(CaptureTruncatedWarning):
        got = B.ble_records(read_capture(path, data=bad).chunks)
    assert got == recs[:40] + recs[41:]
    # a BLE capture without any notification is discarded like an empty serial capture
    with CaptureWriter(tmp_path / "e.stv", port="ble:x", baud=0, discard_empty=True) as w:
        pass
    assert w.discarded and not (tmp_path / "e.stv").exists()
    with pytest.raises(ValueError):
        encode_capture(cap.header, [], [(ord("Z"), b"x", 0.0)])


def test_version_1_captures_still_read(tmp_path):
    from steval_link.link.capture import capture_header

    v1 = ROOT / "tests" / "data" / "v1" / "freefall.stv"  # a capture written by format 1's writer
    if v1.is_file():
        cap = read_capture(v1)
        assert cap.header["format_version"] == 1 and len(cap.data) > 10_000 and cap.chunks == {}
    head = dict(capture_header("/dev/ttyUSB0", 115200, 0.0), format_version=1)
    cap = read_capture(tmp_path / "v1.stv", data=encode_capture(head, [(b"abc", 0.1), (b"def", 0.2)]))
    assert cap.data == b"abcdef" and cap.chunks == {} and cap.header["format_version"] == 1
    head["format_version"] = 3
    with pytest.raises(UserError, match="capture format 3"):
        read_capture(tmp_path / "v3.stv", data=encode_capture(head, []))


def test_demo_is_the_stock_firmware_over_ble():
    cap = read_capture(DEMO)
    extra = cap.header["extra"]
    assert extra["link"] == "ble" and extra["emulated"] and extra["firmware"] == "st-fcu-stock.elf"
    assert cap.data == b""  # notifications only
    ble = load_telemetry(DEMO).link
    assert ble.counts["motion"] == ble.counts["environment"] == ble.counts["arming"] > 5000
    assert ble.bad_payloads == 0 and ble.unknown == 0
    # the 8 ms tick wraps once (HAL_GetTick started at 494288 ms: 30 s after power-up)
    tick, acc = ble.samples["tick"], ble.samples["acc"]
    assert tick[0] < 1 << 16 <= tick[-1] and (np.diff(tick) >= 0).all()
    assert 1 / ble.cadence.interval_s == pytest.approx(161.54, abs=0.01) and ble.cadence.dropped == 0
    # held in the hand at first: about 1 g, mostly on +z (offset removal keeps +1000 mg); never armed
    norm = np.linalg.norm(acc[:100].astype(np.float64), axis=1)
    assert abs(float(np.median(norm)) - 1000) < 80 and float(np.median(acc[:100, 2])) > 900
    assert not ble.arming["armed"].any()
    assert ble.environment["rssi_dbm"][0] == -62.0 and ble.environment["pressure_hpa"][0] == pytest.approx(1013.25)


def test_readme_and_recipe_describe_the_demo():
    text = (REC / "README.md").read_text(encoding="utf-8")
    script = (REC / "make_recordings.sh").read_text(encoding="utf-8")
    cmd = read_capture(DEMO).header["extra"]["command"]
    row = next(line for line in text.splitlines() if line.startswith("| `ble_demo.stv`"))
    assert cmd in row
    # the script runs the same options
    args = shlex.split(cmd)[3:]
    for opt, val in zip(args[::2], args[1::2]):
        if opt.startswith("--") and not val.startswith("--"):
            assert f"{opt} {val}" in script.replace("\\\n", " ").replace("  ", " "), opt
    # ST's stock build is the user's (the repository builds only its own code): the script takes its ELF
    assert "--ble" in script and '"$STEVAL" emulate "$STOCK_ELF" --ble' in script


def test_replay_summary_and_json(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "replay", DEMO)
    assert code == 0, err
    assert "BLE capture, emulated firmware" in out and "161.54 Hz" in out and "1 wrap(s)" in out
    assert "cannot be bit-exact" in out
    code, out, err = run_cli(monkeypatch, capsys, "replay", DEMO, "--json")
    s = json.loads(out)
    assert code == 0 and s["kind"] == "ble" and s["notifications"]["motion"] == 5976
    assert s["motion_dropped_estimate"] == 0 and s["tick_wraps"] == 1 and s["estimator_dt_ms"] == 6.19


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_replay_rrd_has_the_ble_layout(monkeypatch, capsys, tmp_path):
    from steval_viewer.rrd_check import blueprint_views, read_rrd

    rrd = tmp_path / "ble.rrd"
    code, out, err = run_cli(monkeypatch, capsys, "replay", DEMO, "--rrd", rrd, "-e", "st-mahony,ekf3,accel")
    assert code == 0, err
    info = read_rrd(rrd)
    assert info.has_blueprint and {"fw_time", "host_time"} <= info.timelines
    for path in (
        "plots/acc_mg",
        "plots/gyro_dps",
        "ble/mag_mgauss",
        "ble/pressure_hpa",
        "ble/battery_pct",
        "ble/rssi_dbm",
        "ble/armed",
        "ble/temperature_c",
        "world/drone/estimate/st_mahony_replica",
        "plots/pitch_thx_deg/st_mahony_replica",
        "plots/roll_thy_deg/ekf3",
        "world/drone/estimate/accel",
    ):
        assert info.samples.get(path, 0) >= 5976, path
    # no firmware attitude over BLE: nothing plotted for it; the note says why
    assert info.samples.get("plots/pitch_thx_deg/firmware", 0) == 0 and "ble/note" in info.static
    names = " ".join(blueprint_views(rrd))
    assert "magnetometer" in names and "battery" in names and "RSSI" in names and "Note" in names
    # the estimators see the tilts of the demo on the BLE samples (about ±30° in pitch)
    from steval_link.estimators.runner import run_estimator

    est, _ = run_estimator("st-mahony", load_telemetry(DEMO))
    assert 20 < np.degrees(np.nanmax(np.abs(est.thx_rad))) < 45


def test_export_csv_and_refusals(monkeypatch, capsys, tmp_path):
    csv = tmp_path / "b.csv"
    code, out, err = run_cli(monkeypatch, capsys, "export", DEMO, "--csv", csv)
    assert code == 0 and "5976 motion rows (BLE)" in out
    lines = csv.read_text().splitlines()
    assert lines[0].startswith("t_host_s,tick,t_fw_s,acc_x_mg") and "rssi_dbm,armed" in lines[0]
    assert len(lines) == 5977
    code, out, err = run_cli(monkeypatch, capsys, "export", DEMO, "--raw", tmp_path / "x.bin")
    assert code == 2 and "BLE capture" in err and err.count("\n") == 1


def test_ble_capture_without_motion_is_one_line(monkeypatch, capsys, tmp_path):
    path = tmp_path / "env_only.stv"
    with CaptureWriter(path, port="ble:x", baud=0, extra={"link": "ble"}) as w:
        w.write_chunk(CHUNK_BLE, B.ble_chunk(B.CHAR_ENV, bytes(12)), 0.1)
    code, out, err = run_cli(monkeypatch, capsys, "replay", path)
    assert code == 2 and "without motion notifications" in err
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(UserError):
            load_telemetry(path)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_ble_and_serial_captures_replay_through_the_one_model(monkeypatch, capsys):
    """steval replay of a BLE capture and of a serial one: the same Telemetry class, the same summary and estimator
    runner; the BLE link's cadence is data on the model, and its rows are those the live pipeline makes."""
    from support.ble import RecordingViewer

    import steval_link.cli.replay as R
    from steval_link.link.telemetry import Telemetry
    from steval_link.live.pipeline import LivePipeline

    seen = []
    summarize, run_estimator = R.summarize, R.run_estimator

    def summary_spy(tel, **kw):
        seen.append(("summary", type(tel), tel.link is not None))
        return summarize(tel, **kw)

    def estimator_spy(name, tel, **kw):
        seen.append(("estimator", type(tel), len(tel.attitude)))
        return run_estimator(name, tel, **kw)

    monkeypatch.setattr(R, "summarize", summary_spy)
    monkeypatch.setattr(R, "run_estimator", estimator_spy)
    out = {}
    for name, path in (("serial", REC / "demo.stv"), ("ble", DEMO)):
        code, text, err = run_cli(monkeypatch, capsys, "replay", path, "-e", "st-mahony", "--json")
        assert code == 0, err
        out[name] = json.loads(text)
    tel = load_telemetry(DEMO)
    assert seen == [
        ("estimator", Telemetry, len(load_telemetry(REC / "demo.stv").attitude)),
        ("summary", Telemetry, False),
        ("estimator", Telemetry, 5976),
        ("summary", Telemetry, True),
    ]
    assert out["ble"]["motion_cadence"] == tel.link.cadence.kind == BC.STEADY and tel.link.dt_s == BC.STEP_PERIOD_S
    replica = out["ble"]["estimators"][0]
    assert replica["name"] == "st-mahony" and replica["valid_rows"] == replica["rows"] == 5976
    assert replica["rms_diff_pitch_deg"] is None  # no firmware attitude over BLE: nothing to differ from
    assert out["serial"]["estimators"][0]["rms_diff_pitch_deg"] == 0.0  # the replica is the firmware's filter
    # the rows a capture loads are the rows the live pipeline makes of the same notifications
    viewer = RecordingViewer()
    pipe = LivePipeline([], viewer, t0_unix_s=0.0, baud=0)
    items = B.ble_items(read_capture(DEMO).chunks)
    for i in range(0, len(items), 700):
        pipe.feed_ble(items[i : i + 700], final=i + 700 >= len(items))
    pipe.flush_view()
    live = np.concatenate([b.attitude.t_fw_s for b in viewer.batches])
    assert np.array_equal(live, tel.attitude.t_fw_s)
    assert np.array_equal(np.concatenate([b.attitude.acc_mg for b in viewer.batches]), tel.attitude.acc_mg)

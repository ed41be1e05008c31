"""``steval export CAPTURE --mcap OUT.mcap``: read back with the ``mcap`` package's reader (message counts equal to
the frame counts, schema names and encodings as documented, log time on the firmware clock), and opened by Rerun's
own MCAP loader (``rerun mcap convert``)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.analysis.mcap_export import TOPICS
from steval_link.link.load import load_telemetry

reader = pytest.importorskip("mcap.reader")

REC = Path(__file__).resolve().parents[1] / "recordings"


def messages(path: Path):
    with open(path, "rb") as f:
        r = reader.make_reader(f, validate_crcs=True)
        summary = r.get_summary()
        return summary, [(schema, channel, msg) for schema, channel, msg in r.iter_messages()]


def export(monkeypatch, capsys, capture: Path, out: Path, *extra) -> str:
    code, stdout, err = run_cli(monkeypatch, capsys, "export", capture, "--mcap", out, *extra)
    assert code == 0, err
    return stdout


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_counts_schemas_and_firmware_time(monkeypatch, capsys, tmp_path):
    cap = REC / "flight.stv"
    out = tmp_path / "flight.mcap"
    stdout = export(monkeypatch, capsys, cap, out)
    tel = load_telemetry(cap)
    summary, msgs = messages(out)
    counts = Counter(ch.topic for _, ch, _ in msgs)
    n = len(tel.attitude)
    assert counts == {
        "/attitude/transform": n,
        "/attitude/pose": n,
        "/attitude": n,
        "/status": len(tel.status),
        "/flight_control": len(tel.fc),
    }
    assert f"/attitude {n}" in stdout
    names = {ch.topic: schema.name for schema, ch, _ in msgs}
    assert names == {topic: TOPICS[topic][0] for topic in counts}
    assert names["/attitude/transform"] == "foxglove.FrameTransform"
    assert names["/attitude/pose"] == "foxglove.PoseInFrame"
    assert {schema.encoding for schema, _, _ in msgs} == {"jsonschema"}
    assert {ch.message_encoding for _, ch, _ in msgs} == {"json"}
    assert summary.statistics.message_count == len(msgs)
    att = [(m, json.loads(m.data)) for _, ch, m in msgs if ch.topic == "/attitude"]
    t_ns = np.array([m.log_time for m, _ in att])
    assert np.array_equal(t_ns, np.round(tel.attitude.t_fw_s * 1e9).astype(np.int64))  # the firmware clock
    assert all(m.publish_time == m.log_time for m, _ in att[:50])
    first = att[0][1]
    assert np.float32(first["thx_pitch_rad"]) == tel.attitude.thx_rad[0]  # float32 read back exactly
    assert np.array_equal(np.float32(first["acc_mg"]), tel.attitude.acc_mg[0])
    assert first["step"] == tel.attitude.step[0] and first["exact"] is True
    tf = next(json.loads(m.data) for _, ch, m in msgs if ch.topic == "/attitude/transform")
    q = tel.attitude.q_wxyz[0].astype(np.float64)
    q /= np.linalg.norm(q)
    assert tf["parent_frame_id"] == "world" and tf["child_frame_id"] == "drone"
    assert [tf["rotation"][k] for k in "wxyz"] == pytest.approx(q.tolist(), abs=1e-8)
    assert tf["timestamp"]["sec"] * 10**9 + tf["timestamp"]["nsec"] == t_ns[0]
    st = next(json.loads(m.data) for _, ch, m in msgs if ch.topic == "/status")
    assert st["ki"] == pytest.approx(0.1) and st["correction"] is True
    fc = next(json.loads(m.data) for _, ch, m in msgs if ch.topic == "/flight_control")
    assert len(fc["motor_pwm"]) == 4 and set(fc) >= {"target_rad", "outer_s1_radps", "inner_s2_pwm", "armed"}
    with open(out, "rb") as f:
        meta = {m.name: m.metadata for m in reader.make_reader(f).iter_metadata()}
    assert json.loads(meta["settings"]["ki"]) == pytest.approx(0.1)
    assert json.loads(meta["header"]["port"]) == "emulated:steval-fcu-link.elf"


def test_text_mode_and_missing_host_times(monkeypatch, capsys, tmp_path):
    code, _, _ = run_cli(
        monkeypatch,
        capsys,
        "synth",
        "--scenario",
        "bench",
        "--duration",
        "6",
        "--text-mode",
        "--out",
        tmp_path / "text.stv",
    )
    assert code == 0
    out = tmp_path / "text.mcap"
    export(monkeypatch, capsys, tmp_path / "text.stv", out)
    tel = load_telemetry(tmp_path / "text.stv")
    _, msgs = messages(out)
    att = [json.loads(m.data) for _, ch, m in msgs if ch.topic == "/attitude"]
    assert len(att) == len(tel.attitude) > 0
    assert att[0]["q_wxyz"] == [None] * 4 and att[0]["exact"] is False  # text mode: no q, null not NaN
    # a row that is not a binary frame keeps its firmware time to 9 significant digits, not to the µs
    raw = [m.data for _, ch, m in msgs if ch.topic == "/attitude"]
    t_fw = np.asarray(tel.attitude.t_fw_s, np.float64)
    assert all(b'"t_fw_s":%.9g,' % t in r for t, r in zip(t_fw[:50].tolist(), raw))
    tf = [json.loads(m.data) for _, ch, m in msgs if ch.topic == "/attitude/transform"]
    assert len(tf) == len(att) and all(isinstance(t["rotation"]["w"], (int, float)) for t in tf)


def test_refuses_to_overwrite_and_ble(monkeypatch, capsys, tmp_path):
    out = tmp_path / "x.mcap"
    out.write_bytes(b"keep me")
    code, _, err = run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--mcap", out)
    assert code == 2 and err == f"steval: error: --mcap {out} already exists (use --force to overwrite)\n"
    assert out.read_bytes() == b"keep me"
    export(monkeypatch, capsys, REC / "demo.stv", out, "--force")
    assert out.read_bytes()[:8] == b"\x89MCAP0\r\n" and not (tmp_path / "x.mcap.partial").exists()
    code, _, err = run_cli(monkeypatch, capsys, "export", REC / "ble_demo.stv", "--mcap", tmp_path / "b.mcap")
    assert code == 2 and "BLE capture" in err and err.count("\n") == 1 and not (tmp_path / "b.mcap").exists()


def test_without_mcap_one_line(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "mcap.records", None)
    code, _, err = run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--mcap", tmp_path / "x.mcap")
    assert (
        code == 2
        and err
        == 'steval: error: --mcap needs the mcap package, which is not installed: pip install "steval-link[mcap]"\n'
    )


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_rerun_opens_it(monkeypatch, capsys, tmp_path):
    """Rerun 0.41's MCAP loader reads the file: one entity per topic, every message on the log-time timeline
    (JSON messages are kept as raw MCAP messages; Rerun decodes Foxglove schemas only in protobuf)."""
    from steval_viewer.rrd_check import read_rrd
    from steval_viewer.sinks import rerun_command

    out = tmp_path / "demo.mcap"
    export(monkeypatch, capsys, REC / "demo.stv", out)
    rrd = tmp_path / "demo.rrd"
    r = subprocess.run(
        [*rerun_command(), "mcap", "convert", str(out), "-o", str(rrd)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    info = read_rrd(rrd)
    n = len(load_telemetry(REC / "demo.stv").attitude)
    assert info.samples["attitude/transform"] == n and info.samples["attitude"] == n
    assert "message_log_time" in info.timelines


def test_documented_topics_and_schemas_are_the_written_ones():
    """docs/EXPORT_FORMATS.md's MCAP table names exactly the topics and schemas the writer uses."""
    import re

    doc = (REC.parent / "docs" / "EXPORT_FORMATS.md").read_text(encoding="utf-8").split("## MCAP", 1)[1]
    documented = dict(re.findall(r"^\| `(/[\w/]+)` \| `([\w.]+)` \|", doc, re.M))
    assert documented == {topic: schema for topic, (schema, _) in TOPICS.items()}

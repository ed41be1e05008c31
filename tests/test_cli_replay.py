"""``steval replay`` / ``steval ports`` / main(): summaries, JSON, exit codes, one-line user errors."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from support.streams import StreamBuilder

from steval_link.cli import main
from steval_link.link.capture import CaptureWriter


def run(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


@pytest.fixture
def capture(tmp_path, make_stream):
    b: StreamBuilder = make_stream(7)
    b.text("STEVAL-FCU001V1 steval-link 1.0.0")
    for i in range(1000, 2000):
        if i in (1500, 1501, 1502):
            continue  # three frames lost on the way
        b.attitude(i)
        if i % 161 == 0:
            b.status(i, tx_dropped=2, ki=1.0)
    data = b.bytes()
    path = tmp_path / "flight.stv"
    with CaptureWriter(path, port="/dev/ttyUSB0", baud=115200) as w:
        for j in range(0, len(data), 200):
            w.write(data[j : j + 200], t_host_s=j / 11520)
        w.mark_event("disconnect", "cable")
    return path


def test_replay_summary_text(capture, capsys):
    code, out, err = run(["replay", str(capture)], capsys)
    assert code == 0, err
    assert "997 attitude" in out and "6 status" in out and "1 text" in out
    assert "3 frames missing in 1 gaps" in out and "0 CRC failures" in out
    assert "ki 1" in out and "event at" in out and "disconnect" in out
    assert "STEVAL-FCU001V1" in out


def test_replay_json(capture, capsys):
    code, out, _ = run(["replay", str(capture), "--json"], capsys)
    assert code == 0
    s = json.loads(out)
    assert s["frames"]["attitude"] == 997 and s["frames"]["status"] == 6
    assert s["drops"] == {"seq_gaps": 1, "frames_missing": 3, "drop_ratio": 3 / 1000, "seq_resets": 0, "tx_dropped": 2}
    assert s["crc_failures"] == 0 and s["source"]["kind"] == "stv" and s["source"]["baud"] == 115200
    assert s["first_step"] == 1000 and s["last_step"] == 1999
    assert s["step_rate_hz"] == pytest.approx(161.5, rel=1e-3)
    assert s["duration_s"] == pytest.approx(999 * 0.0061919, rel=1e-4)
    assert s["filter"]["ki"] == 1.0 and s["filter"]["kp_ground"] == 10.0 and s["filter"]["min_thr"] == 200


def test_replay_default_is_demo_recording(capture, capsys, monkeypatch):
    import steval_link.cli.replay as replay_mod

    monkeypatch.setattr(replay_mod, "demo_capture_path", lambda: capture)
    code, out, _ = run(["replay", "--json"], capsys)
    assert code == 0 and json.loads(out)["source"]["path"] == str(capture)


def test_replay_raw_dump_and_truncated_capture(tmp_path, capture, capsys):
    from steval_link.link.capture import read_capture

    raw = tmp_path / "log.bin"
    raw.write_bytes(read_capture(capture).data[100:])
    code, out, _ = run(["replay", str(raw), "--json"], capsys)
    assert code == 0 and json.loads(out)["source"]["kind"] == "raw"
    cut = tmp_path / "cut.stv"
    cut.write_bytes(capture.read_bytes()[:-10])
    code, out, err = run(["replay", str(cut)], capsys)
    assert code == 0 and "warning" in err and "cut short" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["replay", "/nonexistent/x.stv"], "no such file"),
        (["export", "/nonexistent/x.stv", "--csv", "o.csv"], "no such file"),
    ],
)
def test_user_errors_exit_2_one_line(argv, needle, capsys):
    code, out, err = run(argv, capsys)
    assert code == 2 and needle in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_not_a_capture_and_empty(tmp_path, capsys):
    p = tmp_path / "notes.txt"
    p.write_text("shopping list\neggs\n")
    code, _, err = run(["replay", str(p)], capsys)
    assert code == 2 and "not a steval capture" in err
    e = tmp_path / "empty.bin"
    e.write_bytes(b"")
    code, _, err = run(["replay", str(e)], capsys)
    assert code == 2 and "empty" in err


def test_usage_errors_are_one_line_and_exit_2(capsys):
    code, out, err = run(["replay", "--bogus"], capsys)
    assert code == 2 and err.startswith("steval: error:") and "--bogus" in err and "steval replay --help" in err
    assert len(err.strip().splitlines()) == 1
    code, out, err = run(["no-such-command"], capsys)
    assert code == 2


def test_help_exits_0(capsys):
    code, out, _ = run(["--help"], capsys)
    assert code == 0 and "replay" in out and "export" in out and "ports" in out
    code, out, _ = run(["replay", "--help"], capsys)
    assert code == 0 and "--json" in out and "--rrd" in out


def test_ports_json(capsys):
    code, out, _ = run(["ports", "--json"], capsys)
    assert code == 0
    ports = json.loads(out)
    assert isinstance(ports, list) and all({"device", "description", "vid_pid"} <= set(p) for p in ports)


@pytest.mark.slow  # two steval children (interpreter start-up, imports): ≈ 2 s
def test_console_script_subprocess(capture):
    """The installed entry point: exit codes as a shell sees them, no traceback."""
    r = subprocess.run(
        [sys.executable, "-c", "from steval_link.cli import main; main()", "replay", str(capture), "--json"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0 and json.loads(r.stdout)["frames"]["attitude"] == 997
    r = subprocess.run(
        [sys.executable, "-c", "from steval_link.cli import main; main()", "replay", "/nope"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and r.stderr.startswith("steval: error:") and "Traceback" not in r.stderr


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_replay_estimators_choose_what_the_rrd_holds(capture, tmp_path, capsys):
    from steval_viewer.rrd_check import read_rrd

    out_rrd = tmp_path / "accel_only.rrd"
    code, out, err = run(["replay", str(capture), "--rrd", str(out_rrd), "-e", "accel"], capsys)
    assert code == 0, err
    paths = read_rrd(out_rrd).samples
    assert any(p.endswith("/accel") for p in paths)
    assert not any(p.endswith("/ekf3") or p.endswith("/mekf") for p in paths)

    default_rrd = tmp_path / "default.rrd"
    code, _, err = run(["replay", str(capture), "--rrd", str(default_rrd)], capsys)
    assert code == 0, err
    paths = read_rrd(default_rrd).samples
    assert any(p.endswith("/ekf3") for p in paths) and any(p.endswith("/mekf") for p in paths)


def test_replay_unknown_estimator_is_one_line_exit_2(capture, tmp_path, capsys):
    code, _, err = run(["replay", str(capture), "--rrd", str(tmp_path / "x.rrd"), "-e", "kalman9"], capsys)
    assert code == 2
    assert err.strip().count("\n") == 0 and "kalman9" in err and "ekf3" in err


def test_replay_names_flight_control_frames_and_their_rate(capsys):
    from pathlib import Path

    flight = Path(__file__).resolve().parents[1] / "recordings" / "flight.stv"
    code, out, err = run(["replay", str(flight)], capsys)
    assert code == 0, err
    line = next(x for x in out.splitlines() if x.startswith("frames:"))
    assert "flight control (every 23 steps)" in line
    code, out, _ = run(["replay", str(flight), "--json"], capsys)
    f = json.loads(out)["frames"]
    assert f["flight_control"] > 100 and f["flight_control_every"] == 23

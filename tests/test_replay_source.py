"""``--port replay://CAPTURE``: a recording played back at its recorded pace walks the whole live path (capture,
decoder, estimators, summary), on the real bytes of the bundled recordings."""

from __future__ import annotations

import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli
from support.ptyfeed import StevalProcess

from steval_link import constants as C
from steval_link.errors import UserError
from steval_link.link.capture import read_capture
from steval_link.link.load import load_telemetry
from steval_link.link.replay_source import PROMPT_NOTE, ReplayPort, open_replay, parse_replay_url
from steval_link.live.session import LiveOptions, LiveSession, source_for

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "recordings" / "demo.stv"
FLIGHT = ROOT / "recordings" / "flight.stv"
TEXTLOG = ROOT / "recordings" / "textmode.log"
FIELDS = ("seq", "t_us", "acc_mg", "gyro_mdps", "thr", "q_wxyz", "thx_rad", "thy_rad", "thz_rad")


class FakeClock:
    def __init__(self) -> None:
        self.t_s = 100.0

    def __call__(self) -> float:
        return self.t_s


def _same_first_frames(new, old) -> int:
    a, b = new.attitude, old.attitude
    n = len(a)
    assert 0 < n <= len(b)
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)[:n], equal_nan=True), f
    return n


def test_url_forms_and_bad_urls_are_one_sentence():
    assert parse_replay_url("replay://recordings/demo.stv").path == Path("recordings/demo.stv")
    assert parse_replay_url("REPLAY:///tmp/x.stv").path == Path("/tmp/x.stv")
    assert parse_replay_url("replay://a%20b.stv?speed=5").speed == 5.0
    for url, words in [
        ("replay://", "no file to replay"),
        ("replay://x.stv?speed=0", "speed must be a positive number"),
        ("replay://x.stv?speed=fast", "speed must be a positive number"),
        ("replay://x.stv?loops=1", "unknown replay option .loops."),
    ]:
        with pytest.raises(UserError, match=words):
            parse_replay_url(url)
    with pytest.raises(UserError, match="no such file"):
        open_replay("replay://no/such/capture.stv")
    with pytest.raises(UserError, match="BLE capture"):
        open_replay(f"replay://{ROOT / 'recordings' / 'ble_demo.stv'}")
    with pytest.raises(UserError, match="no frames found"):
        open_replay(f"replay://{ROOT / 'README.md'}")


def test_capture_bytes_come_out_at_their_recorded_host_times():
    cap = read_capture(DEMO)
    tel = load_telemetry(DEMO)
    clock = FakeClock()
    port = open_replay(f"replay://{DEMO}")
    port = ReplayPort(port.data, port.ends, port.t_s, port=port.port, path=port.path, clock=clock, timeout=0)
    assert port.data == cap.data and port.baudrate == 115200
    # the lead-in (boot banner, start-up silence) is out at once, up to the chunk holding the first attitude frame
    first = int(tel.attitude.offset[0])
    k = int(np.searchsorted(cap.chunk_offsets, first, side="right"))
    lead = int(cap.chunk_offsets[k])
    assert port.in_waiting == lead and lead > first
    t_lead = cap.chunk_times_s[k - 1]
    # then each chunk at its recorded time after the first frame's chunk
    for j in (k, k + 10, k + 500):
        clock.t_s = 100.0 + (cap.chunk_times_s[j] - t_lead) - 1e-6
        assert port.in_waiting == int(cap.chunk_offsets[j])
        clock.t_s += 2e-6
        assert port.in_waiting == int(cap.chunk_offsets[j + 1])
    got = port.read(port.in_waiting)
    assert got == cap.data[: len(got)]
    with pytest.raises(OSError, match="no commands"):
        port.write(b"\xa5\x5a")
    clock.t_s += 1e6
    rest = port.read(len(cap.data))
    assert got + rest == cap.data and port.at_end and port.read(1) == b""


def test_a_text_log_is_paced_by_its_frames_firmware_time_and_speed_divides_it():
    tel = load_telemetry(TEXTLOG)
    port = open_replay(f"replay://{TEXTLOG}?speed=4")
    att = tel.attitude
    # frame i is out at its firmware time after frame 0 (over 4), once frame i+1 starts
    i = len(att) // 2
    j = int(np.searchsorted(port.ends, att.offset[i + 1]))
    assert port.ends[j] == att.offset[i + 1]
    assert port.t_s[j] == pytest.approx((att.t_fw_s[i] - att.t_fw_s[0]) / 4)
    assert np.all(np.diff(port.t_s) >= 0)


@pytest.mark.slow  # real time: 2 s of replay
def test_live_session_on_a_replay_records_the_recorded_rate_and_the_same_frames(tmp_path):
    out = tmp_path / "x.stv"
    opts = LiveOptions(out=out, estimators=["st-mahony"], duration_s=2.0, prompt=False)
    summary = LiveSession(opts, source_for(f"replay://{DEMO}"), stream=open(tmp_path / "err.txt", "w")).run()
    # at the recorded rate; how many frames 2 s of wall time hold depends on the machine's load
    assert summary.attitude >= 1.5 * C.AHRS_RATE_HZ, summary.line()
    assert summary.attitude / summary.streaming_s == pytest.approx(C.AHRS_RATE_HZ, rel=0.04), summary.line()
    assert summary.frames_missing == 0 and summary.crc_failures == 0
    assert "ST replica bit-exact" in summary.line() and str(out) in summary.line()
    cap = read_capture(out)
    assert cap.header["port"] == f"replay://{DEMO}" and cap.header["extra"]["replay_of"] == str(DEMO)
    assert cap.data == read_capture(DEMO).data[: len(cap.data)]  # byte for byte the source's beginning
    assert [e.kind for e in cap.events] == ["stop"] and cap.events[0].text == "duration"
    n = _same_first_frames(load_telemetry(out), load_telemetry(DEMO))
    assert n == summary.attitude


@pytest.mark.slow  # real time: 27 s of flight at 50x
def test_a_replay_played_to_its_end_stops_by_itself_with_every_byte(tmp_path):
    out = tmp_path / "all.stv"
    opts = LiveOptions(out=out, estimators=[], prompt=False)
    t0 = time.monotonic()
    summary = LiveSession(opts, source_for(f"replay://{FLIGHT}?speed=50"), stream=open(tmp_path / "err.txt", "w")).run()
    assert time.monotonic() - t0 < 10
    assert summary.stopped_by == "end of replay"
    src = load_telemetry(FLIGHT)
    assert summary.attitude == len(src.attitude)
    assert read_capture(out).data == read_capture(FLIGHT).data
    assert _same_first_frames(load_telemetry(out), src) == len(src.attitude)


@pytest.mark.slow  # real time: the CLI in a child process
def test_cli_ctrl_c_on_a_replay_ends_cleanly_with_the_capture_kept(tmp_path):
    out = tmp_path / "cap.stv"
    proc = StevalProcess(
        ["live", "--no-view", "--port", f"replay://{DEMO}", "--out", str(out), "-e", "none"], cwd=tmp_path
    )
    assert proc.wait_line("reading ", 60) is not None, proc.stderr
    assert proc.wait_line(" Hz | frames ", 30) is not None, proc.stderr
    time.sleep(1.0)
    rc = proc.finish(sig=signal.SIGINT)
    assert rc == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    summary = proc.stdout.strip().splitlines()
    assert len(summary) == 1 and summary[0].startswith("recorded ") and str(out) in summary[0], proc.stdout
    cap = read_capture(out)
    assert not cap.truncated
    assert [(e.kind, e.text) for e in cap.events] == [("stop", "interrupted")]
    assert len(cap.data) > 10_000 and cap.data == read_capture(DEMO).data[: len(cap.data)]
    assert _same_first_frames(load_telemetry(out), load_telemetry(DEMO)) > 100


def test_cli_bad_replay_url_is_one_line(monkeypatch, capsys, tmp_path):
    for command in (["live", "--no-view"], ["record"]):
        code, _, err = run_cli(
            monkeypatch, capsys, *command, "--port", "replay://no/such.stv", "--out", str(tmp_path / "x.stv")
        )
        assert code == 2 and err.startswith("steval: error: cannot replay replay://no/such.stv"), err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "x.stv").exists()


@pytest.mark.slow  # real time: the CLI in a child process, 2 s of replay
def test_cli_prompt_on_a_replay_says_once_that_commands_go_nowhere(tmp_path):
    import os
    import subprocess
    import sys

    out = tmp_path / "cmd.stv"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "from steval_link.cli import main; main()",
            "live",
            "--no-view",
            "--prompt",
            "--port",
            f"replay://{DEMO}",
            "--out",
            str(out),
            "-e",
            "none",
            "--duration",
            "2",
        ],
        input="set ki 1.0\nstatus\n",
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count(PROMPT_NOTE) == 1, proc.stderr
    assert "set ki" in proc.stderr and "not sent (a replay takes no commands)" in proc.stderr
    cap = read_capture(out)
    assert cap.host == [] and [e.text for e in cap.events] == ["duration"]  # nothing recorded as sent
    assert proc.stdout.startswith("recorded ") and len(proc.stdout.strip().splitlines()) == 1


@pytest.mark.slow  # real time: 17 s of text-mode log at 20x
def test_a_text_mode_log_replays_live_to_its_end(tmp_path):
    out = tmp_path / "text.stv"
    opts = LiveOptions(out=out, estimators=["st-mahony", "accel"], prompt=False)
    source = source_for(f"replay://{TEXTLOG}?speed=20")
    summary = LiveSession(opts, source, stream=open(tmp_path / "err.txt", "w")).run()
    src = load_telemetry(TEXTLOG)
    assert summary.stopped_by == "end of replay" and summary.attitude == len(src.attitude) == 172
    assert "ST replica not run (no binary frames" in summary.line()  # text-mode rows are rounded: not its inputs
    assert read_capture(out).data == TEXTLOG.read_bytes()


@pytest.mark.slow  # real time: 1.5 s of a replay at 5x
def test_a_faster_replay_says_the_drones_own_rate(tmp_path):
    """replay://...?speed=5: the frames arrive at 5 × 161.5 Hz; the summary says the drone's own rate too."""
    opts = LiveOptions(out=tmp_path / "x.stv", estimators=[], duration_s=1.5, prompt=False)
    summary = LiveSession(opts, source_for(f"replay://{DEMO}?speed=5"), stream=open(tmp_path / "err.txt", "w")).run()
    assert summary.pace == 5.0
    drone_hz = float(re.search(r"5× pace: ([\d.]+) Hz in the drone's time", summary.line()).group(1))
    assert drone_hz == pytest.approx(C.AHRS_RATE_HZ, rel=0.04), summary.line()


@pytest.mark.slow  # real time: 4 s, about three rounds of the demo at 40x
def test_a_looped_replay_has_no_cut_frame_at_its_seams(tmp_path):
    """replay://demo.stv?loop=1: each round ends after its last whole frame, so the seams are no CRC failure."""
    opts = LiveOptions(out=tmp_path / "x.stv", estimators=[], duration_s=4.0, prompt=False)
    url = f"replay://{DEMO}?loop=1&speed=40"
    summary = LiveSession(opts, source_for(url), stream=open(tmp_path / "err.txt", "w")).run()
    assert summary.attitude > 2 * len(load_telemetry(DEMO).attitude), summary.line()
    assert summary.crc_failures == 0 and summary.frames_missing == 0, summary.line()

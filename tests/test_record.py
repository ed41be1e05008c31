"""``steval record`` (capture only) against a pseudo-terminal, and the port errors a student meets first."""

from __future__ import annotations

import os
import signal
import time

import pytest
from support.ptyfeed import PtyFeeder, StevalProcess, flight_stream

from steval_link.link.capture import read_capture
from steval_link.link.load import load_telemetry

fcntl = pytest.importorskip("fcntl", reason="POSIX file control on a pseudo-terminal: not on Windows")

pytestmark = pytest.mark.slow  # real time: processes on pseudo-terminals


START_TIMEOUT_S = 60.0


def test_record_duration_writes_the_capture_and_a_summary(tmp_path):
    data = flight_stream(1000)
    out = tmp_path / "field.stv"
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = StevalProcess(["record", "--port", str(feeder.link), "--duration", "2", "--out", str(out)], cwd=tmp_path)
        assert proc.wait_line("reading ", START_TIMEOUT_S) is not None, proc.stderr
        feeder.start()
        rc = proc.finish(timeout_s=60)
    assert rc == 0, proc.stderr
    cap = read_capture(out)
    assert cap.header["port"] == str(feeder.link) and cap.header["baud"] == 115200
    assert [e.kind for e in cap.events] == ["stop"] and cap.events[0].text == "duration"
    assert cap.data == data[: len(cap.data)]
    tel = load_telemetry(out)
    # about 2 s of frames at 161.5 Hz (the feeder started a moment after the port opened)
    assert 200 < len(tel.attitude) < 2.6 * 161.5
    line = proc.stdout.strip()
    assert line.startswith("recorded ") and f"{len(tel.attitude)} attitude frames" in line and str(out) in line
    assert "rerun" not in line and not list(tmp_path.glob("*.rrd"))


def test_record_default_name_is_utc_timestamp_under_recordings(tmp_path):
    with PtyFeeder(flight_stream(400), tmp_path / "ttyUSB0") as feeder:
        proc = StevalProcess(["record", "--port", str(feeder.link)], cwd=tmp_path)
        assert proc.wait_line("reading ", START_TIMEOUT_S) is not None, proc.stderr
        feeder.start()
        assert feeder.wait_done(30)
        time.sleep(0.3)
        assert proc.finish(sig=signal.SIGTERM) == 0, proc.stderr
    files = list((tmp_path / "recordings").glob("steval-*Z.stv"))
    assert len(files) == 1, files
    assert len(files[0].name) == len("steval-20260101T000000Z.stv")
    assert read_capture(files[0]).data == flight_stream(400)
    assert read_capture(files[0]).events[-1].text == "terminated"


def _error_line(proc: StevalProcess) -> str:
    lines = [line for _, line in proc.lines if line.startswith("steval: error:")]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


def test_record_missing_port_lists_the_alternatives(tmp_path):
    proc = StevalProcess(["record", "--port", str(tmp_path / "ttyUSB9"), "--out", str(tmp_path / "x.stv")])
    assert proc.finish() == 2
    line = _error_line(proc)
    assert line.startswith(f"steval: error: no serial port {tmp_path / 'ttyUSB9'}")
    assert "available ports:" in line or "no serial ports found" in line
    assert not (tmp_path / "x.stv").exists()


def test_record_busy_port_names_the_fix(tmp_path):
    with PtyFeeder(flight_stream(100), tmp_path / "ttyUSB0") as feeder:
        holder = os.open(str(feeder.link), os.O_RDWR | os.O_NOCTTY)
        fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as another program holding the port
        try:
            proc = StevalProcess(["record", "--port", str(feeder.link), "--out", str(tmp_path / "x.stv")])
            assert proc.finish() == 2
        finally:
            os.close(holder)
    line = _error_line(proc)
    assert "is busy: close the other program using it (screen, minicom, Arduino IDE" in line


def _without_dac_override():
    """Child side: drop root's power to open any file (CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH) before exec."""
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        if libc.prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            os._exit(97)


def test_record_permission_denied_names_the_dialout_fix(tmp_path):
    with PtyFeeder(flight_stream(100), tmp_path / "ttyUSB0") as feeder:
        os.chmod(feeder.slave_name, 0o000)  # as /dev/ttyUSB0 (root:dialout 660) for a user outside dialout
        try:
            preexec = _without_dac_override if os.geteuid() == 0 else None
            proc = StevalProcess(
                ["record", "--port", str(feeder.link), "--out", str(tmp_path / "x.stv")], preexec_fn=preexec
            )
            rc = proc.finish()
        finally:
            os.chmod(feeder.slave_name, 0o620)
    if rc == 97 or (rc == 0 and os.geteuid() == 0):
        pytest.skip("cannot drop root's file-permission override here")
    assert rc == 2, proc.stderr
    line = _error_line(proc)
    assert line == (
        f"steval: error: permission denied on {feeder.link}: add yourself to the dialout group: "
        "sudo usermod -aG dialout $USER, then log out and in"
    )


def test_record_never_overwrites_a_capture(tmp_path):
    out = tmp_path / "x.stv"
    out.write_bytes(b"precious")
    with PtyFeeder(flight_stream(100), tmp_path / "ttyUSB0") as feeder:
        proc = StevalProcess(["record", "--port", str(feeder.link), "--out", str(out)])
        assert proc.finish() == 2
    assert "already exists" in _error_line(proc)
    assert out.read_bytes() == b"precious"

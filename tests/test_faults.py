"""Faults a lab laptop sees (issue 38), each as a student meets it: ``steval live`` on a pseudo-terminal fed at the
link's real rate (:class:`support.ptyfeed.PtyFeeder`), and what the outputs, the terminal and the exit code say.

The real-time cases run the CLI in a child process and are marked slow; the unit cases (the finder's choice, the
writers' failure sentences, the looping replay) run in the quick suite. A full disk is a tiny tmpfs mounted in the
test's folder: those cases need root (and a kernel that lets us mount), else they skip.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.ptyfeed import REAL_BYTES_PER_S, PtyFeeder, StevalProcess, flight_stream

from steval_link import constants as C
from steval_link.link import autodetect
from steval_link.link.capture import CaptureWriter, OutputLostError, read_capture
from steval_link.link.decoder import StreamDecoder
from steval_link.link.replay_source import ReplayPort, parse_replay_url

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "recordings" / "demo.stv"
START_TIMEOUT_S = 60.0
slow = pytest.mark.slow
#: a second reader of a port (a serial monitor left open): waits for bytes and takes them
MONITOR = (
    "import os, select, sys\n"
    "fd = os.open(sys.argv[1], os.O_RDONLY | os.O_NOCTTY)\n"
    "while True:\n"
    "    select.select([fd], [], [])\n"
    "    os.read(fd, 4096)\n"
)


# ------------------------------------------------------------------------------------------------------------
# helpers


@pytest.fixture
def tiny_disk(tmp_path):
    """A 256 kB tmpfs at ``tmp_path/small`` (root only; skipped where it cannot be mounted)."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("mounting a tiny tmpfs needs root")
    where = tmp_path / "small"
    where.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(where)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.decode(errors='replace').strip()})")
    yield where
    subprocess.run(["umount", "-l", str(where)], capture_output=True)


def fill(folder: Path) -> Path:
    """Fill ``folder``'s file system to the last byte; returns the filler file."""
    filler = folder / "filler"
    with open(filler, "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 512)
        except OSError:
            pass
    return filler


def live(tmp_path, port, *extra: str, out: Path | None = None) -> StevalProcess:
    """``steval live --no-view`` on ``port``, started (its first note seen)."""
    out = out or tmp_path / "cap.stv"
    proc = StevalProcess(
        ["live", "--no-view", "--no-prompt", "--port", str(port), "--out", str(out), *extra], cwd=tmp_path
    )
    assert proc.wait_line("reading ", START_TIMEOUT_S) is not None, proc.stderr
    return proc


def capture_of(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_capture(path)


def no_raw_rerun_lines(text: str) -> bool:
    """Rerun's own log lines (``ERROR re_...``, ``file_sink``, ANSI colours) never reach the user."""
    return "file_sink" not in text and "\x1b[" not in text and " ERROR " not in text and "Traceback" not in text


def summary_line(proc: StevalProcess) -> str:
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 1, proc.stdout + proc.stderr
    return lines[0]


# ------------------------------------------------------------------------------------------------------------
# 1, 2: the .rrd as safe as the capture


@slow
def test_rrd_is_written_as_the_data_arrives_and_opens_after_kill_9(tmp_path):
    from steval_viewer.rrd_check import read_rrd

    data = flight_stream(1600)
    rrd = tmp_path / "live.rrd"
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link, "--rrd", str(rrd), "--estimators", "accel")
        feeder.start()
        assert proc.wait_line(" Hz", 30) is not None, proc.stderr  # the .rrd's side is up
        time.sleep(3.0)
        proc.proc.send_signal(signal.SIGKILL)
        proc.finish()
    frames = [f for f in StreamDecoder().feed(capture_of(tmp_path / "cap.stv").data) if hasattr(f, "seq")]
    assert len(frames) > 2 * C.AHRS_RATE_HZ
    info = read_rrd(rrd)  # Rerun opens the file cut by the kill
    logged = info.samples["plots/pitch_thx_deg/firmware"]
    assert len(frames) - 1.5 * C.AHRS_RATE_HZ <= logged <= len(frames)  # all but about the last second


@slow
def test_rrd_on_a_full_disk_is_one_sentence_the_run_goes_on_and_exits_not_0(tmp_path, tiny_disk):
    data = flight_stream(2400)
    rrd = tiny_disk / "x.rrd"
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link, "--rrd", str(rrd))
        feeder.start()
        assert proc.wait_line("cannot be written", 30) is not None, proc.stderr
        time.sleep(2.5)  # the recording goes on
        rc = proc.finish(sig=signal.SIGINT)
    said = [line for _, line in proc.lines if "cannot be written" in line]
    assert len(said) == 1 and str(rrd) in said[0] and "no space left" in said[0].lower(), proc.stderr
    assert no_raw_rerun_lines(proc.stderr), proc.stderr
    assert rc != 0
    line = summary_line(proc)
    assert "rerun" not in line and str(rrd) not in line  # only complete outputs are listed
    from steval_viewer.rrd_check import read_rrd

    assert read_rrd(rrd).application_id  # what it held then still opens
    cap = capture_of(tmp_path / "cap.stv")
    assert not cap.truncated and len(cap.data) > 2 * REAL_BYTES_PER_S and cap.data == data[: len(cap.data)]
    assert cap.events[-1].kind == "stop" and cap.events[-1].text == "interrupted"


@slow
def test_a_start_on_a_full_disk_leaves_nothing_and_a_retry_works(tmp_path, tiny_disk):
    filler = fill(tiny_disk)
    data = flight_stream(3000)
    with PtyFeeder(data, tmp_path / "ttyUSB0", loop=True) as feeder:
        feeder.start()
        for args, out in (
            ([], tiny_disk / "x.stv"),  # the capture on the full disk
            (["--rrd", str(tiny_disk / "x.rrd")], tmp_path / "x.stv"),  # the .rrd on it
        ):
            proc = StevalProcess(
                ["live", "--no-view", "--no-prompt", "--port", str(feeder.link), "--out", str(out), *args],
                cwd=tmp_path,
            )
            rc = proc.finish(timeout_s=90)
            assert rc == 2 and "no space left" in proc.stderr.lower(), proc.stderr
            assert len(proc.stderr.strip().splitlines()) <= 2 and "Traceback" not in proc.stderr
            assert sorted(p.name for p in tiny_disk.iterdir()) == ["filler"]
            assert not (tmp_path / "x.stv").exists()
        filler.unlink()  # room again: the same --out works
        proc = StevalProcess(
            ["live", "--no-view", "--no-prompt", "--port", str(feeder.link), "--out", str(tiny_disk / "x.stv")]
            + ["--duration", "1.5"],
            cwd=tmp_path,
        )
        assert proc.finish(timeout_s=90) == 0, proc.stderr
    assert len(capture_of(tiny_disk / "x.stv").data) > 0


@slow
def test_a_csv_on_a_full_disk_is_one_sentence_and_leaves_nothing(tmp_path, tiny_disk):
    proc = StevalProcess(["export", str(DEMO), "--csv", str(tiny_disk / "x.csv")], cwd=tmp_path)
    assert proc.finish(timeout_s=120) == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(tiny_disk / "x.csv") in lines[0] and "no space left" in lines[0].lower()
    assert list(tiny_disk.iterdir()) == []


# ------------------------------------------------------------------------------------------------------------
# 5: outputs that vanish


@slow
def test_a_deleted_capture_folder_stops_the_run_in_one_sentence(tmp_path):
    folder = tmp_path / "flights"
    folder.mkdir()
    data = flight_stream(2000)
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link, out=folder / "x.stv")
        feeder.start()
        time.sleep(2.0)
        subprocess.run(["rm", "-rf", str(folder)], check=True)
        t_rm = time.monotonic()
        rc = proc.finish(timeout_s=30)
        t_end = time.monotonic()
    assert rc == 2, proc.stderr
    errors = [line for _, line in proc.lines if line.startswith("steval: error:")]
    assert len(errors) == 1 and "deleted with its folder" in errors[0] and "x.stv" in errors[0], proc.stderr
    assert " kB" in errors[0] or " MB" in errors[0]  # what was written until then is named
    assert t_end - t_rm < 10.0
    assert proc.stdout.strip() == ""  # no summary naming a file that is gone


@slow
def test_a_deleted_rrd_folder_is_said_once_and_the_capture_goes_on(tmp_path):
    folder = tmp_path / "views"
    folder.mkdir()
    data = flight_stream(1600)
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link, "--rrd", str(folder / "x.rrd"))
        feeder.start()
        assert proc.wait_line(" Hz", 30) is not None, proc.stderr  # the .rrd is being written
        time.sleep(1.0)
        subprocess.run(["rm", "-rf", str(folder)], check=True)
        assert proc.wait_line("deleted with its folder", 10) is not None, proc.stderr
        time.sleep(1.0)
        rc = proc.finish(sig=signal.SIGINT)
    assert rc == 1, proc.stderr
    line = summary_line(proc)
    assert "x.rrd" not in line and "cap.stv" in line
    cap = capture_of(tmp_path / "cap.stv")
    assert cap.data == data[: len(cap.data)] and len(cap.data) > 2.5 * REAL_BYTES_PER_S


# ------------------------------------------------------------------------------------------------------------
# 3, 4, 6: the right drone after an unplug, another reader, the summary after faults


@slow
def test_a_squatter_at_the_old_path_is_not_the_drone_which_is_found_under_its_new_name(tmp_path):
    data = flight_stream(1600)
    junk = b"AT+OK\r\nmodem ready\r\n" * 200
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link)
        feeder.start()
        time.sleep(2.0)
        feeder.unplug()
        assert proc.wait_line("disconnected", 10) is not None, proc.stderr
        with PtyFeeder(junk, tmp_path / "ttyUSB0", bytes_per_s=2000, loop=True) as squatter:
            squatter.start()  # another device appears at the old name ...
            time.sleep(0.5)
            feeder.replug(tmp_path / "ttyUSB1")  # ... the drone under a new one
            assert proc.wait_line("not the drone", 15) is not None, proc.stderr
            assert proc.wait_line("reconnected on " + str(tmp_path / "ttyUSB1"), 15) is not None, proc.stderr
            time.sleep(1.5)
            rc = proc.finish(sig=signal.SIGINT)
    assert rc == 0, proc.stderr
    assert "reconnected on " + str(tmp_path / "ttyUSB0") not in proc.stderr
    line = summary_line(proc)
    assert "1 disconnect " in line and "did not come back" not in line
    rate = float(line.split(" attitude frames (")[1].split(" Hz")[0])
    assert 0.8 * C.AHRS_RATE_HZ < rate < 1.1 * C.AHRS_RATE_HZ
    # the frames after the reconnection continue the stream, the gap counted
    missing = int(line.split(" missing")[0].rsplit(" ", 1)[1])
    assert missing > C.AHRS_RATE_HZ


def test_the_finder_takes_the_adapter_that_matches_whatever_its_name(monkeypatch):
    ident = autodetect.PortIdentity("/dev/ttyUSB0", "/dev/ttyUSB0", 0x0403, 0x6001, None, "1-1.2")
    listed: list = []
    monkeypatch.setattr(autodetect, "_comports", lambda: listed)

    def port(device, vid, pid, sn=None, location=None):
        return SimpleNamespace(device=device, vid=vid, pid=pid, serial_number=sn, location=location)

    monkeypatch.setattr(autodetect.os.path, "exists", lambda p: any(x.device == p for x in listed))
    finder = autodetect.PortFinder(ident)
    finder.mark_lost()
    listed[:] = [port("/dev/ttyUSB0", 0x10C4, 0xEA60)]  # another adapter at the old name: never ours
    assert finder.find() is None
    listed.append(port("/dev/ttyUSB1", 0x0403, 0x6001, location="1-1.3"))
    listed.append(port("/dev/ttyUSB2", 0x0403, 0x6001, location="1-1.2"))  # the same USB socket wins
    assert finder.find() == "/dev/ttyUSB2"
    finder.reject("/dev/ttyUSB2")  # it sent no valid frames
    assert finder.find() == "/dev/ttyUSB1"
    with_sn = autodetect.PortFinder(autodetect.PortIdentity("/dev/ttyACM0", "/dev/ttyACM0", 0x0483, 0x5740, "ABC"))
    listed[:] = [port("/dev/ttyACM0", 0x0483, 0x5740, "XYZ"), port("/dev/ttyACM3", 0x0483, 0x5740, "ABC")]
    assert with_sn.find() == "/dev/ttyACM3"  # its serial number, not its old name


@slow
def test_another_reader_on_the_port_is_named_and_is_no_disconnect(tmp_path):
    data = flight_stream(1600)
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link)
        feeder.start()
        time.sleep(1.5)
        # a serial monitor left open: reads whatever comes, without the port's lock
        monitor = subprocess.Popen([sys.executable, "-c", MONITOR, str(feeder.link)], stdout=subprocess.DEVNULL)
        try:
            assert proc.wait_line(f"another program (PID {monitor.pid}, ", 15) is not None, proc.stderr
            time.sleep(2.0)
        finally:
            monitor.kill()
            monitor.wait()
        rc = proc.finish(sig=signal.SIGINT)
    assert rc == 0, proc.stderr
    assert "disconnect" not in summary_line(proc) and "disconnected" not in proc.stderr
    assert sum("another program" in line for _, line in proc.lines) == 1


@slow
def test_a_port_that_does_not_come_back_is_said_and_the_rate_is_over_the_connected_time(tmp_path):
    data = flight_stream(1600)
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link)
        feeder.start()
        time.sleep(2.5)
        feeder.unplug()
        assert proc.wait_line("disconnected", 10) is not None, proc.stderr
        time.sleep(3.0)
        rc = proc.finish(sig=signal.SIGINT)
    assert rc == 0, proc.stderr
    line = summary_line(proc)
    assert "1 disconnect (" in line and "did not come back" in line
    offline = float(line.split("1 disconnect (")[1].split(" s")[0])
    assert 2.5 < offline < 8.0  # measured up to the end
    rate = float(line.split(" attitude frames (")[1].split(" Hz")[0])
    assert 0.8 * C.AHRS_RATE_HZ < rate < 1.1 * C.AHRS_RATE_HZ


# ------------------------------------------------------------------------------------------------------------
# SIGSTOP, garbage, 9: a closed pipe, 10: a looping replay


@slow
def test_sigstop_then_sigcont_goes_on_without_a_disconnect(tmp_path):
    data = flight_stream(2000)
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link)
        feeder.start()
        time.sleep(1.5)
        proc.proc.send_signal(signal.SIGSTOP)
        time.sleep(2.0)
        proc.proc.send_signal(signal.SIGCONT)
        time.sleep(2.0)
        rc = proc.finish(sig=signal.SIGINT)
    assert rc == 0, proc.stderr
    assert "disconnect" not in summary_line(proc)
    cap = capture_of(tmp_path / "cap.stv")
    seqs = [f.seq for f in StreamDecoder().feed(cap.data) if hasattr(f, "seq")]
    assert len(seqs) > 4 * C.AHRS_RATE_HZ and seqs == sorted(seqs)


@slow
def test_garbage_bursts_are_counted_and_the_frames_around_them_kept(tmp_path):
    clean = flight_stream(1000)
    rng = np.random.default_rng(7)
    parts, pos = [], 0
    for cut in range(3000, len(clean), 9000):
        parts += [clean[pos:cut], rng.integers(0, 256, 2000, dtype=np.uint8).tobytes()]
        pos = cut
    data = b"".join(parts + [clean[pos:]])
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = live(tmp_path, feeder.link)
        feeder.start()
        assert feeder.wait_done(30)
        time.sleep(0.5)
        rc = proc.finish(sig=signal.SIGINT)
    assert rc == 0, proc.stderr
    line = summary_line(proc)
    frames = int(line.split(" attitude frames")[0].rsplit(" ", 1)[1])
    assert frames > 0.9 * 1000
    assert " 0 B skipped" not in line
    assert capture_of(tmp_path / "cap.stv").data == data


@slow
def test_a_closed_stdout_pipe_ends_quietly_with_the_capture_intact(tmp_path):
    out = tmp_path / "x.stv"
    args = ["live", "--no-view", "--no-prompt", "--port", f"replay://{DEMO}?speed=5", "--out", str(out)]
    proc = subprocess.Popen(
        [sys.executable, "-c", "from steval_link.cli import main; main()", *args, "--duration", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=tmp_path,
    )
    proc.stdout.close()  # `steval live ... | true`
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert b"Traceback" not in err and b"error" not in err.lower()
    cap = capture_of(out)
    assert not cap.truncated and len(cap.data) > 10_000


@slow
def test_a_looping_replay_runs_past_its_end_for_a_soak(tmp_path):
    proc = StevalProcess(
        ["live", "--no-view", "--no-prompt", "--port", f"replay://{DEMO}?loop=1&speed=40", "--duration", "4"]
        + ["--out", str(tmp_path / "x.stv")],
        cwd=tmp_path,
    )
    assert proc.finish(timeout_s=120) == 0, proc.stderr
    assert "in a loop" in proc.stderr and "end of" not in proc.stderr
    one_pass = len(capture_of(DEMO).data)
    assert len(capture_of(tmp_path / "x.stv").data) > 1.5 * one_pass


def test_replay_port_loop_starts_again_one_period_after_its_end():
    now = [0.0]
    data = bytes(range(100))
    port = ReplayPort(
        data,
        np.array([50, 100]),
        np.array([0.0, 1.0]),
        port="replay://x",
        path=Path("x"),
        loop=True,
        timeout=0,
        clock=lambda: now[0],
    )
    assert port.read(1000) == data[:50]
    now[0] = 1.0
    assert port.read(1000) == data[50:]
    assert not port.at_end and port.in_waiting == 0  # the next round waits for its own time
    now[0] = 1.0 + C.AHRS_PERIOD_S + 1e-6
    assert port.read(1000) == data[:50] and port.loops == 1
    assert parse_replay_url("replay://x.stv?loop=1&speed=40").loop
    assert not parse_replay_url("replay://x.stv?speed=40").loop


# ------------------------------------------------------------------------------------------------------------
# the writers' own checks (quick)


def test_capture_writer_says_when_its_file_or_folder_is_deleted_or_replaced(tmp_path):
    folder = tmp_path / "f"
    folder.mkdir()
    w = CaptureWriter(folder / "x.stv", port="p", baud=115200)
    w.write(b"abc", 0.0)
    assert w.check_present() is None
    (folder / "x.stv").unlink()
    (folder / "x.stv").write_bytes(b"other")
    assert "replaced by another file" in str(w.check_present())
    with pytest.raises(OutputLostError, match="replaced"):
        w.write(b"more", 0.1)
    w.close()
    assert (folder / "x.stv").read_bytes() == b"other"  # never touched
    w2 = CaptureWriter(folder / "y.stv", port="p", baud=115200)
    subprocess.run(["rm", "-rf", str(folder)], check=True)
    assert "deleted with its folder" in str(w2.check_present())
    w2.close()


def test_rrd_writer_failure_is_one_sentence_and_the_stream_is_still_drained(tmp_path):
    import rerun as rr

    from steval_viewer.rrd_check import read_rrd
    from steval_viewer.rrd_writer import RrdWriter

    rec = rr.RecordingStream("t", make_default=False, make_thread_default=False)
    path = tmp_path / "x.rrd"
    writer = RrdWriter(rec, path)

    def log(i):
        rec.send_columns(
            "v",
            indexes=[rr.TimeColumn("t", duration=np.arange(10) * 0.01 + i)],
            columns=rr.Scalars.columns(scalars=np.ones(10)),
        )

    log(0)
    writer.pump(flush=True, sync=True)
    assert read_rrd(path).samples["v"] == 10  # on disk before the end
    path.unlink()
    log(1)
    writer.pump(flush=True)
    assert writer.failure is not None and "was deleted" in writer.failure and str(path) in writer.failure
    log(2)
    writer.close()  # read and dropped; nothing recreated
    assert not path.exists()

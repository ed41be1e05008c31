"""The Rerun sinks' bounds and checks, headless, through the real CLI in a child process: a ``--connect`` URL where no
viewer listens (or a program that is not one), busy ports with the option that frees them, ``--rrd`` checked before
the work, complete or none on Ctrl-C, and the size of a live session's ``.rrd`` whatever its view mode."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from steval_link.cli.checks import user_message
from steval_link.errors import UserError
from steval_link.link.capture import demo_capture_path, read_capture
from steval_viewer import entities as ent
from steval_viewer.rrd_check import read_rrd
from steval_viewer.sink_options import SinkOptions, check_sinks, free_port, speaks_grpc


def _steval(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    env_cmd = [sys.executable, "-c", "from steval_link.cli import main; main()", *args]
    return subprocess.run(env_cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)


class SilentServer:
    """A TCP listener on 127.0.0.1 that accepts and never answers (another program on the port)."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.port = self.sock.getsockname()[1]
        self.conns: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)

    def close(self) -> None:
        for c in self.conns:
            c.close()
        self.sock.close()


@pytest.mark.slow
def test_connect_where_nothing_listens_is_one_line_exit_2_at_once(tmp_path):
    url = f"rerun+http://127.0.0.1:{free_port()}/proxy"
    t0 = time.monotonic()
    done = _steval("replay", "--connect", url, cwd=tmp_path)
    took = time.monotonic() - t0
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"steval: error: no Rerun viewer listens at {url}; start one (`rerun`) or use --spawn or --serve"
    ]
    assert done.stdout == ""  # checked before the work: no summary printed
    assert took < 5.0, took


@pytest.mark.slow
def test_connect_to_a_program_that_is_no_viewer_is_refused_instead_of_hanging(tmp_path):
    server = SilentServer()
    try:
        assert not speaks_grpc("127.0.0.1", server.port, 1.0)
        url = f"rerun+http://127.0.0.1:{server.port}/proxy"
        done = _steval("replay", "--connect", url, cwd=tmp_path, timeout=60)
        assert done.returncode == 2
        assert "is not a Rerun viewer" in done.stderr and len(done.stderr.strip().splitlines()) == 1
        # --spawn on a port that program holds: say so and name the option that picks another
        with pytest.raises(UserError, match="grpc_port= N") as exc:
            check_sinks(SinkOptions(spawn=True, grpc_port=server.port))
        assert "pick another port with --grpc-port N" in user_message(exc.value)
    finally:
        server.close()


def test_serve_on_busy_ports_names_the_option_to_pick_another():
    server = SilentServer()
    try:
        with pytest.raises(UserError, match=r"in use on 127\.0\.0\.1 .*web_port= N") as exc:
            check_sinks(SinkOptions(serve=True, web_port=server.port, grpc_port=free_port()))
        assert "an earlier --serve still running?" in user_message(exc.value)
        with pytest.raises(UserError, match="grpc_port= N"):
            check_sinks(SinkOptions(serve=True, web_port=free_port(), grpc_port=server.port))
    finally:
        server.close()
    with pytest.raises(UserError, match="must differ"):
        check_sinks(SinkOptions(serve=True, web_port=9100, grpc_port=9100))
    with pytest.raises(UserError, match="from 1 to 65535"):
        check_sinks(SinkOptions(serve=True, web_port=70000))


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--rrd", "/nonexistent-folder/x.rrd"], "folder /nonexistent-folder does not exist"),
        (["--connect", "http://127.0.0.1:9876"], "--connect needs a Rerun gRPC URL"),
    ],
)
@pytest.mark.slow
def test_output_options_are_checked_before_the_work(tmp_path, args, needle):
    done = _steval("replay", *args, cwd=tmp_path)
    assert done.returncode == 2 and needle in done.stderr
    assert done.stdout == "" and "Traceback" not in done.stderr


@pytest.mark.slow
def test_replay_rrd_says_where_it_wrote_and_how_to_open_it(tmp_path):
    out = tmp_path / "demo.rrd"
    done = _steval("replay", "--rrd", str(out), "-e", "accel", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert f"steval: Rerun recording written to {out} (open it with: rerun {out})" in done.stderr
    assert read_rrd(out).samples[ent.pitch_path("firmware")] == 9210  # recordings/demo.stv: 9210 attitude frames
    assert not list(tmp_path.glob("*.partial"))


@pytest.mark.slow
def test_ctrl_c_during_replay_rrd_leaves_a_complete_file_or_none_and_says_which(tmp_path):
    # a long raw dump (the demo's bytes 12 times: ~12 min of stream) so that Ctrl-C lands while Rerun writes
    raw = tmp_path / "long.bin"
    raw.write_bytes(read_capture(demo_capture_path()).data * 12)
    from support.ptyfeed import StevalProcess  # POSIX only: skips on Windows

    out = tmp_path / "long.rrd"
    proc = StevalProcess(["replay", str(raw), "--rrd", str(out)], cwd=tmp_path)
    deadline = time.monotonic() + 120
    while "source:" not in proc.stdout and time.monotonic() < deadline and proc.proc.poll() is None:
        time.sleep(0.01)  # the summary comes right before the Rerun logging
    rc = proc.finish(timeout_s=60, sig=signal.SIGINT)
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "long.rrd.partial").exists()
    if rc == 130:  # interrupted while writing: no file, and it says so
        assert not out.exists(), proc.stderr
        assert f"steval: {out} not written (interrupted before it was complete)" in proc.stderr
        assert proc.stderr.strip().endswith("steval: interrupted")
    else:  # the signal came after the file was whole: a complete file, and it says so
        assert rc == 0, proc.stderr
        assert f"Rerun recording written to {out}" in proc.stderr
        assert read_rrd(out).samples[ent.pitch_path("firmware")] > 0


def _live_rrd_size(tmp_path: Path, name: str, *extra: str) -> int:
    """Bytes of the ``.rrd`` of a headless ``steval live`` session over ~4 s of stream at the real rate."""
    folder = tmp_path / name
    folder.mkdir()
    rrd = folder / "live.rrd"
    from support.ptyfeed import PtyFeeder, StevalProcess, flight_stream  # POSIX only: skips on Windows

    with PtyFeeder(flight_stream(650), folder / "ttyUSB0") as feeder:
        proc = StevalProcess(
            ["live", "--port", str(feeder.link), "--out", str(folder / "cap.stv"), "--rrd", str(rrd), *extra],
            cwd=folder,
        )
        assert proc.wait_line("reading ", 60) is not None, proc.stderr
        feeder.start()
        assert feeder.wait_done(30)
        time.sleep(0.5)
        rc = proc.finish(sig=signal.SIGINT)
    assert rc == 0, proc.stderr
    assert read_rrd(rrd).samples[ent.pitch_path("firmware")] == 650
    return rrd.stat().st_size


@pytest.mark.slow
def test_live_rrd_without_a_display_is_as_small_as_no_view(tmp_path):
    # no display: the default view resolves to the .rrd alone, which must get merged batches as with --no-view
    default = _live_rrd_size(tmp_path, "default")
    no_view = _live_rrd_size(tmp_path, "no_view", "--no-view")
    assert default <= 1.5 * no_view, (default, no_view)


@pytest.mark.slow
def test_a_viewer_that_stops_taking_data_ends_the_flush_with_one_sentence(tmp_path):
    """A viewer frozen mid-stream (SIGSTOP): the flush gives up after its bound instead of hanging; one killed
    while we wait: 'cannot be reached'."""
    import numpy as np
    import rerun as rr

    from steval_viewer.sinks import _flush_bounded, start_web_viewer, stop_child

    child, _page, url = start_web_viewer(free_port(), free_port())
    try:
        rec = rr.RecordingStream("steval-link-test", make_default=False, make_thread_default=False)
        rec.set_sinks(rr.GrpcSink(url))
        rec.log("x", rr.Scalars([1.0]))
        _flush_bounded(rec, 10.0, url)  # a live viewer takes it
        child.send_signal(signal.SIGSTOP)
        for i in range(60):  # more than the socket buffers hold
            seq = np.arange(100_000) + i * 100_000
            rec.send_columns(
                "y",
                indexes=[rr.TimeColumn("s", sequence=seq)],
                columns=rr.Scalars.columns(scalars=np.random.default_rng(i).random(100_000)),
            )
        t0 = time.monotonic()
        with pytest.raises(UserError, match=r"did not take the data within 2 s"):
            _flush_bounded(rec, 2.0, url)
        assert time.monotonic() - t0 < 4.0
        child.kill()
        child.wait(10)
        with pytest.raises(UserError, match="cannot be reached"):
            _flush_bounded(rec, 2.0, url)
        rec.disconnect()
    finally:
        if child.poll() is None:
            child.send_signal(signal.SIGCONT)
        stop_child(child)

"""Every viewer path as a user walks it, on a virtual X display with the real ``rerun`` viewer binary (no mock).

The README's main job word for word (``steval replay recordings/demo.stv --spawn``): the desktop viewer opens, gets
the whole recording and stays open, and the command returns. ``--serve`` (a web viewer, stopped on SIGINT, SIGTERM
and SIGHUP), ``--connect`` to a running viewer, and ``steval live`` with its default sink (spawn) against a
pseudo-terminal, ended by one Ctrl-C. What the viewer received is asked from the viewer itself (its gRPC control
API); the main job's screenshot is kept under the test's tmp path.
"""

from __future__ import annotations

import re
import signal
import subprocess
import time
import urllib.request
from pathlib import Path

import pytest
from support.cli import run_steval
from support.ptyfeed import PtyFeeder, StevalProcess, flight_stream
from support.xdisplay import (
    kill_processes,
    process_alive,
    rerun_processes,
    screenshot,
    viewer_port,
    viewer_recording,
    virtual_display,
)

from steval_viewer import entities as ent
from steval_viewer.sink_options import free_port, port_free, port_open
from steval_viewer.sinks import rerun_command

ROOT = Path(__file__).resolve().parents[1]
DEMO_LAST_STEP = 9209  # recordings/demo.stv: AHRS steps 0..9209
#: generous bound for a command on a loaded 2-core CI machine (imports, estimators, the viewer's start)
RETURN_S = 90.0

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def display():
    with virtual_display() as d:
        yield d


def _url(port: int) -> str:
    return f"rerun+http://127.0.0.1:{port}/proxy"


def _steval(args: list[str], env: dict, cwd: Path, timeout: float = RETURN_S) -> subprocess.CompletedProcess:
    return run_steval(args, env=env, cwd=cwd, timeout=timeout)


def _readme_main_job() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("The main job", 1)[1]
    return re.search(r"```sh\n(.*?)```", section, re.S).group(1).strip()


def test_readme_main_job_opens_the_viewer_with_the_data_and_returns(display, tmp_path):
    command = _readme_main_job()
    assert command == "steval replay recordings/demo.stv --spawn"
    port = 9876  # the default, as the README runs it
    ours = port_free(port)  # a viewer already there (a developer's) is reused, and left alone afterwards
    try:
        t0 = time.monotonic()
        done = _steval(command.split()[1:], display.env, ROOT)
        took = time.monotonic() - t0
        assert done.returncode == 0, done.stderr
        assert "Traceback" not in done.stderr and "WARNING" not in done.stderr, done.stderr
        assert f"frames: {DEMO_LAST_STEP + 1} attitude" in done.stdout
        # returned, and the viewer stays open for the user
        pids = rerun_processes(port) if ours else []
        assert not ours or pids, "the spawned viewer is not running after the command returned"
        rec = viewer_recording(_url(port), timeline="ahrs_step", end=DEMO_LAST_STEP)
        assert rec.timelines["ahrs_step"] == (0, DEMO_LAST_STEP)
        assert {
            "/" + ent.pitch_path("firmware"),
            "/" + ent.pitch_path("st_mahony_replica"),
            "/plots/gyro_dps",
            "/world/drone/firmware/model",
            "/log/firmware",
        } <= rec.entities
        png = screenshot(_url(port), tmp_path / "main_job.png")
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000  # a rendered window, not a blank one
        print(f"main job returned in {took:.1f} s; screenshot {tmp_path / 'main_job.png'}")
    finally:
        if ours:
            kill_processes(rerun_processes(port))


def test_spawn_again_reuses_the_open_viewer(display, tmp_path):
    with viewer_port() as port:
        first = _steval(["replay", "--spawn", "--grpc-port", str(port), "-e", "none"], display.env, tmp_path)
        assert first.returncode == 0, first.stderr
        assert len(rerun_processes(port)) == 1
        second = _steval(["replay", "--spawn", "--grpc-port", str(port), "-e", "none"], display.env, tmp_path)
        assert second.returncode == 0, second.stderr
        assert "already listening" in second.stderr
        assert len(rerun_processes(port)) == 1  # no second window


def _listening_viewer(env: dict) -> tuple[subprocess.Popen, int]:
    """A Rerun viewer started by hand, once it listens (a second try if the first one exits before it listens)."""
    for _attempt in range(2):
        port = free_port()
        viewer = subprocess.Popen(
            rerun_command() + ["--port", str(port), "--bind", "127.0.0.1", "--hide-welcome-screen"],
            env=dict(env, RERUN_APP_ONLY="true"),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline = time.monotonic() + RETURN_S  # a bound for a loaded machine: the loop ends as soon as it listens
        while viewer.poll() is None and time.monotonic() < deadline:
            if port_open("127.0.0.1", port, 0.2):  # listening, not just bound
                return viewer, port
            time.sleep(0.1)
        if viewer.poll() is None:
            viewer.terminate()
            pytest.fail(f"the viewer did not listen on port {port} within {RETURN_S:g} s")
    pytest.fail(f"the viewer exited twice before it listened (last exit code {viewer.returncode})")


def test_connect_sends_to_a_running_viewer(display, tmp_path):
    viewer, port = _listening_viewer(display.env)
    try:
        done = _steval(["replay", "--connect", _url(port)], display.env, tmp_path)
        assert done.returncode == 0, done.stderr
        rec = viewer_recording(_url(port), timeline="ahrs_step", end=DEMO_LAST_STEP)
        assert "/" + ent.pitch_path("ekf3") in rec.entities  # the default estimators with a viewer
        assert viewer.poll() is None  # --connect never ends the user's viewer
    finally:
        viewer.terminate()
        viewer.wait(10)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["INT", "TERM", "HUP"])
def test_serve_shows_the_data_and_every_stop_signal_cleans_up_the_web_viewer(display, tmp_path, sig):
    web, grpc, second = free_port(), free_port(), free_port()
    proc = StevalProcess(
        ["replay", "--serve", "--web-port", str(web), "--grpc-port", str(grpc), "-e", "none"],
        cwd=tmp_path,
        env=display.env,
    )
    client = None
    try:
        assert proc.wait_line("serving until Ctrl-C", RETURN_S) is not None, proc.stderr
        urls = [line for _, line in proc.lines if "web viewer at" in line]
        assert len(urls) == 1, proc.stderr  # the page URL printed once
        assert urls[0].endswith(f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy")
        assert urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10).status == 200
        # a second client: a desktop viewer connected to the web viewer's gRPC proxy gets the whole recording
        client = subprocess.Popen(
            rerun_command() + ["--port", str(second), "--bind", "127.0.0.1", _url(grpc)],
            env=dict(display.env, RERUN_APP_ONLY="true"),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        rec = viewer_recording(_url(second), timeline="ahrs_step", end=DEMO_LAST_STEP)
        assert "/" + ent.pitch_path("firmware") in rec.entities
        server_pids = [p for p in _children_named(proc.proc.pid, "rerun")]
        assert server_pids
        rc = proc.finish(timeout_s=20, sig=sig)
        assert rc == 0, proc.stderr
        assert "Traceback" not in proc.stderr
        assert port_free(web) and port_free(grpc)  # the next run can use the same ports
        time.sleep(0.5)
        assert not any(process_alive(p) for p in server_pids)
    finally:
        if proc.proc.poll() is None:
            proc.proc.kill()
        if client is not None:
            client.terminate()
            client.wait(10)


def test_live_default_sink_spawns_the_viewer_and_one_ctrl_c_ends(display, tmp_path):
    data = flight_stream(1300, first_step=500)
    with viewer_port() as port:
        with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
            proc = StevalProcess(
                ["live", "--port", str(feeder.link), "--out", str(tmp_path / "cap.stv"), "--grpc-port", str(port)],
                cwd=tmp_path,
                env=display.env,
            )
            assert proc.wait_line("reading ", RETURN_S) is not None, proc.stderr
            feeder.start()
            assert feeder.wait_done(RETURN_S)
            # the viewer shows the stream while the session runs
            rec = viewer_recording(_url(port), timeline="ahrs_step", end=500 + 1299)
            assert "/" + ent.pitch_path("firmware") in rec.entities
            t0 = time.monotonic()
            rc = proc.finish(timeout_s=RETURN_S, sig=signal.SIGINT)  # one Ctrl-C (a generous bound, not a wait)
            print(f"live ended {time.monotonic() - t0:.2f} s after one Ctrl-C")
        assert rc == 0, proc.stderr
        assert "Traceback" not in proc.stderr
        assert proc.stdout.startswith("recorded ") and "1300 attitude frames" in proc.stdout
        assert rerun_processes(port), "the spawned viewer should stay open after the session"


def _children_named(pid: int, name: str) -> list[int]:
    import psutil

    return [c.pid for c in psutil.Process(pid).children(recursive=True) if c.name().startswith(name)]


def test_readme_ble_replay_opens_the_ble_layout(display, tmp_path):
    """The docs' Bluetooth page: `steval replay recordings/ble_demo.stv --spawn` (on its own port here)."""
    text = (ROOT / "docs" / "reference" / "ble-link.md").read_text(encoding="utf-8")
    assert "steval replay recordings/ble_demo.stv --spawn" in text
    with viewer_port() as port:
        done = _steval(["replay", "recordings/ble_demo.stv", "--spawn", "--grpc-port", str(port)], display.env, ROOT)
        assert done.returncode == 0, done.stderr
        assert "Traceback" not in done.stderr and "BLE capture" in done.stdout
        end_ns = int(520 * 1e9)  # the drone's clock (ticks since HAL_GetTick's start at 494.288 s) reaches ~534 s
        rec = viewer_recording(_url(port), timeline="fw_time", end=end_ns)
        assert {  # the one live logger: the rows' plots, the BLE link's own values, the estimates
            "/" + ent.PLOT_ACC,
            "/" + ent.BLE_BATTERY,
            "/" + ent.BLE_PRESSURE,
            "/" + ent.BLE_RSSI,
            "/" + ent.BLE_ARMED,
            "/" + ent.BLE_NOTE,
            "/" + ent.pitch_path(ent.SOURCE_REPLICA),
        } <= rec.entities
        png = screenshot(_url(port), tmp_path / "ble.png")
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000

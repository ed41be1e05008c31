"""A virtual X display (Xvfb) and the real Rerun viewer on it, for the tests that walk the viewer paths a user walks.

- :class:`VirtualDisplay` starts ``Xvfb`` on a free display number (``-displayfd``) and gives the environment a
  child process needs (``DISPLAY``, a private ``XDG_RUNTIME_DIR``). The viewer renders there with Mesa's llvmpipe
  through Vulkan (Debian ``mesa-vulkan-drivers``).
- :func:`viewer_recording` asks a running viewer what it holds, through its own gRPC control API
  (``rerun.experimental.ViewerClient``): the recording's timelines and entity paths.
- :func:`rerun_processes` finds viewer processes by the port on their command line (to end what a test started).

Without Xvfb or the Vulkan driver the tests that need a display skip on a developer's machine; in CI (``CI`` set)
they fail instead, since CI must walk these paths (``.ci/run`` installs both).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

VULKAN_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d")


def display_tools_missing() -> str | None:
    """Why a virtual display with a Vulkan renderer cannot be had here (None: it can)."""
    if shutil.which("Xvfb") is None:
        return "Xvfb is not installed (Debian: apt-get install xvfb)"
    if not any(Path(d).is_dir() and any(Path(d).glob("lvp_icd*.json")) for d in VULKAN_ICD_DIRS):
        return "no llvmpipe Vulkan driver (Debian: apt-get install mesa-vulkan-drivers)"
    return None


def require_display_tools() -> None:
    """Skip (developer machine) or fail (CI) when the display tools are missing."""
    why = display_tools_missing()
    if why is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"CI must run the viewer tests on a virtual display: {why}")
    pytest.skip(why)


class VirtualDisplay:
    """``Xvfb`` on a free display number; :attr:`env` is ``os.environ`` with ``DISPLAY`` set to it."""

    def __init__(self, width: int = 1600, height: int = 1000) -> None:
        read_fd, write_fd = os.pipe()
        self.proc = subprocess.Popen(
            ["Xvfb", "-displayfd", str(write_fd), "-screen", "0", f"{width}x{height}x24", "-nolisten", "tcp"],
            pass_fds=(write_fd,),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
        os.close(write_fd)
        with os.fdopen(read_fd) as f:
            number = f.readline().strip()  # Xvfb writes the display number once it accepts connections
        if not number:
            self.proc.kill()
            raise RuntimeError("Xvfb did not start")
        self.display = f":{number}"
        self.runtime_dir = tempfile.mkdtemp(prefix="steval-xdg-")
        os.chmod(self.runtime_dir, 0o700)
        self.env = dict(os.environ, DISPLAY=self.display, XDG_RUNTIME_DIR=self.runtime_dir)
        self.env.pop("WAYLAND_DISPLAY", None)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        shutil.rmtree(self.runtime_dir, ignore_errors=True)


@dataclass
class ViewerRecording:
    """What a viewer holds of one recording: timeline name → (start, end), the entity paths."""

    store_id: str
    timelines: dict[str, tuple[int, int]]
    entities: set[str]


def viewer_recording(
    url: str, *, timeline: str, end: int, timeout_s: float = 90.0, bound_s: float = 900
) -> ViewerRecording:
    """The recording a viewer at ``url`` shows once its ``timeline`` reaches ``end`` (data arrives over time).

    Waits for progress, not for a fixed time: it gives up (AssertionError with what the viewer last held) only when
    the viewer has shown no new data for ``timeout_s`` seconds, or after ``bound_s`` in all (a loaded machine is slow,
    not stuck)."""
    from rerun.experimental import ViewerClient

    start = last_progress = time.monotonic()
    last, best = None, None
    while True:
        try:
            client = ViewerClient.connect(url)
            state = client.get_state()
            for rec in state.recordings:
                spans = {t.name: (t.start, t.end) for t in rec.timelines}
                last = spans
                reached = spans.get(timeline, (None, None))[1]
                if reached is not None and (best is None or reached > best):
                    best, last_progress = reached, time.monotonic()
                if reached is not None and reached >= end:
                    schema = client.get_recording_schema()
                    return ViewerRecording(rec.store_id, spans, {e.entity_path for e in schema.entities})
        except Exception as exc:  # noqa: BLE001 - the viewer may still be starting
            last = repr(exc)
        now = time.monotonic()
        if now - last_progress > timeout_s or now - start > bound_s:
            raise AssertionError(
                f"the viewer at {url} did not get {timeline} up to {end} (no progress for {now - last_progress:.0f} s, "
                f"{now - start:.0f} s in all); it held {last}"
            )
        time.sleep(0.5)


def screenshot(url: str, path: Path) -> bytes:
    """A PNG of what the viewer at ``url`` shows, written to ``path``."""
    from rerun.experimental import ViewerClient

    png = ViewerClient.connect(url).take_screenshot()
    path.write_bytes(png)
    return png


def rerun_processes(port: int) -> list[int]:
    """Pids of Rerun viewer processes started with ``--port PORT``."""
    import psutil

    pids = []
    for p in psutil.process_iter(["pid", "cmdline"]):
        cmd = p.info.get("cmdline") or []
        if cmd and Path(cmd[0]).name.startswith("rerun") and "--port" in cmd:
            i = cmd.index("--port")
            if i + 1 < len(cmd) and cmd[i + 1] == str(port):
                pids.append(p.info["pid"])
    return pids


def kill_processes(pids: list[int]) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and any(process_alive(p) for p in pids):
        time.sleep(0.05)
    for pid in pids:
        if process_alive(pid):
            os.kill(pid, signal.SIGKILL)


@contextlib.contextmanager
def virtual_display():
    """A :class:`VirtualDisplay` (the test skips, or fails in CI, without the tools), closed on exit."""
    require_display_tools()
    display = VirtualDisplay()
    try:
        yield display
    finally:
        display.close()


@contextlib.contextmanager
def viewer_port(port: int | None = None):
    """A gRPC port for a spawned viewer (default: a free one); the viewers started on it are ended on exit."""
    if port is None:
        from steval_viewer.sink_options import free_port

        port = free_port()
    try:
        yield port
    finally:
        kill_processes(rerun_processes(port))


def process_alive(pid: int) -> bool:
    import psutil

    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False

"""Where a recording goes: native viewer (``--spawn``), web viewer on localhost (``--serve``), a running viewer
(``--connect URL``) and/or an ``.rrd`` file (``--rrd FILE``), any combination.

``open_session(...)`` returns a :class:`ViewerSession` whose ``rec`` (a ``rerun.RecordingStream``) is handed to
the logging functions; ``session.close()`` flushes everything (the ``.rrd`` is complete after it). With
``split_file=True`` (the live session) a viewer and an ``.rrd`` get two streams of one recording (same application
and recording id, so both open as one): ``rec`` to the viewer and ``file_rec`` to the file, each logged at its own
cadence (Rerun's file sink keeps ~1 kB per chunk until the file closes, a viewer wants every frame at once). With no sink
chosen, :func:`resolve_sinks` adds ``--spawn`` when a display exists; without one an ``--rrd`` alone is fine
(headless runs, CI), and nothing at all fails with one clear sentence.

The web viewer (``--serve``) runs as a ``rerun --serve-web --bind 127.0.0.1`` child process: its HTTP page and
its gRPC proxy listen on the loopback interface only.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path

import rerun as rr

from steval_link.errors import UserError

APPLICATION_ID = "steval-link"
DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876


@dataclass
class SinkOptions:
    """The sink flags of a command. ``serve``: web viewer on localhost; ``connect``: a gRPC URL such as
    ``rerun+http://127.0.0.1:9876/proxy``; ``rrd``: output file."""

    spawn: bool = False
    serve: bool = False
    connect: str | None = None
    rrd: Path | None = None
    web_port: int = DEFAULT_WEB_PORT
    grpc_port: int = DEFAULT_GRPC_PORT

    def any(self) -> bool:
        return bool(self.spawn or self.serve or self.connect or self.rrd)


@dataclass
class ViewerSession:
    """An open recording and the processes serving it.

    ``rec``: the stream to log to (every sink; with ``open_session(split_file=True)`` and a viewer plus an
    ``.rrd``: the viewer's sinks only). ``file_rec``: the ``.rrd``'s own stream of the same recording in that
    split case, else None.
    """

    rec: rr.RecordingStream
    options: SinkOptions
    web_url: str | None = None
    children: list[subprocess.Popen] = field(default_factory=list)
    file_rec: rr.RecordingStream | None = None

    @property
    def streams(self) -> list[rr.RecordingStream]:
        """Every stream of the session (``rec`` first)."""
        return [self.rec] + ([self.file_rec] if self.file_rec is not None else [])

    def flush(self) -> None:
        """Push everything logged so far to the sinks."""
        for rec in self.streams:
            rec.flush()

    def close(self) -> None:
        """Flush and finish the recording (the ``.rrd`` file is complete afterwards). A spawned native viewer
        keeps running; a ``--serve`` web viewer is stopped (call :meth:`wait_for_viewer` first to keep it up)."""
        try:
            for rec in self.streams:
                try:
                    rec.flush()
                finally:
                    rec.disconnect()
        finally:
            for child in self.children:
                _stop_child(child)
            self.children.clear()

    def wait_for_viewer(self) -> None:
        """With ``--serve``: keep the web viewer up until Ctrl-C (the data is buffered in its server)."""
        if not self.children:
            return
        print(f"steval: web viewer at {self.web_url} (Ctrl-C to stop)", file=sys.stderr)
        try:
            while all(c.poll() is None for c in self.children):
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass


def display_available() -> bool:
    """Whether a native viewer window can open (a display on Linux/BSD; always on macOS and Windows)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def resolve_sinks(options: SinkOptions) -> SinkOptions:
    """Apply the default viewer: when no viewer is chosen (``--spawn``/``--serve``/``--connect``), ``--spawn``
    where a display exists; without a display, an ``--rrd`` alone is fine (headless), nothing at all is a
    UserError."""
    if options.spawn or options.serve or options.connect:
        return options
    if display_available():
        options.spawn = True
        return options
    if options.rrd is not None:
        return options
    raise UserError(
        "no display for the native viewer: pass --rrd FILE to write a recording, --serve for the web viewer, "
        "or --connect URL for a running viewer"
    )


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _wait_port(port: int, timeout_s: float, child: subprocess.Popen) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if child.poll() is not None:
            return False
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return True
        time.sleep(0.1)
    return False


def _rerun_command() -> list[str]:
    """The Rerun viewer binary (the ``rerun`` script is a Python wrapper around it)."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
        if exe.is_file():
            return [str(exe)]
    except ImportError:  # pragma: no cover - rerun-sdk ships rerun_cli
        pass
    found = shutil.which("rerun")
    return [found] if found else [sys.executable, "-m", "rerun"]


def _stop_child(child: subprocess.Popen) -> None:
    """Stop a viewer process and whatever it started (its own process group on POSIX)."""
    if child.poll() is not None:
        return
    try:
        if hasattr(os, "killpg"):
            os.killpg(child.pid, signal.SIGTERM)
        else:  # pragma: no cover - Windows
            child.terminate()
        child.wait(timeout=5)
    except (ProcessLookupError, PermissionError):
        pass
    except subprocess.TimeoutExpired:
        child.kill()


def start_web_viewer(web_port: int, grpc_port: int) -> tuple[subprocess.Popen, str, str]:
    """Start ``rerun --serve-web`` bound to 127.0.0.1; returns (process, page URL, gRPC proxy URL)."""
    for port, what in ((web_port, "web viewer"), (grpc_port, "gRPC")):
        if not _port_free(port):
            raise UserError(f"port {port} for the {what} is in use on 127.0.0.1; pick another port")
    cmd = _rerun_command() + [
        "--serve-web",
        "--bind",
        "127.0.0.1",
        "--web-viewer-port",
        str(web_port),
        "--port",
        str(grpc_port),
    ]
    child = subprocess.Popen(
        cmd,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=sys.platform != "win32",
    )
    if not _wait_port(grpc_port, 15.0, child):
        _stop_child(child)
        raise UserError("the Rerun web viewer did not start (is rerun-sdk installed completely?)")
    proxy = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    page = f"http://127.0.0.1:{web_port}/?url={urllib.parse.quote(proxy, safe='')}"
    return child, page, proxy


def open_session(
    options: SinkOptions,
    *,
    recording_name: str | None = None,
    application_id: str = APPLICATION_ID,
    split_file: bool = False,
) -> ViewerSession:
    """Open a RecordingStream on the sinks of ``options`` (call :func:`resolve_sinks` first for the default).

    ``split_file``: when a viewer and an ``.rrd`` are both chosen, the file gets its own stream
    (``session.file_rec``) with the same application and recording id as ``session.rec`` (the viewer's), so the
    caller can log to each at its own cadence; the two are one recording when opened together.

    Raises UserError when the ``.rrd`` cannot be written or a viewer cannot be started/reached.
    """
    if not options.any():
        raise UserError("no Rerun sink chosen: pass --rrd FILE, --spawn, --serve or --connect URL")
    rec = rr.RecordingStream(application_id, make_default=False, make_thread_default=False)
    session = ViewerSession(rec=rec, options=options)
    sinks: list = []
    file_sinks: list = []
    viewer = bool(options.spawn or options.serve or options.connect)
    if options.rrd is not None:
        path = Path(options.rrd)
        if path.parent and not path.parent.exists():
            raise UserError(f"cannot write {path}: folder {path.parent} does not exist")
        if path.is_dir():
            raise UserError(f"cannot write {path}: it is a folder")
        (file_sinks if split_file and viewer else sinks).append(rr.FileSink(str(path)))
    if options.spawn:
        port = options.grpc_port if _port_free(options.grpc_port) else _free_port()
        try:
            rr.spawn(port=port, connect=False, hide_welcome_screen=True)
        except Exception as exc:  # the viewer binary is missing or cannot start
            raise UserError(f"could not start the Rerun viewer ({exc}); use --rrd FILE or --serve") from None
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
    if options.serve:
        child, page, proxy = start_web_viewer(options.web_port, options.grpc_port if not options.spawn else _free_port())
        session.children.append(child)
        session.web_url = page
        sinks.append(rr.GrpcSink(proxy))
        print(f"steval: web viewer at {page}", file=sys.stderr)
    if options.connect:
        url = options.connect
        if not url.startswith(("rerun://", "rerun+http://", "rerun+https://")):
            raise UserError(f"--connect needs a Rerun gRPC URL such as rerun+http://127.0.0.1:9876/proxy, got {url!r}")
        try:
            sinks.append(rr.GrpcSink(url))
        except Exception as exc:
            raise UserError(f"cannot connect to {url}: {exc}") from None
    rec.set_sinks(*sinks)
    if file_sinks:
        file_rec = rr.RecordingStream(
            application_id, recording_id=rec.get_recording_id(), make_default=False, make_thread_default=False
        )
        file_rec.set_sinks(*file_sinks)
        session.file_rec = file_rec
    if recording_name:
        for stream in session.streams:
            stream.send_recording_name(recording_name)
    return session


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]

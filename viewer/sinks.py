"""Where a recording goes: the desktop viewer, a web viewer on localhost, a running viewer and/or an ``.rrd`` file,
any combination, through :func:`open_session`. Every wait has a bound and ends in one :class:`UserError` sentence."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TypeVar

import rerun as rr

from steval_link.errors import ParamError, UserError
from steval_viewer import QUIETED_RUST_LOG
from steval_viewer.rrd_writer import RrdWriter
from steval_viewer.sink_options import SinkOptions, check_sinks, free_port, port_free, port_open

APPLICATION_ID = "steval-link"
#: longest wait for a started viewer (desktop or web) to listen on its port
VIEWER_START_TIMEOUT_S = 20.0
#: a spawned desktop viewer must still run this long after it listens (without a GPU it dies a moment later)
VIEWER_SETTLE_S = 1.0
#: longest wait for the viewers to take everything logged (a 1-hour replay takes ~10 s on loopback)
FLUSH_TIMEOUT_S = 120.0
#: a flush is waited for in slices this long (Ctrl-C is handled between two)
FLUSH_SLICE_S = 0.25
PARTIAL_SUFFIX = ".partial"


@dataclass
class ViewerSession:
    """An open recording and its viewers; ``file_rec``: the ``.rrd``'s own stream when split, ``viewer_url``: gRPC."""

    rec: rr.RecordingStream
    options: SinkOptions
    web_url: str | None = None
    viewer_url: str | None = None
    children: list[subprocess.Popen] = field(default_factory=list)
    file_rec: rr.RecordingStream | None = None
    rrd_partial: Path | None = None
    rrd_writer: RrdWriter | None = None
    #: the caller said :attr:`rrd_failure` already: close() does not raise it
    rrd_failure_said: bool = False

    @property
    def rrd_failure(self) -> str | None:
        """One sentence when the ``.rrd`` could not be written to the end (disk full, deleted), else None."""
        return self.rrd_writer.failure if self.rrd_writer is not None else None

    @property
    def streams(self) -> list[rr.RecordingStream]:
        return [self.rec] + ([self.file_rec] if self.file_rec is not None else [])

    def flush(self, timeout_s: float = FLUSH_TIMEOUT_S) -> None:
        """Push everything logged so far to the sinks; UserError when a viewer does not take it in ``timeout_s``."""
        for rec in self.streams:
            _flush_bounded(rec, timeout_s, self.viewer_url if rec is self.rec else None)

    def close(self, *, complete: bool = True) -> None:
        """Flush and finish the recording: the ``.rrd`` whole (``complete=False``, interrupted: an atomic one
        removed); a ``--serve`` web viewer stopped. Bounded; UserError when a viewer did not take the data."""
        error: UserError | None = None
        rrd_rec = None if self.rrd_writer is None else self.streams[-1]  # (else no .rrd, or Rerun's own file sink)
        try:
            for rec in self.streams:
                try:
                    if complete:
                        _flush_bounded(rec, FLUSH_TIMEOUT_S, self.viewer_url if rec is self.rec else None)
                except UserError as exc:  # a viewer that went away; the file still closes whole below
                    error = error or exc
                finally:
                    if rec is rrd_rec:
                        self.rrd_writer.close()  # the rest of the stream, then the file is closed
                    rec.disconnect()
        finally:
            for child in self.children:
                stop_child(child)
            self.children.clear()
            partial, self.rrd_partial = self.rrd_partial, None
            if partial is not None and complete and self.rrd_failure is None and partial.exists():
                os.replace(partial, Path(self.options.rrd))
            elif partial is not None:
                partial.unlink(missing_ok=True)
        if error is None and self.rrd_failure is not None and not self.rrd_failure_said:
            error = UserError(self.rrd_failure)  # (a live session said it when it happened)
        if error is not None:
            raise error


def _flush_bounded(rec: rr.RecordingStream, timeout_s: float, viewer_url: str | None) -> None:
    """``rec.flush`` in short slices (Ctrl-C gets through); UserError when a viewer is gone or not done in time."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            rec.flush(timeout_sec=min(FLUSH_SLICE_S, max(0.01, deadline - time.monotonic())))
            return
        except RuntimeError as exc:  # Rerun raises RuntimeError for a sink that failed or a flush that timed out
            timed_out = "timed out" in str(exc).lower()
            if timed_out and time.monotonic() < deadline:
                continue
        where = f"the Rerun viewer at {viewer_url}" if viewer_url else "the Rerun sink"
        if not timed_out:
            raise UserError(f"{where} cannot be reached (closed?); nothing more was sent to it") from None
        raise UserError(f"{where} did not take the data within {timeout_s:.0f} s") from None


def rerun_command() -> list[str]:
    """The Rerun viewer binary (the ``rerun`` script is a Python wrapper around it)."""
    with contextlib.suppress(ImportError):  # rerun-sdk ships rerun_cli
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
        if exe.is_file():
            return [str(exe)]
    found = shutil.which("rerun")
    return [found] if found else [sys.executable, "-m", "rerun"]


def stop_child(child: subprocess.Popen) -> None:
    """Stop a viewer process and whatever it started (its own process group on POSIX); bounded (≤ 7 s)."""
    for sig, wait_s in ((signal.SIGTERM, 5), (getattr(signal, "SIGKILL", signal.SIGTERM), 2)):
        if child.poll() is not None:
            return
        try:
            if hasattr(os, "killpg"):
                os.killpg(child.pid, sig)
            else:  # pragma: no cover - Windows
                child.terminate() if sig == signal.SIGTERM else child.kill()
            child.wait(timeout=wait_s)
        except (ProcessLookupError, PermissionError):
            return
        except subprocess.TimeoutExpired:  # next: SIGKILL; a process that survives it is left
            pass


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Linux: deliver SIGTERM to this process when the process that started it dies (prctl PR_SET_PDEATHSIG)."""
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM, 0, 0, 0)  # 1 = PR_SET_PDEATHSIG


def _start(args: list[str], tcp_port: int, *, detached: bool, settle_s: float = 0.0) -> subprocess.Popen:
    """Start ``rerun`` with ``args`` (``detached``: the desktop viewer, it outlives us; else the web viewer) until it
    listens on ``tcp_port`` and still runs ``settle_s`` later (one with no window dies then); OSError, ParamError."""
    what = "Rerun viewer" if detached else "Rerun web viewer"
    log_path = Path(tempfile.gettempdir()) / f"steval-{'viewer' if detached else 'web-viewer'}-{tcp_port}.log"
    env = dict(os.environ, RERUN_APP_ONLY="true")  # no first-run analytics banner
    if QUIETED_RUST_LOG or env.get("RUST_LOG") == "off":  # quiet here; the viewer's log file keeps its lines
        env.pop("RUST_LOG", None)
    kwargs: dict = {}
    if sys.platform == "win32":  # pragma: no cover - Windows
        kwargs["creationflags"] = subprocess.CREATE_NEW_PROCESS_GROUP | (subprocess.DETACHED_PROCESS if detached else 0)
    else:
        kwargs["start_new_session"] = True  # its own process group: Ctrl-C in the terminal is ours to handle
        if not detached and sys.platform.startswith("linux"):
            kwargs["preexec_fn"] = _die_with_parent
    with open(log_path, "wb") as log:
        cmd = rerun_command() + args
        child = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env, **kwargs)
    deadline = time.monotonic() + VIEWER_START_TIMEOUT_S
    while not port_open("127.0.0.1", tcp_port, 0.2):
        if child.poll() is not None:
            raise ParamError(f"the {what} exited at start ({_last_line(log_path)}); use {{rrd}} FILE instead", "rrd")
        if time.monotonic() >= deadline:
            stop_child(child)
            why = f"the {what} did not listen on port {tcp_port} within {VIEWER_START_TIMEOUT_S:.0f} s"
            raise ParamError(f"{why}; use {{rrd}} FILE instead", "rrd")
        time.sleep(0.05)
    time.sleep(settle_s)
    if settle_s and child.poll() is not None:
        why = f"the Rerun viewer exited right after it started ({_last_line(log_path)}; log {log_path})"
        raise ParamError(f"{why}; use {{rrd}} FILE or {{serve}} instead", "rrd", "serve")
    return child


def _last_line(log_path: Path) -> str:
    """The last meaningful line a viewer printed (ANSI colours removed), for an error message."""
    with contextlib.suppress(OSError):
        lines = [re.sub(r"\x1b\[[0-9;]*m", "", ln).strip() for ln in log_path.read_text(errors="replace").splitlines()]
        lines = [ln for ln in lines if ln]
        errors = [ln for ln in lines if "error" in ln.lower() or "panic" in ln.lower()]
        return (errors or lines or ["no output"])[-1][:200]
    return "no output"


def spawn_desktop_viewer(tcp_port: int) -> str:
    """Start the desktop viewer (detached) on 127.0.0.1:``tcp_port``, or reuse one listening there; its gRPC URL."""
    url = f"rerun+http://127.0.0.1:{tcp_port}/proxy"
    if not port_free(tcp_port):
        note = f"sending to the viewer already listening on port {tcp_port} (another grpc_port for a new one)"
        print(f"steval: {note}", file=sys.stderr)
        return url
    cmd = ["--port", str(tcp_port), "--bind", "127.0.0.1", "--hide-welcome-screen", "--memory-limit", "75%"]
    try:
        _start(cmd, tcp_port, detached=True, settle_s=VIEWER_SETTLE_S)
    except OSError as exc:
        raise ParamError(
            f"could not start the Rerun viewer ({exc.strerror or exc}); use {{rrd}} FILE or {{serve}}", "rrd", "serve"
        ) from None
    return url


def start_web_viewer(web_port: int, grpc_port: int) -> tuple[subprocess.Popen, str, str]:
    """Start ``rerun --serve-web`` on 127.0.0.1 (ports checked free); returns (process, page URL, gRPC URL)."""
    cmd = ["--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web_port), "--port", str(grpc_port)]
    try:
        child = _start(cmd, grpc_port, detached=False)
    except OSError as exc:
        raise UserError(f"could not start the Rerun web viewer ({exc.strerror or exc})") from None
    proxy = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    page = f"http://127.0.0.1:{web_port}/?url={urllib.parse.quote(proxy, safe='')}"
    return child, page, proxy


def open_session(
    options: SinkOptions,
    *,
    recording_name: str | None = None,
    split_file: bool = False,
    atomic_rrd: bool = False,
    checked: bool = False,
) -> ViewerSession:
    """Open a RecordingStream on the sinks of ``options``; UserError when one cannot be opened. ``split_file``: with
    a viewer and an ``.rrd``, the file gets its own stream (``session.file_rec``) of the same recording.
    ``atomic_rrd``: the ``.rrd`` is ``NAME.partial`` until ``close()``. ``checked``: by :func:`check_sinks`."""
    if not options.any():
        flags = ("rrd", "spawn", "serve", "connect")
        raise ParamError("no Rerun sink chosen: pass {rrd} FILE, {spawn}, {serve} or {connect} URL", *flags)
    if not checked:
        check_sinks(options)
    rec = rr.RecordingStream(APPLICATION_ID, make_default=False, make_thread_default=False)
    session = ViewerSession(rec=rec, options=options)
    own_file = options.rrd is not None and (split_file or not options.viewer)
    try:
        sinks = _open_sinks(session, options, own_file=own_file, atomic_rrd=atomic_rrd)
        if sinks:
            rec.set_sinks(*sinks)
        if own_file and options.viewer:  # the file's own stream of the same recording
            session.file_rec = rr.RecordingStream(
                APPLICATION_ID, recording_id=rec.get_recording_id(), make_default=False, make_thread_default=False
            )
        if own_file:
            where = session.rrd_partial or Path(options.rrd)
            session.rrd_writer = RrdWriter(session.streams[-1], where, shown=str(options.rrd))
    except RuntimeError as exc:  # Rerun's "Failed to create file: ...": one sentence, not its traceback
        session.close(complete=False)
        where = f"{{rrd}} {options.rrd}: cannot write it" if options.rrd is not None else "Rerun cannot open its sinks"
        text = str(exc).strip()
        first = text.splitlines()[0].rstrip(".") if text else type(exc).__name__
        raise ParamError(f"{where} ({first})", "rrd") from None
    except BaseException:
        session.close(complete=False)
        raise
    if recording_name:
        for stream in session.streams:
            stream.send_recording_name(recording_name)
    return session


def _open_sinks(session: ViewerSession, options: SinkOptions, *, own_file: bool, atomic_rrd: bool) -> list:
    """Start or reach the viewers of ``options``; returns the stream's sinks (the ``.rrd``'s unless ``own_file``)."""
    sinks: list = []
    if options.rrd is not None:
        path = Path(options.rrd)
        if atomic_rrd:
            session.rrd_partial = path.with_name(path.name + PARTIAL_SUFFIX)
            path = session.rrd_partial
        if not own_file:  # one stream to a viewer and the file (a whole replay): Rerun's own file sink
            sinks.append(rr.FileSink(str(path)))
    if options.spawn:
        session.viewer_url = spawn_desktop_viewer(options.grpc_port)
        sinks.append(rr.GrpcSink(session.viewer_url))
    if options.serve:
        grpc = options.grpc_port if not options.spawn else free_port()
        child, page, proxy = start_web_viewer(options.web_port, grpc)
        session.children.append(child)
        session.web_url, session.viewer_url = page, proxy
        sinks.append(rr.GrpcSink(proxy))
        print(f"steval: web viewer at {page}", file=sys.stderr)
    if options.connect:
        session.viewer_url = options.connect
        sinks.append(rr.GrpcSink(options.connect))
    return sinks


T = TypeVar("T")


def log_whole(options: SinkOptions, recording_name: str, log: Callable[[rr.RecordingStream], T]) -> T:
    """``log(rec)`` on the sinks of ``options`` (checked) and its result; the ``.rrd`` whole, or none if interrupted."""
    session = open_session(options, recording_name=recording_name, atomic_rrd=True, checked=True)
    try:
        result = log(session.rec)
        session.flush()
        if session.children:  # --serve: the web viewer stays up until Ctrl-C or until it exits
            print("steval: serving until Ctrl-C", file=sys.stderr)
            with contextlib.suppress(KeyboardInterrupt):
                while all(c.poll() is None for c in session.children):
                    time.sleep(0.2)
    except UserError:  # a viewer went away: the .rrd is still complete
        with contextlib.suppress(UserError):
            session.close()
        say_rrd_written(options.rrd)
        raise
    except BaseException:  # Ctrl-C, SIGTERM: no half file
        session.close(complete=False)
        raise
    session.close()
    say_rrd_written(options.rrd)
    return result


def say_rrd_written(rrd: Path | None) -> None:
    """The one stderr line that says where a complete ``.rrd`` is and how to open it."""
    if rrd is not None:
        print(f"steval: Rerun recording written to {rrd} (open it with: rerun {rrd})", file=sys.stderr)

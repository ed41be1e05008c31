"""The live session behind ``steval live``, ``record``, ``emulate`` and ``live --ble``: one source, chosen by URL
(:func:`source_for`; the interface: :mod:`steval_link.live.sources`) → capture → decoder → estimators → viewer.

The source writes each chunk to the capture first (in its reader thread or its round: each goes to the OS at once,
so even ``kill -9`` loses nothing received), and a slow viewer never costs bytes. The session owns, once for every
source: the capture file (its errors are one sentence), the viewer, the command prompt (typed commands go to the
source's locked write), the stop requests (Ctrl-C, SIGTERM, SIGHUP, ``--duration``: :meth:`LiveSession.
request_stop`) and the summary (:class:`LiveSummary`).
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, TextIO

from steval_link.errors import UserError
from steval_link.link.capture import CaptureWriter, default_capture_path
from steval_link.link.transport import HostClock
from steval_link.live.console import CommandConsole
from steval_link.live.health import HealthDisplay
from steval_link.live.recorder import capture_failure_sentence, open_capture
from steval_link.live.serial_source import SerialSource
from steval_link.live.sources import Source
from steval_link.live.summary import LiveSummary

__all__ = ["LiveOptions", "LiveSession", "LiveSummary", "source_for", "install_stop_signals", "restore_signals"]

BLE_SCHEME = "ble:"
EMULATED_SCHEME = "emulated:"


def source_for(url: str, **settings: Any) -> Source:
    """The source a URL names (table in :mod:`steval_link.live.sources`); ``settings`` go to its driver (``baud``,
    ``wait`` for a serial port; ``emulation``, ``realtime``, ``commands`` for the board; ``backend`` for BLE)."""
    if url.lower().startswith(BLE_SCHEME):
        from steval_link.live.ble_source import BleSource  # reason: BLE loads only when a session uses it

        target = url[len(BLE_SCHEME) :].strip()
        return BleSource(None if target in ("", "auto") else target, **settings)
    if url.lower().startswith(EMULATED_SCHEME):
        from steval_link.live.emulated import EmulatedSource  # reason: the emulator loads only when used

        return EmulatedSource(**settings)
    return SerialSource(url, **settings)


def port_source(port: str, **settings: Any) -> Source:
    """The source a ``--port`` value names: a serial port or ``replay://``; BLE and the emulated board are chosen by
    their own commands, so their URLs here are one sentence saying which (``settings``: ``baud``, ``wait``)."""
    low = port.lower()
    if low.startswith(BLE_SCHEME):
        name = port[len(BLE_SCHEME) :].strip()
        raise UserError(f"--port {port}: a BLE drone is read with steval live --ble {name}".rstrip())
    if low.startswith(EMULATED_SCHEME):
        raise UserError(f"--port {port}: the emulated board is run with steval emulate FIRMWARE.elf")
    return source_for(port, **settings)


@dataclass
class LiveOptions:
    """What every live session configures (a source's own settings are its driver's: the baud rate, --wait, the
    ELF...). ``sinks``: the Rerun outputs (``steval_viewer.sink_options.SinkOptions``), built and checked once by
    the CLI (None: no Rerun at all)."""

    out: Path | None = None
    sinks: Any = None
    estimators: list[str] = field(default_factory=list)
    duration_s: float | None = None
    recordings_dir: Path = Path("recordings")
    #: the command prompt (lines typed on stdin → commands to the drone); None: when stdin is a terminal
    prompt: bool | None = None

    @property
    def uses_rerun(self) -> bool:
        return self.sinks is not None

    @property
    def rrd(self) -> Path | None:
        return self.sinks.rrd if self.sinks is not None else None


class LiveSession:
    """One live run over ``source``; :meth:`run` returns the summary or raises :class:`UserError`.

    ``stream``: where the health line and notes go (stderr). ``viewer_factory(options, recording_name)`` makes the
    Rerun side (``steval_viewer.live_adapter.make_viewer_logger``, ``steval_viewer.ble_log.BleLiveLogger``); it is
    required when ``options.sinks`` is set. ``check_outputs``: the CLI's checks of the outputs, run once the
    input is open (errors come in the command line's order, the input first) and before any file is made.
    """

    def __init__(
        self,
        options: LiveOptions,
        source: Source,
        *,
        stream: TextIO | None = None,
        tty: bool | None = None,
        viewer_factory: Callable | None = None,
        check_outputs: Callable[[], None] | None = None,
    ) -> None:
        if options.uses_rerun and viewer_factory is None:
            raise ValueError("a session that uses Rerun (a view or --rrd) needs a viewer_factory")
        self.options = options
        self.source = source
        self.check_outputs = check_outputs
        self.display = HealthDisplay(stream or sys.stderr, tty=tty)
        self.viewer_factory = viewer_factory
        self.clock = HostClock()
        self.capture: CaptureWriter | None = None
        self.viewer = None
        self.console: CommandConsole | None = None
        self._stop_reason: str | None = None
        #: outputs that failed during the run (the ``.rrd``: disk full, deleted), one sentence each
        self.output_failures: list[str] = []

    # -- control ----------------------------------------------------------------------------------------------

    def request_stop(self, reason: str = "stopped") -> None:
        """Finish cleanly at the next round (thread-safe; what Ctrl-C, SIGTERM and --duration do)."""
        if self._stop_reason is None:
            self._stop_reason = reason

    @property
    def stop_requested(self) -> bool:
        return self._stop_reason is not None

    @property
    def pipeline(self):
        """The source's :class:`~steval_link.live.pipeline.LivePipeline` (None before it is made, and for BLE)."""
        return getattr(self.source, "pipeline", None)

    # -- main -------------------------------------------------------------------------------------------------

    def run(self) -> LiveSummary:
        src, opts = self.source, self.options
        src.open(self)  # the input first: a bad port, ELF or BLE backend is one line before any file is made
        try:
            if self.check_outputs is not None:
                self.check_outputs()
            capture = self.capture = self._open_capture()
        except BaseException:
            src.close_input()
            raise
        self.clock = HostClock(wall0_s=capture.header["start_time_unix_s"])
        t0 = time.monotonic()
        error: BaseException | None = None
        started = False
        old_handlers = install_stop_signals(self)
        try:
            if src.describe():  # (BLE says when it is connected)
                self.display.note(
                    f"{src.describe()}; recording to {capture.path}"
                    + (f" and {opts.rrd}" if opts.rrd else "")
                    + " (Ctrl-C to stop)"
                )
            src.start(self)  # bytes flow into the capture from now on, while the viewer starts
            if opts.uses_rerun:
                self.viewer = self.viewer_factory(opts, src.recording_name(self))
            src.attach(self)
            self.console = self._console()
            started = True
            self._loop(t0)
        except KeyboardInterrupt:
            self.request_stop("interrupted")
        except BaseException as exc:  # noqa: BLE001 - finish the files first, then re-raise
            error = exc
        finally:
            try:
                src.finish(error)
            finally:
                if self.console is not None:
                    self.console.close()
                self._close_outputs(self._stop_reason or (type(error).__name__ if error else "end"))
                restore_signals(old_handlers)
                if error is not None and not started:  # a failed start leaves nothing half-made
                    capture.discard()
        if error is not None:
            raise src.error_of(error)
        self._watch_outputs()
        return LiveSummary(
            capture_path=capture.path,
            rrd_path=opts.rrd if not self.output_failures else None,
            failures=list(self.output_failures),
            seconds=time.monotonic() - t0,
            stopped_by=self._stop_reason or "end",
            capture_discarded=capture.discarded,
            kind=src.kind,
            **src.summary_fields(),
        )

    # -- internals --------------------------------------------------------------------------------------------

    def _open_capture(self) -> CaptureWriter:
        """The capture file, with the source's header fields; one sentence when it cannot be made."""
        opts, fields = self.options, self.source.capture_fields()
        path = Path(opts.out) if opts.out else default_capture_path(opts.recordings_dir)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"cannot write the capture {path}: {exc.strerror or exc}") from None
        extra = {**fields.extra, "estimators": list(opts.estimators)}
        return open_capture(path, port=fields.link, baud=fields.baud, extra=extra, discard_empty=fields.discard_empty)

    def _close_outputs(self, stop_reason: str) -> None:
        """In their order of importance: the capture (its stop event at the source's time, then closed), then the
        Rerun side (a failure there is a note: the capture is safe), then the health line."""
        try:
            self.capture.mark_event("stop", stop_reason, t_host_s=self.source.t_stop_s())
        except Exception:  # noqa: BLE001 - the capture's bytes are written already; the event is a courtesy
            pass
        self.capture.close()
        if self.viewer is not None:
            try:
                self.viewer.close()
            except Exception as exc:  # noqa: BLE001 - the capture is safe; say what went wrong
                self.display.note(f"could not finalise the Rerun output: {exc}")
        self.display.close()

    def _console(self) -> CommandConsole:
        """The command prompt: each frame typed goes to the source (locked), then into the capture and the log."""
        src = self.source
        prompt = self.options.prompt if self.options.prompt is not None else _stdin_is_tty()
        enabled = bool(prompt) and src.takes_commands
        console = CommandConsole(src.write, self.display.note, record=src.record, enabled=enabled)
        if enabled:
            self.display.note(src.prompt_note)
        return console

    def _watch_outputs(self) -> None:
        """A capture that can take no more stops the run (one sentence); an ``.rrd`` that failed is said once and
        the run goes on without it (``output_failures``: the summary leaves it out, the exit code is not 0)."""
        failure = self.capture.check_present()
        if failure is not None:
            raise UserError(capture_failure_sentence(self.capture, failure))
        said = getattr(self.viewer, "output_failure", None)
        if said and said not in self.output_failures:
            self.output_failures.append(said)
            self.display.note(said)

    def _loop(self, t0: float) -> None:
        src, console, duration_s = self.source, self.console, self.options.duration_s
        while self._stop_reason is None:
            if not src.round():
                break
            self._watch_outputs()
            now = time.monotonic()
            line = src.health(now)
            if line:  # (a source with nothing to say yet says "")
                self.display.show(console.decorate(line), now, force=console.take_typing_change())
            if duration_s is not None and now - t0 >= duration_s:
                self.request_stop("duration")


def _stdin_is_tty() -> bool:
    try:
        return sys.stdin is not None and sys.stdin.isatty()
    except (AttributeError, ValueError):
        return False


def install_stop_signals(session) -> dict | None:
    """Ctrl-C, SIGTERM and SIGHUP ask ``session`` to stop at its next round (``session.request_stop``; one that
    comes while it is stopping already, ``session.stop_requested``, stops it at once: the files are flushed often).
    Returns the old handlers for :func:`restore_signals` (None outside the main thread, where signals cannot be
    handled)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    old = {}

    def on_signal(signum, _frame):
        if session.stop_requested:  # second Ctrl-C (or one while stopping anyway): stop now
            raise KeyboardInterrupt
        session.request_stop("interrupted" if signum == signal.SIGINT else "terminated")

    for sig in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is None:  # pragma: no cover - Windows has no SIGHUP
            continue
        try:
            old[sig] = signal.signal(sig, on_signal)
        except (ValueError, OSError):
            pass
    return old


def restore_signals(old: dict | None) -> None:
    """Put back the handlers :func:`install_stop_signals` replaced."""
    for sig, handler in (old or {}).items():
        try:
            signal.signal(sig, handler)
        except (ValueError, OSError):
            pass

"""The live session behind ``steval live`` and ``steval record``: serial port → capture → decoder → estimators → viewer.

Flow (one way)::

    SerialReader thread ──► RecorderProtocol: capture.write(chunk)  [always first, in the reader thread]
                                   │ (bounded inbox of chunks)
                                   ▼
    main thread: StreamDecoder.feed ──► frames ──► LiveEstimators (ST port seeded from status snapshots,
                                                   accel, EKF...) ──► viewer logger (optional)
                                   └─► LinkHealth ──► HealthDisplay (stderr) and the summary line

The capture is written before anything is decoded (each chunk goes to the OS at once, so even ``kill -9`` loses
nothing already received; the writer syncs to disk at least once a second), and a slow viewer never costs bytes: when
the main thread falls behind,
the inbox drops the oldest chunks from the *live* display only (counted), never from the capture.

Faults the session survives: unplug/replug (the reader reopens the port, by path or USB identity, and the capture
marks the gap), garbage and truncated frames (counted by the decoder), non-finite values (counted, never fed to an
estimator, never plotted), a wrong baud rate or another device (one line and :class:`LinkError`, see
:func:`steval_link.link.autodetect.no_frames_message`).
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TextIO

import serial

from steval_link import constants as C
from steval_link.errors import UserError
from steval_link.link import autodetect
from steval_link.link.capture import CaptureWriter, default_capture_path
from steval_link.link.plausibility import held_back_sentence
from steval_link.link.replay_source import is_replay_url, open_replay
from steval_link.link.transport import (
    HostClock,
    SerialReader,
    open_error_message,
    open_serial,
)
from steval_link.live.console import PROMPT_HELP, CommandConsole
from steval_link.live.health import HealthDisplay, LinkHealth, _fmt_bytes, _fmt_duration
from steval_link.live.pipeline import (
    LivePipeline,
    LiveViewer,
)
from steval_link.live.recorder import Inbox, RecorderProtocol

#: Wrong baud / not a STEVAL: give up after this long with bytes but no valid frame, s (sooner with many bytes) ...
NO_FRAMES_TIMEOUT_S = 2.5


#: ... or after this long once at least NO_FRAMES_EARLY_BYTES arrived without a valid frame.
NO_FRAMES_EARLY_S = 1.0


NO_FRAMES_EARLY_BYTES = 2048


class LinkError(UserError):
    """The port carries no valid frames (wrong baud rate, another device, silence): one line, exit code 2."""


@dataclass
class LiveOptions:
    """Everything ``steval live`` / ``steval record`` configure."""

    port: str = "auto"
    baud: int = C.BAUD
    out: Path | None = None
    rrd: Path | None = None
    view: bool = True  # False: --no-view
    spawn: bool = False
    serve: bool = False
    connect: str | None = None
    web_port: int | None = None  # None: the viewer's default ports
    grpc_port: int | None = None
    estimators: list[str] = field(default_factory=list)
    duration_s: float | None = None
    wait: bool = False
    recordings_dir: Path = Path("recordings")
    #: the command prompt (lines typed on stdin → commands to the drone); None: when stdin is a terminal
    prompt: bool | None = None

    @property
    def uses_rerun(self) -> bool:
        return bool(self.rrd) or self.view


@dataclass
class LiveSummary:
    """What a session did (the summary line prints it)."""

    capture_path: Path
    rrd_path: Path | None
    seconds: float
    streaming_s: float  # from the first to the last attitude frame, less the time disconnected
    bytes_total: int
    attitude: int
    status: int
    text: int
    frames_missing: int
    crc_failures: int
    bytes_skipped: int
    nonfinite: int
    disconnects: int
    offline_s: float
    live_dropped_bytes: int
    port_note: str | None
    stopped_by: str
    capture_discarded: bool = False  # no byte came: the header-only file was removed
    implausible: int = 0  # CRC-valid frames the decoder's plausibility checks held back
    values_sentence: str | None = None  # the frames kept with NaN or out-of-range values, in words
    held_values: int = 0  # of ``implausible``: protocol v1 frames held back for their values

    def line(self) -> str:
        rate = self.attitude / self.streaming_s if self.streaming_s > 0.5 else float("nan")
        parts = [
            f"{_fmt_duration(self.seconds)}",
            f"{self.attitude} attitude frames" + ("" if math.isnan(rate) else f" ({rate:.1f} Hz)"),
            f"{self.frames_missing} missing",
            f"{self.crc_failures} CRC failures",
            f"{_fmt_bytes(self.bytes_skipped)} skipped",
        ]
        if self.values_sentence:
            parts.append(self.values_sentence)
        elif self.nonfinite:
            parts.append(f"{self.nonfinite} with NaN/inf")
        if self.implausible:
            parts.append(held_back_sentence(self.implausible, self.held_values))
        if self.disconnects:
            parts.append(f"{self.disconnects} disconnect{'s' if self.disconnects > 1 else ''} ({self.offline_s:.1f} s)")
        if self.live_dropped_bytes:
            parts.append(f"{_fmt_bytes(self.live_dropped_bytes)} not shown live (in the capture)")
        if self.port_note:
            parts.append(self.port_note)
        if self.capture_discarded:
            out = "no byte received, so no capture file was kept"
        else:
            out = f"capture {self.capture_path} ({_fmt_bytes(self.bytes_total)})"
        if self.rrd_path:
            out += f", rerun {self.rrd_path}"
        return "recorded " + ", ".join(parts) + "; " + out


class LiveSession:
    """One ``steval live`` / ``steval record`` run; :meth:`run` returns the summary or raises :class:`UserError`.

    ``stream``: where the health line and notes go (stderr). ``viewer_factory(options, recording_name)`` makes the
    Rerun side, a :class:`~steval_link.live.pipeline.LiveViewer` (``steval_viewer.live_adapter.make_viewer_logger``
    for the CLI; it is required when the options use Rerun, and the caller checks its sinks first with
    ``steval_viewer.live_adapter.viewer_sink_options``). An optional ``file`` attribute of the viewer (another
    LiveViewer: the ``.rrd``'s own stream next to a live viewer) is fed merged batches every RRD_ONLY_INTERVAL_S.
    """

    def __init__(
        self,
        options: LiveOptions,
        *,
        stream: TextIO | None = None,
        tty: bool | None = None,
        viewer_factory: Callable[[LiveOptions, str], LiveViewer] | None = None,
        check_outputs: Callable[[], None] | None = None,
    ) -> None:
        if options.uses_rerun and viewer_factory is None:
            raise ValueError("a session that uses Rerun (a view or --rrd) needs a viewer_factory")
        self.options = options
        #: the CLI's checks of the outputs (capture, .rrd, a display for the viewer), run once the port is open:
        #: errors come in the command line's order, the input (the port) first
        self.check_outputs = check_outputs
        self.display = HealthDisplay(stream or sys.stderr, tty=tty)
        self.viewer_factory = viewer_factory
        self.clock = HostClock()
        self._stop_reason: str | None = None

    # -- control ----------------------------------------------------------------------------------------------

    def request_stop(self, reason: str = "stopped") -> None:
        """Finish cleanly at the next round (thread-safe; what Ctrl-C and SIGTERM do)."""
        if self._stop_reason is None:
            self._stop_reason = reason

    @property
    def stop_requested(self) -> bool:
        return self._stop_reason is not None

    # -- opening ----------------------------------------------------------------------------------------------

    def _open_port(self) -> tuple[str, serial.Serial]:
        opts = self.options
        if is_replay_url(opts.port):  # the one place a source is opened by its URL scheme
            return opts.port, open_replay(opts.port, baud=opts.baud)
        deadline = time.monotonic() + (math.inf if opts.wait else 0.0)
        announced = False
        while True:
            try:
                path = autodetect.choose_port(opts.port, opts.baud)
            except autodetect.PortChoiceError as exc:
                if time.monotonic() >= deadline or self._stop_reason:
                    raise UserError(str(exc)) from None
                if not announced:
                    self.display.note(f"{exc}; waiting (--wait)")
                    announced = True
                time.sleep(0.25)
                continue
            try:
                return path, open_serial(path, opts.baud)
            except serial.SerialException as exc:
                missing = getattr(exc, "errno", None) == 2 or not os.path.exists(path)
                if missing and time.monotonic() < deadline and not self._stop_reason:
                    if not announced:
                        self.display.note(f"{path} is not there; waiting for it (--wait)")
                        announced = True
                    time.sleep(0.1)
                    continue
                try:
                    available = autodetect.list_candidate_ports()
                except Exception:  # noqa: BLE001 - the listing is only a hint in the message
                    available = []
                raise UserError(open_error_message(path, exc, available)) from None

    # -- main -------------------------------------------------------------------------------------------------

    def run(self) -> LiveSummary:
        path, ser = self._open_port()
        if self.check_outputs is not None:
            try:
                self.check_outputs()
            except BaseException:
                ser.close()
                raise
        opts = self.options
        if is_replay_url(path):  # a recording: nothing to find again after a loss
            finder, described, extra = None, ser.describe(), {"replay_of": str(ser.path)}
        else:
            identity = autodetect.PortIdentity.of(path)
            finder = autodetect.PortFinder(identity, pattern=opts.port if autodetect.is_glob(opts.port) else None)
            described, extra = identity.describe(), {"device": identity.device, "usb": identity.describe()}
        capture_path = Path(opts.out) if opts.out else default_capture_path(opts.recordings_dir)
        try:
            capture_path.parent.mkdir(parents=True, exist_ok=True)
            capture = CaptureWriter(
                capture_path,
                discard_empty=True,  # a session that got no byte leaves no header-only file behind
                port=path,
                baud=ser.baudrate,
                extra={**extra, "estimators": list(opts.estimators)},
            )
        except FileExistsError:
            ser.close()
            raise UserError(f"{capture_path} already exists; choose another --out (captures are never overwritten)")
        except OSError as exc:
            ser.close()
            raise UserError(f"cannot write the capture {capture_path}: {exc.strerror or exc}") from None
        self.clock = HostClock(wall0_s=capture.header["start_time_unix_s"])

        inbox = Inbox()
        proto = RecorderProtocol(capture, inbox, finder, self.clock)
        reader = SerialReader(
            ser, proto, baud=ser.baudrate, clock=self.clock, find_port=finder.find if finder is not None else None
        )
        viewer = None
        t0 = time.monotonic()
        error: BaseException | None = None
        old_handlers = self._install_signals()
        try:
            self.display.note(
                f"reading {described} at {ser.baudrate} baud; recording to {capture_path}"
                + (f" and {opts.rrd}" if opts.rrd else "")
                + " (Ctrl-C to stop)"
            )
            reader.start()
            if opts.uses_rerun:
                viewer = self.viewer_factory(opts, capture_path.stem)
            self._loop(reader, proto, inbox, viewer, t0)
        except BaseException as exc:  # noqa: BLE001 - finish the files first, then re-raise
            error = exc
        finally:
            reader.stop()
            # whatever is still queued goes to the live side; the capture already holds it
            try:
                if error is None or isinstance(error, (LinkError, KeyboardInterrupt)):
                    self._drain(inbox)
            except Exception:  # noqa: BLE001
                pass
            stop = self._stop_reason or (type(error).__name__ if error else "end")
            console = getattr(self, "console", None)
            if console is not None:
                console.close()
            close_outputs(capture, viewer, self.display, stop)
            self._restore_signals(old_handlers)
        if isinstance(error, KeyboardInterrupt):
            self.request_stop("interrupted")
        elif error is not None:
            raise error
        seconds = time.monotonic() - t0
        summary = self._summary(capture_path, seconds, proto, inbox)
        summary.capture_discarded = capture.discarded
        return summary

    # -- internals --------------------------------------------------------------------------------------------

    def _install_signals(self):
        return install_stop_signals(self)

    @staticmethod
    def _restore_signals(old) -> None:
        restore_signals(old)

    def _loop(self, reader: SerialReader, proto: RecorderProtocol, inbox: Inbox, viewer, t0: float) -> None:
        opts = self.options
        pipe = self.pipeline = LivePipeline.for_viewer(
            opts.estimators, viewer, t0_unix_s=self.clock.wall0_s, baud=proto.capture.header["baud"]
        )
        self.warned_no_frames = False
        was_connected = True
        console = self.console = self._console(reader, proto, pipe)
        while self._stop_reason is None:
            if reader.error is not None:
                if isinstance(reader.error, OSError):  # the capture could not be written (disk full, removed)
                    raise UserError(
                        f"writing the capture failed ({reader.error.strerror or reader.error}); "
                        f"what was received until then is in {proto.capture.path}"
                    )
                raise reader.error
            chunks = inbox.get_all(0.02)
            now = time.monotonic()
            if chunks:
                pipe.feed(chunks)
                if viewer is not None:
                    viewer.log_link(pipe.decoder.stats, self.clock.now_s())
            pipe.tick(now)
            for _ in range(len(proto.events)):
                self.display.note(proto.events.popleft())
            for _ in range(len(pipe.texts)):
                self.display.note("firmware: " + pipe.texts.popleft()[:200])
            console.poll(pipe.notes)
            if proto.connected != was_connected:
                was_connected = proto.connected
                if proto.connected:
                    pipe.sample.clear()
            self._check_frames(proto, now)
            self.display.show(
                console.decorate(self._health_line(proto, inbox, now, reader)), now, force=console.take_typing_change()
            )
            if opts.duration_s is not None and now - t0 >= opts.duration_s:
                self.request_stop("duration")
            elif getattr(source := reader.serial, "at_end", False):  # a replay played to its end
                self.display.note(f"end of {source.path}")
                self.request_stop("end of replay")

    def _console(self, reader: SerialReader, proto: RecorderProtocol, pipe: LivePipeline) -> CommandConsole:
        """The command prompt: each frame goes to the port, then into the capture (H chunk) and the pipeline's log."""
        enabled = self.options.prompt if self.options.prompt is not None else _stdin_is_tty()

        def record(frame: bytes) -> None:
            t_unix_s = self.clock.now_s()
            proto.capture.write_host(frame, t_unix_s - self.clock.wall0_s)  # the capture's time base, as the D chunks
            pipe.feed_host(frame, t_unix_s)

        def send(frame: bytes) -> None:
            ser = reader.serial
            if ser is None:
                raise UserError("the port is not connected")
            ser.write(frame)

        console = CommandConsole(send, self.display.note, record=record, enabled=enabled)
        if enabled:  # a replay says once that commands go nowhere
            self.display.note(getattr(reader.serial, "prompt_note", PROMPT_HELP))
        return console

    def _drain(self, inbox: Inbox) -> None:
        pipe = getattr(self, "pipeline", None)
        if pipe is None:
            return
        chunks = inbox.get_all(0.0)
        if chunks:
            pipe.feed(chunks)
        pipe.flush_view()

    def _check_frames(self, proto: RecorderProtocol, now: float) -> None:
        """Wrong baud rate / not a STEVAL / silence: give up (or warn once with --wait) when no frame ever came."""
        stats = self.pipeline.decoder.stats
        if (
            stats.attitude + stats.status > 0
            or self.warned_no_frames
            or not proto.connected
            or proto.connected_at_s is None
        ):
            return
        elapsed = now - proto.connected_at_s
        nbytes = proto.connect_bytes
        if not (elapsed >= NO_FRAMES_TIMEOUT_S or (elapsed >= NO_FRAMES_EARLY_S and nbytes >= NO_FRAMES_EARLY_BYTES)):
            return
        message = autodetect.no_frames_message(
            proto.port or "?", self.options.baud, bytes(self.pipeline.sample), elapsed, total=nbytes
        )
        if self.options.wait:
            self.warned_no_frames = True
            self.display.note(message + "; still waiting (--wait)")
            return
        raise LinkError(message)

    def _health_line(self, proto: RecorderProtocol, inbox: Inbox, now: float, reader: SerialReader) -> str:
        s = self.pipeline.decoder.stats
        h = self.pipeline.health
        if not proto.connected:
            lost = now - (proto.lost_at_s or now)
            head = f"disconnected, waiting for {proto.port} ({lost:.0f} s)"
            failed = reader.reopen_error
            if failed is not None:  # it is back but cannot be opened: say why (busy, permissions)
                head += f"; {open_error_message(failed[0], failed[1])}"
        elif s.attitude + s.status == 0:
            head = f"{proto.port}: waiting for frames ({_fmt_bytes(proto.connect_bytes)} received)"
        else:
            rate = h.rate_hz(self.clock.now_s())
            head = f"{proto.port} {'--' if math.isnan(rate) else f'{rate:5.1f}'} Hz"
        parts = [
            head,
            f"frames {h.attitude}",
            f"missing {_stat(s, 'frames_missing')}",
            f"CRC {_stat(s, 'crc_failures')}",
            f"skipped {_fmt_bytes(_stat(s, 'bytes_skipped'))}",
        ]
        if h.values_bad:
            parts.insert(2, h.values_sentence())
        if _stat(s, "implausible"):
            parts.append(f"held back {_stat(s, 'implausible')}")
        if proto.disconnects:
            parts.append(f"disconnects {proto.disconnects}")
        if inbox.dropped_bytes:
            parts.append(f"live lag: {_fmt_bytes(inbox.dropped_bytes)} not shown")
        if self.pipeline.mahony is not None:
            parts.append(self.pipeline.mahony.describe())
        parts.append(f"rec {_fmt_bytes(proto.bytes_total)}")
        return " | ".join(parts)

    def _summary(self, capture_path: Path, seconds: float, proto: RecorderProtocol, inbox: Inbox) -> LiveSummary:
        pipe = getattr(self, "pipeline", None)
        s = pipe.decoder.stats if pipe is not None else None
        h = pipe.health if pipe is not None else LinkHealth()
        port_note = None
        streaming_s = 0.0
        if h.first_frame_s is not None and h.last_frame_s is not None:
            streaming_s = max(0.0, h.last_frame_s - h.first_frame_s - proto.offline_s)
        p = pipe.mahony if pipe is not None else None
        if p is not None:
            if p.rows_mismatch:
                port_note = f"ST port differs from the firmware on {p.rows_mismatch} frames"
            elif p.rows_exact:
                port_note = f"ST port bit-exact on {p.rows_exact} frames"
            else:
                port_note = "ST port not seeded (no status snapshot)"
        return LiveSummary(
            capture_path=capture_path,
            rrd_path=self.options.rrd,
            seconds=seconds,
            streaming_s=streaming_s,
            bytes_total=proto.bytes_total,
            attitude=h.attitude,
            status=h.status,
            text=h.text,
            frames_missing=_stat(s, "frames_missing"),
            crc_failures=_stat(s, "crc_failures"),
            bytes_skipped=_stat(s, "bytes_skipped"),
            nonfinite=h.nonfinite,
            disconnects=proto.disconnects,
            offline_s=proto.offline_s,
            live_dropped_bytes=inbox.dropped_bytes,
            port_note=port_note,
            stopped_by=self._stop_reason or "end",
            implausible=_stat(s, "implausible"),
            values_sentence=h.values_sentence(),
            held_values=_stat(s, "held_values"),
        )


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


def close_outputs(capture, viewer, display: HealthDisplay, stop_reason: str, t_stop_s: float | None = None) -> None:
    """End a session's outputs in their order of importance: the capture (its stop event, then closed), then the
    Rerun side (a failure there is a note: the capture is safe), then the health line. ``t_stop_s``: the stop
    event's time on the capture's clock (the emulated time of an emulated session; default: the host clock now)."""
    try:
        capture.mark_event("stop", stop_reason, t_host_s=t_stop_s)
    except Exception:  # noqa: BLE001 - the capture's bytes are written already; the event is a courtesy
        pass
    capture.close()
    if viewer is not None:
        try:
            viewer.close()
        except Exception as exc:  # noqa: BLE001 - the capture is safe; say what went wrong
            display.note(f"could not finalise the Rerun output: {exc}")
    display.close()


def _stat(stats, name: str) -> int:
    return int(getattr(stats, name, 0) or 0) if stats is not None else 0

"""The live session (``steval live``, ``record``, ``emulate``, ``live --ble``): a source by URL (:func:`source_for`)
→ capture → decoder → estimators → viewer; each chunk to the capture first (a slow viewer costs no byte)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import os
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, TextIO

from steval_link.errors import ParamError, UserError, param_word
from steval_link.link.autodetect import no_frames_message
from steval_link.link.capture import CaptureWriter, default_capture_path
from steval_link.link.commands import CommandChannel, parse_command
from steval_link.link.transport import HostClock
from steval_link.live import health
from steval_link.live.health import HealthDisplay, LiveSummary, _fmt_bytes
from steval_link.live.pipeline import LivePipeline
from steval_link.live.serial_source import LinkError, SerialSource, serial_health, serial_summary
from steval_link.live.sources import BREAK, END, NOTE, Chunk, LinkInfo, Source, open_capture, record_chunk
from steval_link.stop_signals import on_stop_signals

__all__ = ["CommandConsole", "LiveOptions", "LiveSession", "LiveSummary", "source_for"]

#: A serial link with bytes but no valid frame (wrong baud, not a STEVAL): one sentence after this long, s ...
NO_FRAMES_TIMEOUT_S = 2.5
#: ... or after this long once at least NO_FRAMES_EARLY_BYTES came.
NO_FRAMES_EARLY_S = 1.0
NO_FRAMES_EARLY_BYTES = 2048

BLE_SCHEME = "ble:"
EMULATED_SCHEME = "emulated:"


def source_for(url: str, **settings: Any) -> Source:
    """The source a URL names (table in :mod:`.sources`); its driver parses the URL and takes ``settings``."""
    if url.lower().startswith(BLE_SCHEME):
        from steval_link.live.ble_source import BleSource  # reason: BLE loads only when used

        return BleSource.from_url(url, **settings)
    if url.lower().startswith(EMULATED_SCHEME):
        from steval_link.live.emulated import EmulatedSource  # reason: the emulator loads only when used

        return EmulatedSource.from_url(url, **settings)
    return SerialSource.from_url(url, **settings)  # any other URL is a serial port's


def port_source(port: str, **settings: Any) -> Source:
    """A serial port or ``replay://`` (BLE and the emulated board: one sentence naming their own commands)."""
    low = port.lower()
    if low.startswith(BLE_SCHEME):
        name = port[len(BLE_SCHEME) :].strip()
        raise ParamError(
            f"{{port}} {port}: a BLE drone is read with steval live {{ble}} {name}".rstrip(), "port", "ble"
        )
    if low.startswith(EMULATED_SCHEME):
        raise ParamError(f"{{port}} {port}: the emulated board is run with steval emulate FIRMWARE.elf", "port")
    return source_for(port, **settings)


@dataclass
class LiveOptions:
    """What every live session configures (a source's own settings are its driver's)."""

    out: Path | None = None
    sinks: Any = None  # the Rerun outputs (``steval_viewer.sink_options.SinkOptions``); None: no Rerun
    estimators: list[str] = field(default_factory=list)
    duration_s: float | None = None
    prompt: bool | None = None  # lines typed on stdin → commands to the drone; None: when stdin is a terminal
    link_kind: str | None = None  # the source's kind ("serial", "ble"...), set by the session: the viewer's layout
    variant: str | None = None  # the ST release whose filter the replica runs ("ST 221117"); None: the status's
    text_map: dict | None = None  # which series of text telemetry are the attitude ({target: (series, unit)})
    word: Callable[[str], str] = param_word  # how a note names a parameter (the CLI gives its flag)


class LiveSession:
    """One live run over ``source``: :meth:`run` returns the summary or raises UserError. ``stream``: the health line's
    (stderr); ``viewer_factory(options, name)``: the Rerun side; ``check_outputs()``: run once the input is open."""

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
        if options.sinks is not None and viewer_factory is None:
            raise ValueError("a session that uses Rerun (a view or an .rrd file) needs a viewer_factory")
        self.options = options
        self.source = source
        self.viewer_factory = viewer_factory
        self.check_outputs = check_outputs
        self.display = HealthDisplay(stream or sys.stderr, tty=tty)
        self.clock = HostClock()
        self.capture: CaptureWriter | None = None  # set by run()
        self.viewer = None
        self.console: CommandConsole | None = None
        self.info: LinkInfo | None = None
        self.pipeline: LivePipeline | None = None  # made once the capture and the viewer are there
        self._stop_reason: str | None = None
        self._t_link_s: float | None = None  # the last chunk's time on a link's own clock (emulated)
        self._connected, self._warned_no_frames = True, False
        self.output_failures: list[str] = []  # outputs that failed during the run (the ``.rrd``), one sentence each

    def request_stop(self, reason: str = "stopped") -> None:
        """Finish cleanly at the next round (thread-safe; what Ctrl-C, SIGTERM and --duration do)."""
        if self._stop_reason is None:
            self._stop_reason = reason

    def _on_signal(self, signum: int) -> None:
        """Ctrl-C, SIGTERM, SIGHUP: stop at the next round; a second one (or one while stopping) stops now."""
        if self._stop_reason is not None:
            raise KeyboardInterrupt
        self.request_stop("interrupted" if signum == signal.SIGINT else "terminated")

    def run(self) -> LiveSummary:
        src, opts = self.source, self.options
        src.open(self.display.note)  # the input first: a bad port, ELF or BLE backend is one line before any file
        try:
            self.info = info = src.describe()
            if self.check_outputs is not None:
                self.check_outputs()
            path = Path(opts.out) if opts.out else default_capture_path()
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise UserError(f"cannot write the capture {path}: {exc.strerror or exc}") from None
            extra = {**info.extra, "estimators": list(opts.estimators)}
            capture = self.capture = open_capture(
                path, port=info.link, baud=info.baud, extra=extra, discard_empty=info.discard_empty
            )
        except BaseException:
            src.close()
            raise
        self.clock = HostClock(wall0_s=capture.header["start_time_unix_s"])
        t0 = min(time.monotonic(), src.status.started_s or math.inf)  # (a board that ran while the session began)
        error, started, stream = None, False, None
        with on_stop_signals(self._on_signal):
            try:
                if info.note:  # (BLE says when it is connected)
                    rrd = f" and {opts.sinks.rrd}" if opts.sinks is not None and opts.sinks.rrd else ""
                    self.display.note(f"{info.note}; recording to {capture.path}{rrd} (Ctrl-C to stop)")
                # bytes flow into the capture now, as the viewer starts
                stream = src.chunks(functools.partial(record_chunk, capture), self.clock)
                if opts.sinks is not None:
                    name = info.recording_name or capture.path.stem
                    self.viewer = self.viewer_factory(dataclasses.replace(opts, link_kind=info.kind), name)
                self.pipeline = LivePipeline.for_session(self)
                self.console = self._console()
                started = True
                self._loop(stream, t0)
            except KeyboardInterrupt:
                self.request_stop("interrupted")
            except BaseException as exc:  # noqa: BLE001 - finish the files first, then re-raise
                error = exc
            finally:
                try:
                    self._finish(stream, error)
                finally:
                    if self.console is not None:
                        self.console.close()
                    self._close_outputs(self._stop_reason or (type(error).__name__ if error else "end"))
                    if error is not None and not started:  # a failed start leaves nothing half-made
                        capture.discard()
        if error is not None:
            raise self._error_of(error)
        self._watch_outputs()
        return LiveSummary(
            capture_path=capture.path,
            rrd_path=opts.sinks.rrd if opts.sinks is not None and not self.output_failures else None,
            failures=list(self.output_failures),
            seconds=time.monotonic() - t0,
            stopped_by=self._stop_reason or "end",
            capture_discarded=capture.discarded,
            kind=info.kind,
            **self._summary_fields(),
        )

    def _take(self, chunks: list[Chunk]) -> None:
        """One round's chunks to the pipeline, in order; notes to the terminal."""
        pipe, wall0 = self.pipeline, self.clock.wall0_s
        serial, ble = [], []
        for c in chunks:
            if c.kind == "D":
                serial.append((c.data, c.t_unix_s if c.t_unix_s is not None else wall0 + c.t_s))
                self._t_link_s = c.t_s
            elif c.kind == "H":
                self._feed_serial(serial)
                serial = []
                pipe.feed_host(c.data, wall0 + c.t_s)
            elif c.kind in ("B", BREAK):
                ble.append((None, b"", 0.0) if c.kind == BREAK else (c.data[0], c.data[1], c.t_s))
            elif c.kind == NOTE:
                self.display.note(c.data)
            elif c.kind == END:
                self.request_stop(c.data)
        self._feed_serial(serial)
        if ble or self.info.kind == "ble":
            pipe.feed_ble(ble, final=any(c.kind == END for c in chunks))
        pipe.tick(time.monotonic())
        for _ in range(len(pipe.texts)):
            self.display.note("firmware: " + pipe.texts.popleft()[:200])
        self.console.poll(pipe.notes)

    def _feed_serial(self, serial: list) -> None:
        if serial:
            self.pipeline.feed(serial)
            if self.viewer is not None:
                t = serial[-1][1] if self.info.own_clock else self.clock.now_s()
                self.viewer.log_link(self.pipeline.decoder.stats, t)

    def _loop(self, stream, t0: float) -> None:
        console, duration_s = self.console, self.options.duration_s
        for t_s, command in self.info.commands:  # a script: numbered by the prompt's channel, sent at link times
            self.source.write(console.channel.next_frame(command).frame, at_s=t_s)
        for chunks in stream:
            self._take(chunks)
            self._watch_outputs()
            now = time.monotonic()
            self._check_link(now)
            if line := self._health(now, t0):  # (a link with nothing to say yet says "")
                self.display.show(console.decorate(line), now, force=console.take_typing_change())
            if duration_s is not None and now - t0 >= duration_s:
                self.request_stop("duration")
            if self._stop_reason is not None:
                break

    def _check_link(self, now: float) -> None:
        """A serial link: new connection, new sample; no valid frame in time: one sentence (a note with ``wait``)."""
        if self.info.kind != "serial":
            return
        status, stats, sample = self.source.status, self.pipeline.decoder.stats, self.pipeline.sample
        if status.connected and not self._connected:  # a new connection: a new sample
            sample.clear()
        self._connected = status.connected
        frames = stats.attitude + stats.status + stats.text_records
        if self._warned_no_frames or frames or not status.connected or status.connected_at_s is None:
            return
        elapsed, nbytes = now - status.connected_at_s, status.connect_bytes
        if elapsed < NO_FRAMES_TIMEOUT_S and (elapsed < NO_FRAMES_EARLY_S or nbytes < NO_FRAMES_EARLY_BYTES):
            return
        message = no_frames_message(status.port or "?", self.info.baud, bytes(sample), elapsed, total=nbytes)
        if not status.wait:
            raise LinkError(message.template, *message.params)
        self._warned_no_frames = True
        self.display.note(message.worded(self.options.word) + "; still waiting")

    def _health(self, now: float, t0: float) -> str:
        kind, pipe, status = self.info.kind, self.pipeline, self.source.status
        if kind == "ble":
            return health.ble_health(pipe)
        if kind == "emulated":
            return health.emulated_health(status, pipe, now - t0)
        return serial_health(status, pipe, now, self.clock.now_s(), self.options.word)

    def _summary_fields(self) -> dict[str, Any]:
        kind, pipe, status = self.info.kind, self.pipeline, self.source.status
        if kind == "ble":
            return health.ble_summary(status, pipe)
        if kind == "emulated":
            return health.emulated_summary(status, pipe, self.info.extra.get("filter") or {})
        return serial_summary(status, pipe, self.clock.now_s())

    def _finish(self, stream, error: BaseException | None) -> None:
        """The link stopped, then what it still held to the pipeline (the capture has it already)."""
        self.source.close()
        if stream is None or self.pipeline is None or not (error is None or isinstance(error, LinkError)):
            return
        with contextlib.suppress(Exception):  # the capture is whole whatever happens here
            for chunks in stream:
                self._take(chunks)
            if self.info.kind == "ble":  # the rows held for the cadence, also when a stop cut the last round
                self.pipeline.feed_ble([], final=True)
            self.pipeline.flush_view()

    def _error_of(self, error: BaseException) -> BaseException:
        """The error raised: a capture that failed, or the emulated board's error, says where the bytes are."""
        if isinstance(error, OSError) and not isinstance(error, UserError):  # disk full, deleted, replaced
            return UserError(capture_failure_sentence(self.capture, error))
        if self.info.own_clock and isinstance(error, UserError):
            return UserError(f"{error} (the capture {self.capture.path} holds everything until then)")
        return error

    def _close_outputs(self, stop_reason: str) -> None:
        """The capture (its stop event at the link's time), the Rerun side (a failure is a note), the health line."""
        with contextlib.suppress(Exception):  # the capture's bytes are written already; the event is a courtesy
            t = self._t_link_s if self.info is not None and self.info.own_clock else None
            self.capture.mark_event("stop", stop_reason, t_host_s=t)
        self.capture.close()
        if self.viewer is not None:
            try:
                self.viewer.close()
            except Exception as exc:  # noqa: BLE001 - the capture is safe; say what went wrong
                self.display.note(f"could not finalise the Rerun output: {exc}")
        self.display.close()

    def _console(self) -> CommandConsole:
        """The command prompt: each frame typed goes to the source (locked), then into the capture and the log."""
        prompt = self.options.prompt
        if prompt is None:  # when stdin is a terminal
            with contextlib.suppress(AttributeError, ValueError):  # no stdin, or a closed one
                prompt = sys.stdin.isatty()
        enabled = bool(prompt) and self.info.takes_commands
        console = CommandConsole(self.source.write, self.display.note, record=self._sent, enabled=enabled)
        if enabled:
            self.display.note(self.info.prompt_note)
        return console

    def _sent(self, frame: bytes) -> None:
        """A typed command as sent: into the capture (chunk H) and the pipeline (the board's come back as H chunks)."""
        if self.info.own_clock:
            return
        t_unix_s = self.clock.now_s()
        self.capture.write_host(frame, t_unix_s - self.clock.wall0_s)  # the capture's time base, as D chunks
        self.pipeline.feed_host(frame, t_unix_s)

    def _watch_outputs(self) -> None:
        """A capture that can take no more stops the run; an ``.rrd`` that failed is said once and the run goes on."""
        if (failure := self.capture.check_present()) is not None:
            raise UserError(capture_failure_sentence(self.capture, failure))
        said = getattr(self.viewer, "output_failure", None)
        if said and said not in self.output_failures:
            self.output_failures.append(said)
            self.display.note(said)


def capture_failure_sentence(capture: CaptureWriter, failure: OSError) -> str:
    """The one sentence for a capture that can take no more (disk full, deleted, replaced), naming what it holds."""
    amount = _fmt_bytes(capture.bytes_written)
    if "cannot be written" in str(failure) and capture.path.exists():
        return f"{failure}; stopped: the {amount} received until then are in {capture.path}"
    return f"the capture {failure}; stopped: the {amount} received until then went with it"


class CommandConsole:
    """Typed lines (``set ki 1.0``...) → commands → ``send(frame)``, then ``record(frame)``. A thread reads ``stream``
    (stdin); a POSIX terminal key by key, the line being typed shown in the health line (a redraw cannot wipe it)."""

    def __init__(
        self,
        send: Callable[[bytes], object],
        note: Callable[[str], None],
        *,
        record: Callable[[bytes], object] | None = None,
        stream: TextIO | None = None,
        enabled: bool = True,
    ) -> None:
        self.channel = CommandChannel(send, record)
        self.note = note
        self._lines: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.typing = ""  # the line being typed on a terminal (shown in the health line), "" otherwise
        self.typing_changed = False
        self._restore = None  # (fd, its old mode) while the terminal is raw
        if enabled:
            src = stream if stream is not None else sys.stdin
            target = self._read_keys if self._raw_terminal(src) else self._read
            threading.Thread(target=target, args=(src,), name="steval-prompt", daemon=True).start()

    def _raw_terminal(self, stream) -> bool:
        """Switch a terminal to key-by-key input without echo (Ctrl-C still interrupts); False when not one."""
        with contextlib.suppress(ImportError, AttributeError, ValueError, OSError):  # not a POSIX terminal
            import termios  # reason: POSIX only (Windows reads whole lines)
            import tty

            fd = stream.fileno()
            if os.isatty(fd):
                old = termios.tcgetattr(fd)
                tty.setcbreak(fd, termios.TCSANOW)
                self._restore = (fd, old)
        return self._restore is not None

    def close(self) -> None:
        """Give the terminal its line mode and echo back (idempotent)."""
        if self._restore is not None:
            import termios  # reason: only set on POSIX

            (fd, old), self._restore = self._restore, None
            with contextlib.suppress(OSError, ValueError):
                termios.tcsetattr(fd, termios.TCSANOW, old)

    def _read(self, stream: TextIO) -> None:
        with contextlib.suppress(OSError, ValueError):  # stdin closed
            for line in stream:
                self._lines.put(line)

    def _read_keys(self, stream) -> None:
        fd, buf = stream.fileno(), ""
        with contextlib.suppress(OSError):
            while b := os.read(fd, 64):
                for ch in b.decode("utf-8", "replace"):
                    if ch in "\r\n":
                        self._lines.put(buf + "\n")
                        buf = ""
                    elif ch in "\x7f\b":
                        buf = buf[:-1]
                    elif ch == "\x15":  # Ctrl-U: the whole line
                        buf = ""
                    elif ch.isprintable():
                        buf += ch
                self.typing, self.typing_changed = buf, True

    def type_line(self, line: str) -> None:
        self._lines.put(line)

    def decorate(self, health_line: str) -> str:
        """The health line after the command being typed (on a terminal)."""
        return health_line if self._restore is None else f"> {self.typing}_  | {health_line}"

    def take_typing_change(self) -> bool:
        """True once after each key typed (the session then redraws at once, so typing shows without delay)."""
        changed, self.typing_changed = self.typing_changed, False
        return changed

    def poll(self, notes=()) -> int:
        """Send what was typed since the last call; print ``notes`` (the pipeline's answers). Returns commands sent."""
        n = 0
        while not self._lines.empty():
            line = self._lines.get_nowait()
            if not line.strip():
                continue
            try:
                command = parse_command(line)
            except UserError as exc:
                self.note(str(exc))
                continue
            try:
                self.channel.send(command)
            except (OSError, UserError) as exc:
                self.note(f"{command.describe()}: not sent ({exc})")
            else:
                self.note(f"sent: {command.describe()}")
                n += 1
        for _ in range(len(notes)):
            self.note(notes.popleft())
        return n

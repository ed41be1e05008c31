"""The serial driver of a live session: a port (``/dev/ttyUSB0``, ``COM3``, a glob, ``auto``) or a replay
(``replay://FILE.stv``, played at its recorded pace as a port: :mod:`steval_link.link.replay_source`).

A reader thread (:class:`~steval_link.link.transport.SerialReader`) hands each chunk to :class:`RecorderProtocol`:
the capture first, then a bounded inbox; each round decodes the inbox (:class:`LivePipeline`). Faults it survives:
unplug/replug (the reader reopens the port, by path or USB identity, and the capture marks the gap), garbage and
truncated frames (counted by the decoder), non-finite values (counted, never fed to an estimator, never plotted).
A wrong baud rate or another device: one line and :class:`LinkError` (see
:func:`steval_link.link.autodetect.no_frames_message`). Commands go out through the reader's locked write.
"""

from __future__ import annotations

import math
import os
import time
from typing import Any

import serial

from steval_link import constants as C
from steval_link.errors import UserError
from steval_link.link import autodetect
from steval_link.link.replay_source import is_replay_url, open_replay
from steval_link.link.transport import SerialReader, open_error_message, open_serial
from steval_link.live.console import PROMPT_HELP
from steval_link.live.health import LinkHealth, _fmt_bytes, pipeline_health, stat
from steval_link.live.pipeline import LivePipeline
from steval_link.live.recorder import Inbox, RecorderProtocol, capture_failure_sentence
from steval_link.live.sources import CaptureFields, Source
from steval_link.live.summary import pipeline_counts

__all__ = ["LinkError", "SerialSource", "NO_FRAMES_TIMEOUT_S", "open_port"]

#: Wrong baud / not a STEVAL: give up after this long with bytes but no valid frame, s (sooner with many bytes) ...
NO_FRAMES_TIMEOUT_S = 2.5
#: ... or after this long once at least NO_FRAMES_EARLY_BYTES arrived without a valid frame.
NO_FRAMES_EARLY_S = 1.0
NO_FRAMES_EARLY_BYTES = 2048
#: How long a round waits for the reader's first chunk, s.
ROUND_WAIT_S = 0.02


class LinkError(UserError):
    """The port carries no valid frames (wrong baud rate, another device, silence): one line, exit code 2."""


def open_port(url: str, baud: int, *, wait: bool = False, note=None, stopped=None) -> tuple[str, serial.Serial]:
    """(path, open port) of ``url``: a replay URL, or the port :func:`~steval_link.link.autodetect.choose_port`
    picks; one UserError sentence (with the ports there are) when it cannot be opened. ``wait``: until the port
    appears (``note(text)`` says so once) or ``stopped()``."""
    if is_replay_url(url):  # the one place a source is opened by its URL scheme
        return url, open_replay(url, baud=baud)
    deadline = time.monotonic() + (math.inf if wait else 0.0)
    announced = note is None  # a waiting note is said once
    while True:
        try:
            path = autodetect.choose_port(url, baud)
        except autodetect.PortChoiceError as exc:
            if time.monotonic() >= deadline or (stopped and stopped()):
                raise UserError(str(exc)) from None
            if not announced:
                note(f"{exc}; waiting (--wait)")
                announced = True
            time.sleep(0.25)
            continue
        try:
            return path, open_serial(path, baud)
        except serial.SerialException as exc:
            missing = getattr(exc, "errno", None) == 2 or not os.path.exists(path)
            if missing and time.monotonic() < deadline and not (stopped and stopped()):
                if not announced:
                    note(f"{path} is not there; waiting for it (--wait)")
                    announced = True
                time.sleep(0.1)
                continue
            try:
                available = autodetect.list_candidate_ports()
            except Exception:  # noqa: BLE001 - the listing is only a hint in the message
                available = []
            raise UserError(open_error_message(path, exc, available)) from None


class SerialSource(Source):
    """A serial port or a replay URL at ``baud``; ``wait``: wait for the port to appear and for valid frames."""

    def __init__(self, url: str, *, baud: int = C.BAUD, wait: bool = False) -> None:
        self.url, self.baud, self.wait = url, baud, wait
        self.path, self.ser = url, None  # the port opened (a glob or auto resolved)
        self.reader: SerialReader | None = None
        self.pipeline: LivePipeline | None = None
        self.warned_no_frames, self._was_connected = False, True

    @property
    def replay(self) -> bool:
        return is_replay_url(self.url)

    @property
    def prompt_note(self) -> str:  # a replay says once that commands go nowhere
        return getattr(self.ser, "prompt_note", PROMPT_HELP)

    # -- opening ----------------------------------------------------------------------------------------------

    def open(self, session) -> None:
        self.session = session
        note = session.display.note
        self.path, self.ser = open_port(
            self.url, self.baud, wait=self.wait, note=note, stopped=lambda: session.stop_requested
        )
        if self.replay:  # a recording: nothing to find again after a loss
            self.finder, self._described, self._extra = None, self.ser.describe(), {"replay_of": str(self.ser.path)}
        else:
            identity = autodetect.PortIdentity.of(self.path)
            glob = self.url if autodetect.is_glob(self.url) else None
            self.finder = autodetect.PortFinder(identity, pattern=glob)
            self._described = identity.describe()
            self._extra = {"device": identity.device, "usb": identity.describe()}

    def close_input(self) -> None:
        if self.ser is not None:
            self.ser.close()

    def describe(self) -> str:
        return f"reading {self._described} at {self.ser.baudrate} baud"

    def capture_fields(self) -> CaptureFields:
        return CaptureFields(self.path, self.ser.baudrate, dict(self._extra))

    # -- running ----------------------------------------------------------------------------------------------

    def start(self, session) -> None:
        self.inbox = Inbox()
        self.proto = RecorderProtocol(session.capture, self.inbox, self.finder, session.clock)
        find = self.finder.find if self.finder is not None else None
        self.reader = SerialReader(self.ser, self.proto, baud=self.ser.baudrate, clock=session.clock, find_port=find)
        self.reader.start()

    def attach(self, session) -> None:
        self.pipeline = LivePipeline.for_session(session)

    def round(self) -> bool:
        reader, proto, pipe, session = self.reader, self.proto, self.pipeline, self.session
        if reader.error is not None:
            if isinstance(reader.error, OSError):  # the capture could not be written (disk full, removed)
                raise UserError(capture_failure_sentence(proto.capture, reader.error))
            raise reader.error
        chunks = self.inbox.get_all(ROUND_WAIT_S)
        now = time.monotonic()
        if chunks:
            pipe.feed(chunks)
            if session.viewer is not None:
                session.viewer.log_link(pipe.decoder.stats, session.clock.now_s())
        pipe.tick(now)
        for _ in range(len(proto.events)):
            session.display.note(proto.events.popleft())
        for _ in range(len(pipe.texts)):
            session.display.note("firmware: " + pipe.texts.popleft()[:200])
        session.console.poll(pipe.notes)
        if proto.connected != self._was_connected:
            self._was_connected = proto.connected
            if proto.connected:
                pipe.sample.clear()
        self._check_frames(now)
        if getattr(reader.serial, "at_end", False):  # a replay played to its end
            session.display.note(f"end of {reader.serial.path}")
            session.request_stop("end of replay")
        return True

    def write(self, frame: bytes) -> None:
        if self.reader is None:
            raise UserError("the port is not connected")
        self.reader.write(frame)  # under the lock a reconnection holds

    def record(self, frame: bytes) -> None:
        clock = self.session.clock
        t_unix_s = clock.now_s()
        self.session.capture.write_host(frame, t_unix_s - clock.wall0_s)  # the capture's time base, as D chunks
        self.pipeline.feed_host(frame, t_unix_s)

    def finish(self, error: BaseException | None) -> None:
        if self.reader is not None:
            self.reader.stop()
        # whatever is still queued goes to the live side; the capture already holds it
        if self.pipeline is not None and (error is None or isinstance(error, LinkError)):
            try:
                chunks = self.inbox.get_all(0.0)
                if chunks:
                    self.pipeline.feed(chunks)
                self.pipeline.flush_view()
            except Exception:  # noqa: BLE001
                pass

    # -- what it says -----------------------------------------------------------------------------------------

    def _check_frames(self, now: float) -> None:
        """Wrong baud rate / not a STEVAL / silence: give up (or warn once with --wait) when no frame ever came."""
        proto, stats = self.proto, self.pipeline.decoder.stats
        if stats.attitude + stats.status > 0 or self.warned_no_frames or not proto.connected:
            return
        if proto.connected_at_s is None:
            return
        elapsed = now - proto.connected_at_s
        nbytes = proto.connect_bytes
        if not (elapsed >= NO_FRAMES_TIMEOUT_S or (elapsed >= NO_FRAMES_EARLY_S and nbytes >= NO_FRAMES_EARLY_BYTES)):
            return
        message = autodetect.no_frames_message(
            proto.port or "?", self.baud, bytes(self.pipeline.sample), elapsed, total=nbytes
        )
        if self.wait:
            self.warned_no_frames = True
            self.session.display.note(message + "; still waiting (--wait)")
            return
        raise LinkError(message)

    def health(self, now_mono_s: float) -> str:
        proto, pipe, s = self.proto, self.pipeline, self.pipeline.decoder.stats
        if not proto.connected:
            lost = now_mono_s - (proto.lost_at_s or now_mono_s)
            head = f"disconnected, waiting for {proto.port} ({lost:.0f} s)"
            if proto.probing is not None:
                head = f"disconnected ({lost:.0f} s); trying {proto.probing}: no valid frames yet"
            failed = self.reader.reopen_error
            if failed is not None:  # it is back but cannot be opened: say why (busy, permissions)
                head += f"; {open_error_message(failed[0], failed[1])}"
        elif s.attitude + s.status == 0:
            head = f"{proto.port}: waiting for frames ({_fmt_bytes(proto.connect_bytes)} received)"
        else:
            rate = pipe.health.rate_hz(self.session.clock.now_s())
            head = f"{proto.port} {'--' if math.isnan(rate) else f'{rate:5.1f}'} Hz"
        more = [f"disconnects {proto.disconnects}"] if proto.disconnects else []
        if self.inbox.dropped_bytes:
            more.append(f"live lag: {_fmt_bytes(self.inbox.dropped_bytes)} not shown")
        skipped = f"skipped {_fmt_bytes(stat(s, 'bytes_skipped'))}"
        return pipeline_health(
            head, pipe, after_crc=[skipped], before_port=more, last=[f"rec {_fmt_bytes(proto.bytes_total)}"]
        )

    def summary_fields(self) -> dict[str, Any]:
        pipe, proto = self.pipeline, getattr(self, "proto", None)
        h = pipe.health if pipe is not None else LinkHealth()
        streaming_s = offline_s = 0.0
        now_s = self.session.clock.now_s()
        if proto is not None:  # every loss measured, one not over yet up to now
            offline_s = proto.offline_within(-math.inf, math.inf, now_s)
        if h.first_frame_s is not None and h.last_frame_s is not None:  # the rate's time: connected, with frames
            within = proto.offline_within(h.first_frame_s, h.last_frame_s, now_s) if proto is not None else 0.0
            streaming_s = max(0.0, h.last_frame_s - h.first_frame_s - within)
        p = pipe.mahony if pipe is not None else None
        filter_note = None
        if p is not None:
            if p.rows_mismatch:
                filter_note = f"ST port differs from the firmware on {p.rows_mismatch} frames"
            elif p.rows_exact:
                filter_note = f"ST port bit-exact on {p.rows_exact} frames"
            else:
                filter_note = "ST port not seeded (no status snapshot)"
        return {
            **pipeline_counts(pipe),
            "streaming_s": streaming_s,
            "bytes_total": proto.bytes_total if proto is not None else 0,
            "disconnects": proto.disconnects if proto is not None else 0,
            "offline_s": offline_s,
            "lost_for_good": bool(proto is not None and proto.offline and proto.offline[-1][1] is None),
            "live_dropped_bytes": self.inbox.dropped_bytes if proto is not None else 0,
            "filter_note": filter_note,
        }

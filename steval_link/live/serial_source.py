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

import dataclasses
import math
import os
import threading
import time
from collections.abc import Iterator
from typing import Any

import serial

from steval_link import constants as C
from steval_link.errors import ParamError, UserError, param_word
from steval_link.link import autodetect
from steval_link.link.replay_source import is_replay_url, open_replay
from steval_link.link.transport import SerialReader, open_error_message, open_serial
from steval_link.live.console import PROMPT_HELP
from steval_link.live.health import LinkHealth, _fmt_bytes, pipeline_counts, pipeline_health
from steval_link.live.recorder import Inbox, RecorderProtocol, offline_within
from steval_link.live.sources import END, NOTE, Chunk, LinkInfo, LinkStatus, Record, Source

__all__ = [
    "LinkError",
    "SerialSource",
    "NO_FRAMES_TIMEOUT_S",
    "open_port",
    "check_frames",
    "serial_health",
    "serial_summary",
]

#: Wrong baud / not a STEVAL: give up after this long with bytes but no valid frame, s (sooner with many bytes) ...
NO_FRAMES_TIMEOUT_S = 2.5
#: ... or after this long once at least NO_FRAMES_EARLY_BYTES arrived without a valid frame.
NO_FRAMES_EARLY_S = 1.0
NO_FRAMES_EARLY_BYTES = 2048
#: How long a round waits for the reader's first chunk, s.
ROUND_WAIT_S = 0.02


class LinkError(ParamError):
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
                raise
            if not announced:
                note(f"{str(exc).split('; ')[0]}; waiting")
                announced = True
            time.sleep(0.25)
            continue
        try:
            return path, open_serial(path, baud)
        except serial.SerialException as exc:
            missing = getattr(exc, "errno", None) == 2 or not os.path.exists(path)
            if missing and time.monotonic() < deadline and not (stopped and stopped()):
                if not announced:
                    note(f"{path} is not there; waiting for it")
                    announced = True
                time.sleep(0.1)
                continue
            try:
                available = autodetect.list_candidate_ports()
            except Exception:  # noqa: BLE001 - the listing is only a hint in the message
                available = []
            raise open_error_message(path, exc, available) from None


class SerialSource(Source):
    """A serial port or a replay URL at ``baud``; ``wait``: wait for the port to appear and for valid frames."""

    def __init__(self, url: str, *, baud: int = C.BAUD, wait: bool = False) -> None:
        self.url, self.baud, self.wait = url, baud, wait
        self.path, self.ser = url, None  # the port opened (a glob or auto resolved)
        self.reader: SerialReader | None = None
        self.proto: RecorderProtocol | None = None
        self.inbox = Inbox()
        self._closed = False
        self._stopped = threading.Event()  # close() before the port appeared (--wait)

    @classmethod
    def from_url(cls, url: str, **settings: Any) -> SerialSource:
        """A port (``/dev/ttyUSB0``, ``COM3``, a glob, ``auto``) or ``replay://FILE[?speed=X]``: opened as they are
        (:func:`open_port` reads the replay URL's path and speed)."""
        return cls(url, **settings)

    @property
    def replay(self) -> bool:
        return is_replay_url(self.url)

    @property
    def status(self) -> LinkStatus:
        if self.proto is None:
            return LinkStatus(port=self.path, wait=self.wait)
        return dataclasses.replace(
            self.proto.status,
            live_dropped_bytes=self.inbox.dropped_bytes,
            reopen_error=self.reader.reopen_error if self.reader is not None else None,
            wait=self.wait,
            pace=float(getattr(self.ser, "speed", 1.0) or 1.0),  # a replay's ?speed=
            offline=list(self.proto.status.offline),
        )

    def open(self, note=print) -> None:
        """The port (waiting for it with ``wait``: ``note(text)`` says so once), or one UserError sentence."""
        self.path, self.ser = open_port(self.url, self.baud, wait=self.wait, note=note, stopped=self._stopped.is_set)
        if self.replay:  # a recording: nothing to find again after a loss
            self.finder, self._described, self._extra = None, self.ser.describe(), {"replay_of": str(self.ser.path)}
            if getattr(self.ser, "emulated", False):  # its status frames count emulated instructions, not cycles
                self._extra["emulated"] = True
            if self.ser.line_start:  # a log: its first line is whole, live and in the capture made of it
                self._extra["line_start"] = True
        else:
            identity = autodetect.PortIdentity.of(self.path)
            glob = self.url if autodetect.is_glob(self.url) else None
            self.finder = autodetect.PortFinder(identity, pattern=glob)
            self._described = identity.describe()
            self._extra = {"device": identity.device, "usb": identity.describe()}

    def describe(self) -> LinkInfo:
        return LinkInfo(
            self.path,
            self.ser.baudrate,
            dict(self._extra),
            note=f"reading {self._described} at {self.ser.baudrate} baud",
            prompt_note=getattr(self.ser, "prompt_note", PROMPT_HELP),  # a replay says commands go nowhere
        )

    def chunks(self, record: Record, clock) -> Iterator[list[Chunk]]:
        """The reader thread starts now: each chunk goes to the capture first (:class:`RecorderProtocol`), then to a
        bounded inbox that each round takes."""
        self.proto = RecorderProtocol(_Capture(record), self.inbox, self.finder, clock)
        find = self.finder.find if self.finder is not None else None
        self.reader = SerialReader(self.ser, self.proto, baud=self.ser.baudrate, clock=clock, find_port=find)
        self.reader.start()
        return self._rounds(clock)

    def _rounds(self, clock) -> Iterator[list[Chunk]]:
        reader, proto = self.reader, self.proto
        while True:
            if reader.error is not None and not self._closed:
                raise reader.error  # an OSError: the capture could not be written (the session says where it is)
            got = self.inbox.get_all(0.0 if self._closed else ROUND_WAIT_S)
            out = [Chunk(NOTE, proto.events.popleft(), 0.0) for _ in range(len(proto.events))]
            out += [Chunk("D", data, t_unix_s - clock.wall0_s, t_unix_s) for data, t_unix_s in got]
            if self._closed:
                yield out
                return
            if getattr(reader.serial, "at_end", False):  # a replay played to its end
                out += [Chunk(NOTE, f"end of {reader.serial.path}", 0.0), Chunk(END, "end of replay", 0.0)]
            yield out

    def write(self, frame: bytes, at_s: float | None = None) -> None:
        if self.reader is None:
            raise UserError("the port is not connected")
        self.reader.write(frame)  # under the lock a reconnection holds

    def close(self) -> None:
        self._stopped.set()
        self._closed = True
        if self.reader is not None:
            self.reader.stop()
        elif self.ser is not None:
            self.ser.close()


class _Capture:
    """The capture as :class:`RecorderProtocol` writes it (bytes, events), through the session's ``record``."""

    def __init__(self, record: Record) -> None:
        self.record = record

    def write(self, data: bytes, t_s: float) -> None:
        self.record(Chunk("D", data, t_s))

    def mark_event(self, kind: str, text: str, t_s: float | None = None) -> None:
        self.record(Chunk("E", (kind, text), t_s))


def check_frames(status: LinkStatus, pipe, baud: int, now: float) -> ParamError | None:
    """Wrong baud rate / not a STEVAL / silence: the sentence when no frame came in time on this connection (None:
    frames came, or not yet time to say)."""
    stats = pipe.decoder.stats
    if stats.attitude + stats.status + stats.text_records > 0 or not status.connected or status.connected_at_s is None:
        return None
    elapsed = now - status.connected_at_s
    nbytes = status.connect_bytes
    if not (elapsed >= NO_FRAMES_TIMEOUT_S or (elapsed >= NO_FRAMES_EARLY_S and nbytes >= NO_FRAMES_EARLY_BYTES)):
        return None
    return autodetect.no_frames_message(status.port or "?", baud, bytes(pipe.sample), elapsed, total=nbytes)


def serial_health(status: LinkStatus, pipe, now_mono_s: float, now_unix_s: float, word=param_word) -> str:
    """The health line of a serial port or a replay (``word``: how its advice names a parameter)."""
    s = pipe.decoder.stats
    if not status.connected:
        lost = now_mono_s - (status.lost_at_s or now_mono_s)
        head = f"disconnected, waiting for {status.port} ({lost:.0f} s)"
        if status.probing is not None:
            head = f"disconnected ({lost:.0f} s); trying {status.probing}: no valid frames yet"
        if status.reopen_error is not None:  # it is back but cannot be opened: say why (busy, permissions)
            head += f"; {open_error_message(*status.reopen_error).worded(word)}"
    elif s.attitude + s.status == 0:
        head = f"{status.port}: waiting for frames ({_fmt_bytes(status.connect_bytes)} received)"
    else:
        rate = pipe.health.rate_hz(now_unix_s)
        head = f"{status.port} {'--' if math.isnan(rate) else f'{rate:5.1f}'} Hz"
    more = [f"disconnects {status.disconnects}"] if status.disconnects else []
    if status.live_dropped_bytes:
        more.append(f"live lag: {_fmt_bytes(status.live_dropped_bytes)} not shown")
    skipped = f"skipped {_fmt_bytes(s.bytes_skipped)}"
    return pipeline_health(
        head, pipe, after_crc=[skipped], before_replica=more, last=[f"rec {_fmt_bytes(status.bytes_total)}"]
    )


def serial_summary(status: LinkStatus, pipe, now_s: float) -> dict[str, Any]:
    """The summary fields of a serial port or a replay (``now_s``: the host's Unix time; a loss not over yet lasts
    until then)."""
    h = pipe.health if pipe is not None else LinkHealth()
    streaming_s = 0.0
    offline_s = offline_within(status.offline, -math.inf, math.inf, now_s)  # every loss measured
    if h.first_frame_s is not None and h.last_frame_s is not None:  # the rate's time: connected, with frames
        within = offline_within(status.offline, h.first_frame_s, h.last_frame_s, now_s)
        streaming_s = max(0.0, h.last_frame_s - h.first_frame_s - within)
    p = pipe.mahony if pipe is not None else None
    filter_note = None
    if p is not None:
        if p.rows_mismatch:
            filter_note = f"ST replica differs from the firmware on {p.rows_mismatch} frames"
        elif p.rows_exact:
            filter_note = f"ST replica bit-exact on {p.rows_exact} frames"
        elif not pipe.binary:
            filter_note = "ST replica not run (no binary frames: text has no bit-exact inputs)"
        else:
            filter_note = "ST replica not seeded (no status snapshot)"
        if p.rows_mismatch or p.rows_exact:
            filter_note += f" with {p.settings.variant}'s filter"
    return {
        **pipeline_counts(pipe),
        "streaming_s": streaming_s,
        "bytes_total": status.bytes_total,
        "disconnects": status.disconnects,
        "offline_s": offline_s,
        "lost_for_good": bool(status.offline and status.offline[-1][1] is None),
        "live_dropped_bytes": status.live_dropped_bytes,
        "pace": status.pace,
        "filter_note": filter_note,
    }

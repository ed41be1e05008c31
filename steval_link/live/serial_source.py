"""The serial driver of a live session: a port (``/dev/ttyUSB0``, ``COM3``, a glob, ``auto``) or a replay
(``replay://FILE.stv``, played at its recorded pace as a port). A reader thread (``SerialReader``, which reopens an
unplugged port) hands each chunk to :class:`RecorderProtocol`: the capture first, then a bounded :class:`Inbox`.
:func:`run_command` (``steval param``/``command``) sends one command on a port and waits for its answer."""

from __future__ import annotations

import collections
import contextlib
import math
import os
import re
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import serial

from steval_link import constants as C
from steval_link.errors import ParamError, UserError, param_word
from steval_link.link import autodetect, transport
from steval_link.link import protocol as P
from steval_link.link.commands import Command, CommandChannel, ack_of_text, describe_ack
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AckFrame, AttitudeFrame, StatusFrame, TextFrame
from steval_link.link.replay_source import is_replay_url, open_replay
from steval_link.link.transport import PortRejected, Protocol, SerialReader, open_error_message, open_serial
from steval_link.live.health import LinkHealth, _fmt_bytes, pipeline_counts, pipeline_health
from steval_link.live.sources import END, NOTE, PROMPT_HELP, Chunk, LinkInfo, LinkStatus, Record, Source, open_capture

__all__ = ["LinkError", "Reply", "SerialSource", "open_port", "run_command", "serial_health", "serial_summary"]

ROUND_WAIT_S = 0.02  # how long a round waits for the reader's first chunk, s
INBOX_MAX_BYTES = 4 * 1024 * 1024  # bytes held for the decoder before the oldest leave the live view
#: A port reopened after a loss is the drone once it sent PROBATION_FRAMES valid frames; none in PROBATION_S: not
PROBATION_S = 3.0
PROBATION_FRAMES = 2
#: Port holders are looked up at a (re)connection, a taken read or SILENT_S of silence; at most every HOLDERS_CHECK_S, s
HOLDERS_CHECK_S = 5.0
SILENT_S = 1.0


class LinkError(ParamError):
    """The port carries no valid frames (wrong baud rate, another device, silence): one line, exit code 2."""


def open_port(url: str, baud: int, *, wait: bool = False, note=None, stopped=None) -> tuple[str, serial.Serial]:
    """(path, open port) of a replay URL or the port ``choose_port`` picks; one UserError sentence (with the ports
    there are) when it cannot be opened. ``wait``: until it appears (``note(text)`` says so once) or ``stopped()``."""
    if is_replay_url(url):  # the one place a source is opened by its URL scheme
        return url, open_replay(url, baud=baud)
    said = note is None  # a waiting note is said once
    while True:
        waiting = wait and not (stopped and stopped())
        try:
            path = autodetect.choose_port(url, baud)
        except autodetect.PortChoiceError as exc:
            if not waiting:
                raise
            why, pause_s = f"{str(exc).split('; ')[0]}; waiting", 0.25
        else:
            try:
                return path, open_serial(path, baud)
            except serial.SerialException as exc:
                if not (waiting and (getattr(exc, "errno", None) == 2 or not os.path.exists(path))):
                    available = []
                    with contextlib.suppress(Exception):  # the listing is only a hint in the message
                        available = autodetect.list_candidate_ports()
                    raise open_error_message(path, exc, available) from None
                why, pause_s = f"{path} is not there; waiting for it", 0.1
        if not said:
            note(why)
            said = True
        time.sleep(pause_s)


class Inbox:
    """Chunks handed from the reader thread to the main thread; bounded by bytes (oldest dropped, counted)."""

    def __init__(self, max_bytes: int = INBOX_MAX_BYTES) -> None:
        self.max_bytes = max_bytes
        self._chunks, self._bytes = collections.deque(), 0  # (data, t_unix_s) waiting, and their bytes
        self._cond = threading.Condition()
        self.dropped_bytes = 0  # dropped from the live view as the main thread fell behind (still in the capture)

    def put(self, data: bytes, t_unix_s: float) -> None:
        with self._cond:
            self._chunks.append((data, t_unix_s))
            self._bytes += len(data)
            while self._bytes > self.max_bytes and len(self._chunks) > 1:
                old, _ = self._chunks.popleft()
                self._bytes -= len(old)
                self.dropped_bytes += len(old)
            self._cond.notify()

    def get_all(self, timeout_s: float) -> list[tuple[bytes, float]]:
        """Every waiting chunk (waits up to ``timeout_s`` for the first one)."""
        with self._cond:
            if not self._chunks:
                self._cond.wait(timeout_s)
            out, self._bytes = list(self._chunks), 0
            self._chunks.clear()
            return out


class RecorderProtocol(Protocol):
    """Reader-thread side: each chunk to the capture, then the inbox; events to the capture and :attr:`status`. A port
    reopened that sends no valid frame on probation is rejected; another program reading the port is named once."""

    def __init__(self, record: Record, inbox: Inbox, finder: autodetect.PortFinder | None, clock) -> None:
        self.record = record
        self.inbox = inbox
        self.finder = finder
        self.clock = clock
        self.status = LinkStatus()  # ``offline``: host Unix times; ``lost_at_s``, ``connected_at_s``: monotonic
        self.events: collections.deque[str] = collections.deque(maxlen=64)  # messages for the display
        self._probe: StreamDecoder | None = None  # a port reopened on probation: its frames so far
        self._probe_frames = 0
        self._holders_said: set[int] = set()  # the pids named already
        self._holders: list[tuple[int, str]] = []  # the (pid, name) last looked up
        self._last_data_s = self._holders_checked_s = -math.inf  # monotonic times of the last chunk and lookup

    def _t_capture(self, t_unix_s: float | None = None) -> float:
        """Capture time base: s since the capture started (the clock's origin is the capture's start)."""
        return (self.clock.now_s() if t_unix_s is None else t_unix_s) - self.clock.wall0_s

    def _mark(self, kind: str, text: str, t_s: float | None = None) -> None:
        """A link event into the capture (``t_s``: on its time base; None: now)."""
        self.record(Chunk("E", (kind, text), self._t_capture() if t_s is None else t_s))

    def connection_made(self, port: str) -> None:
        st, now = self.status, time.monotonic()
        st.connections += 1
        st.port, st.connect_bytes, st.connected_at_s = port, 0, now
        if st.connections > 1:  # back after a loss: the drone only once it sends valid frames
            st.probing, self._probe, self._probe_frames = port, StreamDecoder(), 0
            self._probe_at = self._t_capture()  # its bytes flow from now on (the capture marks where)
            self._mark("reconnect", f"{port} opened again after {now - (st.lost_at_s or now):.2f} s", self._probe_at)
            return
        st.connected = True
        self._say_holders(port)

    def _confirm(self) -> None:
        """The port reopened sent valid frames: the drone is back."""
        st = self.status
        back = st.connected_at_s or time.monotonic()  # its bytes flowed from the reopening on
        gap = max(0.0, back - (st.lost_at_s or back))
        if st.offline and st.offline[-1][1] is None:
            st.offline[-1] = (st.offline[-1][0], self._probe_at + self.clock.wall0_s)
        port, st.probing, self._probe = st.probing, None, None
        self.events.append(f"reconnected on {port} after {gap:.1f} s")
        st.connected = True
        self._say_holders(port)

    def data_received(self, data: bytes, t_unix_s: float) -> None:
        self.record(Chunk("D", data, self._t_capture(t_unix_s)))  # first: whatever happens next, the bytes are kept
        self.status.bytes_total += len(data)
        self.status.connect_bytes += len(data)
        self.inbox.put(data, t_unix_s)
        self._last_data_s = time.monotonic()
        if self._probe is not None:
            self._probe_frames += sum(1 for f in self._probe.feed(data) if isinstance(f, (AttitudeFrame, StatusFrame)))
            if self._probe_frames >= PROBATION_FRAMES:
                self._confirm()

    def idle(self, t_unix_s: float) -> None:
        now = time.monotonic()
        if self.status.probing is not None and now - (self.status.connected_at_s or 0.0) >= PROBATION_S:
            raise PortRejected(f"{self.status.probing} sent no valid frames in {PROBATION_S:.0f} s")
        if self.status.connected and now - max(self._last_data_s, self.status.connected_at_s or now) >= SILENT_S:
            self._say_holders(self.status.port)  # silent: another reader may take every byte (at most every few s)

    def shared_access(self, exc: BaseException) -> bool:
        if self.status.port is None or not os.path.exists(self.status.port):
            return False  # the node is gone: an unplug
        return bool(self._say_holders(self.status.port, force=True))

    def _say_holders(self, port: str, *, force: bool = False) -> list[tuple[int, str]]:
        """Name the other programs that have ``port`` open, once each (looked up at most every few seconds)."""
        now = time.monotonic()
        if now - self._holders_checked_s < (1.0 if force else HOLDERS_CHECK_S):
            return self._holders if force else []
        self._holders_checked_s = now
        self._holders = autodetect.port_holders(port)
        if new := [h for h in self._holders if h[0] not in self._holders_said]:
            self._holders_said.update(pid for pid, _ in new)
            sentence = autodetect.holders_sentence(port, new)
            self._mark("shared", sentence)
            self.events.append(sentence)
        return self._holders

    def connection_lost(self, exc: BaseException | None) -> None:
        was_probing, self.status.connected = self.status.probing, False
        self.status.probing, self._probe = None, None
        if exc is None:  # closed by stop()
            return
        if isinstance(exc, PortRejected):  # not the drone: keep looking (still the same disconnect)
            if self.finder is not None:
                self.finder.reject(was_probing)
            self._mark("rejected", str(exc))
            self.events.append(f"{was_probing} answers but sends no valid frames: not the drone; still looking")
            return
        if was_probing is not None:  # lost again before it sent a frame: the same disconnect goes on
            return
        st = self.status
        st.disconnects += 1
        st.lost_at_s = time.monotonic()
        st.offline.append((self.clock.now_s(), None))
        if self.finder is not None:
            self.finder.mark_lost()
        self._mark("disconnect", f"{self.status.port}: {exc}")
        self.events.append(f"disconnected from {self.status.port}, waiting for it to come back")


def offline_within(offline: list, t0_s: float, t1_s: float, now_s: float) -> float:
    """Seconds without the drone between host times ``t0_s`` and ``t1_s`` (a loss not over yet lasts to ``now_s``)."""
    return sum((max(0.0, min(t1_s, now_s if back is None else back) - max(t0_s, lost)) for lost, back in offline), 0.0)


class SerialSource(Source):
    """A serial port or a replay URL at ``baud``; ``wait``: wait for the port to appear and for valid frames."""

    def __init__(self, url: str, *, baud: int = C.BAUD, wait: bool = False) -> None:
        self.url, self.baud, self.wait = url, baud, wait
        self.path, self.ser = url, None  # the port opened (a glob or auto resolved)
        self.reader = self.proto = None  # the reader thread and its protocol, once chunks() starts them
        self.inbox = Inbox()
        self._closed = threading.Event()  # close() (also before the port appeared: --wait)

    @classmethod
    def from_url(cls, url: str, **settings: Any) -> SerialSource:
        return cls(url, **settings)

    @property
    def replay(self) -> bool:
        return is_replay_url(self.url)

    @property
    def status(self) -> LinkStatus:
        if self.proto is None:
            return LinkStatus(port=self.path, wait=self.wait)
        st = self.proto.status  # the reader thread's: a copy, with the session's side of the link
        dropped, reopen_error = self.inbox.dropped_bytes, self.reader.reopen_error
        return replace(st, offline=list(st.offline), live_dropped_bytes=dropped, reopen_error=reopen_error)

    def open(self, note=print) -> None:
        """The port (waiting for it with ``wait``: ``note(text)`` says so once), or one UserError sentence."""
        self.path, self.ser = open_port(self.url, self.baud, wait=self.wait, note=note, stopped=self._closed.is_set)
        if self.replay:  # a recording: nothing to find again after a loss
            self.finder = None
            self._described = self.ser.describe()
            self._extra = {"replay_of": str(self.ser.path)}
            # an emulator's file (its status frames count instructions); a log (its first line is whole)
            self._extra.update({flag: True for flag in ("emulated", "line_start") if getattr(self.ser, flag)})
        else:
            identity = autodetect.PortIdentity.of(self.path)
            self.finder = autodetect.PortFinder(identity, pattern=self.url if autodetect.is_glob(self.url) else None)
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
        self.proto = RecorderProtocol(record, self.inbox, self.finder, clock)
        self.proto.status.wait, self.proto.status.pace = self.wait, float(getattr(self.ser, "speed", 1.0) or 1.0)
        find = self.finder.find if self.finder is not None else None
        self.reader = SerialReader(self.ser, self.proto, baud=self.ser.baudrate, clock=clock, find_port=find)
        self.reader.start()
        return self._rounds(clock)

    def _rounds(self, clock) -> Iterator[list[Chunk]]:
        reader, proto = self.reader, self.proto
        while True:
            closed = self._closed.is_set()
            if reader.error is not None and not closed:
                raise reader.error  # an OSError: the capture could not be written (the session says where it is)
            got = self.inbox.get_all(0.0 if closed else ROUND_WAIT_S)
            out = [Chunk(NOTE, proto.events.popleft(), 0.0) for _ in range(len(proto.events))]
            out += [Chunk("D", data, t_unix_s - clock.wall0_s, t_unix_s) for data, t_unix_s in got]
            if not closed and getattr(reader.serial, "at_end", False):  # a replay played to its end
                out += [Chunk(NOTE, f"end of {reader.serial.path}", 0.0), Chunk(END, "end of replay", 0.0)]
            yield out
            if closed:
                return

    def write(self, frame: bytes, at_s: float | None = None) -> None:
        if self.reader is None:
            raise UserError("the port is not connected")
        self.reader.write(frame)  # under the lock a reconnection holds

    def close(self) -> None:
        self._closed.set()
        if self.reader is not None:
            self.reader.stop()
        elif self.ser is not None:
            self.ser.close()


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
    return pipeline_health(head, pipe, status)


def serial_summary(status: LinkStatus, pipe, now_s: float) -> dict[str, Any]:
    """The summary fields of a serial port or a replay (``now_s``: the host's Unix time)."""
    h = pipe.health if pipe is not None else LinkHealth()
    streaming_s = 0.0
    if h.first_frame_s is not None:  # the rate's time: connected, with frames
        within = offline_within(status.offline, h.first_frame_s, h.last_frame_s, now_s)
        streaming_s = max(0.0, h.last_frame_s - h.first_frame_s - within)
    p, filter_note = (pipe.mahony if pipe is not None else None), None
    if p is not None and (p.rows_mismatch or p.rows_exact):
        what = f"differs from the firmware on {p.rows_mismatch}" if p.rows_mismatch else f"bit-exact on {p.rows_exact}"
        filter_note = f"ST replica {what} frames with {p.settings.variant}'s filter"
    elif p is not None:
        why = "seeded (no status snapshot)" if pipe.binary else "run (no binary frames: text has no bit-exact inputs)"
        filter_note = f"ST replica not {why}"
    return {
        **pipeline_counts(pipe),
        "streaming_s": streaming_s,
        "bytes_total": status.bytes_total,
        "disconnects": status.disconnects,
        "offline_s": offline_within(status.offline, -math.inf, math.inf, now_s),  # every loss measured
        "lost_for_good": bool(status.offline and status.offline[-1][1] is None),
        "live_dropped_bytes": status.live_dropped_bytes,
        "pace": status.pace,
        "filter_note": filter_note,
    }


@dataclass
class Reply:
    """What the drone answered to one command: its ack and the EVENT status frame after it (None if none came)."""

    command: Command
    ack: AckFrame
    status: StatusFrame | None
    text: str

    @property
    def accepted(self) -> bool:
        return int(self.ack.result) == P.ACK_ACCEPTED


def run_command(port: str, baud: int, command: Command, *, timeout_s: float = 2.0, out: Path | None = None) -> Reply:
    """The drone's reply to ``command`` (UserError: no answer); ``out``: record the exchange to this new capture."""
    try:
        path, ser = open_port(port, baud)
    except UserError as exc:  # the advice to wait goes: no waiting for one command
        message = re.sub(r" \(or use [^)]*\)$", "", getattr(exc, "template", str(exc)))
        if " is busy" in message:
            message += " (if steval live has it, type the command at its prompt instead)"
        raise ParamError(message, *getattr(exc, "params", ())) from None
    capture = None
    try:
        if out is not None:
            capture = open_capture(out, port=path, baud=baud, extra={"source": "steval param/command"})

        def write(frame: bytes) -> None:
            try:
                ser.write(frame)
                ser.flush()
            except (serial.SerialException, OSError) as exc:
                raise UserError(f"cannot write to {path}: {exc}") from None

        channel = CommandChannel(write, capture.write_host if capture is not None else None)
        return _answer(ser, path, channel, command, timeout_s, capture)
    finally:
        if capture is not None:
            capture.close()
        transport.close_quietly(ser)


def _answer(ser, path: str, channel: CommandChannel, command: Command, timeout_s: float, capture) -> Reply:
    sent = channel.send(command)
    decoder = StreamDecoder()
    deadline = time.monotonic() + timeout_s
    ack: AckFrame | None = None
    while time.monotonic() < deadline:
        try:
            data = ser.read(4096)
        except (serial.SerialException, OSError) as exc:
            raise UserError(f"reading {path} failed: {exc}") from None
        if not data:
            continue
        if capture is not None:
            capture.write(data)
        for frame in decoder.feed(data):
            if isinstance(frame, TextFrame):
                frame = ack_of_text(frame.text) or frame
            if ack is None and isinstance(frame, AckFrame) and channel.match(frame) is sent:
                ack = frame
                if int(ack.result) != P.ACK_ACCEPTED:  # a refused command: no status frame follows
                    return Reply(command, ack, None, describe_ack(command, ack))
            elif ack is not None and isinstance(frame, StatusFrame) and int(frame.flags) & P.FLAG_EVENT:
                return Reply(command, ack, frame, describe_ack(command, ack))
    if ack is not None:  # the ack came, the status frame did not (dropped): the ack is the answer
        return Reply(command, ack, None, describe_ack(command, ack))
    if not decoder.stats.bytes_total:  # nothing received
        raise UserError(
            f"no answer from the drone on {path} within {timeout_s:g} s (nothing received: is it on, and "
            "is the adapter's RX wired to PA9 and its TX to PA10 on header P7?)"
        )
    if not decoder.stats.frames_ok:
        raise ParamError(
            f"no answer from the drone on {path} within {timeout_s:g} s (no valid frames either: wrong "
            "{baud}, or not a STEVAL with the steval-link firmware)",
            "baud",
        )
    raise UserError(
        f"the drone on {path} did not acknowledge '{command.describe()}' within {timeout_s:g} s (its "
        "frames arrive: is the adapter's TX wired to PA10 on header P7, and does the firmware have the "
        "two-way link, protocol v2?)"
    )

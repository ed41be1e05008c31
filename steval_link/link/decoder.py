"""Wire-protocol decoder: :class:`StreamDecoder` (incremental, bounded memory) and :func:`decode_bytes` (bulk, fast).

Both implement ``firmware_patch/PROTOCOL.md`` and give the same frames and counters on the same bytes.

Rules (position by position, from the start of the stream):

* ``A5 5A``: a binary frame candidate. Valid (v2 with CRC-32 or v1 with CRC-16, known type, the type's ``LEN``,
  CRC) → consumed and handed to the plausibility gate (:mod:`steval_link.link.plausibility`); otherwise only the
  ``A5`` is discarded. A known header whose CRC fails counts in ``crc_failures``; an unknown type whose CRC matches
  in ``unknown_frames``. Once a v2 frame was accepted, v1 candidates are refused (a damaged v2 stream cannot yield
  a v1 frame that passed only the weaker CRC-16).
* Text mode: a line ending in ``\\n`` (``\\r`` before it dropped), at most 512 bytes, printable UTF-8. A ``$``
  line is accepted wherever it starts when its checksum and fields are right (else ``crc_failures``). A plain line
  has no checksum: it is accepted only at a clean line start (after a frame or line handed out, or a whole printable
  line), so a stream joined mid-line never yields that line's tail. ``line_start=True``: the stream's first byte
  starts a line (a log file).
* Blank lines and the ``\\r`` of ``\\n\\r`` endings at a line start count in ``blank_bytes`` (text, not damage).
* Every other byte not in a handed-out frame or line counts in ``bytes_skipped``.

The decoder waits only while the candidate at its position could still become valid: it holds at most one frame or
line, and the frames do not depend on how the bytes are chunked.

Sequence counters between consecutive binary attitude frames: ``d = (seq - previous seq) mod 2¹⁶``; ``d = 1`` is
normal, ``2 ≤ d < 2¹⁵`` a gap (``seq_gaps``, ``frames_missing`` += d − 1), else a firmware restart (``seq_resets``).
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from steval_link.link import protocol as P
from steval_link.link.frames import (
    FRAME_OF_TYPE,
    AckFrame,
    AttitudeFrame,
    CommandFrame,
    DecoderStats,
    FlightFrame,
    Frame,
    StatusFrame,
    TextFrame,
    TextRecordFrame,
)
from steval_link.link.plausibility import (
    PlausibilityGate,
    attitude_frame_bad,
    attitude_rows_bad,
    attitude_values_ok,
    gate_rows,
    status_values_ok,
)
from steval_link.link.telemetry import Telemetry, TelemetryParts
from steval_link.link.text_series import RecordBlock
from steval_link.link.text_telemetry import TextTelemetryReader, looks_like_text
from steval_link.link.textmode import MAX_LINE_BYTES, decode_line, parse_sentence

#: frame type -> (frame class, its payload's struct layout and field picker, made from ``protocol.PAYLOAD_DTYPE``)
_UNPACK = {t: (FRAME_OF_TYPE[t], *P.payload_layout(d)) for t, d in P.PAYLOAD_DTYPE.items()}

_V1, _V2 = P.VERSION_1, P.VERSION
#: the ``DecoderStats`` counter of each frame class but attitude (whose count goes with the ``seq`` checks)
_COUNTED = (StatusFrame, TextFrame, TextRecordFrame, FlightFrame, AckFrame, CommandFrame)
_COUNTER = dict(zip(_COUNTED, ("status", "text", "text_records", "flight", "ack", "command")))
_HEAD = P.HEADER_SIZE
#: (VT byte) -> payload length of the fixed-size types; text frames (type 3) take 1..255 bytes.
_FIXED_LEN = {P.vt_byte(_V2, t): n for t, n in P.FIXED_PAYLOAD_SIZE.items()}
_FIXED_LEN.update({P.vt_byte(_V1, t): n for t, n in P.FIXED_PAYLOAD_SIZE_V1.items()})
_VT_TEXT = {P.vt_byte(_V1, P.TYPE_TEXT), P.vt_byte(_V2, P.TYPE_TEXT)}
_SYNC0, _SYNC1 = P.SYNC
_NEXT_START = re.compile(b"[" + re.escape(P.SYNC[:1]) + rb"$\n]")
_BAD_PARTIAL = re.compile(rb"[\x00-\x08\x0a-\x0c\x0e-\x1f\x7f]")
_CHECK = P.CHECK


def _hides_sentence(raw: bytes) -> bool:
    """True when a valid ``$`` sentence starts inside the line ``raw`` (then the line is not a plain log line)."""
    j = raw.find(b"$", 1)
    while j >= 0:
        if parse_sentence(raw[j:].rstrip(b"\r")) is not None:
            return True
        j = raw.find(b"$", j + 1)
    return False


def seq_gap_counts(seq: np.ndarray) -> tuple[int, int, int]:
    """``(seq_gaps, frames_missing, seq_resets)`` of consecutive binary attitude ``seq`` values (u16)."""
    s = np.asarray(seq, dtype=np.int64)
    if len(s) < 2:
        return 0, 0, 0
    d = (s[1:] - s[:-1]) % P.SEQ_MODULUS
    gap = (d >= 2) & (d < P.SEQ_MODULUS // 2)
    reset = (d == 0) | (d >= P.SEQ_MODULUS // 2)
    return int(gap.sum()), int((d[gap] - 1).sum()), int(reset.sum())


class StreamDecoder:
    """Incremental decoder: :meth:`feed` chunks, get the frames they complete; :meth:`finish` decides the last one."""

    def __init__(self, *, plausibility: bool = True, line_start: bool = False) -> None:
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._base = 0  # stream offset of _buf[0]
        self._boundary = line_start  # True when _buf[0] starts a line (after a handed-out frame/line or a "\n")
        self._last_seq: int | None = None
        self._v2_seen = False  # a version-2 frame was accepted: version-1 candidates are refused from now on
        self.gate = PlausibilityGate() if plausibility else None
        self._ended_nl = False  # the bytes decoded so far end with "\n"
        self._damaged = False  # bytes were skipped since the text reader last heard
        self._skipping = False  # a skip reached the end of the bytes fed: it goes on to the next possible start
        self.text_reader = TextTelemetryReader()  # plain lines → records of text telemetry and text lines

    @property
    def pending_bytes(self) -> int:
        """Bytes held back because the candidate frame or line at the current position is not complete yet."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Decode ``data`` (the next bytes of the stream); returns the frames completed by it, in stream order."""
        self._buf += data
        self.stats.bytes_total += len(data)
        return self._run(final=False)

    def finish(self) -> list[Frame]:
        """End of stream: the pending bytes decided, frames the plausibility gate still holds dropped."""
        out = self._run(final=True)
        self._read_text(out, "finish")
        if self.gate is not None:
            self.gate.finish()
            self._gate_stats()
        return out

    def _gate_stats(self) -> None:
        self.stats.implausible, self.stats.held_values = self.gate.held_back, self.gate.held_values

    def resume_at(self, offset: int, *, line_start: bool) -> None:
        """Continue at stream byte ``offset`` (the bytes before it decoded elsewhere), with no bytes pending."""
        if self._buf:
            raise ValueError(f"resume_at({offset}) with {len(self._buf)} bytes pending")
        self._base = offset
        self._boundary = line_start
        self._skipping = self._skipping and not line_start

    def text_template(self):
        """The text reader's ``bulk_template`` at a clean line start with nothing pending; else None."""
        return None if self._buf or not self._boundary or self._damaged else self.text_reader.bulk_template()

    def skip_records(self, offset: int, count: int, *, blank_bytes: int = 0, blank_last: bool = False) -> None:
        """``count`` records (and ``blank_bytes`` of blank lines) up to line start ``offset`` were made in bulk."""
        self.resume_at(offset, line_start=True)
        self._ended_nl = True
        self.text_reader.bulk_records(blank_last=blank_last)
        self.stats.text_records += count
        self.stats.frames_ok += count
        self.stats.blank_bytes += blank_bytes

    def _skip(self, buf: bytearray, p: int, n: int, first: int = 1) -> int:
        """Reject the candidate at ``p`` (``first`` 0: go on with a skip cut by the end of the bytes fed before):
        move to the next byte that could start something (``A5``, ``$``, or the byte after a ``\\n``)."""
        m = _NEXT_START.search(buf, p + first)
        q = n if m is None else m.start() + (buf[m.start()] == 0x0A)
        self._skipping = m is None  # the next bytes fed go on with this skip (as if they had come with these)
        self.stats.bytes_skipped += q - p
        self._boundary = False
        self._damaged = True
        return q

    def _run(self, final: bool) -> list[Frame]:
        """Decide every candidate in the buffer that can be decided now; the rest waits for more bytes."""
        buf, p, out = self._buf, 0, []
        n = len(buf)
        while p < n:
            if self._skipping:
                p = self._skip(buf, p, n, 0)
                continue
            c = buf[p]
            if c == 0x0D and self._boundary and (buf[p - 1] == 0x0A if p else self._ended_nl):  # "\n\r" endings
                self.stats.blank_bytes += 1
                p += 1
                continue
            q = self._binary_at(buf, p, n, final, out) if c == _SYNC0 else self._line_at(buf, p, n, final, out)
            if q is None:
                break
            p = q
        if p:
            self._ended_nl = buf[p - 1] == 0x0A
            del buf[:p]
            self._base += p
        return out

    def _binary_at(self, buf: bytearray, p: int, n: int, final: bool, out: list[Frame]) -> int | None:
        """The binary frame candidate at ``p``: the position after it (handed out or skipped), None to wait."""
        if n - p < _HEAD:
            if not final and (n - p < 2 or buf[p + 1] == _SYNC1):
                return None
            return self._skip(buf, p, n)
        vt, ln = buf[p + 2], buf[p + 3]
        ver = vt >> 4
        if buf[p + 1] != _SYNC1 or ver not in _CHECK or (ver == _V1 and self._v2_seen):
            return self._skip(buf, p, n)
        want = _FIXED_LEN.get(vt)
        known = (ln == want) if want is not None else (vt in _VT_TEXT and ln >= 1)
        if not known and (want is not None or vt in _VT_TEXT):
            return self._skip(buf, p, n)  # known type, wrong length
        end = p + _HEAD + ln
        csz, check = _CHECK[ver]
        if end + csz > n:
            return None if not final else self._skip(buf, p, n)
        crc_ok = check(memoryview(buf)[p + 2 : end]) == int.from_bytes(buf[end : end + csz], "little")
        if not (known and crc_ok):
            if known:
                self.stats.crc_failures += 1
            elif crc_ok:
                self.stats.unknown_frames += 1
            return self._skip(buf, p, n)
        self._v2_seen |= ver == _V2
        self._emit(out, _frame_at(buf, p, vt, ln, csz, self._base + p), ver)
        self._boundary = True
        return end + csz

    def _line_at(self, buf: bytearray, p: int, n: int, final: bool, out: list[Frame]) -> int | None:
        """The text line candidate at ``p``: the position after it (handed out or skipped), None to wait."""
        limit = min(n, p + MAX_LINE_BYTES)
        nl = buf.find(b"\n", p, limit)
        if nl < 0:
            # wait while the line can still become valid (no control byte; "\r" only at the end)
            if final or limit - p >= MAX_LINE_BYTES or _BAD_PARTIAL.search(buf, p, limit) is not None:
                return self._skip(buf, p, n)
            return None if buf.find(b"\r", p, limit - 1) < 0 else self._skip(buf, p, n)
        raw, nbytes = bytes(buf[p:nl]), nl + 1 - p
        if not (raw[:-1] if raw[-1:] == b"\r" else raw).strip(b" \t"):
            # a blank line keeps the boundary state: text at a line start, maybe a damaged line's end after damage
            if self._boundary:
                self.stats.blank_bytes += nbytes
                self._read_text(out, "end_block", "blank")
            else:
                self.stats.bytes_skipped += nbytes
            return nl + 1
        text = decode_line(raw)
        dollar = buf[p] == 0x24
        if text is None or (not dollar and _hides_sentence(raw)):  # e.g. a glitch byte before a "$ATT" line
            return self._skip(buf, p, n)
        if dollar:
            frame = parse_sentence(raw.rstrip(b"\r"), offset=self._base + p, nbytes=nbytes)
            if frame is None:
                self.stats.crc_failures += 1
                return self._skip(buf, p, n)
            if isinstance(frame, TextFrame):
                frame.text = text
            self._count(frame)
            out.append(frame)
        elif self._boundary:
            self._read_text(out, "line", text, self._base + p, nbytes)
        else:
            # a whole printable line that may be the tail of a line cut off: skipped, the next one is clean
            self.stats.bytes_skipped += nbytes
            self._read_text(out, "cut_line", text)
        self._boundary = True
        return nl + 1

    def _read_text(self, out: list[Frame], method: str, *args) -> None:
        """One call of the text reader, told first of any damage since its last call; its frames into ``out``."""
        reader = self.text_reader
        if self._damaged:
            self._damaged = False
            self._text(out, reader.end_block("break"))
        self._text(out, getattr(reader, method)(*args))

    def _text(self, out: list[Frame], frames: list) -> None:
        """Frames of the text reader into ``out``; a text line that does not read as text is dropped."""
        for frame in frames:
            if isinstance(frame, TextFrame) and not looks_like_text(frame.text):
                self.stats.text_dropped += 1
                self.stats.bytes_skipped += frame.nbytes
                continue
            self._count(frame)
            out.append(frame)

    def _emit(self, out: list[Frame], frame: Frame, version: int) -> None:
        """A CRC-valid binary frame: through the plausibility gate, then counted and handed out."""
        if version == _V1:
            self.stats.v1_frames += 1
        gate = self.gate
        released = [frame]
        if gate is not None and isinstance(frame, AttitudeFrame):
            # values gate v1 only: a v2 frame with NaN is what the firmware sent (kept, counted in values_bad)
            ok = version == _V2 or attitude_values_ok(frame.acc_mg, frame.gyro_mdps, frame.q_wxyz, frame.thz_rad)
            released = gate.offer(P.TYPE_ATTITUDE, frame.seq, frame.t_us, ok, frame)
        elif gate is not None and isinstance(frame, StatusFrame):
            ok = version == _V2 or status_values_ok(
                frame.q_wxyz, frame.int_xyz, frame.kp_ground, frame.kp_flight, frame.ki, frame.dt_s
            )
            released = gate.offer(P.TYPE_STATUS, frame.step, frame.t_us, ok, frame)
        for f in released:
            self._count(f)
            out.append(f)
        if gate is not None:
            self._gate_stats()

    def _count(self, frame: Frame) -> None:
        stats = self.stats
        stats.frames_ok += 1
        if isinstance(frame, AttitudeFrame):
            stats.attitude += 1
            if attitude_frame_bad(frame):
                stats.values_bad += 1
            if frame.exact and self._last_seq is not None:
                d = (frame.seq - self._last_seq) % P.SEQ_MODULUS
                if 2 <= d < P.SEQ_MODULUS // 2:
                    stats.seq_gaps += 1
                    stats.frames_missing += d - 1
                elif d != 1:
                    stats.seq_resets += 1
            if frame.exact:
                self._last_seq = frame.seq
        else:
            name = _COUNTER[type(frame)]
            setattr(stats, name, getattr(stats, name) + 1)


def _frame_at(buf, p: int, vt: int, ln: int, crc_size: int, offset: int) -> Frame:
    """The binary frame whose sync is at ``buf[p]`` (already validated); ``offset`` its stream offset."""
    size = _HEAD + ln + crc_size
    fixed = _UNPACK.get(vt & 0x0F)
    if fixed is not None:
        cls, layout, pick = fixed
        return cls(*pick(layout.unpack_from(buf, p + _HEAD)), offset=offset, nbytes=size)
    return TextFrame(bytes(buf[p + _HEAD : p + _HEAD + ln]).decode("utf-8", "replace"), offset, size)


#: The bulk text path: bytes fed to the stream decoder between tries, and the first window of lines it reads.
_TEXT_PROBE = 2048
_TEXT_WINDOW = 4096
_TEXT_WINDOW_MAX = 1 << 20


def _feed_region(sd: StreamDecoder, data: bytes, p: int, end: int, blocks: list[RecordBlock]) -> list[Frame]:
    """``data[p:end]`` through ``sd``; runs of lines of a learned one-line record shape go into ``blocks`` as arrays."""
    out: list[Frame] = []
    window = _TEXT_WINDOW
    while p < end:
        tpl = sd.text_template()
        if tpl is None:
            stop = data.find(b"\n", min(p + _TEXT_PROBE, end - 1), end) + 1 or end
            out += sd.feed(data[p:stop])
            p = stop
            continue
        win_end = data.rfind(b"\n", p, min(p + window, end)) + 1
        valid = tpl.valid_blanks if sd.text_reader.idle else tpl.valid
        run_end = valid.match(data, p, win_end).end() if win_end else p
        if run_end > p:
            ends = np.flatnonzero(np.frombuffer(data, np.uint8, run_end - p, p) == 0x0A) + (p + 1)
            starts = np.concatenate([[p], ends[:-1]]).astype(np.int64)
            size = ends - starts
            blank = (size == 1) | ((size == 2) & (np.frombuffer(data, np.uint8, run_end - p, p)[starts - p] == 0x0D))
            count = int(len(ends) - blank.sum())
        if run_end == p or count == 0 or int(size.max()) > MAX_LINE_BYTES:
            # a line that does not fit, blank lines only, or a line too long: the stream decoder decides it
            stop = data.find(b"\n", p, end) + 1 or end
            out += sd.feed(data[p:stop])
            p = stop
            window = _TEXT_WINDOW
            continue
        values = tpl.values(data[p:run_end], count)
        blocks.append(RecordBlock(tpl.names, tpl.units, tpl.kind, values, starts[~blank], size[~blank]))
        sd.skip_records(run_end, count, blank_bytes=int(size[blank].sum()), blank_last=bool(blank[-1]))
        window = min(window * 2, _TEXT_WINDOW_MAX) if run_end == win_end else _TEXT_WINDOW
        p = run_end
    return out


_LEN_LUT = np.full(256, -1, np.int64)  # VT -> payload length of a fixed-size type; -2 text; -1 unknown
for _vt, _n in _FIXED_LEN.items():
    _LEN_LUT[_vt] = _n
for _vt in _VT_TEXT:
    _LEN_LUT[_vt] = -2


def _valid_binary_starts(arr: np.ndarray, data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Offsets, sizes and VT bytes of the valid binary frames (overlaps too; no v1 after v2), the first v2's offset."""
    n = len(arr)
    idx = np.flatnonzero((arr[:-1] == _SYNC0) & (arr[1:] == _SYNC1)) if n >= 2 else np.zeros(0, np.int64)
    idx = idx[idx + _HEAD <= n]
    vt = arr[idx + 2]
    ln = arr[idx + 3].astype(np.int64)
    want = _LEN_LUT[vt]
    ok = (want == ln) | ((want == -2) & (ln >= 1))
    ver = vt >> 4
    csz = np.where(ver == _V2, P.CRC_SIZE, P.CRC_SIZE_V1)
    size = ln + _HEAD + csz
    ok &= idx + size <= n
    idx, size, vt, ver = idx[ok], size[ok], vt[ok], ver[ok]
    end = idx + size
    mv = memoryview(data)
    good = np.zeros(len(idx), bool)
    for v, (csz, check) in _CHECK.items():
        sel = np.flatnonzero(ver == v)
        e = end[sel]
        stored = np.zeros(len(sel), np.int64)
        for k in range(csz):
            stored |= arr[e - csz + k].astype(np.int64) << (8 * k)
        crc = [check(mv[a:b]) for a, b in zip((idx[sel] + 2).tolist(), (e - csz).tolist())]
        good[sel] = np.array(crc, np.int64) == stored
    idx, size, vt, ver = idx[good], size[good], vt[good], ver[good]
    v2 = np.flatnonzero(ver == _V2)
    first_v2 = float(idx[v2[0]]) if len(v2) else float("inf")
    keep = (ver == _V2) | (idx < first_v2)
    idx, size, vt = idx[keep], size[keep], vt[keep]
    return idx.astype(np.int64), size, vt, first_v2


def decode_bytes(
    data: bytes | bytearray | memoryview,
    chunk_times: tuple[np.ndarray, np.ndarray] | None = None,
    *,
    baud: int | None = None,
    source: dict | None = None,
    events: list | None = None,
    plausibility: bool = True,
    sent_commands: np.ndarray | None = None,
    line_start: bool = False,
) -> Telemetry:
    """A whole byte stream as :class:`~steval_link.link.telemetry.Telemetry`, with :class:`StreamDecoder`'s frames
    and counters (runs of back-to-back binary frames decoded with numpy, the rest by one :class:`StreamDecoder`).

    ``chunk_times``: ``(chunk_offsets, t_host_s)`` of the received chunks (None: NaN host times).
    ``sent_commands``: timed ``COMMAND_ROW_DTYPE`` rows of a capture's H chunks."""
    data = bytes(data)
    arr = np.frombuffer(data, dtype=np.uint8)
    starts, sizes, vts, first_v2 = _valid_binary_starts(arr, data)
    parts = TelemetryParts()
    fast, sd, slow_frames = _decode_regions(data, starts, sizes, first_v2, line_start, parts.record_blocks)
    _add_fast_frames(parts, arr, data, starts[fast], vts[fast], sizes[fast])
    for f in slow_frames:
        parts.add_frame(f)
    gate = PlausibilityGate()
    if plausibility:
        att, sta = parts.attitude_records(), parts.status_records()
        keep_a, keep_s = gate_rows(att, sta, gate)
        parts.att_blocks, parts.sta_blocks = [att[keep_a]], [sta[keep_s]]
        gate.finish()
    stats = _bulk_stats(parts, sd.stats, gate, len(data), int(np.count_nonzero((vts[fast] >> 4) == _V1)))
    parts.sent_commands = sent_commands
    return Telemetry.from_parts(parts, stats, chunk_times=chunk_times, baud=baud, source=source, events=events)


def _decode_regions(data: bytes, starts, sizes, first_v2: float, line_start: bool, blocks: list[RecordBlock]):
    """(indices of the frames in runs left to numpy, the :class:`StreamDecoder` of the rest, its frames)."""
    n, count = len(data), len(starts)
    nxt = starts + sizes
    breaks = np.flatnonzero(nxt[:-1] != starts[1:]) if count > 1 else np.zeros(0, np.int64)  # last frame of a run
    fast, frames = [], []  # index arrays of the runs left to numpy; the stream decoder's frames
    sd = StreamDecoder(plausibility=False, line_start=line_start)
    p, last_fast = 0, False
    while p < n:
        k = int(np.searchsorted(starts, p))
        if not sd.pending_bytes and k < count and starts[k] == p:
            b = int(np.searchsorted(breaks, k))
            j = int(breaks[b]) if b < len(breaks) else count - 1
            fast.append(np.arange(k, j + 1))
            p = int(nxt[j])
            last_fast = True
            continue
        if not sd.pending_bytes:
            sd.resume_at(p, line_start=(last_fast or sd._boundary) if p else line_start)
        if first_v2 < p:  # a version-2 frame was accepted before: version-1 candidates are refused
            sd._v2_seen = True
        last_fast = False
        end = int(nxt[k]) if k < count else n
        frames.extend(_feed_region(sd, data, p, end, blocks))
        p = end
    frames.extend(sd.finish())
    return (np.concatenate(fast) if fast else np.zeros(0, np.int64)), sd, frames


def _add_fast_frames(parts: TelemetryParts, arr: np.ndarray, data: bytes, starts, vts, sizes) -> None:
    """The frames of the runs into ``parts``: attitude and status as arrays, the others one by one."""
    types = vts & 0x0F
    for kind in (P.TYPE_ATTITUDE, P.TYPE_STATUS):
        sel = types == kind
        parts.add_payloads(kind, arr, starts[sel] + _HEAD, starts[sel], sizes[sel])
    other = (types != P.TYPE_ATTITUDE) & (types != P.TYPE_STATUS)
    for s, vt, size in zip(starts[other].tolist(), vts[other].tolist(), sizes[other].tolist()):
        ln = data[s + 3]
        parts.add_frame(_frame_at(data, s, vt, ln, size - _HEAD - ln, s))


def _bulk_stats(parts: TelemetryParts, st: DecoderStats, gate: PlausibilityGate, n: int, v1_fast: int):
    """The counters of the whole stream: the frames in ``parts`` and the stream decoder's ``st`` of the rest."""
    att, sta = parts.attitude_records(), parts.status_records()  # in stream order, kept so for from_parts
    exact = att["exact"]
    kinds = [_COUNTER[type(f)] for f in parts.others]
    stats = replace(  # the damage counters are the stream decoder's; the frames are counted here
        st,
        attitude=len(att),
        status=len(sta),
        text=len(parts.texts),
        **{name: kinds.count(name) for name in ("flight", "ack", "command")},
        text_records=len(parts.records) + sum(len(b.offset) for b in parts.record_blocks),
        bytes_total=n,
        v1_frames=st.v1_frames + v1_fast,
        implausible=gate.held_back,
        held_values=gate.held_values,
    )
    bad = attitude_rows_bad(
        exact, *(att[k] for k in ("acc_mg", "gyro_mdps", "q_wxyz", "thz_rad", "thx_rad", "thy_rad"))
    )
    stats.values_bad = int(np.count_nonzero(bad))
    stats.frames_ok = stats.attitude + sum(getattr(stats, name) for name in _COUNTER.values())
    stats.seq_gaps, stats.frames_missing, stats.seq_resets = seq_gap_counts(att["seq"][exact])
    return stats

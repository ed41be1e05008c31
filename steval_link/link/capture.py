"""Capture files (``.stv``): the raw serial bytes exactly as received, with host receive times, plus events.

Format (``firmware_patch/CAPTURE_FORMAT.md``): an 8-byte magic, a JSON header, then self-checking chunks (CRC-32),
so a file cut anywhere reads back up to its last complete chunk. Raw bytes are the source of truth: a decoder fix
re-decodes old captures.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import struct
import threading
import time
import warnings
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from steval_link import __version__
from steval_link.errors import ParamError, UserError

#: First 8 bytes of every capture file (PNG-style: catches text-mode transfers and truncation of the magic).
MAGIC = b"\x89STV\r\n\x1a\n"
FORMAT_VERSION = 2
CHUNK_DATA = ord("D")
CHUNK_EVENT = ord("E")
CHUNK_BLE = ord("B")
CHUNK_HOST = ord("H")
CHUNK_TRUTH = ord("T")
CHUNK_SYMBOLS = ord("S")
#: the chunk types known: D, E, H go to the bytes, events, ``Capture.host``; others (and a newer writer's) as they are
CHUNK_TYPES = (CHUNK_DATA, CHUNK_EVENT, CHUNK_BLE, CHUNK_HOST, CHUNK_TRUTH, CHUNK_SYMBOLS)
#: one row of a truth chunk T (the ground truth an emulated run was fed, per AHRS step; CAPTURE_FORMAT.md), packed
TRUTH_DTYPE = np.dtype([("step", "<u4"), ("t_s", "<f8"), ("q_wxyz", "<f8", (4,)), ("movement", "u1")])
TRUTH_ROWS_PER_CHUNK = (1 << 20) // TRUTH_DTYPE.itemsize
#: one row of a symbol chunk S (an AHRS step's inputs and outputs the emulator read from the firmware's globals),
#: packed. ``read``: bit 0 inputs, 1 q, 2 Euler angles.
SYMBOL_DTYPE = np.dtype(
    [
        ("step", "<u4"),
        ("t_s", "<f8"),
        ("acc_mg", "<f4", (3,)),
        ("gyro_mdps", "<f4", (3,)),
        ("thr", "<i2"),
        ("q_wxyz", "<f4", (4,)),
        ("euler_rad", "<f4", (3,)),
        ("read", "u1"),
    ]
)
_HEADER_LEN = struct.Struct("<I")
_CHUNK_HEAD = struct.Struct("<BId")  # type, payload length, t_host_s
_CRC = struct.Struct("<I")
_CHUNK_TYPE = re.compile(b"[" + bytes(sorted(CHUNK_TYPES)) + b"]")
#: Largest chunk payload the reader accepts (the writer splits larger writes).
MAX_CHUNK = 1 << 20
MAX_HEADER = 1 << 20
#: Longest time between two fsyncs while data is pending, s.
SYNC_INTERVAL_S = 1.0


class CaptureTruncatedWarning(UserWarning):
    """The capture ends in an incomplete or damaged chunk (recording cut short); data before it is intact."""


@dataclass(frozen=True, slots=True)
class CaptureEvent:
    """A marked event (``kind`` e.g. "disconnect") at ``t_host_s`` (s since capture start), stream byte ``offset``."""

    t_host_s: float
    kind: str
    text: str
    offset: int


@dataclass(frozen=True, slots=True)
class HostChunk:
    """Bytes the host sent to the drone at host time ``t_host_s``, after ``offset`` received bytes."""

    t_host_s: float
    data: bytes
    offset: int


@dataclass
class Capture:
    """A capture read back: its bytes; chunk i starts at ``chunk_offsets[i]``, came at ``chunk_times_s[i]`` s."""

    path: Path
    header: dict[str, Any]
    data: bytes
    chunk_offsets: np.ndarray
    chunk_times_s: np.ndarray
    events: list[CaptureEvent]
    truncated: bool = False
    warning: str | None = None
    #: chunk type → [(t_host_s, payload)] of the chunks other than D, E and H (e.g. B: one BLE notification each)
    chunks: dict[int, list[tuple[float, bytes]]] = field(default_factory=dict)
    #: what the host sent to the drone (chunk type H), in file order
    host: list[HostChunk] = field(default_factory=list)


def _chunk(kind: int, payload: bytes, t_host_s: float) -> bytes:
    head = _CHUNK_HEAD.pack(kind, len(payload), t_host_s)
    return head + payload + _CRC.pack(zlib.crc32(payload, zlib.crc32(head)))


def _file_header(header: dict[str, Any]) -> bytes:
    head = json.dumps(header, sort_keys=True).encode("utf-8")
    return MAGIC + _HEADER_LEN.pack(len(head)) + head + _CRC.pack(zlib.crc32(head))


def capture_header(port: str, baud: int, start_unix_s: float, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The JSON header of a capture (CAPTURE_FORMAT.md): where and when it was recorded, by which tool version."""
    return {
        "format": "steval-capture",
        "format_version": FORMAT_VERSION,
        "port": port,
        "baud": int(baud),
        "start_time_utc": datetime.fromtimestamp(start_unix_s, timezone.utc).isoformat(timespec="microseconds"),
        "start_time_unix_s": start_unix_s,
        "tool_version": __version__,
        "extra": dict(extra or {}),
    }


def encode_capture(
    header: dict[str, Any], chunks: Iterable[tuple[bytes, float]], typed: Iterable[tuple[int, bytes, float]] = ()
) -> bytes:
    """A whole ``.stv`` file: ``header``, ``(bytes, t_host_s)`` chunks, then ``(type, payload, t_host_s)`` ones."""
    parts = [_file_header(header)]
    parts += [_chunk(CHUNK_DATA, piece, float(t_host_s)) for data, t_host_s in chunks for piece in _pieces(data)]
    parts += [_chunk(_known_kind(kind), bytes(payload), float(t_host_s)) for kind, payload, t_host_s in typed]
    return b"".join(parts)


def _pieces(data: bytes | bytearray | memoryview) -> list[bytes]:
    """``data`` in pieces of at most :data:`MAX_CHUNK` bytes."""
    data = bytes(data)
    return [data[i : i + MAX_CHUNK] for i in range(0, len(data), MAX_CHUNK)]


@dataclass(frozen=True)
class CaptureTruth:
    """Truth chunks T, per AHRS step: ``step``, ``t_s`` (the step's middle input tick, emulated s since power-up),
    ``q_wxyz`` (M, 4) body → earth (NaN: none), ``movement`` (the step counts for the metric)."""

    step: np.ndarray
    t_s: np.ndarray
    q_wxyz: np.ndarray
    movement: np.ndarray

    def __len__(self) -> int:
        return int(self.step.shape[0])


def capture_truth(chunks: dict[int, list[tuple[float, bytes]]]) -> CaptureTruth | None:
    """The truth rows of a capture's T chunks (``Capture.chunks``) in file order, or None when it has none."""
    rows = _chunk_rows(chunks, CHUNK_TRUTH, TRUTH_DTYPE)
    if rows is None:
        return None
    return CaptureTruth(rows["step"].astype(np.int64), rows["t_s"].copy(), rows["q_wxyz"].copy(), rows["movement"] != 0)


def capture_symbol_rows(chunks: dict[int, list[tuple[float, bytes]]]) -> np.ndarray | None:
    """The rows of a capture's symbol chunks S (``SYMBOL_DTYPE``, file order), or None when it has none."""
    return _chunk_rows(chunks, CHUNK_SYMBOLS, SYMBOL_DTYPE)


def _chunk_rows(chunks: dict[int, list[tuple[float, bytes]]], kind: int, dtype: np.dtype) -> np.ndarray | None:
    """The ``dtype`` rows of the chunks of type ``kind`` in file order (whole rows), or None when there are none."""
    size = dtype.itemsize
    parts = [np.frombuffer(p[: len(p) - len(p) % size], dtype=dtype) for _, p in chunks.get(kind, [])]
    return np.concatenate(parts) if parts else None


def _known_kind(kind: int) -> int:
    if kind not in CHUNK_TYPES or kind in (CHUNK_DATA, CHUNK_EVENT) or not 0 <= kind < 256:
        raise ValueError(f"not a typed chunk type: {kind!r}")
    return kind


class CaptureWriter:
    """Append-only ``.stv`` writer and context manager. Every chunk goes to the OS at once (``kill -9`` loses
    nothing); a thread ``fsync``\\s every :data:`SYNC_INTERVAL_S`. ``t_host_s``: s since the capture started
    (default: now). Never overwrites; ``discard_empty``: a capture without bytes is deleted on :meth:`close`."""

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        port: str,
        baud: int,
        extra: dict[str, Any] | None = None,
        sync_interval_s: float = SYNC_INTERVAL_S,
        discard_empty: bool = False,
    ) -> None:
        self.path = Path(path)
        self._t0 = time.monotonic()
        self.header: dict[str, Any] = capture_header(port, baud, time.time(), extra)
        self._file = open(self.path, "xb", buffering=0)
        st = os.fstat(self._file.fileno())
        self._identity = (st.st_dev, st.st_ino)
        self._lock = threading.Lock()
        #: why the file can take no more (disk full, removed, replaced): an OSError whose text is one sentence
        self.failure: OSError | None = None
        self._dirty = self._closed = False
        self._discard_empty = bool(discard_empty)
        self.discarded = False  #: True once close() deleted a capture without serial bytes (discard_empty)
        self.bytes_written = 0  #: raw serial bytes stored so far
        self.chunks_written = 0  #: typed chunks (e.g. BLE notifications) stored so far
        try:
            self._write_all(_file_header(self.header))
            self._sync()
        except OSError:  # a start on a full disk: nothing half-made is left
            self._file.close()
            self.path.unlink(missing_ok=True)
            raise
        self._stop = threading.Event()
        self._interval = float(sync_interval_s)
        self._thread = threading.Thread(target=self._sync_loop, name="stv-fsync", daemon=True)
        self._thread.start()

    def write(self, data: bytes | bytearray | memoryview, t_host_s: float | None = None) -> None:
        """Store one chunk of received bytes (``t_host_s``: when it was received, s since capture start)."""
        self._write_stream(CHUNK_DATA, data, t_host_s)

    def write_host(self, data: bytes | bytearray | memoryview, t_host_s: float | None = None) -> None:
        """Store bytes the host sent to the drone (``t_host_s``: when they were sent, s since capture start)."""
        self._write_stream(CHUNK_HOST, data, t_host_s)

    def _write_stream(self, kind: int, data: bytes | bytearray | memoryview, t_host_s: float | None) -> None:
        """Bytes of one stream (D received, H sent) as chunks of at most MAX_CHUNK bytes."""
        if data:
            self._append(kind, _pieces(data), t_host_s)

    def _append(self, kind: int, payloads: list, t_host_s: float | None) -> None:
        """Chunks of type ``kind`` at ``t_host_s`` (None: now), under the lock (so an event's offset is never stale)."""
        t = time.monotonic() - self._t0 if t_host_s is None else float(t_host_s)
        with self._lock:
            if self._closed:
                raise ValueError("write to a closed CaptureWriter")
            if self.failure is not None:
                raise self.failure
            for payload in payloads:
                if kind == CHUNK_EVENT:
                    payload = json.dumps({**payload, "offset": self.bytes_written}).encode()
                self._write_all(_chunk(kind, payload, t))
                self.bytes_written += len(payload) if kind == CHUNK_DATA else 0
            self.chunks_written += kind not in (CHUNK_DATA, CHUNK_HOST, CHUNK_EVENT)
            self._dirty = True

    def write_chunk(self, kind: int, payload: bytes | bytearray | memoryview, t_host_s: float | None = None) -> None:
        """Store one typed chunk (not D or E; e.g. :data:`CHUNK_BLE`: ``char id + bytes``) received at ``t_host_s``."""
        kind = _known_kind(kind)
        payload = bytes(payload)
        if len(payload) > MAX_CHUNK:
            raise ValueError(f"typed chunk of {len(payload)} bytes (at most {MAX_CHUNK})")
        self._append(kind, [payload], t_host_s)

    def write_truth(self, step, t_s, q_wxyz, movement, t_host_s: float | None = None) -> None:
        """Store ground-truth rows (see :class:`CaptureTruth`) as T chunks of at most :data:`TRUTH_ROWS_PER_CHUNK`."""
        rows = np.zeros(np.size(step), dtype=TRUTH_DTYPE)
        rows["step"], rows["t_s"], rows["q_wxyz"] = np.ravel(step), np.ravel(t_s), np.reshape(q_wxyz, (-1, 4))
        rows["movement"] = np.asarray(movement, dtype=bool).reshape(-1)
        for i in range(0, len(rows), TRUTH_ROWS_PER_CHUNK):
            self.write_chunk(CHUNK_TRUTH, rows[i : i + TRUTH_ROWS_PER_CHUNK].tobytes(), t_host_s)

    def mark_event(self, kind: str, text: str = "", t_host_s: float | None = None) -> None:
        """Store an event (e.g. kind "disconnect" / "reconnect") at the current position of the byte stream."""
        self._append(CHUNK_EVENT, [{"kind": str(kind), "text": str(text)}], t_host_s)

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if self._closed:
            return
        self._stop.set()
        self._thread.join()
        with self._lock:
            with contextlib.suppress(OSError):  # kept in ``failure`` for the caller; the file is closed all the same
                if self.failure is None:
                    self._sync()
            self._closed = True
            try:
                self._file.close()
            except OSError as exc:
                self.failure = self.failure or _failed(self.path, exc)
            if self._discard_empty and self.bytes_written == 0 and self.chunks_written == 0:
                try:
                    if output_gone(self.path, self._identity) is not None:  # not ours any more: left alone
                        raise FileNotFoundError(self.path)
                    self.path.unlink()
                    self.discarded = True
                except OSError:  # e.g. removed meanwhile: nothing left behind either way
                    self.discarded = not self.path.exists()

    def discard(self) -> None:
        """Close and delete the file (a session that failed to start leaves nothing half-made behind)."""
        self.close()
        with contextlib.suppress(OSError):
            if output_gone(self.path, self._identity) is None:  # only our own file, never one that replaced it
                self.path.unlink()
        self.discarded = True

    def __enter__(self) -> CaptureWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _write_all(self, b: bytes) -> None:
        view = memoryview(b)
        try:
            while view:
                n = self._file.write(view)
                view = view[n:]
        except OSError as exc:
            self.failure = self.failure or _failed(self.path, exc)
            raise self.failure from None

    def _sync(self) -> None:
        try:
            os.fsync(self._file.fileno())
        except OSError as exc:
            self.failure = self.failure or _failed(self.path, exc)
            raise self.failure from None
        self._dirty = False

    def check_present(self) -> OSError | None:
        """None while the file is still where it was written, else the failure (also raised by the next write)."""
        if self.failure is None and not self._closed:
            gone = output_gone(self.path, self._identity)
            if gone is not None:
                self.failure = OutputLostError(f"{self.path} {gone}")
        return self.failure

    def _sync_loop(self) -> None:
        # fsync outside the lock: a slow disk must never hold up write(); close() joins this thread first
        while not self._stop.wait(self._interval):
            with self._lock:
                if self._closed or self.check_present() is not None or not self._dirty:
                    continue
                self._dirty = False
            try:
                os.fsync(self._file.fileno())
            except OSError as exc:  # the next write raises it
                self.failure = self.failure or _failed(self.path, exc)


class OutputLostError(OSError):
    """An output file that can take no more: its text is one sentence naming the file and why."""

    def __init__(self, text: str, errno_: int = 0) -> None:
        super().__init__(errno_, text)
        self.text = text

    def __str__(self) -> str:
        return self.text


def _failed(path: Path, exc: OSError) -> OSError:
    """``exc`` as an :class:`OutputLostError` naming ``path`` (disk full, I/O error)."""
    if isinstance(exc, OutputLostError):
        return exc
    why = exc.strerror.rstrip(".").lower() if exc.strerror else str(exc)
    return OutputLostError(f"{path} cannot be written ({why})", exc.errno or 0)


def output_gone(path: str | os.PathLike, identity: tuple[int, int]) -> str | None:
    """Why the file open with ``identity`` (``st_dev``, ``st_ino``) is gone from ``path``, in a few words, or None."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "was deleted" if path.parent.is_dir() else "was deleted with its folder"
    except OSError as exc:
        return f"cannot be reached ({exc.strerror or exc})"
    return None if (st.st_dev, st.st_ino) == identity else "was replaced by another file"


def default_capture_path(directory: str | os.PathLike = "recordings", now: datetime | None = None) -> Path:
    """``recordings/steval-YYYYmmddTHHMMSSZ.stv`` (UTC); a ``-2``, ``-3``... suffix keeps it unique."""
    now = now or datetime.now(timezone.utc)
    stem = "steval-" + now.strftime("%Y%m%dT%H%M%SZ")
    path = Path(directory) / f"{stem}.stv"
    k = 2
    while path.exists():
        path = Path(directory) / f"{stem}-{k}.stv"
        k += 1
    return path


def resolve_capture_out(out: str | os.PathLike | None) -> Path | None:
    """Where a capture ``out`` goes (a directory: a new file in it; never an existing file), else a ParamError."""
    if out is None:
        return None
    path = Path(out).expanduser()
    if path.is_dir():
        return default_capture_path(path)
    if str(out).endswith(("/", os.sep)):
        raise ParamError(f"{{out}} {out}: directory {path} does not exist (create it first)", "out")
    if path.exists():
        raise ParamError(f"{{out}} {path} already exists; choose another name (captures are never overwritten)", "out")
    parent = path.parent
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise ParamError(
            f"{{out}} {path}: directory {parent} {what} (create it first, or give an existing "
            "directory to write a capture inside it)",
            "out",
        )
    return path


def read_file_bytes(path: Path) -> bytes:
    """The whole file ``path``; a UserError when it is missing, a directory, a device or unreadable."""
    if not path.exists():
        raise UserError(f"{path}: no such file.")
    if path.is_dir():
        raise UserError(f"{path} is a directory, not a capture file.")
    if not path.is_file():  # a device or a pipe: it may never end (record a port with steval record)
        raise UserError(f"{path} is not a regular file (a device or a pipe); record a port with steval record.")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise UserError(f"cannot read {path}: {exc.strerror or exc}.") from None


def read_capture(path: str | os.PathLike, *, data: bytes | None = None) -> Capture:
    """Read a ``.stv`` file. A file cut short reads up to its last complete chunk; a damaged chunk is skipped (a
    "damaged" event marks the spot). Either way ``truncated`` is set, ``warning`` says where, and a
    :class:`CaptureTruncatedWarning` is issued. UserError when the file is missing, unreadable or not a capture."""
    path = Path(path)
    raw = read_file_bytes(path) if data is None else data
    header, pos = _read_header(path, raw)
    body = _read_chunks(raw, pos)
    problems = ([_damage_summary(body.damaged)] if body.damaged else []) + ([body.cut] if body.cut else [])
    warning = f"{path}: " + "; ".join(problems) + "." if problems else None
    if warning is not None:
        warnings.warn(warning, CaptureTruncatedWarning, stacklevel=2)
    data, offsets, times = b"".join(body.pieces), np.asarray(body.offsets, np.int64), np.asarray(body.times, np.float64)
    return Capture(path, header, data, offsets, times, body.events, warning is not None, warning, body.typed, body.host)


def _read_header(path: Path, raw: bytes) -> tuple[dict, int]:
    """The capture's JSON header and the file position after it; a :class:`UserError` when there is none."""
    truncated = UserError(f"{path}: {len(raw)} bytes, capture truncated in its header: no frames.")
    if not raw.startswith(MAGIC):
        if raw and MAGIC.startswith(raw):
            raise truncated
        raise UserError(f"{path} is not a steval capture (.stv) file.")
    pos = len(MAGIC)
    hlen = _HEADER_LEN.unpack_from(raw, pos)[0] if len(raw) >= pos + 4 else None
    if hlen is None or (hlen <= MAX_HEADER and pos + 4 + hlen + 4 > len(raw)):
        raise truncated
    try:
        head = raw[pos + 4 : pos + 4 + hlen]
        if hlen > MAX_HEADER or zlib.crc32(head) != _CRC.unpack_from(raw, pos + 4 + hlen)[0]:
            raise ValueError
        header = json.loads(head.decode("utf-8"))
        if not isinstance(header, dict):
            raise ValueError
    except (ValueError, UnicodeDecodeError):
        raise UserError(f"{path}: {len(raw)} bytes, capture header damaged: no frames.") from None
    if int(header.get("format_version", 0)) > FORMAT_VERSION:
        raise UserError(
            f"{path} uses capture format {header.get('format_version')}; this steval-link reads up to "
            f"{FORMAT_VERSION} (please upgrade)."
        )
    return header, pos + 4 + hlen + 4


def _chunk_at(
    raw: bytes, mv: memoryview, p: int, size=_CHUNK_HEAD.size, head=_CHUNK_HEAD.unpack_from, crc=_CRC.unpack_from
) -> tuple[int, int, float, int] | str:
    """(kind, length, t, end) of a valid chunk at file position ``p``, or why there is none."""
    if p + size > len(raw):
        return "incomplete chunk header"
    kind, length, t = head(raw, p)
    end = p + size + length
    if length > MAX_CHUNK:  # an unknown type with a good CRC is a newer writer's chunk: kept, not damage
        return "damaged chunk header"
    if end + 4 > len(raw):
        return "incomplete chunk"
    if zlib.crc32(mv[p:end]) != crc(raw, end)[0]:
        return "chunk CRC mismatch"
    return kind, length, t, end


def _next_chunk(raw: bytes, mv: memoryview, p: int) -> int | None:
    """File position of the first valid chunk after ``p``, None when there is none."""
    for m in _CHUNK_TYPE.finditer(raw, p + 1):
        if not isinstance(_chunk_at(raw, mv, m.start()), str):
            return m.start()
    return None


@dataclass
class _Chunks:
    """A capture's chunks: serial bytes, the other chunks, damaged stretches skipped, why the file ended early."""

    pieces: list[memoryview] = field(default_factory=list)
    offsets: list[int] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    events: list[CaptureEvent] = field(default_factory=list)
    typed: dict[int, list[tuple[float, bytes]]] = field(default_factory=dict)
    host: list[HostChunk] = field(default_factory=list)
    damaged: list[tuple[int, int, str]] = field(default_factory=list)  # (file byte, length, why) of each stretch
    cut: str | None = None


def _read_chunks(raw: bytes, pos: int) -> _Chunks:
    """Every chunk from file position ``pos``; damage loses only itself, unless no valid chunk follows."""
    mv, n, out = memoryview(raw), len(raw), _Chunks()
    offsets, times, pieces, chunk_at, head = out.offsets, out.times, out.pieces, _chunk_at, _CHUNK_HEAD.size
    total = 0
    while pos < n:
        found = chunk_at(raw, mv, pos)
        if isinstance(found, str):
            resume = _next_chunk(raw, mv, pos)
            if resume is None:
                out.cut = (
                    f"capture cut short or damaged at file byte {pos} ({found}); read {total} bytes of serial "
                    f"data up to the last complete chunk, {n - pos} trailing bytes ignored"
                )
                break
            out.damaged.append((pos, resume - pos, found))
            t = times[-1] if times else 0.0
            out.events.append(CaptureEvent(t, "damaged", f"{resume - pos} capture bytes unreadable here", total))
            pos = resume
            continue
        kind, length, t, end = found
        payload = mv[pos + head : end]
        if kind == CHUNK_DATA:
            offsets.append(total)
            times.append(t)
            pieces.append(payload)
            total += length
        elif kind == CHUNK_HOST:
            out.host.append(HostChunk(t, bytes(payload), total))
        elif kind == CHUNK_EVENT:
            out.events.append(_event(t, payload, total))
        else:
            out.typed.setdefault(kind, []).append((t, bytes(payload)))
        pos = end + 4
    return out


def _event(t: float, payload: memoryview, offset: int) -> CaptureEvent:
    """The event of an E chunk's JSON payload (an "unreadable-event" when it does not read)."""
    try:
        ev = json.loads(bytes(payload).decode("utf-8"))
        return CaptureEvent(t, str(ev.get("kind", "")), str(ev.get("text", "")), offset)
    except (ValueError, UnicodeDecodeError, AttributeError):
        return CaptureEvent(t, "unreadable-event", "", offset)


#: Damaged stretches a warning lists by position; the rest are counted.
DAMAGE_LISTED = 3


def _damage_summary(damaged: list[tuple[int, int, str]]) -> str:
    """One short sentence for any number of damaged stretches: count, bytes, the first few file byte ranges."""
    listed = ", ".join(f"{p}–{p + k - 1} ({why})" for p, k, why in damaged[:DAMAGE_LISTED])
    more = f" and {len(damaged) - DAMAGE_LISTED} more" if len(damaged) > DAMAGE_LISTED else ""
    places = "1 place" if len(damaged) == 1 else f"{len(damaged)} places"
    total = sum(k for _, k, _ in damaged)
    return f"{total} damaged bytes in {places} skipped (file bytes {listed}{more})"


def demo_capture_path() -> Path:
    """The bundled demo recording (``recordings/demo.stv``) of a source tree or installed package; else UserError."""
    package = Path(__file__).resolve().parents[1]  # steval_link/ (steval_link/recordings/ once installed)
    for c in (package.parent / "recordings" / "demo.stv", package / "recordings" / "demo.stv"):
        if c.is_file():
            return c
    raise UserError("the demo recording (recordings/demo.stv) is not installed; pass a capture file.")

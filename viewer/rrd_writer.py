"""An ``.rrd`` written by us as the data arrives (:class:`RrdWriter`): Rerun encodes, this module writes the file.

Why not Rerun's own file sink: it keeps its errors to itself and about 1 kB per chunk in memory until the file
closes. Here a thread appends what a Rerun binary stream holds every :data:`WRITE_INTERVAL_S` and ``fsync``\\s every
second. The file gets one stream header and the messages (:func:`rrd_messages`), no footer: Rerun reads it from
its start, and a file cut after any write still opens. A failed write or a vanished file becomes one sentence in
:attr:`RrdWriter.failure`; the run goes on with its other outputs."""

from __future__ import annotations

import contextlib
import os
import struct
import threading
from pathlib import Path

from steval_link.errors import ParamError
from steval_link.link.capture import output_gone

#: How often the encoded bytes are appended to the file and synced to disk, s.
WRITE_INTERVAL_S = 0.25
#: How often the file is forced to disk, s (``fsync``).
SYNC_INTERVAL_S = 1.0
#: Longest wait for Rerun to encode what was logged, at each write, s (at the end: longer).
FLUSH_TIMEOUT_S = 0.5
#: An RRD stream starts with this magic and 8 more bytes (version, encoding options) ...
STREAM_MAGIC = b"RRF2"
STREAM_HEADER_BYTES = 12
#: ... then messages, each (kind u64, length u64, payload); kind 0 ends the stream, followed by a 32-byte footer.
_MESSAGE_HEAD = struct.Struct("<QQ")
END_KIND, STORE_INFO_KIND = 0, 1
FOOTER_BYTES = 32


def rrd_messages(data: bytes) -> tuple[bytes, list[tuple[int, bytes]]]:
    """(stream header, [(kind, whole message)...]) of the RRD streams in ``data`` but end messages; ValueError."""
    header, out, pos, n = b"", [], 0, len(data)
    while pos < n:
        if data[pos : pos + 4] != STREAM_MAGIC:
            raise ValueError(f"no RRD stream header at byte {pos}")
        header = header or bytes(data[pos : pos + STREAM_HEADER_BYTES])
        pos += STREAM_HEADER_BYTES
        while pos < n:
            kind, length = _MESSAGE_HEAD.unpack_from(data, pos)
            end = pos + _MESSAGE_HEAD.size + length
            if end > n:
                raise ValueError(f"an RRD message runs past the end ({end} > {n})")
            if kind == END_KIND:
                footer = data[end + 20 : end + 28] == b"RRF2FOOT"  # after (offset u64, length u64, crc u32)
                pos = end + FOOTER_BYTES if footer else end
                break
            out.append((kind, bytes(data[pos:end])))
            pos = end
    return header, out


class RrdWriter:
    """Writes the stream ``rec`` to the new file ``path`` until :meth:`close`; UserError when it cannot start."""

    def __init__(self, rec, path: str | os.PathLike, *, shown: str | None = None) -> None:
        self.path = Path(path)
        self.shown = shown or str(self.path)  # the name the user gave (a partial file is named by its final name)
        self.failure: str | None = None
        self.bytes_written = 0
        try:
            self._file = open(self.path, "xb", buffering=0)
        except OSError as exc:
            raise ParamError(f"{{rrd}} {self.shown}: cannot write it ({_why(exc)})", "rrd") from None
        st = os.fstat(self._file.fileno())
        self._identity = (st.st_dev, st.st_ino)
        self._lock = threading.Lock()
        self._stream = rec.binary_stream()
        self._store_infos: set[bytes] = set()
        try:
            self._write(self._stream.read(flush=True) or b"")
            os.fsync(self._file.fileno())
        except OSError as exc:  # a start on a full disk: nothing half-made is left
            self._file.close()
            self.path.unlink(missing_ok=True)
            raise ParamError(f"{{rrd}} {self.shown}: cannot write it ({_why(exc)})", "rrd") from None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="rrd-writer", daemon=True)
        self._thread.start()

    def _write(self, segment: bytes) -> None:
        """Append the messages of ``segment`` (whole RRD streams): the stream header and each store's info once."""
        if not segment:
            return
        header, messages = rrd_messages(segment)
        parts = [] if self.bytes_written else [header]  # the stream header once, first
        for kind, message in messages:
            if kind == STORE_INFO_KIND:
                if message in self._store_infos:
                    continue
                self._store_infos.add(message)
            parts.append(message)
        data = b"".join(parts)
        view = memoryview(data)
        while view:
            view = view[self._file.write(view) :]
        self.bytes_written += len(data)  # after the whole write: a failed one is cut back to here

    def _fail(self, why: str) -> None:
        """Stop writing (the file is closed) and keep one sentence saying what happened and what the file holds."""
        n = self.bytes_written
        held = f"{n / 1e6:.1f} MB" if n >= 1e6 else f"{n / 1e3:.1f} kB" if n >= 1e3 else f"{n} B"
        self.failure = f"{self.shown} {why}; nothing more is written to it (it held {held} then)"
        with contextlib.suppress(OSError):  # a write cut by a full disk leaves part of a message: back to the last
            if output_gone(self.path, self._identity) is None:  # whole one, so the file opens
                os.ftruncate(self._file.fileno(), self.bytes_written)
        with contextlib.suppress(OSError):
            self._file.close()

    def pump(self, *, flush: bool = False, sync: bool = False) -> None:
        """Append what Rerun encoded since the last call (``flush``: waiting up to 30 s for it, at the end);
        ``sync``: then ``fsync``. After a failure the bytes are read and dropped."""
        with self._lock:
            try:  # Rerun's pending rows into the stream first (bounded: a slow flush leaves them to the next pump)
                data = self._stream.read(flush=True, flush_timeout_sec=FLUSH_TIMEOUT_S if not flush else 30.0) or b""
            except RuntimeError:
                data = self._stream.read(flush=False) or b""
            if self.failure is not None or self._file.closed:
                return
            gone = output_gone(self.path, self._identity)
            if gone is not None:
                self._fail(gone)
                return
            try:
                self._write(data)
                if sync:
                    os.fsync(self._file.fileno())
            except OSError as exc:
                self._fail(f"cannot be written ({_why(exc)})")

    def _loop(self) -> None:
        ticks = max(1, round(SYNC_INTERVAL_S / WRITE_INTERVAL_S))
        k = 0
        while not self._stop.wait(WRITE_INTERVAL_S):
            k += 1
            try:
                self.pump(sync=k % ticks == 0)
            except Exception as exc:  # noqa: BLE001 - Rerun's stream failed: one sentence, the run goes on
                self.failure = self.failure or f"{self.shown}: Rerun stopped encoding it ({exc})"

    def close(self) -> None:
        """Write the rest and close the file (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join()
        self.pump(flush=True, sync=True)
        with self._lock:
            if not self._file.closed:
                try:
                    self._file.close()
                except OSError as exc:
                    self._fail(f"cannot be written ({_why(exc)})")


def _why(exc: OSError) -> str:
    return (exc.strerror or str(exc)).rstrip(".").lower() if exc.strerror else str(exc)

"""Serial transport: a reader thread that hands raw byte chunks with host times to a protocol object.

The thread only moves bytes (as pyserial's ``serial.threaded``): it gathers a burst (until no byte came for
:data:`CHUNK_GAP_S`, at most :data:`CHUNK_MAX_S`), stamps it with its host time and calls
:meth:`Protocol.data_received`. When the port fails it calls :meth:`Protocol.connection_lost`, polls ``find_port``
for the device, reopens it and calls :meth:`Protocol.connection_made` again; only :meth:`SerialReader.stop` ends it.
"""

from __future__ import annotations

import contextlib
import errno
import select
import sys
import threading
import time
from typing import Callable

import serial

from steval_link.errors import ParamError

#: How long one read waits for a first byte, s (the tick of :meth:`Protocol.idle` on a silent port).
READ_TIMEOUT_S = 0.05
#: A chunk ends when no more bytes came for this long, s (a USB adapter delivers a frame in a burst or a few: a short
#: gap hands a whole frame on quickly; ``select`` on the port returns as soon as more bytes arrive) ...
CHUNK_GAP_S = 0.0002
#: ... or after this long since its first byte, s (bounds the latency of a continuous stream) ...
CHUNK_MAX_S = 0.01
#: ... or at this many bytes.
READ_SIZE = 4096
#: How often a lost port is looked for again, s.
RECONNECT_POLL_S = 0.1


class HostClock:
    """Host receive times: Unix seconds from ``wall0_s`` (default now), advancing with the monotonic clock."""

    def __init__(self, wall0_s: float | None = None) -> None:
        self.mono0_s = time.monotonic()
        self.wall0_s = time.time() if wall0_s is None else float(wall0_s)

    def now_s(self) -> float:
        """Current host time, s since the Unix epoch (monotonic since construction)."""
        return self.wall0_s + (time.monotonic() - self.mono0_s)


class PortRejected(Exception):
    """Raised by a :class:`Protocol` method: the port reopened is not the device (the reader looks again)."""


class Protocol:
    """What the reader thread calls, in the reader thread; an exception but :class:`PortRejected` stops it."""

    def shared_access(self, exc: BaseException) -> bool:
        """Bytes announced were taken: True when another program reading the port explains it, False: port lost."""
        return False

    def connection_made(self, port: str) -> None:
        """The port ``port`` was (re)opened and bytes may follow."""

    def data_received(self, data: bytes, t_unix_s: float) -> None:
        """``data`` arrived; ``t_unix_s`` is the host time (s, Unix epoch) the read returned."""

    def connection_lost(self, exc: BaseException | None) -> None:
        """The port failed with ``exc`` (``None``: closed by :meth:`SerialReader.stop`)."""

    def idle(self, t_unix_s: float) -> None:
        """Called after every read (even an empty one) and while waiting to reconnect: a periodic tick."""


def open_serial(port: str, baud: int, *, timeout_s: float = READ_TIMEOUT_S) -> serial.Serial:
    """Open ``port`` at ``baud`` 8N1, exclusively (fail if another program holds its lock)."""
    try:
        return serial.Serial(port, baud, timeout=timeout_s, exclusive=True)
    except ValueError as exc:  # pyserial: baud rate out of range
        raise serial.SerialException(errno.EINVAL, f"cannot open {port} at {baud} baud: {exc}") from exc


def open_error_message(port: str, exc: BaseException, available: list[str] | None = None) -> ParamError:
    """Why ``port`` could not be opened and the fix; ``available``: the ports listed when it does not exist."""
    code, text = getattr(exc, "errno", None), str(exc)
    if code is None:  # pyserial's own exception: its cause's
        code = getattr(exc.__cause__ or exc.__context__, "errno", None)
    if code == errno.ENOENT or "No such file or directory" in text:
        if available:
            return ParamError(
                f"no serial port {port}; available ports: {', '.join(available)} (pick one with {{port}}, or {{port}} "
                "auto)",
                "port",
            )
        return ParamError(
            f"no serial port {port}, and no serial ports found; plug in the USB-UART adapter (or use {{wait}})", "wait"
        )
    if code in (errno.EACCES, errno.EPERM) or "Permission denied" in text or "Access is denied" in text:
        return ParamError(
            f"permission denied on {port}: add yourself to the dialout group: "
            "sudo usermod -aG dialout $USER, then log out and in"
        )
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK) or "exclusively lock" in text or "busy" in text.lower():
        return ParamError(
            f"{port} is busy: close the other program using it (screen, minicom, Arduino IDE, another steval...) "
            "and try again"
        )
    if code == errno.EINVAL:
        return ParamError(f"cannot open {port}: {text.split(': ', 1)[-1]}")
    if code == errno.ENOTTY or "Inappropriate ioctl" in text:
        return ParamError(f"{port} is not a serial port")
    return ParamError(f"cannot open {port}: {text}")


class SerialReader(threading.Thread):
    """Reads an open port in a thread into a :class:`Protocol`; a failed port is reopened at ``find_port()``."""

    def __init__(
        self,
        ser: serial.Serial,
        protocol: Protocol,
        *,
        baud: int,
        clock: HostClock | None = None,
        find_port: Callable[[], str | None] | None = None,
        opener: Callable[[str], serial.Serial] | None = None,
    ) -> None:
        super().__init__(name="steval-serial-reader", daemon=True)
        self.serial: serial.Serial | None = ser
        self.protocol = protocol
        self.baud = baud
        self.clock = clock or HostClock()
        self.find_port = find_port
        self.opener = opener or (lambda path: open_serial(path, baud))
        self.port: str = ser.port
        #: The exception that ended the thread (raised by the protocol), or ``None``.
        self.error: BaseException | None = None
        #: While disconnected: (path, exception) of the last failed attempt to reopen the port, else ``None``.
        self.reopen_error: tuple[str, BaseException] | None = None
        self.connected = threading.Event()
        #: held while the port is written (:meth:`write`) and while it is swapped (a loss, a reconnection, the end)
        self.lock = threading.Lock()
        self._stop_event = threading.Event()

    def write(self, data: bytes) -> int:
        """Send ``data`` from any thread, under the lock a reconnection holds; ``OSError`` when no port is open."""
        with self.lock:
            ser = self.serial
            if ser is None:
                raise serial.SerialException("the port is not connected")
            return ser.write(data)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Ask the thread to finish, wait for it (up to ``timeout_s``) and close the port."""
        self._stop_event.set()
        with contextlib.suppress(serial.SerialException, OSError, AttributeError):  # no port, or no cancel_read
            self.serial.cancel_read()  # wake a read that waits for bytes
        if self.ident is None:  # never started: close the port here
            self._release()
        elif self.is_alive() and threading.current_thread() is not self:
            self.join(timeout_s)

    def run(self) -> None:
        try:
            self.connected.set()
            self.protocol.connection_made(self.port)
            while not self._stop_event.is_set():
                if self.serial is None:
                    if not self._reconnect():
                        break
                    continue
                try:
                    data = self._read_chunk(self.serial)
                except (serial.SerialException, OSError) as exc:
                    # pyserial's error for a read woken by bytes another reader took first (or a USB unplug)
                    taken = "multiple access" in str(exc) or "returned no data" in str(exc)
                    if not (taken and self.protocol.shared_access(exc)):
                        self._drop(exc)
                    continue
                t_unix_s = self.clock.now_s()
                try:
                    if data:
                        self.protocol.data_received(data, t_unix_s)
                    self.protocol.idle(t_unix_s)
                except PortRejected as exc:
                    self._drop(exc)
        except BaseException as exc:  # noqa: BLE001 - kept for the owner of the thread to re-raise
            self.error = exc
        finally:
            if self._release():
                try:
                    self.protocol.connection_lost(None)
                except BaseException as exc:  # noqa: BLE001
                    self.error = self.error or exc

    def _read_chunk(self, ser: serial.Serial) -> bytes:
        """Wait up to the port's timeout for bytes, then gather the burst (see the module doc)."""
        data = ser.read(ser.in_waiting or 1)
        if not data:
            return data
        buf = bytearray(data)
        t_end = time.monotonic() + CHUNK_MAX_S
        fd = _fileno(ser)
        while len(buf) < READ_SIZE and not self._stop_event.is_set():
            if fd is None:
                time.sleep(CHUNK_GAP_S)
            else:
                try:
                    select.select([fd], [], [], CHUNK_GAP_S)  # returns at once when bytes come
                except (OSError, ValueError):
                    time.sleep(CHUNK_GAP_S)
            try:
                n = ser.in_waiting
                if n:
                    buf += ser.read(min(n, READ_SIZE - len(buf)))
            except (serial.SerialException, OSError):  # the bytes so far are handed on; the next read fails again
                break
            if n == 0 or time.monotonic() >= t_end:
                break
        return bytes(buf)

    def _release(self) -> bool:
        """Close the port (under the lock); False when none was open."""
        with self.lock:
            ser, self.serial = self.serial, None
        if ser is not None:
            close_quietly(ser)
        self.connected.clear()
        return ser is not None

    def _drop(self, exc: BaseException) -> None:
        self._release()
        self.protocol.connection_lost(exc)

    def _reconnect(self) -> bool:
        """Wait for the port to return and reopen it; ``False`` when the thread should end."""
        if self.find_port is None:
            return False
        while not self._stop_event.is_set():
            path = self.find_port()
            if path is not None:
                try:
                    ser = self.opener(path)
                except (serial.SerialException, OSError) as exc:
                    ser = None  # still settling (udev permissions, ModemManager probing): try again next poll
                    self.reopen_error = (path, exc)
                if ser is not None:
                    self.reopen_error = None
                    with self.lock:
                        self.serial = ser
                        self.port = path
                    self.connected.set()
                    self.protocol.connection_made(path)
                    return True
            self.protocol.idle(self.clock.now_s())
            self._stop_event.wait(RECONNECT_POLL_S)
        return False


def _fileno(ser) -> int | None:
    """The port's file descriptor where ``select`` works on it (POSIX), else ``None`` (then the gap is slept)."""
    if sys.platform.startswith("win"):
        return None
    try:
        fd = ser.fileno()
    except (AttributeError, OSError, ValueError, serial.SerialException):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


def close_quietly(ser: serial.Serial) -> None:
    """Close a port that may have failed already (its errors say nothing more)."""
    with contextlib.suppress(serial.SerialException, OSError):
        ser.close()

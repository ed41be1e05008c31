"""A fake drone on a pseudo-terminal: replays bytes at the link's real rate behind a device path, with unplug/replug.

``PtyFeeder(data, link)`` makes a pty, points the symlink ``link`` at its slave side (as udev's
``/dev/serial/by-id`` links or socat's ``pty,link=...``) and writes ``data`` into the master at ``bytes_per_s``
(default: the real stream rate, 161.5 attitude frames + 1 status frame a second = 9461 B/s), in 5 ms ticks.

- :meth:`unplug` removes the link and closes the master: a reader of the slave gets an I/O error, the device node
  vanishes. The stream keeps going in time (the drone keeps flying): bytes due while unplugged are lost.
- :meth:`replug` makes a new pty and link (optionally under another name, like ``ttyUSB0`` → ``ttyUSB1``).
- Writes never block: when nobody reads the slave and the pty buffer is full, bytes are dropped (a UART does
  the same); ``blocking=True`` instead writes as fast as the reader consumes (soak benchmark).

Also :func:`uart_resample`: the bytes a UART receiving at one baud rate makes of a stream sent at another (8N1),
for realistic wrong-baud input.
"""

from __future__ import annotations

import errno
import os
import select
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from steval_link import constants as C
from steval_link.link import protocol

# POSIX only: a test module importing this one skips on Windows, with this reason
pty = pytest.importorskip("pty", reason="the fake drone runs on a pseudo-terminal (POSIX only)")
tty = pytest.importorskip("tty", reason="the fake drone runs on a pseudo-terminal (POSIX only)")

#: Bytes per second of the real stream at 161.5 Hz (PROTOCOL.md, "Bandwidth").
REAL_BYTES_PER_S = C.AHRS_RATE_HZ * protocol.ATTITUDE_FRAME_SIZE + protocol.STATUS_FRAME_SIZE

TICK_S = 0.005


class PtyFeeder:
    """Replays ``data`` into a pty reachable as ``link``; a thread paces the bytes (see the module doc)."""

    def __init__(
        self,
        data: bytes,
        link: str | os.PathLike,
        *,
        bytes_per_s: float | None = REAL_BYTES_PER_S,
        blocking: bool = False,
        loop: bool = False,
    ) -> None:
        self.data = memoryview(bytes(data))
        self.link = Path(link)
        self.bytes_per_s = bytes_per_s
        self.blocking = blocking
        self.loop = loop
        #: stream position: bytes of ``data`` due so far (sent or lost)
        self.pos = 0
        #: bytes written into a pty while plugged / bytes lost while unplugged or with a full buffer
        self.sent = 0
        self.dropped = 0
        #: (start, end) byte ranges of ``data`` written successfully, in order
        self.sent_ranges: list[tuple[int, int]] = []
        self.master: int | None = None
        self.slave_name: str | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ptyfeed", daemon=True)
        self.plug()

    # ---- device node ------------------------------------------------------------------------------------------

    def plug(self, link: str | os.PathLike | None = None) -> None:
        """Create a new pty and point ``link`` (default: the current link) at it."""
        with self._lock:
            if link is not None:
                self.link = Path(link)
            master, slave = pty.openpty()
            tty.setraw(slave)  # no echo, no line editing before the reader opens it
            self.slave_name = os.ttyname(slave)
            os.close(slave)
            os.set_blocking(master, False)  # "blocking" feeding waits with select, never inside a write
            tmp = self.link.with_name(self.link.name + ".tmp")
            tmp.unlink(missing_ok=True)
            os.symlink(self.slave_name, tmp)
            os.replace(tmp, self.link)
            self.master = master

    replug = plug

    def unplug(self) -> None:
        """Remove the link and close the master (the reader gets an error; the node is gone)."""
        with self._lock:
            self.link.unlink(missing_ok=True)
            if self.master is not None:
                os.close(self.master)
                self.master = None

    @property
    def plugged(self) -> bool:
        return self.master is not None

    # ---- feeding ----------------------------------------------------------------------------------------------

    def start(self) -> "PtyFeeder":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)
        self.unplug()

    def __enter__(self) -> "PtyFeeder":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def wait_done(self, timeout_s: float) -> bool:
        """Wait until every byte of ``data`` is due (sent or lost); False on timeout."""
        return self.done.wait(timeout_s)

    def sent_bytes(self) -> bytes:
        """The bytes of ``data`` that went into a pty, in order (what a perfect reader could have read)."""
        return b"".join(bytes(self.data[a:b]) for a, b in self.sent_ranges)

    def _run(self) -> None:
        n = len(self.data)
        t0 = time.monotonic()
        base = 0  # stream position at t0 (for looping)
        while not self._stop.is_set():
            if self.bytes_per_s is None:
                due = self.pos + 65536
            else:
                due = base + int((time.monotonic() - t0) * self.bytes_per_s)
            while self.pos < due and not self._stop.is_set():
                if self.pos >= n:
                    if not self.loop:
                        break
                    self.pos = 0
                    base -= n
                    due -= n
                end = min(due, n)
                self._write(self.pos, end)
            if self.pos >= n and not self.loop:
                self.done.set()
                if self.blocking:
                    return
            if self.bytes_per_s is not None:
                self._stop.wait(TICK_S)

    def _write(self, start: int, end: int) -> None:
        with self._lock:
            master = self.master
            if master is None:
                self.dropped += end - start
                self.pos = end
                return
            try:
                k = os.write(master, self.data[start:end])
            except BlockingIOError:
                k = 0
            except OSError as exc:
                if exc.errno not in (errno.EIO, errno.EAGAIN):
                    raise
                k = 0
        if k:
            self.sent += k
            if self.sent_ranges and self.sent_ranges[-1][1] == start:
                self.sent_ranges[-1] = (self.sent_ranges[-1][0], start + k)
            else:
                self.sent_ranges.append((start, start + k))
        if self.blocking:
            self.pos = start + k  # a partial write continues where it stopped
            if k == 0:  # the pty is full: wait until the reader makes room (or for stop/unplug)
                try:
                    select.select([], [master], [], 0.05)
                except (OSError, ValueError):
                    time.sleep(0.01)
            return
        self.dropped += (end - start) - k
        self.pos = end


def uart_resample(data: bytes, baud_tx: int, baud_rx: int, *, idle_bits: int = 0) -> bytes:
    """The bytes a UART at ``baud_rx`` receives from ``data`` sent at ``baud_tx`` (8N1, LSB first).

    The receiver waits for a falling edge, samples the middle of each bit at its own rate and keeps the 8 data bits
    whatever the stop bit (Linux delivers framing-error bytes too). ``idle_bits`` of idle line follow each byte.
    """
    raw = np.frombuffer(bytes(data), dtype=np.uint8)
    bits_per_byte = 10 + idle_bits
    frame = np.ones((len(raw), bits_per_byte), dtype=np.uint8)
    frame[:, 0] = 0
    frame[:, 1:9] = (raw[:, None] >> np.arange(8)) & 1
    line = frame.reshape(-1)
    zeros = np.flatnonzero(line == 0)
    t_bit_tx = 1.0 / baud_tx
    t_bit_rx = 1.0 / baud_rx
    t_end = len(line) * t_bit_tx
    out = bytearray()
    t = 0.0
    while True:
        # next low level at or after t: its edge is the start of that tx bit (or t itself when already low)
        k = int(np.searchsorted(zeros, int(t / t_bit_tx)))
        if k >= len(zeros):
            break
        edge = max(t, zeros[k] * t_bit_tx)
        if edge + 9.5 * t_bit_rx >= t_end:
            break
        value = 0
        for bit in range(8):
            ts = edge + (bit + 1.5) * t_bit_rx
            value |= int(line[int(ts / t_bit_tx)]) << bit
        out.append(value)
        t = edge + 9.5 * t_bit_rx  # middle of the stop bit: look for the next start from here
        # a receiver re-arms only on a high→low transition: skip while the line is still low
        i = int(t / t_bit_tx)
        while i < len(line) and line[i] == 0:
            i += 1
        t = max(t, i * t_bit_tx)
    return bytes(out)


def flight_stream(
    n_steps: int,
    *,
    first_step: int = 0,
    status_every: int = 161,
    seed: int = 0,
    text_lines: tuple[str, ...] = (),
    ki: float = 0.1,
) -> bytes:
    """The byte stream of a drone on the bench / in the air, as the patched firmware sends it.

    Steps 0..first_step+n_steps-1 are run through the bit-exact filter replica (so ``q`` is what the firmware would
    send); frames from ``first_step`` on are emitted (``first_step`` > 0: the link joins mid-flight). A status frame
    with the filter snapshot follows every ``status_every``-th attitude frame (step % status_every == status_every-1).
    Inputs: gravity on a slow rocking motion plus noise, throttle ramping through MIN_THR, in float32. ``ki``: the
    firmware's AHRS_KI (0.1; lab exercise 4 sets 1.0), used by the filter and reported in the status frames.
    """
    from steval_link.estimators import st_mahony

    settings = st_mahony.MahonySettings(ki=ki)
    rng = np.random.default_rng(seed)
    total = first_step + n_steps
    t = np.arange(total) * C.AHRS_PERIOD_S
    pitch = 0.35 * np.sin(2 * np.pi * 0.3 * t)
    roll = 0.25 * np.sin(2 * np.pi * 0.17 * t + 1.0)
    acc = np.stack(
        [1000 * np.sin(roll), -1000 * np.sin(pitch) * np.cos(roll), 1000 * np.cos(pitch) * np.cos(roll)], axis=1
    ) + rng.normal(0, 15, (total, 3))
    gyro = np.stack(
        [np.gradient(pitch, t) * 57295.8, np.gradient(roll, t) * 57295.8, 2000 * np.sin(0.5 * t)], axis=1
    ) + rng.normal(0, 300, (total, 3))
    acc = acc.astype(np.float32)
    gyro = gyro.astype(np.float32)
    thr = np.clip((t * 80).astype(np.int64) % 600, 0, 500).astype(np.int16)
    state = st_mahony.MahonyState()
    out = bytearray(b"".join(protocol.encode_text(line) for line in text_lines))
    t_us = (t * 1e6).astype(np.int64) + 1_234_567
    thz = np.cumsum(gyro[:, 2].astype(np.float64) * C.AHRS_PERIOD_S / 57295.8).astype(np.float32)
    block = status_every
    start = 0
    while start < total:
        # run up to and including the next status step
        end = min(total, (start // block + 1) * block)
        q, _, _, state = st_mahony.run(
            acc[start:end], gyro[start:end], thr[start:end], settings=settings, state=state, euler=False
        )
        lo = max(start, first_step)
        if lo < end:
            rec = np.zeros(end - lo, dtype=protocol.ATTITUDE_DTYPE)
            rec["t_us"] = t_us[lo:end] % protocol.T_US_MODULUS
            rec["acc_mg"] = acc[lo:end]
            rec["gyro_mdps"] = gyro[lo:end]
            rec["q_wxyz"] = q[lo - start :]
            rec["thz_rad"] = thz[lo:end]
            rec["seq"] = np.arange(lo, end) % protocol.SEQ_MODULUS
            rec["thr"] = thr[lo:end]
            out += protocol.encode_attitude_block(rec)
            if end % block == 0:
                out += protocol.encode_status(
                    step=end - 1,
                    t_us=int(t_us[end - 1]),
                    q_wxyz=state.q_wxyz,
                    int_xyz=state.int_xyz,
                    cyc_min=9000,
                    cyc_mean=9100,
                    cyc_max=9500,
                    cyc_n=block,
                    ki=ki,
                )
        start = end
    return bytes(out)


class StevalProcess:
    """``steval ARGS`` in a child process; stderr lines are collected with the monotonic time they arrived.

    The CLI runs as ``python -c "from steval_link.cli import main; main()"`` (no console script needed), with no
    display unless ``env`` (a whole environment, e.g. a virtual display's) is given.
    """

    def __init__(
        self, args: list[str], *, cwd: str | os.PathLike | None = None, preexec_fn=None, env: dict | None = None
    ) -> None:
        import subprocess
        import sys

        if env is None:  # headless unless the test hands a display's environment
            env = dict(os.environ)
            env.pop("DISPLAY", None)
            env.pop("WAYLAND_DISPLAY", None)
        env = dict(env, PYTHONUNBUFFERED="1", COLUMNS="200")
        self.t_start = time.monotonic()
        self.proc = subprocess.Popen(
            [sys.executable, "-c", "from steval_link.cli import main; main()", *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            cwd=cwd,
            env=env,
            preexec_fn=preexec_fn,
        )
        self.lines: list[tuple[float, str]] = []
        self._out: list[bytes] = []
        self._threads = [
            threading.Thread(target=self._read_err, daemon=True),
            threading.Thread(target=self._read_out, daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _read_err(self) -> None:
        for raw in self.proc.stderr:
            self.lines.append((time.monotonic(), raw.decode("utf-8", "replace").rstrip("\n")))

    def _read_out(self) -> None:
        for raw in self.proc.stdout:
            self._out.append(raw)

    def wait_line(self, text: str, timeout_s: float) -> float | None:
        """Monotonic arrival time of the first stderr line containing ``text`` (waits up to ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while True:
            for t, line in list(self.lines):
                if text in line:
                    return t
            if time.monotonic() > deadline or self.proc.poll() is not None and not self._threads[0].is_alive():
                return None
            time.sleep(0.01)

    def finish(self, timeout_s: float = 60.0, sig: int | None = None) -> int:
        """Send ``sig`` (if any), wait for the exit code; the output threads are drained."""
        if sig is not None and self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(timeout_s)
        except Exception:
            self.proc.kill()
            raise
        for t in self._threads:
            t.join(10)
        return rc

    @property
    def stderr(self) -> str:
        return "\n".join(line for _, line in self.lines)

    @property
    def stdout(self) -> str:
        return b"".join(self._out).decode("utf-8", "replace")

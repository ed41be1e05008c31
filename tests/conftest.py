"""Shared fixtures: the ``../shared`` data directory and builders of synthetic wire streams."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from steval_link import protocol as P
from steval_link.textmode import format_att, format_sta

SHARED_DIR = Path(__file__).resolve().parents[1] / ".." / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` next to the project (lab docs, conformance vectors, datasets); skips the test when absent."""
    if not SHARED_DIR.is_dir():
        pytest.skip("../shared is not available (fresh clone without the shared data)")
    return SHARED_DIR.resolve()


class StreamBuilder:
    """Builds wire streams frame by frame and remembers what was sent (frame bytes, kind, key values)."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)
        self.parts: list[bytes] = []
        self.sent: list[tuple[str, bytes, object]] = []  # (kind, exact frame bytes, key)

    def _add(self, kind: str, frame: bytes, key) -> bytes:
        self.parts.append(frame)
        self.sent.append((kind, frame, key))
        return frame

    def attitude(self, step: int, t_us: int | None = None, thr: int = 0) -> bytes:
        r = self.rng
        t_us = int(step * 6191.9) if t_us is None else t_us
        frame = P.encode_attitude(
            t_us=t_us,
            acc_mg=r.normal([0, 0, 1000], 30, 3).astype(np.float32),
            gyro_mdps=r.normal(0, 800, 3).astype(np.float32),
            q_wxyz=np.array([0.9983, r.normal(0, 0.05), r.normal(0, 0.05), 0.01], np.float32),
            thz_rad=np.float32(r.normal()),
            seq=step,
            thr=thr,
        )
        return self._add("attitude", frame, step % P.SEQ_MODULUS)

    def status(self, step: int, t_us: int | None = None, **kw) -> bytes:
        t_us = int(step * 6191.9) if t_us is None else t_us
        frame = P.encode_status(step=step, t_us=t_us, q_wxyz=[0.9983, 0, 0, 0], int_xyz=[1e-4, -2e-4, 0], **kw)
        return self._add("status", frame, step)

    def text(self, line: str) -> bytes:
        frame = P.encode_text(line)
        return self._add("text", frame, line)

    def att_line(self, step: int, t_ms: int | None = None) -> bytes:
        r = self.rng
        t_ms = int(step * 6.1919) if t_ms is None else t_ms
        line = format_att(
            step=step, t_ms=t_ms, thr=0, thx_mdeg=int(r.integers(-90000, 90000)),
            thy_mdeg=int(r.integers(-90000, 90000)), thz_mdeg=int(r.integers(-180000, 180000)),
            acc_mg=r.integers(-2000, 2000, 3), gyro_mdps=r.integers(-100000, 100000, 3),
        )
        return self._add("att_line", line, step)

    def sta_line(self, step: int) -> bytes:
        line = format_sta(step=step, t_ms=int(step * 6.1919), cyc_min=1000, cyc_mean=1100, cyc_max=1500,
                          cyc_n=161, tx_dropped=0, flags=P.FLAG_TEXT_MODE, ki_micro=100000)
        return self._add("sta_line", line, step)

    def log_line(self, text: str) -> bytes:
        return self._add("log_line", text.encode() + b"\r\n", text)

    def flight(self, n: int, start: int = 0, status_every: int = 161, text_every: int = 0) -> "StreamBuilder":
        """``n`` attitude frames from step ``start``, a status frame after every ``status_every``th."""
        for i in range(start, start + n):
            self.attitude(i)
            if status_every and i % status_every == status_every - 1:
                self.status(i)
            if text_every and i % text_every == text_every - 1:
                self.text(f"log line at step {i}")
        return self

    def bytes(self) -> bytes:
        return b"".join(self.parts)


@pytest.fixture
def stream() -> StreamBuilder:
    """A fresh :class:`StreamBuilder` (deterministic values)."""
    return StreamBuilder(seed=1)


@pytest.fixture
def make_stream():
    """Factory of :class:`StreamBuilder` with a given seed."""
    return StreamBuilder


def frame_keys(frames) -> list[tuple]:
    """Comparable identity of decoded frames (kind-specific fields + offset)."""
    from steval_link.frames import AttitudeFrame, StatusFrame

    out = []
    for f in frames:
        if isinstance(f, AttitudeFrame):
            out.append(("a", f.offset, f.seq, f.t_us, f.exact, f.step, *f.acc_mg, *f.gyro_mdps,
                        *(0.0 if math.isnan(x) else x for x in f.q_wxyz)))
        elif isinstance(f, StatusFrame):
            out.append(("s", f.offset, f.step, f.t_us, f.exact))
        else:
            out.append(("t", f.offset, f.text))
    return out


def run_cli(monkeypatch, capsys, *args):
    """``steval`` as a user runs it (``sys.argv`` and ``main()``): returns (exit code, stdout, stderr)."""
    import sys

    from steval_link.cli import main

    monkeypatch.setattr(sys, "argv", ["steval", *map(str, args)])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    out, err = capsys.readouterr()
    return code, out, err


def run_cli_tty(*args, timeout: float = 120.0):
    """``steval ARGS`` in a subprocess whose stderr is a terminal (a pseudo-terminal, 100 columns), as on a user's
    screen: returns (exit code, stdout text, everything written to the terminal as text)."""
    import os
    import pty
    import select
    import subprocess
    import sys
    import time

    master, slave = pty.openpty()
    env = dict(os.environ, TERM="xterm", COLUMNS="100", LINES="30")
    proc = subprocess.Popen(
        [sys.executable, "-c", "from steval_link.cli import main; main()", *map(str, args)],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=slave, env=env,
    )
    os.close(slave)
    chunks = []
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # the child closed the terminal
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        else:
            proc.kill()
            raise AssertionError(f"steval {' '.join(map(str, args))} did not end within {timeout} s")
        stdout = proc.communicate(timeout=timeout)[0]
    finally:
        os.close(master)
    return proc.returncode, stdout.decode("utf-8", "replace"), b"".join(chunks).decode("utf-8", "replace")

"""Benchmark: live latency from a frame's last byte on the serial line to its data being logged to Rerun.

A fake drone (separate process) writes attitude frames into a pseudo-terminal at 161.5 Hz (a status frame every
162 steps, as the firmware). Each frame carries in ``t_us`` the writer's CLOCK_MONOTONIC time in µs (mod 2³²) taken
as its bytes are written, so the reader can measure, per frame, ``logged - written`` on the same clock.

Reader pipeline (the live path, one way): serial reader thread -> queue of chunks -> StreamDecoder -> estimators
(seeded ST-Mahony port + accelerometer tilt, as ``steval_link.live.LiveEstimators``) -> ``LiveLogger.log_batch``
-> .rrd file sink. The latency of a frame is taken when ``log_batch`` returns for its batch.

``--reader transport`` (default when present) uses the project's ``steval_link.transport.SerialReader`` on the
pty's slave; ``--reader own`` a minimal select()-based reader (returns as soon as bytes arrive), to tell the
transport's read timeout apart from the logging cost.

Goal: p99 <= 5 ms at 161.5 Hz.

    python benchmarks/bench_live_latency.py [--seconds 20] [--reader transport|own|both]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import queue
import select
import tempfile
import threading
import time
import tty
from pathlib import Path
from types import SimpleNamespace

import numpy as np

RATE_HZ = 161.5
U32 = 1 << 32


def now_us() -> int:
    return time.monotonic_ns() // 1000


def fake_drone(master_fd: int, seconds: float, ready) -> None:
    """Write frames at 161.5 Hz into the pty master; t_us = monotonic µs at write time."""
    from steval_link import protocol as P

    n = int(seconds * RATE_HZ)
    period = 1.0 / RATE_HZ
    q = (1.0, 0.0, 0.0, 0.0)
    ready.wait()
    t0 = time.monotonic() + 0.2
    for i in range(n):
        due = t0 + i * period
        while True:
            d = due - time.monotonic()
            if d <= 0:
                break
            time.sleep(min(d, 0.002) if d > 0.0005 else 0)
        t = now_us()
        frame = P.encode_attitude(
            t_us=t % U32, acc_mg=(10.0, -20.0, 1000.0), gyro_mdps=(100.0, 0.0, -50.0), q_wxyz=q, thz_rad=0.0,
            seq=i, thr=0,
        )
        if i % 162 == 161:
            frame += P.encode_status(step=i, t_us=t % U32, q_wxyz=q, int_xyz=(0.0, 0.0, 0.0), cyc_n=162,
                                     cyc_min=9000, cyc_mean=9400, cyc_max=12000)
        os.write(master_fd, frame)
    time.sleep(0.3)


class _Queue:
    """What the reader thread hands the main thread: (bytes, host time) chunks."""

    def __init__(self) -> None:
        self.q: queue.Queue = queue.Queue()

    def data_received(self, data: bytes, t_host_s: float) -> None:
        self.q.put(data)


def _own_reader(fd: int, sink: _Queue, stop: threading.Event) -> None:
    while not stop.is_set():
        r, _, _ = select.select([fd], [], [], 0.05)
        if r:
            try:
                data = os.read(fd, 4096)
            except OSError:
                return
            if data:
                sink.data_received(data, time.time())


def run_once(reader: str, seconds: float) -> dict:
    from steval_link.decoder import StreamDecoder
    from steval_link.frames import AttitudeFrame, StatusFrame
    from steval_viewer.live_log import LiveLogger
    from steval_viewer.sinks import SinkOptions, open_session

    master, slave = os.openpty()
    tty.setraw(slave)
    slave_name = os.ttyname(slave)
    ready = mp.get_context("fork").Event()
    writer = mp.get_context("fork").Process(target=fake_drone, args=(master, seconds, ready), daemon=True)
    writer.start()

    inbox = _Queue()
    stop = threading.Event()
    ser = None
    if reader == "transport":
        import serial

        from steval_link.transport import Protocol, SerialReader

        class P(Protocol):
            def data_received(self, data, t_host_s):
                inbox.data_received(data, t_host_s)

        ser = serial.Serial(slave_name, 115200, timeout=0.01)
        thread = SerialReader(ser, P(), baud=115200)
        thread.start()
    else:
        thread = threading.Thread(target=_own_reader, args=(slave, inbox, stop), daemon=True)
        thread.start()

    estimators = None
    try:
        from steval_link.live import LiveEstimators

        estimators = LiveEstimators(["st-mahony", "accel"])
    except Exception:  # the live module is not there: log the firmware side only
        estimators = None

    out = Path(tempfile.mkdtemp()) / "live_bench.rrd"
    session = open_session(SinkOptions(rrd=out))
    logger = LiveLogger(session.rec, ["st-mahony", "accel"] if estimators else [])
    dec = StreamDecoder()
    lat_us: list[int] = []
    log_ms: list[float] = []
    est_ms: list[float] = []
    batch_sizes: list[int] = []
    step = 0
    ready.set()
    deadline = time.monotonic() + seconds + 1.5
    while time.monotonic() < deadline:
        try:
            chunks = [inbox.q.get(timeout=0.05)]
        except queue.Empty:
            if not writer.is_alive() and inbox.q.empty():
                break
            continue
        while True:  # everything that arrived meanwhile goes into the same batch (as the live session's inbox)
            try:
                chunks.append(inbox.q.get_nowait())
            except queue.Empty:
                break
        frames = dec.feed(b"".join(chunks))
        att = [f for f in frames if isinstance(f, AttitudeFrame)]
        for f in frames:
            if isinstance(f, StatusFrame) and estimators is not None:
                estimators.status(f)
        if not att:
            continue
        n = len(att)
        batch = SimpleNamespace(
            step=np.array([f.seq for f in att], dtype=np.int64),
            t_us=np.array([f.t_us for f in att], dtype=np.int64),
            t_host_s=np.full(n, time.time()),
            acc_mg=np.array([f.acc_mg for f in att], dtype=np.float32),
            gyro_mdps=np.array([f.gyro_mdps for f in att], dtype=np.float32),
            q_wxyz=np.array([f.q_wxyz for f in att], dtype=np.float32),
            thz_rad=np.array([f.thz_rad for f in att], dtype=np.float32),
            thr=np.array([f.thr for f in att], dtype=np.int16),
            finite=np.ones(n, dtype=bool),
            exact=np.ones(n, dtype=bool),
            thx_rad=np.full(n, np.nan, dtype=np.float32),
            thy_rad=np.full(n, np.nan, dtype=np.float32),
            estimates={},
        )
        batch = _Batch(batch)
        t_e = time.perf_counter()
        if estimators is not None:
            estimators.process(batch)
        t_a = time.perf_counter()
        est_ms.append((t_a - t_e) * 1e3)
        logger.log_batch(batch)
        t_b = time.perf_counter()
        done = now_us()
        lat_us += [int((done - f.t_us) % U32) for f in att]
        log_ms.append((t_b - t_a) * 1e3)
        batch_sizes.append(n)
        step += n
    stop.set()
    if reader == "transport":
        thread.stop()
    writer.join(2)
    session.close()
    os.close(master)
    os.close(slave)
    out.unlink(missing_ok=True)
    lat = np.array(lat_us[int(RATE_HZ):], dtype=np.float64) / 1e3  # skip the first second (warm-up)
    return {
        "reader": reader,
        "frames": len(lat_us),
        "p50": float(np.percentile(lat, 50)),
        "p90": float(np.percentile(lat, 90)),
        "p99": float(np.percentile(lat, 99)),
        "max": float(lat.max()),
        "log_p50": float(np.percentile(log_ms, 50)),
        "log_p99": float(np.percentile(log_ms, 99)),
        "batch_mean": float(np.mean(batch_sizes)),
        "est_p50": float(np.percentile(est_ms, 50)),
    }


class _Batch:
    """An AttitudeBatch view for LiveEstimators.process (needs len())."""

    def __init__(self, ns) -> None:
        self.__dict__ = ns.__dict__

    def __len__(self) -> int:
        return int(self.step.shape[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--reader", choices=("transport", "own", "both"), default="both")
    args = ap.parse_args()
    readers = ["transport", "own"] if args.reader == "both" else [args.reader]
    for r in readers:
        if r == "transport":
            try:
                import steval_link.transport  # noqa: F401
            except ImportError:
                print("transport: steval_link.transport not present, skipped")
                continue
        res = run_once(r, args.seconds)
        print(
            f"reader {res['reader']:9s}: {res['frames']} frames at {RATE_HZ} Hz, latency last byte -> logged: "
            f"p50 {res['p50']:.2f} ms, p90 {res['p90']:.2f} ms, p99 {res['p99']:.2f} ms, max {res['max']:.2f} ms "
            f"(goal p99 <= 5 ms); log_batch p50 {res['log_p50']:.2f} ms p99 {res['log_p99']:.2f} ms; "
            f"estimators p50 {res['est_p50']:.2f} ms; {res['batch_mean']:.2f} frames/batch"
        )


if __name__ == "__main__":
    main()

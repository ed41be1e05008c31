"""Benchmark: live latency from a frame's last byte on the serial line to its data being logged to Rerun.

A fake drone (separate process) writes attitude frames into a pseudo-terminal at 161.5 Hz (a status frame every
162 steps, as the firmware). Each frame carries in ``t_us`` the writer's CLOCK_MONOTONIC time in µs (mod 2³²) taken
as its bytes are written, so the reader can measure, per frame, ``logged - written`` on the same clock.

The measured path is the live session's own (``steval_link.live``): ``SerialReader`` thread with
``RecorderProtocol`` (each chunk to a capture file first, then the session's ``Inbox``) -> the session's main
loop -> ``LivePipeline`` (``StreamDecoder``, ``LiveRows``, ``LiveEstimators``: the default estimators, e.g.
the seeded ST replica, accel and EKF3) -> ``LiveLogger.log_batch`` on an .rrd file sink, with the live viewer's batching
(``steval_link.live.pipeline.VIEW_INTERVAL_S``). The latency of a frame is taken when ``log_batch`` returns for its
batch.

``--stream text`` writes ST's release 221117 line instead (``%d\t%d\t%d\t%d\t%f\t%f\t%f\t%f\t%f``, 161.5 lines/s,
text telemetry: :mod:`steval_link.link.text_telemetry`), its write time in µs in the first two ``%d`` fields (s, µs);
its latency is taken when ``log_batch`` returns for the attitude row the record maps to (ST's thx, thy); ``both``
runs the binary stream, then the text stream (each run), and prints how much text adds to p50 and p99 and to the
main loop's CPU time per line: a figure that a loaded machine moves less than the latency.

``--reader transport`` uses ``steval_link.link.transport.SerialReader`` on the pty's slave; ``--reader own`` a minimal
select()-based reader (hands bytes on as soon as they arrive), to tell the transport's cost apart from the rest;
``--reader inline`` no pty: each step's bytes are fed at once and timed in CPU time (:func:`run_inline`).

Goal: p99 <= 5 ms at 161.5 Hz; live text adds no more than 1 ms p99.

    python benchmarks/bench_live_latency.py [--seconds 20] [--reader transport|own|both|inline] [--stream ...]
        [--runs 3] [--estimators ...]
"""

from __future__ import annotations

import argparse
import functools
import multiprocessing as mp
import os
import select
import tempfile
import threading
import time
import tty
from pathlib import Path

import numpy as np

RATE_HZ = 161.5
U32 = 1 << 32


def now_us() -> int:
    return time.monotonic_ns() // 1000


def st_line(i: int, t_us: int) -> bytes:
    """ST 221117's line of step ``i`` written at monotonic ``t_us``: (s, µs) in gELE, gAIL; a slow sway in thx/thy."""
    thx, thy = 5.0 * np.sin(i / 80.0), 3.0 * np.cos(i / 95.0)
    return b"%d\t%d\t%d\t%d\t%f\t%f\t%f\t%f\t%f\n" % (t_us // 10**6, t_us % 10**6, 0, 400, 1200.0, thx, thy, 0.0, 0.0)


def step_bytes(i: int, t_us: int, stream: str) -> bytes:
    """The bytes of step ``i`` written at monotonic ``t_us``: an attitude frame (and a status frame every 162 steps),
    or ST's text line."""
    from steval_link.link import protocol as P

    if stream == "text":
        return st_line(i, t_us)
    q = (1.0, 0.0, 0.0, 0.0)
    frame = P.encode_attitude(
        t_us=t_us % U32,
        acc_mg=(10.0, -20.0, 1000.0),
        gyro_mdps=(100.0, 0.0, -50.0),
        q_wxyz=q,
        thz_rad=0.0,
        seq=i,
        thr=0,
    )
    if i % 162 == 161:
        frame += P.encode_status(
            step=i, t_us=t_us % U32, q_wxyz=q, int_xyz=(0.0,) * 3, cyc_n=162, cyc_min=9000, cyc_mean=9400, cyc_max=12000
        )
    return frame


def fake_drone(master_fd: int, seconds: float, ready, stream: str = "binary") -> None:
    """Write frames (or ST's text lines) at 161.5 Hz into the pty master; t_us = monotonic µs at write time."""
    n = int(seconds * RATE_HZ)
    period = 1.0 / RATE_HZ
    ready.wait()
    t0 = time.monotonic() + 0.2
    for i in range(n):
        due = t0 + i * period
        while True:
            d = due - time.monotonic()
            if d <= 0:
                break
            time.sleep(min(d, 0.002) if d > 0.0005 else 0)
        os.write(master_fd, step_bytes(i, now_us(), stream))
    time.sleep(0.3)


def _time_estimators(pipe) -> list[float]:
    """The wall time of each call of the pipeline's estimators, ms (filled as they run)."""
    est_ms: list[float] = []
    process = pipe.estimators.process if pipe.estimators is not None else None
    if process is not None:

        def timed(batch, _process=process):
            t = time.perf_counter()
            _process(batch)
            est_ms.append((time.perf_counter() - t) * 1e3)

        pipe.estimators.process = timed
    return est_ms


def run_inline(seconds: float, estimators: list[str], stream: str) -> dict:
    """``--reader inline``: no port, no thread, no waiting; each step's bytes go through the live pipeline and its
    logger (.rrd sink) as one chunk, and its figure is the main thread's CPU time for it (``time.thread_time``),
    which other processes on a loaded machine move much less than a latency."""
    from steval_link.live import pipeline
    from steval_viewer.live_log import LiveLogger
    from steval_viewer.sink_options import SinkOptions
    from steval_viewer.sinks import open_session

    with tempfile.TemporaryDirectory() as tmp:
        session = open_session(SinkOptions(rrd=Path(tmp) / "inline.rrd"))
        viewer = _TimedViewer(LiveLogger(session.rec, estimators))
        pipe = pipeline.LivePipeline(estimators, viewer, view_interval_s=pipeline.VIEW_INTERVAL_S)
        est_ms, cpu_ms, t0 = _time_estimators(pipe), [], time.time()
        for i in range(int(seconds * RATE_HZ)):
            data = step_bytes(i, int(i * 1e6 / RATE_HZ), stream)
            t = time.thread_time()
            pipe.feed([(data, t0 + i / RATE_HZ)])
            pipe.tick(time.monotonic())
            cpu_ms.append((time.thread_time() - t) * 1e3)
        pipe.flush_view()
        session.close()
    cpu = np.array(cpu_ms[int(RATE_HZ) :])  # skip the first second (warm-up)
    return {
        "reader": "inline",
        "stream": stream,
        "frames": len(cpu_ms),
        "p50": float(np.percentile(cpu, 50)),
        "p90": float(np.percentile(cpu, 90)),
        "p99": float(np.percentile(cpu, 99)),
        "max": float(cpu.max()),
        "log_p50": float(np.percentile(viewer.log_ms, 50)),
        "log_p99": float(np.percentile(viewer.log_ms, 99)),
        "batch_mean": float(np.mean(viewer.batch_sizes)),
        "est_p50": float(np.percentile(est_ms, 50)) if est_ms else 0.0,
        "cpu_ms": float(cpu.mean()),
    }


class _OwnInbox:
    """For ``--reader own``: what a minimal reader thread hands on (bytes with the host time)."""

    def __init__(self, inbox, clock) -> None:
        self.inbox = inbox
        self.clock = clock

    def data_received(self, data: bytes) -> None:
        self.inbox.put(data, self.clock.now_s())


def _own_reader(fd: int, sink: _OwnInbox, stop: threading.Event) -> None:
    while not stop.is_set():
        r, _, _ = select.select([fd], [], [], 0.05)
        if r:
            try:
                data = os.read(fd, 4096)
            except OSError:
                return
            if data:
                sink.data_received(data)


class _TimedViewer:
    """The live session's viewer side (``steval_viewer.live_adapter.ViewerLogger``: a ``LiveLogger`` on an .rrd
    sink) that notes, for each frame, when ``log_batch`` returned for it."""

    def __init__(self, logger) -> None:
        self.logger = logger
        self.lat_us: list[int] = []
        self.log_ms: list[float] = []
        self.batch_sizes: list[int] = []
        self.text = False  # the rows come from text records: their write time is in the record (see log_record)
        self._done_at: dict[int, int] = {}  # text: stream offset of a row -> when log_batch returned for it, µs

    def log_batch(self, batch) -> None:
        t_a = time.perf_counter()
        self.logger.log_batch(batch)
        t_b = time.perf_counter()
        done = now_us()
        if self.text:
            self._done_at.update(dict.fromkeys(batch.attitude.offset.tolist(), done))
        else:
            self.lat_us += [int((done - t) % U32) for t in batch.attitude.t_us.tolist()]
        self.log_ms.append((t_b - t_a) * 1e3)
        self.batch_sizes.append(len(batch))

    def log_record(self, frame, at) -> None:
        """A record of ST's line (after its row's batch): the row's latency from the write time it carries."""
        self.logger.log_record(frame, at)
        done = self._done_at.pop(frame.offset, None)
        if done is not None:
            written = int(frame.values[0]) * 10**6 + int(frame.values[1])
            self.lat_us.append(done - written)

    def log_status(self, frame, at) -> None:
        self.logger.log_status(frame, at)

    def log_text(self, frame, at) -> None:
        self.logger.log_text(frame, at)

    def log_link(self, stats, t_unix_s) -> None:
        self.logger.log_link(stats, t_unix_s)


def run_once(reader: str, seconds: float, estimators: list[str], stream: str = "binary") -> dict:
    from steval_link.link.capture import CaptureWriter
    from steval_link.link.transport import HostClock, SerialReader
    from steval_link.live import pipeline, serial_source
    from steval_link.live.sources import record_chunk
    from steval_viewer.live_log import LiveLogger
    from steval_viewer.sink_options import SinkOptions
    from steval_viewer.sinks import open_session

    master, slave = os.openpty()
    tty.setraw(slave)
    slave_name = os.ttyname(slave)
    ready = mp.get_context("fork").Event()
    writer = mp.get_context("fork").Process(target=fake_drone, args=(master, seconds, ready, stream), daemon=True)
    writer.start()

    tmp = Path(tempfile.mkdtemp())
    capture = CaptureWriter(tmp / "live_bench.stv", port=slave_name, baud=115200)
    clock = HostClock(wall0_s=capture.header["start_time_unix_s"])
    inbox = serial_source.Inbox()
    stop = threading.Event()
    if reader == "transport":  # the live session's reader thread: capture first, then the inbox
        import serial

        ser = serial.Serial(slave_name, 115200, timeout=0.05)
        proto = serial_source.RecorderProtocol(functools.partial(record_chunk, capture), inbox, None, clock)
        thread = SerialReader(ser, proto, baud=115200, clock=clock)
        thread.start()
    else:
        thread = threading.Thread(target=_own_reader, args=(slave, _OwnInbox(inbox, clock), stop), daemon=True)
        thread.start()

    out = tmp / "live_bench.rrd"
    session = open_session(SinkOptions(rrd=out))
    viewer = _TimedViewer(LiveLogger(session.rec, estimators))
    viewer.text = stream == "text"
    # the live viewer's path: every processing round is logged at once (pipeline.VIEW_INTERVAL_S)
    pipe = pipeline.LivePipeline(estimators, viewer, view_interval_s=pipeline.VIEW_INTERVAL_S)
    est_ms = _time_estimators(pipe)
    loop_cpu_s = 0.0  # the main loop's CPU time (thread time) spent decoding, estimating, logging
    ready.set()
    deadline = time.monotonic() + seconds + 1.5
    while time.monotonic() < deadline:  # the session's main loop (steval_link.live.session.LiveSession._loop)
        chunks = inbox.get_all(0.02)
        t_cpu = time.thread_time()
        if chunks:
            pipe.feed(chunks)
            viewer.log_link(pipe.decoder.stats, clock.now_s())
        pipe.tick(time.monotonic())
        loop_cpu_s += time.thread_time() - t_cpu
        if not writer.is_alive() and not chunks:
            break
    stop.set()
    if reader == "transport":
        thread.stop()
    pipe.flush_view()
    writer.join(2)
    session.close()
    capture.close()
    os.close(master)
    os.close(slave)
    for f in tmp.iterdir():
        f.unlink()
    os.rmdir(tmp)
    lat = np.array(viewer.lat_us[int(RATE_HZ) :], dtype=np.float64) / 1e3  # skip the first second (warm-up)
    return {
        "reader": reader,
        "stream": stream,
        "frames": len(viewer.lat_us),
        "p50": float(np.percentile(lat, 50)),
        "p90": float(np.percentile(lat, 90)),
        "p99": float(np.percentile(lat, 99)),
        "max": float(lat.max()),
        "log_p50": float(np.percentile(viewer.log_ms, 50)),
        "log_p99": float(np.percentile(viewer.log_ms, 99)),
        "batch_mean": float(np.mean(viewer.batch_sizes)),
        "est_p50": float(np.percentile(est_ms, 50)) if est_ms else 0.0,
        "cpu_ms": loop_cpu_s * 1e3 / max(1, len(viewer.lat_us)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--reader", choices=("transport", "own", "both", "inline"), default="both")
    ap.add_argument(
        "--estimators", default=None, help="comma list (default: the live session's defaults that are installed)"
    )
    ap.add_argument("--runs", type=int, default=1, help="repeat each reader this many times")
    ap.add_argument("--stream", choices=("binary", "text", "both"), default="both", help="frames, ST's text, or both")
    args = ap.parse_args()
    from steval_link.estimators import registry

    estimators = registry.parse_names(args.estimators, registry.LIVE_DEFAULT)
    print(f"estimators: {', '.join(estimators) or 'none'}; .rrd sink; {args.seconds:.0f} s per run")
    readers = ["transport", "own"] if args.reader == "both" else [args.reader]
    streams = ["binary", "text"] if args.stream == "both" else [args.stream]
    for r in readers:
        if r == "transport":
            try:
                import steval_link.link.transport  # noqa: F401
            except ImportError:
                print("transport: steval_link.link.transport not present, skipped")
                continue
        figs: dict[str, dict[str, list[float]]] = {s: {"p50": [], "p99": [], "cpu_ms": []} for s in streams}
        for _ in range(args.runs):
            for stream in streams:
                res = (
                    run_inline(args.seconds, estimators, stream)
                    if r == "inline"
                    else run_once(r, args.seconds, estimators, stream)
                )
                for k, v in figs[stream].items():
                    v.append(res[k])
                what = "frames" if stream == "binary" else "ST text lines"
                print(
                    f"reader {res['reader']:9s} {stream:6s}: {res['frames']} {what} at {RATE_HZ} Hz, "
                    f"{'CPU per step' if r == 'inline' else 'latency last byte -> logged'}: p50 {res['p50']:.2f} ms, "
                    f"p90 {res['p90']:.2f} ms, p99 {res['p99']:.2f} ms, "
                    f"max {res['max']:.2f} ms (goal p99 <= 5 ms); log_batch p50 {res['log_p50']:.2f} ms p99 "
                    f"{res['log_p99']:.2f} ms; estimators p50 {res['est_p50']:.2f} ms; {res['batch_mean']:.2f} "
                    f"rows/batch; main loop CPU {res['cpu_ms']:.2f} ms per {what.split()[-1].rstrip('s')}"
                )
        if len(streams) == 2:
            med = {s: {k: float(np.median(v)) for k, v in figs[s].items()} for s in streams}
            t, b = med["text"], med["binary"]
            print(
                f"reader {r} (medians of {args.runs} run(s)): text p50 {t['p50']:.2f} / p99 {t['p99']:.2f} ms, "
                f"binary p50 {b['p50']:.2f} / p99 {b['p99']:.2f} ms: live text adds {t['p50'] - b['p50']:+.2f} ms "
                f"p50, {t['p99'] - b['p99']:+.2f} ms p99 (goal <= 1 ms); main loop CPU {t['cpu_ms']:.2f} ms per "
                f"line vs {b['cpu_ms']:.2f} ms per frame ({t['cpu_ms'] - b['cpu_ms']:+.2f} ms)"
            )


if __name__ == "__main__":
    main()

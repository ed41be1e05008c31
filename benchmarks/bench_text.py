"""Benchmark: decode a one-hour text log at 161.5 lines/s (ST's release 221117 output, ≈ 581 000 lines).

Goal (from the issue): ``decode_bytes`` of the log ≤ 3 s on the CI machine. Also prints the figure for a student's
``Drone_Pitch = %f\\tDrone_Roll = %f\\n\\n`` log and a ``%10.2f`` table, and the StreamDecoder's line rate (the live
path). Run: ``python benchmarks/bench_text.py [--seconds 3600]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from steval_link import constants as C
from steval_link.link.decoder import StreamDecoder, decode_bytes

BANNER = b"STEVAL-FCU001V1 FW rev.1.0 - Sep 2017\r\nLSM6DSL MEMS Accelerometer initialized and enabled\r\n"


def logs(seconds: float, seed: int = 1) -> dict[str, bytes]:
    """The text logs of ``seconds`` at the main loop's rate, a line (or record) each pass."""
    n = int(seconds * C.AHRS_RATE_HZ)
    rng = np.random.default_rng(seed)
    thx = np.cumsum(rng.normal(0, 0.05, n))
    thy = np.cumsum(rng.normal(0, 0.05, n))
    thr = rng.integers(0, 800, n)
    st = BANNER + b"".join(
        b"%d\t%d\t%d\t%d\t%f\t%f\t%f\t%f\t%f\n" % (0, 0, 0, thr[i], 1200.0, thx[i], thy[i], 0.0, 0.0) for i in range(n)
    )
    pitch = b"".join(b"Drone_Pitch = %f\tDrone_Roll = %f\n\n" % (thx[i], thy[i]) for i in range(n))
    table = b"".join(b"%10.2f\t%10.2f\t%10.2f\n" % (thx[i], thy[i], thr[i]) for i in range(n))
    return {"ST 221117 TSV": st, "Drone_Pitch lines": pitch, "%10.2f table": table}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3600.0, help="length of the log, s (default one hour)")
    args = ap.parse_args()
    for name, data in logs(args.seconds).items():
        decode_bytes(data[:300_000])  # imports (pandas) and first-use costs out of the figure
        t0 = time.perf_counter()
        tel = decode_bytes(data)
        dt = time.perf_counter() - t0
        print(
            f"{name}: {len(data) / 1e6:.1f} MB, {tel.stats.text_records} records, {len(tel.text_series.names)} "
            f"series: decode_bytes {dt:.2f} s (goal ≤ 3 s for one hour)"
        )
    data = logs(min(args.seconds, 60.0))["ST 221117 TSV"]
    dec = StreamDecoder()
    t0 = time.perf_counter()
    for i in range(0, len(data), 64):  # live: a chunk a few lines long
        dec.feed(data[i : i + 64])
    dec.finish()
    dt = time.perf_counter() - t0
    per_line_us = 1e6 * dt / dec.stats.text_records
    print(f"StreamDecoder (live path): {dec.stats.text_records / dt:,.0f} lines/s ({per_line_us:.1f} µs a line)")
    live_line_cost(data)


def live_line_cost(data: bytes) -> None:
    """What live text adds to a processing round: ``LivePipeline.feed`` of one line as it arrives, through the
    decoder to the Rerun live logger (an in-memory recording), per line: p50 / p99 / max, ms."""
    import rerun as rr  # the live logger's own dependency

    from steval_link.live.pipeline import LivePipeline
    from steval_viewer.live_log import LiveLogger

    rec = rr.RecordingStream("bench_text")
    rec.memory_recording()
    pipe = LivePipeline([], LiveLogger(rec))
    lines = data.split(b"\n")[:3000]
    t_unix = time.time()
    cost = []
    for i, line in enumerate(lines):
        t0 = time.perf_counter()
        pipe.feed([(line + b"\n", t_unix + i / C.AHRS_RATE_HZ)])
        pipe.flush_view()
        cost.append(time.perf_counter() - t0)
    ms = 1e3 * np.array(cost[100:])  # after the shape is learned
    print(
        f"live, one line a round through the decoder and the Rerun logger: p50 {np.percentile(ms, 50):.3f} ms, "
        f"p99 {np.percentile(ms, 99):.3f} ms, max {ms.max():.3f} ms (goal: p99 adds ≤ 1 ms)"
    )


if __name__ == "__main__":
    main()

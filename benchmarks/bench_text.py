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


class _NoLogger:
    """A logger that takes everything and does nothing: the decoder and the pipeline's own cost."""

    def __getattr__(self, name):
        return lambda *args, **kwargs: None


def round_cost_ms(chunks: list[bytes], rerun: bool = True) -> np.ndarray:
    """``LivePipeline.feed`` of one chunk a processing round, through the decoder to the Rerun live logger (an
    in-memory recording; ``rerun`` False: a logger that does nothing), no estimators: the cost of each round after
    the first 100, ms."""
    import rerun as rr  # the live logger's own dependency

    from steval_link.live.pipeline import LivePipeline
    from steval_viewer.live_log import LiveLogger

    if rerun:
        rec = rr.RecordingStream("bench_text")
        rec.memory_recording()
    pipe = LivePipeline([], LiveLogger(rec) if rerun else _NoLogger())
    t_unix = time.time()
    cost = []
    for i, chunk in enumerate(chunks):
        t0 = time.perf_counter()
        pipe.feed([(chunk, t_unix + i / C.AHRS_RATE_HZ)])
        pipe.flush_view()
        cost.append(time.perf_counter() - t0)
    return 1e3 * np.array(cost[100:])  # after the shape is learned


def live_line_cost(data: bytes) -> None:
    """What live text adds to a processing round: one ST line a round against one binary attitude frame a round
    (the same pipeline and logger): p50 / p99 / max, ms, and the difference."""
    from steval_link.link import protocol as P

    lines = [line + b"\n" for line in data.split(b"\n")[2:3002]]
    text = round_cost_ms(lines)
    frames = [
        P.encode_attitude(
            t_us=int(i * 1e6 / C.AHRS_RATE_HZ), acc_mg=(10.0, -20.0, 1000.0), gyro_mdps=(100.0, 0.0, -50.0),
            q_wxyz=(1.0, 0.0, 0.0, 0.0), thz_rad=0.0, seq=i, thr=0,
        )
        for i in range(3000)
    ]  # fmt: skip
    binary = round_cost_ms(frames)
    for rerun, (b, t) in ((True, (binary, text)), (False, (round_cost_ms(frames, False), round_cost_ms(lines, False)))):
        where = "the decoder and the Rerun logger" if rerun else "the decoder and the pipeline only (no logger)"
        for name, ms in (("binary frame", b), ("ST text line", t)):
            print(
                f"live, one {name} a round through {where}: p50 {np.percentile(ms, 50):.3f} ms, "
                f"p99 {np.percentile(ms, 99):.3f} ms, max {ms.max():.3f} ms"
            )
        p50, p99 = (np.percentile(t, q) - np.percentile(b, q) for q in (50, 99))
        print(f"  live text adds {p50:+.3f} ms p50, {p99:+.3f} ms p99 a round (goal: p99 ≤ 1 ms)")


if __name__ == "__main__":
    main()

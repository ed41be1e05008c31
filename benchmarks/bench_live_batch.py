"""Cost of logging one live processing round to Rerun: one Arrow record batch for every entity
(``steval_viewer.record_batch.RowBatch``, what ``steval live`` does) against the public ``rr.send_columns`` once
per entity. Prints the median and p99 per round, in ms, for ``--entities`` scalar series of ``--frames`` frames
each, into an ``.rrd`` file sink. This is the measurement behind ``record_batch``'s use of Rerun's column metadata.

    python benchmarks/bench_live_batch.py                 # 22 entities, 3 frames a round (~20 ms of stream)
    python benchmarks/bench_live_batch.py --frames 30
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import rerun as rr

from steval_viewer.columns import Times
from steval_viewer.record_batch import RowBatch


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--entities", type=int, default=22)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=1000)
    args = ap.parse_args()
    rec = rr.RecordingStream("bench-live-batch", make_default=False, make_thread_default=False)
    rec.set_sinks(rr.FileSink(str(Path(tempfile.mkdtemp()) / "bench.rrd")))
    paths = [f"plots/series_{i}" for i in range(args.entities)]
    n = args.frames
    rng = np.random.default_rng(0)
    cache: dict = {}

    def times(k: int) -> Times:
        t = (np.arange(n) + k * n) / 161.5
        return Times(t, t + 0.01, np.arange(n) + k * n)

    def record_batch(k: int) -> None:
        batch = RowBatch(times(k), {}, cache)
        for p in paths:
            batch.scalars(p, rng.random(n))
        batch.send(rec)

    def send_columns(k: int) -> None:
        t = times(k)
        idx = [
            rr.TimeColumn("fw_time", duration=t.t_fw_s),
            rr.TimeColumn("host_time", duration=t.t_host_s),
            rr.TimeColumn("ahrs_step", sequence=t.step),
        ]
        for p in paths:
            rec.send_columns(p, indexes=idx, columns=rr.Scalars.columns(scalars=rng.random(n)))

    print(f"{args.entities} entities x {n} frames per round, {args.rounds} rounds, .rrd file sink")
    for fn in (record_batch, send_columns, record_batch, send_columns):
        ms = []
        for k in range(args.rounds):
            t0 = time.perf_counter()
            fn(k)
            ms.append((time.perf_counter() - t0) * 1e3)
        ms = np.array(ms[args.rounds // 10 :])
        print(f"{fn.__name__:>13}: median {np.median(ms):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms per round")
    rec.disconnect()


if __name__ == "__main__":
    main()

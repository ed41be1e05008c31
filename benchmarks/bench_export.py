"""Benchmark: a 1-hour capture (≈ 581 000 attitude frames + 3600 status frames, as bench_decode.py makes it) to a
MATLAB ``.mat`` and to an ``.mcap`` file, as ``steval export --mat`` / ``--mcap`` write them.

Goal (issue 26): ≤ 10 s each on the 2-core CI machine. Decoding is not counted (bench_decode.py measures it).
Prints wall time and the process's CPU time (the two part when other jobs share the cores).
Run: ``python benchmarks/bench_export.py [--seconds 3600]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from bench_decode import synthetic_stream

from steval_link.analysis.frame_tables import frame_tables, header_of, settings_of
from steval_link.analysis.mat_export import write_mat
from steval_link.analysis.mcap_export import write_mcap
from steval_link.cli.export import write_atomic
from steval_link.link.decoder import decode_bytes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=3600.0)
    args = ap.parse_args()
    tel = decode_bytes(synthetic_stream(args.seconds))
    tel.source = {"path": "synthetic", "kind": "raw", "header": {}}
    print(f"capture: {args.seconds:.0f} s, {len(tel.attitude)} attitude + {len(tel.status)} status frames")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "flight.mat"
        t0, c0 = time.perf_counter(), time.process_time()
        tables = frame_tables(tel)
        write_atomic(out, "--mat", lambda f: write_mat(tables, settings_of(tel), header_of(tel), f))
        t_mat, c_mat = time.perf_counter() - t0, time.process_time() - c0
        print(f".mat:  {t_mat:.2f} s ({c_mat:.2f} s CPU), {out.stat().st_size / 1e6:.0f} MB  [goal ≤ 10 s]")
        out = Path(tmp) / "flight.mcap"
        t0, c0 = time.perf_counter(), time.process_time()
        counts: dict[str, int] = {}
        write_atomic(
            out, "--mcap", lambda f: counts.update(write_mcap(tel, f, metadata={"settings": settings_of(tel)}))
        )
        t_mcap, c_mcap = time.perf_counter() - t0, time.process_time() - c0
        print(
            f".mcap: {t_mcap:.2f} s ({c_mcap:.2f} s CPU), {out.stat().st_size / 1e6:.0f} MB, "
            f"{sum(counts.values())} messages "
            f"({sum(counts.values()) / t_mcap / 1e3:.0f} k/s)  [goal ≤ 10 s]"
        )


if __name__ == "__main__":
    main()

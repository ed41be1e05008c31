"""Accuracy of every estimator on the BROAD trials: inclination RMSE (deg) per trial, the mean over 02/07/15/24 and
over all trials, and each estimator's speed (steps/s, Python per step unless the estimator has a batch path).

    python benchmarks/bench_accuracy.py [DATA_DIR] [--own-rate]

DATA_DIR defaults to ../shared/datasets/broad next to the project. The trials go through the STEVAL sensor
pipeline model (161.5 Hz AHRS steps) unless --own-rate is given (285.7 Hz, no pipeline).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from steval_link.analysis import evaluate as ev
from steval_link.emulation import broad


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "data",
        nargs="?",
        type=Path,
        default=Path(__file__).resolve().parents[1] / ".." / "shared" / "datasets" / "broad",
    )
    ap.add_argument("--own-rate", action="store_true", help="run at the trials' own rate, without the pipeline")
    args = ap.parse_args(argv)
    paths = sorted(args.data.glob("*.npz"))
    if not paths:
        print(f"no BROAD trials in {args.data}", file=sys.stderr)
        return 2
    results = []
    t_pipe = 0.0
    for p in paths:
        trial = broad.load_trial(p)
        t0 = time.perf_counter()
        view = broad.own_rate_view(trial) if args.own_rate else broad.steval_view(trial)
        t_pipe += time.perf_counter() - t0
        specs = ev.default_specs(view.rate_hz, own_rate=args.own_rate)
        results.append(ev.evaluate_view(view, specs, trial.name))
        print(f"  {trial.name}: {view.acc_mg.shape[0]} steps", file=sys.stderr)
    mode = "own rate, 285.7 Hz" if args.own_rate else "STEVAL pipeline, 161.5 Hz"
    print(f"BROAD inclination accuracy ({mode})")
    print(ev.format_table(results))
    if not args.own_rate:
        n_ticks = sum(r.t_s.shape[0] for r in results) * 5
        print(f"\nsensor pipeline model: {n_ticks / t_pipe:,.0f} ticks/s (resampling, quantisation, ISR, averaging)")
    print("\nspeed (steps/s, median over trials):")
    labels = ev.summary(results)["estimators"]
    for k in labels:
        v = np.median([r.steps_per_s[k] for r in results if k in r.steps_per_s])
        print(f"  {k:<18} {v:>12,.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Benchmark: the plug-in path's overhead per step against a built-in estimator.

A user's estimator runs behind ``steval_link.estimators.plugins.Guarded`` (non-finite rows skipped, output shapes
checked, exceptions turned into one line). This measures what that costs per AHRS step:

* the same filter (``ekf3``) as a built-in and as a plug-in reference (``steval_link.estimators.ekf3:Ekf3``), each
  with its own bulk ``run()`` (the C loop): the guard's cost around a bulk run;
* ``ekf3``'s Python ``step()`` called row by row by the base class's ``run()`` (the built-in path) and by the
  guard's loop (the plug-in path of an estimator without its own ``run()``);
* a trivial estimator (a constant quaternion): a bare Python loop against the guard's loop, the overhead alone;
* the starter of ``steval estimator new`` through the guard (steps/s; live needs ≥ 323);
* loading a file reference (``registry.resolve`` + ``create``) once.

Run: ``python benchmarks/bench_plugin.py [--steps 50000]``. Prints µs per step (best of 3).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from steval_link.estimators import registry
from steval_link.estimators.base import Estimator
from steval_link.estimators.ekf3 import Ekf3
from steval_link.estimators.plugins import Guarded
from steval_link.link.capture import demo_capture_path
from steval_link.link.load import load_telemetry


class Trivial:
    """The cheapest possible estimator: the identity attitude."""

    Q = np.array([1.0, 0.0, 0.0, 0.0])

    def reset(self) -> None:
        pass

    def step(self, acc_mg, gyro_mdps, thr=0):
        return self.Q


class StepOnly:
    """``ekf3`` seen as a plug-in without a run() of its own (step() and reset() only)."""

    def __init__(self) -> None:
        self.inner = Ekf3()

    def reset(self) -> None:
        self.inner.reset()

    def step(self, acc_mg, gyro_mdps, thr=0):
        return self.inner.step(acc_mg, gyro_mdps, thr)


def inputs(n: int):
    a = load_telemetry(demo_capture_path()).attitude
    reps = -(-n // len(a))
    acc = np.tile(np.asarray(a.acc_mg), (reps, 1))[:n]
    gyro = np.tile(np.asarray(a.gyro_mdps), (reps, 1))[:n]
    thr = np.tile(np.asarray(a.thr, np.int64), reps)[:n]
    return acc, gyro, thr


def best_us_per_step(fn, n: int, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return 1e6 * best / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=50_000, help="steps per run (the demo capture repeated)")
    args = ap.parse_args()
    n = args.steps
    acc, gyro, thr = inputs(n)
    acc64, gyro64 = acc.astype(np.float64), gyro.astype(np.float64)
    rows = []

    builtin = best_us_per_step(lambda: registry.create("ekf3").run(acc, gyro, thr), n)
    plugin = best_us_per_step(lambda: registry.create("steval_link.estimators.ekf3:Ekf3").run(acc, gyro, thr), n)
    rows.append(("ekf3 run() (C loop): built-in", builtin, ""))
    rows.append(("ekf3 run() (C loop): as a plug-in", plugin, f"+{plugin - builtin:.3f} µs/step"))

    m = min(n, 20_000)  # the Python step() paths are slower: fewer steps
    base = best_us_per_step(lambda: Estimator.run(Ekf3(), acc[:m], gyro[:m], thr[:m]), m)
    guarded = best_us_per_step(lambda: Guarded(StepOnly(), "ekf3-step").run(acc[:m], gyro[:m], thr[:m]), m)
    rows.append(("ekf3 step() loop: built-in (Estimator.run)", base, ""))
    rows.append(("ekf3 step() loop: as a plug-in (guard)", guarded, f"{guarded - base:+.3f} µs/step"))

    def bare():
        q = np.empty((n, 4))
        est = Trivial()
        t_l = thr.tolist()
        for k in range(n):
            q[k] = est.step(acc64[k], gyro64[k], t_l[k])

    bare_us = best_us_per_step(bare, n)
    trivial = best_us_per_step(lambda: Guarded(Trivial(), "trivial").run(acc, gyro, thr), n)
    rows.append(("trivial estimator: bare Python loop", bare_us, ""))
    rows.append(("trivial estimator: the guard's loop + angles", trivial, f"+{trivial - bare_us:.3f} µs/step"))

    starter = Path(__file__).resolve().parents[1] / "steval_link" / "estimators" / "starter_ekf.py"
    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "my_ekf.py"
        f.write_text(starter.read_text())
        t0 = time.perf_counter()
        sel = registry.resolve(f"{f}:MyEkf")
        registry.create(sel)
        load_ms = 1e3 * (time.perf_counter() - t0)
        k = min(n, 10_000)
        mine = best_us_per_step(lambda: registry.create(sel).run(acc[:k], gyro[:k], thr[:k]), k, repeat=2)
    rows.append(("starter MyEkf (steval estimator new), guarded", mine, f"{1e6 / mine:,.0f} steps/s"))

    print(f"{n} steps (recordings/demo.stv repeated); µs per step, best of 3")
    width = max(len(r[0]) for r in rows)
    for name, us, note in rows:
        print(f"{name:<{width}}  {us:9.3f}  {note}")
    print(f"loading a file reference (resolve + create): {load_ms:.1f} ms once")


if __name__ == "__main__":
    main()

"""Benchmark: steps/s of every estimator in the registry over a 1-hour flight (≈ 581 000 AHRS steps).

Goal (from the issue): the bit-exact ST Mahony port re-runs a 1-hour flight in a few seconds, ≥ 1 M steps/s
(native loop). Every registered estimator that can be built here is timed through ``registry.create(name).run``;
``st-mahony`` is timed on both its native and its pure-numpy loop. Estimators too slow to run the whole flight
within ``--budget`` seconds are timed on a subset and the full-flight time is extrapolated (marked ``*``).
Also times ``quaternion_to_euler`` and ``replay_firmware`` on the whole flight.

Run: ``python benchmarks/bench_estimators.py [--steps 581000] [--budget 20]``.
"""

from __future__ import annotations

import argparse
import time
from types import SimpleNamespace

import numpy as np

from steval_link import constants as C
from steval_link.estimators import firmware_replay, registry, st_mahony


def flight_inputs(n: int, seed: int = 1):
    """Plausible flight inputs: tilting slowly (random-walk gyro), ±1 g plus vibration, throttle 0 then 450."""
    rng = np.random.default_rng(seed)
    gyro = np.clip(np.cumsum(rng.normal(0, 200, (n, 3)), axis=0), -200_000, 200_000).astype(np.float32)
    acc = (rng.normal([0, 0, 1000], 40, (n, 3))).astype(np.float32)
    thr = np.where(np.arange(n) < min(n, 3230), 0, 450).astype(np.int64)
    return acc, gyro, thr


def time_run(make, acc, gyro, thr, n_total: int, budget_s: float):
    """(steps/s, steps actually run, extrapolated?) for ``make().run`` on the first steps of the inputs."""
    probe = min(n_total, 2000)
    est = make()
    t0 = time.perf_counter()
    est.run(acc[:probe], gyro[:probe], thr[:probe])
    rate = probe / max(time.perf_counter() - t0, 1e-9)
    n = n_total if n_total / rate <= budget_s else max(probe, int(rate * budget_s / 2))
    est = make()
    t0 = time.perf_counter()
    est.run(acc[:n], gyro[:n], thr[:n])
    dt = time.perf_counter() - t0
    return n / dt, n, n < n_total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=int(round(3600 * C.AHRS_RATE_HZ)), help="steps of the flight")
    ap.add_argument("--budget", type=float, default=20.0, help="seconds allowed per estimator before extrapolating")
    args = ap.parse_args()
    n = args.steps
    acc, gyro, thr = flight_inputs(n)
    print(f"{n} AHRS steps ({n / C.AHRS_RATE_HZ / 60:.1f} min of flight at {C.AHRS_RATE_HZ:.1f} Hz)")
    print(f"{'estimator':<24} {'steps/s':>12} {'1-h flight':>11}  note")

    cases = []
    for name in registry.names():
        if not registry.is_available(name):
            print(f"{name:<24} {'-':>12} {'-':>11}  not available here (missing optional dependency)")
            continue
        if name == "st-mahony":
            if st_mahony.NATIVE_AVAILABLE:
                cases.append(("st-mahony (native)", lambda: registry.create("st-mahony", native=True)))
            else:
                print(f"{'st-mahony (native)':<24} {'-':>12} {'-':>11}  extension not built")
            cases.append(("st-mahony (pure)", lambda: registry.create("st-mahony", native=False)))
        else:
            cases.append((name, lambda name=name: registry.create(name)))

    for label, make in cases:
        try:
            rate, ran, extrapolated = time_run(make, acc, gyro, thr, n, args.budget)
        except Exception as exc:  # a benchmark reports, it does not stop at the first broken estimator
            print(f"{label:<24} {'-':>12} {'-':>11}  failed: {type(exc).__name__}: {exc}")
            continue
        note = f"* measured on {ran} steps, extrapolated" if extrapolated else ""
        print(f"{label:<24} {rate:>12,.0f} {n / rate:>10.2f}s  {note}")

    q, _, _, _ = st_mahony.run(acc, gyro, thr)
    t0 = time.perf_counter()
    st_mahony.quaternion_to_euler(q)
    print(
        f"{'quaternion_to_euler':<24} {n / (time.perf_counter() - t0):>12,.0f} "
        f"{time.perf_counter() - t0:>10.2f}s  (vectorised, bit-exact)"
    )

    steps = np.arange(n, dtype=np.int64)
    thx, thy = st_mahony.quaternion_to_euler(q)
    att = SimpleNamespace(step=steps, acc_mg=acc, gyro_mdps=gyro, thr=thr, q_wxyz=q, thx_rad=thx, thy_rad=thy)
    t0 = time.perf_counter()
    rep = firmware_replay.replay_firmware(SimpleNamespace(attitude=att, status=None))
    dt = time.perf_counter() - t0
    print(f"{'replay_firmware':<24} {n / dt:>12,.0f} {dt:>10.2f}s  ({rep.n_bit_exact} of {n} rows bit-exact)")


if __name__ == "__main__":
    main()

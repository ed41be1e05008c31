"""Benchmark: log a 1-hour capture (581 000 attitude frames at 161.5 Hz) with every series to an .rrd.

Measures ``steval_viewer.replay_log.log_replay`` (all entities: firmware attitude, gravity arrow, angles, raw
sensors, throttle, link health, and five host estimates: ST-Mahony replica, EKF3, MEKF, accelerometer-only, VQF-like)
from in-memory arrays to a finished .rrd file (flushed and closed). The estimators themselves are timed by their own
benchmarks; here the estimate arrays are synthetic so only the viewer side is measured.

Goal: ≤ 15 s on the project's 2-core machine.

    python benchmarks/bench_viewer_replay.py [--frames 581000] [--out /tmp/bench.rrd]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

RATE_HZ = 161.5


def synthetic_telemetry(n: int, seed: int = 1) -> SimpleNamespace:
    """A Telemetry-shaped object of ``n`` attitude rows: a wobbling drone, a few NaN roll values, drops."""
    rng = np.random.default_rng(seed)
    step = np.arange(n, dtype=np.int64)
    step[n // 2 :] += 7  # a gap of 7 frames
    t = step / RATE_HZ + 2.0
    pitch = 0.4 * np.sin(0.7 * t) + 0.01 * rng.standard_normal(n)
    roll = 0.3 * np.sin(0.45 * t + 1.0)
    cp, sp, cr, sr = np.cos(pitch / 2), np.sin(pitch / 2), np.cos(roll / 2), np.sin(roll / 2)
    q = np.stack([cp * cr, sp * cr, cp * sr, -sp * sr], axis=1).astype(np.float32)
    thy = roll.astype(np.float32)
    thy[::5000] = np.nan
    acc = np.stack([1000 * np.sin(roll), -1000 * np.sin(pitch), 1000 * np.cos(pitch) * np.cos(roll)], 1)
    acc = (acc + 5 * rng.standard_normal((n, 3))).astype(np.float32)
    att = SimpleNamespace(
        step=step,
        seq=(step % 65536).astype(np.uint16),
        t_fw_s=t,
        t_host_s=t - 2.0 + 0.003 + 0.001 * rng.random(n),
        acc_mg=acc,
        gyro_mdps=(1000 * rng.standard_normal((n, 3))).astype(np.float32),
        thr=np.where(t > 60, 400, 0).astype(np.int16),
        q_wxyz=q,
        thz_rad=(0.01 * t).astype(np.float32),
        thx_rad=pitch.astype(np.float32),
        thy_rad=thy,
        exact=np.ones(n, dtype=bool),
    )
    ns = n // 162
    si = np.arange(ns) * 162
    status = SimpleNamespace(
        t_fw_s=t[si],
        t_host_s=att.t_host_s[si],
        step=step[si],
        cyc_min=np.full(ns, 9000),
        cyc_mean=np.full(ns, 9500),
        cyc_max=np.full(ns, 12000),
        cyc_n=np.full(ns, 161),
        tx_dropped=np.zeros(ns),
        queue_peak=np.full(ns, 116),
        q_wxyz=att.q_wxyz[si],
        int_xyz=np.zeros((ns, 3), np.float32),
        kp_ground=np.full(ns, 10.0, np.float32),
        kp_flight=np.full(ns, 0.4, np.float32),
        ki=np.full(ns, 0.1, np.float32),
        dt_s=np.full(ns, 0.00625, np.float32),
        min_thr=np.full(ns, 200, np.int16),
        flags=np.zeros(ns, np.uint16),
    )
    return SimpleNamespace(
        attitude=att,
        status=status,
        text=[(0.01, "STEVAL-FCU001V1 telemetry v1.0.0")],
        stats=SimpleNamespace(crc_failures=0),
    )


def estimate(tel: SimpleNamespace, scale: float, rng) -> SimpleNamespace:
    att = tel.attitude
    n = len(att.t_fw_s)
    return SimpleNamespace(
        q_wxyz=att.q_wxyz,
        thx_rad=(att.thx_rad * scale).astype(np.float32),
        thy_rad=(np.nan_to_num(att.thy_rad) * scale).astype(np.float32),
        thz_rad=att.thz_rad,
        valid=np.arange(n) > 10,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=581_000)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--run-estimators",
        default=None,
        metavar="NAMES",
        help="comma-separated registry names to really run (e.g. accel,vqf,ekf3,mekf) and time, plus the seeded "
        "firmware replica; default: synthetic estimate arrays (viewer side only)",
    )
    args = ap.parse_args()

    from steval_viewer.replay_log import log_replay
    from steval_viewer.rrd_check import read_rrd
    from steval_viewer.sink_options import SinkOptions
    from steval_viewer.sinks import open_session

    rng = np.random.default_rng(2)
    tel = synthetic_telemetry(args.frames)
    if args.run_estimators:
        from steval_link.estimators.firmware_replay import replay_firmware
        from steval_link.estimators.registry import create

        t = time.perf_counter()
        replica = replay_firmware(tel)
        print(f"estimator st-mahony replica (seeded replay): {time.perf_counter() - t:.2f} s")
        estimates = {}
        a = tel.attitude
        for name in args.run_estimators.split(","):
            t = time.perf_counter()
            estimates[name] = create(name).run(a.acc_mg, a.gyro_mdps, a.thr)
            print(f"estimator {name}: {time.perf_counter() - t:.2f} s")
    else:
        replica = estimate(tel, 1.0, rng)
        estimates = {
            name: estimate(tel, s, rng) for name, s in (("ekf3", 0.98), ("mekf", 0.97), ("accel", 1.05), ("vqf", 0.99))
        }
    out = args.out or Path(tempfile.mkdtemp()) / "bench_replay.rrd"

    t0 = time.perf_counter()
    session = open_session(SinkOptions(rrd=out), recording_name="bench")
    summary = log_replay(session.rec, tel, estimates, replica=replica)
    t_logged = time.perf_counter()
    session.close()
    t_done = time.perf_counter()

    size_mb = os.path.getsize(out) / 1e6
    print(
        f"frames: {args.frames} ({args.frames / RATE_HZ / 3600:.2f} h at {RATE_HZ} Hz), "
        f"entities with samples: {len(summary.samples)}, sources: {', '.join(summary.sources)}"
    )
    print(
        f"log_replay calls: {t_logged - t0:.2f} s; flushed .rrd ({size_mb:.0f} MB): {t_done - t0:.2f} s (goal <= 15 s)"
    )
    t1 = time.perf_counter()
    info = read_rrd(out)
    print(
        f"read back: {time.perf_counter() - t1:.2f} s, "
        f"firmware pitch samples {info.samples.get('plots/pitch_thx_deg/firmware')}, blueprint {info.has_blueprint}"
    )
    if args.out is None:
        out.unlink()
    sys.exit(0)


if __name__ == "__main__":
    main()

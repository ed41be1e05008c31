"""Benchmark: decode a clean 1-hour binary capture (≈ 581 000 attitude frames + 3600 status frames).

Goal (from the issue): ``decode_bytes`` ≤ 3 s on the CI machine. Also prints the StreamDecoder throughput and the
``.stv`` read time. Run: ``python benchmarks/bench_decode.py [--seconds 3600]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.link import protocol as P
from steval_link.link.capture import CaptureWriter, read_capture
from steval_link.link.decoder import StreamDecoder, decode_bytes
from steval_link.link.load import load_telemetry


def synthetic_stream(seconds: float, seed: int = 1) -> bytes:
    """Binary stream of ``seconds`` of flight: attitude every AHRS step, a status frame after every 161st."""
    n = int(seconds * C.AHRS_RATE_HZ)
    rng = np.random.default_rng(seed)
    rec = np.zeros(n, P.ATTITUDE_DTYPE)
    rec["t_us"] = (np.arange(n) * C.AHRS_PERIOD_S * 1e6).astype(np.int64) % P.T_US_MODULUS
    rec["acc_mg"] = rng.normal([0, 0, 1000], 20, (n, 3)).astype(np.float32)
    rec["gyro_mdps"] = rng.normal(0, 500, (n, 3)).astype(np.float32)
    rec["q_wxyz"] = np.array([0.9983, 0.01, -0.02, 0.0], np.float32)
    rec["thz_rad"] = rng.normal(0, 1, n).astype(np.float32)
    rec["seq"] = np.arange(n) % P.SEQ_MODULUS
    rec["thr"] = 0
    att = np.frombuffer(P.encode_attitude_block(rec), np.uint8).reshape(n, P.ATTITUDE_FRAME_SIZE)
    out = []
    every = 161
    for i in range(0, n, every):
        out.append(att[i : i + every].tobytes())
        last = min(i + every, n) - 1
        out.append(P.encode_status(step=last, t_us=int(rec["t_us"][last]), q_wxyz=[1, 0, 0, 0], int_xyz=[0, 0, 0]))
    return b"".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=3600.0)
    args = ap.parse_args()
    data = synthetic_stream(args.seconds)
    print(f"stream: {args.seconds:.0f} s, {len(data) / 1e6:.1f} MB")

    t0 = time.perf_counter()
    tel = decode_bytes(data)
    t_bulk = time.perf_counter() - t0
    print(
        f"decode_bytes: {t_bulk:.2f} s for {len(tel.attitude)} attitude + {len(tel.status)} status frames "
        f"({len(tel.attitude) / t_bulk / 1e3:.0f} k frames/s)  [goal ≤ 3 s]"
    )

    n_stream = min(len(data), 4_000_000)
    sd = StreamDecoder()
    t0 = time.perf_counter()
    for i in range(0, n_stream, 4096):
        sd.feed(data[i : i + 4096])
    sd.finish()
    t_stream = time.perf_counter() - t0
    print(
        f"StreamDecoder: {n_stream / t_stream / 1e6:.2f} MB/s in 4 kB chunks "
        f"({sd.stats.attitude / t_stream / 1e3:.0f} k frames/s; the live link needs 0.01 MB/s at 115200 baud)"
    )

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.stv"
        t0 = time.perf_counter()
        with CaptureWriter(path, port="bench", baud=115200) as w:
            chunk = 160  # about what a USB-serial adapter returns per read at 115200 baud
            for i, j in enumerate(range(0, len(data), chunk)):
                w.write(data[j : j + chunk], t_host_s=j / 11520.0)
        t_write = time.perf_counter() - t0
        t0 = time.perf_counter()
        cap = read_capture(path)
        t_read = time.perf_counter() - t0
        t0 = time.perf_counter()
        tel2 = load_telemetry(path)
        t_load = time.perf_counter() - t0
        print(
            f"capture: write {t_write:.2f} s ({path.stat().st_size / 1e6:.1f} MB, {len(cap.chunk_offsets)} chunks "
            f"of {chunk} bytes), read_capture {t_read:.2f} s, load_telemetry (read + decode + host times) "
            f"{t_load:.2f} s ({len(tel2.attitude)} attitude frames)"
        )


if __name__ == "__main__":
    main()

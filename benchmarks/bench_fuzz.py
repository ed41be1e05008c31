"""Benchmark: a loose wire on header P7. Damage a capture with fresh random seeds and count fake frames.

The capture's attitude and status payloads are repeated (step counter and firmware time continued, so every frame
is unique and plausible) up to ``--frames`` frames, re-encoded as protocol v2 (or v1 with ``--v1``), damaged in
blocks by :func:`steval_link.emulation.line_damage.damage` (one event every 200-5000 bytes: 60 % a bit flip, 20 % a
cut of 1-16 bytes, 20 % a burst of 1-64 random bytes; a fresh seed per run unless ``--seed``), decoded by
``decode_bytes`` and scored: sent, recovered (decoded and sent) and fake (decoded and never sent) frames.

Issue #16's goal: 0 fake frames in ≥ 10⁷ fuzzed v2 frames and ≥ 93 % recovered. Since issue #24 the values of a
v2 frame no longer guard it (a diverged filter's NaN is kept): the CRC-32 and the sequence/time gate do. The run
prints the damaged candidates that reached the frame check (``crc_failures``) and the false accepts CRC-32 alone
would let through among them, ≈ candidates × 2⁻³².
Run: ``python benchmarks/bench_fuzz.py [--frames 10000000] [--capture recordings/demo.stv] [--v1]``.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from steval_link.emulation.line_damage import FuzzScore, damage, long_stream, payload_records, score
from steval_link.link import protocol as P
from steval_link.link.decoder import decode_bytes
from steval_link.link.load import load_telemetry


def to_v1(data: bytes) -> bytes:
    """Re-encode a v2 stream's frames as protocol v1 (CRC-16), for the comparison run."""
    tel = decode_bytes(data)
    out = bytearray()
    # the frames in stream order, by their offsets
    rows = [(int(o), P.TYPE_ATTITUDE, i) for i, o in enumerate(tel.attitude.offset)]
    rows += [(int(o), P.TYPE_STATUS, i) for i, o in enumerate(tel.status.offset)]
    rows.sort()
    for off, t, _ in rows:
        ln = data[off + 3]
        out += P.encode_frame(t, data[off + 4 : off + 4 + ln], version=1)
    return bytes(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10_000_000, help="attitude frames to send (default 10^7)")
    ap.add_argument("--block", type=int, default=200_000, help="frames per damaged block")
    ap.add_argument("--capture", default="recordings/demo.stv")
    ap.add_argument("--seed", type=int, default=None, help="fixed seed (default: fresh from the OS)")
    ap.add_argument("--v1", action="store_true", help="send protocol v1 (CRC-16) instead, for comparison")
    args = ap.parse_args()
    seed = args.seed if args.seed is not None else int.from_bytes(os.urandom(8), "little")
    rng = np.random.default_rng(seed)
    att, sta = payload_records(load_telemetry(args.capture))
    total = FuzzScore()
    damage_events = 0
    bytes_sent = 0
    t0 = time.perf_counter()
    t_decode = 0.0
    reps_per_block = max(1, args.block // len(att))
    rep = 0
    fakes: list[bytes] = []
    candidates = 0  # damaged candidates that reached the frame check (and failed it)
    while total.sent < args.frames:
        data, payloads = long_stream(att, sta, reps_per_block * len(att), start_rep=rep)
        rep += reps_per_block
        if args.v1:
            data = to_v1(data)
        hurt, counts = damage(data, rng)
        bytes_sent += len(data)
        damage_events += counts.flips + counts.cuts + counts.bursts
        t1 = time.perf_counter()
        tel = decode_bytes(hurt)
        t_decode += time.perf_counter() - t1
        candidates += tel.stats.crc_failures
        sc, fk = score(payloads, tel)
        total.add(sc)
        fakes += fk
        print(
            f"  {total.sent:>10} sent  {total.recovered:>10} recovered ({100 * total.recovered_ratio:.2f} %)  "
            f"{total.fake} fake  [{time.perf_counter() - t0:.0f} s]",
            flush=True,
        )
    wall = time.perf_counter() - t0
    print(f"protocol v{1 if args.v1 else 2}, capture {args.capture}, seed {seed}")
    print(f"frames sent (attitude + status): {total.sent}")
    per = bytes_sent / max(1, damage_events)
    print(f"bytes sent: {bytes_sent}, damage events: {damage_events} (one per {per:.0f} bytes)")
    print(f"recovered: {total.recovered} ({100 * total.recovered_ratio:.2f} %)")
    print(f"fake frames: {total.fake}")
    bits = 16 if args.v1 else 32
    print(
        f"damaged candidates checked: {candidates}; expected false accepts of CRC-{bits} alone: "
        f"{candidates * 2.0**-bits:.2g} (candidates × 2^-{bits}); the sequence/time gate stops most of those"
    )
    print(f"run time: {wall:.0f} s (decode {t_decode:.0f} s)")
    for f in fakes[:5]:
        print("  fake payload:", f.hex())


if __name__ == "__main__":
    main()

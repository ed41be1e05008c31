"""Firmware-in-the-loop benchmark: how fast the emulated board runs a firmware, and what one AHRS step costs.

Builds the reference firmware (``make -C firmware_patch reference`` into a temporary directory; or pass ELF paths,
e.g. a build of ST's release made elsewhere), then for each ELF:
- emulated seconds per wall second and per CPU second of this process, for the boot (power-up to the first
  attitude frame, ≈ 2.985 s) and for the streaming phase (the full 82 % UART load at 115200 baud);
- instructions per AHRS step (``ahrs_fusion_ag`` + ``QuaternionToEuler``, interrupts excluded) and the firmware's
  own DWT window (CYCCNT, which here counts instructions, interrupts included): instruction counts of this
  emulator, not Cortex-M4 cycles;
- interrupts per emulated second, idle instructions skipped, peak memory (RSS) of the run.
Asserts nothing.

Run: ``python benchmarks/bench_emulate.py [--duration 20] [--pure] [ELF...]`` (``--pure``: the Python block-hook
counter instead of the C one, to see what the optional extension buys).
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from support import firmware as S  # noqa: E402

from steval_link.emulation.board import CPU_HZ  # noqa: E402
from steval_link.emulation.runner import Emulation, EmulationOptions  # noqa: E402
from steval_link.link.decoder import StreamDecoder  # noqa: E402


def bench(elf: Path, duration_s: float, native: bool | None, scenario: str) -> None:
    emu = Emulation(EmulationOptions(elf=elf, scenario=scenario, duration_s=duration_s, seed=1))
    if native is False:
        from steval_link.emulation.board import Board

        emu.board = Board(emu.elf, emu.bus, native=False)
        emu.board.tick_observers.append(emu._on_tick)
        emu._install_step_probes()
    dec = StreamDecoder()
    marks = []  # (emulated s, wall s, cpu s)
    w0, c0 = time.perf_counter(), time.process_time()
    boot = None
    for data, t in emu.chunks(slice_s=0.25):
        dec.feed(data)
        marks.append((emu.board.now / CPU_HZ, time.perf_counter() - w0, time.process_time() - c0))
        if boot is None and dec.stats.attitude:
            boot = marks[-1]
    rep = emu.report()
    end = marks[-1]
    print(f"\n{elf.name}  ({'C counter' if emu.board.native else 'Python block counter'}, {scenario}, "
          f"{duration_s:g} s emulated)")
    print(f"  whole run: {end[0] / end[1]:.2f} emulated s per wall s, {end[0] / end[2]:.2f} per CPU s "
          f"({end[1]:.1f} s wall)")
    if boot is not None and end[0] - boot[0] > 1:
        print(f"  boot (to first frame at {rep.first_attitude_s:.3f} s): {boot[0] / boot[1]:.2f} per wall s; "
              f"streaming: {(end[0] - boot[0]) / (end[1] - boot[1]):.2f} per wall s, "
              f"{(end[0] - boot[0]) / (end[2] - boot[2]):.2f} per CPU s")
    a = np.asarray(rep.step_instructions)
    d = np.asarray(rep.dwt_windows)
    if a.size:
        print(f"  instructions per AHRS step (emulator count, not M4 cycles): min {a.min()} mean {a.mean():.0f} "
              f"max {a.max()} (n={a.size}); DWT window min {d.min()} mean {d.mean():.0f} max {d.max()}")
    per_s = {k: round(v / rep.emulated_s) for k, v in rep.interrupts.items()}
    print(f"  interrupts per emulated s: {per_s}; instructions executed {rep.instructions / rep.emulated_s / 1e6:.2f} M"
          f"/s, idle skipped {rep.skipped_instructions / rep.emulated_s / 1e6:.1f} M/s")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"  frames: {dec.stats.attitude} attitude, {dec.stats.crc_failures} CRC failures, "
          f"{dec.stats.frames_missing} missing; peak RSS {peak_mb:.0f} MB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("elf", nargs="*", type=Path)
    ap.add_argument("--duration", type=float, default=15.0)
    ap.add_argument("--scenario", default="hand-tilts")
    ap.add_argument("--pure", action="store_true", help="also run with the Python block-hook counter")
    args = ap.parse_args()
    elfs = list(args.elf)
    with tempfile.TemporaryDirectory() as tmp:
        if not elfs:
            why = S.missing()
            if why:
                print(f"cannot build the firmware: {why}")
                return
            t = time.perf_counter()
            elfs = [S.build_reference(Path(tmp) / "b")]
            print(f"built the reference firmware in {time.perf_counter() - t:.1f} s")
        for elf in elfs:
            bench(elf, args.duration, None, args.scenario)
            if args.pure:
                bench(elf, args.duration, False, args.scenario)


if __name__ == "__main__":
    main()

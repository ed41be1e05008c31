"""Firmware-in-the-loop benchmark: how fast the emulated board runs a firmware, and what one AHRS step costs.

Builds the reference firmware (``make -C firmware_patch reference`` into a temporary directory; or pass ELF paths,
e.g. a build of ST's release made elsewhere), then for each ELF:
- emulated seconds per wall second and per CPU second of this process, for the boot (power-up to the first
  attitude frame, ≈ 2.985 s) and for the streaming phase (the full 82 % UART load at 115200 baud);
- instructions per AHRS step (``ahrs_fusion_ag`` + ``QuaternionToEuler``, interrupts excluded) and the firmware's
  own DWT window (CYCCNT, which here counts instructions, interrupts included): instruction counts of this
  emulator, not Cortex-M4 cycles;
- interrupts per emulated second, instructions executed and idle-skipped per emulated second, the USART1 baud rate
  the firmware set (pass a 460800 baud build as another ELF), peak memory (RSS) of the run (each run in its own
  process).
Asserts nothing.

Run: ``python benchmarks/bench_emulate.py [--duration 20] [--pure] [ELF...]`` (``--pure``: also the Python models,
as on a machine without a C compiler, to see what the C core buys). Before/after in one run:
``--python OTHER/.venv/bin/python --repeat 5`` runs the same benchmark in turn with another checkout's interpreter
(its installed steval_link) and prints the median emulated seconds per CPU second of each.
"""

from __future__ import annotations

import argparse
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from support import firmware as S  # noqa: E402

from steval_link import constants as C  # noqa: E402
from steval_link.emulation.runner import Emulation, EmulationOptions  # noqa: E402
from steval_link.link.decoder import StreamDecoder  # noqa: E402


def bench(elf: Path, duration_s: float, native: bool | None, scenario: str) -> None:
    """One run (in its own process, for its peak RSS): speeds, counts, memory."""
    from steval_link.emulation.board import Board  # reason: after sys.path is set (module top)

    emu = Emulation(EmulationOptions(elf=elf, scenario=scenario, duration_s=duration_s, seed=1))
    if native is not None:
        emu.board = Board(emu.elf, emu.bus, native=native)
        emu.board.tick_observers.append(emu._on_tick)
        emu.board.tick_planner = emu.plan_ticks  # (the C core's TIM9 tables; the Python models call the observer)
        emu._install_step_probes()
    dec = StreamDecoder()
    marks = []  # (emulated s, wall s, cpu s)
    w0, c0 = time.perf_counter(), time.process_time()
    boot = None
    for data, t in emu.chunks(slice_s=0.25):
        dec.feed(data)
        marks.append((emu.board.now / C.CPU_HZ, time.perf_counter() - w0, time.process_time() - c0))
        if boot is None and dec.stats.attitude:
            boot = marks[-1]
    marks.append((emu.board.now / C.CPU_HZ, time.perf_counter() - w0, time.process_time() - c0))  # (quiet ends)
    rep = emu.report()
    end = marks[-1]
    brr = emu.board.usart1.read(0x08)
    baud = f"{C.CPU_HZ / brr:.0f} baud" if brr else "baud ?"
    core = "C core" if emu.board.native else "Python models (no C compiler)"
    print(f"\n{elf.name}  ({core}, {scenario}, {duration_s:g} s emulated, USART1 at {baud})")
    print(
        f"  overall: {end[0] / end[1]:.2f} emulated s per wall s, {end[0] / end[2]:.2f} per CPU s "
        f"({end[1]:.1f} s wall, {end[2]:.1f} s CPU)"
    )
    if boot is not None and end[0] - boot[0] > 1:
        print(
            f"  boot (to the first frame at {rep.first_attitude_s:.3f} s): {boot[0] / boot[1]:.2f} per wall s; "
            f"streaming: {(end[0] - boot[0]) / (end[1] - boot[1]):.2f} per wall s, "
            f"{(end[0] - boot[0]) / (end[2] - boot[2]):.2f} per CPU s"
        )
    a = np.asarray(rep.step_instructions)
    d = np.asarray(rep.dwt_windows)
    if a.size:
        print(
            f"  instructions per AHRS step (emulator count, not M4 cycles): min {a.min()} mean {a.mean():.0f} "
            f"max {a.max()} (n={a.size})"
            + (f"; DWT window min {d.min()} mean {d.mean():.0f} max {d.max()}" if d.size and d.any() else "")
        )
    per_s = {k: round(v / rep.emulated_s) for k, v in rep.interrupts.items()}
    print(f"  interrupts per emulated s: {per_s} (total {sum(per_s.values())})")
    polled = getattr(getattr(emu.board, "st", None), "polled", 0)
    print(
        f"  instructions per emulated s: {rep.instructions / rep.emulated_s / 1e6:.2f} M executed "
        f"(of which {polled / rep.emulated_s / 1e6:.2f} M TXE/TC polling passes skipped), "
        f"{rep.skipped_instructions / rep.emulated_s / 1e6:.1f} M idle skipped"
    )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"  frames: {dec.stats.attitude} attitude, {dec.stats.crc_failures} CRC failures, "
        f"{dec.stats.frames_missing} missing; peak RSS {peak_mb:.0f} MB"
    )


def _in_child(elf: Path, args, native: bool | None, python: str = sys.executable) -> float | None:
    """Run :func:`bench` in a fresh process (its own peak RSS) with ``python``; its emulated s per CPU s."""
    cmd = [python, __file__, "--one", str(elf), "--duration", str(args.duration), "--scenario", args.scenario]
    if native is not None:
        cmd += ["--native" if native else "--pure-only"]
    out = subprocess.run(cmd, check=False, capture_output=True, text=True).stdout
    print(f"[{python}]{out}", end="", flush=True)
    m = re.search(r"([0-9.]+) per CPU s \(", out)
    return float(m.group(1)) if m else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("elf", nargs="*", type=Path)
    ap.add_argument("--duration", type=float, default=15.0)
    ap.add_argument("--scenario", default="hand-tilts")
    ap.add_argument("--pure", action="store_true", help="also run with the Python models (as without a C compiler)")
    ap.add_argument("--python", action="append", default=[], help="also run with this interpreter (another checkout)")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each interpreter, in turn")
    ap.add_argument("--one", type=Path, help=argparse.SUPPRESS)  # (the child process of one run)
    ap.add_argument("--native", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--pure-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        bench(args.one, args.duration, True if args.native else False if args.pure_only else None, args.scenario)
        return
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
        pythons = [sys.executable, *args.python]
        for elf in elfs:
            speeds: dict[str, list[float]] = {p: [] for p in pythons}
            for _ in range(args.repeat):
                for python in pythons:
                    v = _in_child(elf, args, None, python)
                    if v is not None:
                        speeds[python].append(v)
            if args.pure:
                _in_child(elf, args, False)
            if len(pythons) > 1 or args.repeat > 1:
                for python, v in speeds.items():
                    med = f"{statistics.median(v):.2f}" if v else "?"
                    print(f"{elf.name} [{python}]: median {med} emulated s per CPU s over {len(v)} runs {v}")


if __name__ == "__main__":
    main()

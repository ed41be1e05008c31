"""Flight-control frame: what it adds to each AHRS step of the reference firmware, and what it adds to the line.

Builds the reference firmware three times (``STV_FC_EVERY=0``: the hook compiled out,
the baseline; the default 115200 build, one frame every N steps; ``BAUD=460800``, a frame every step) and runs the
emulator's ``flight`` scenario (armed, hover, stick moves) on each. It counts the instructions the main loop
executes from the entry of ``FlightControlPID_OuterLoop`` to the next ``hw_sleep_until_irq`` (where the main loop
goes to sleep after the flight-control block), interrupts excluded, per AHRS step, and prints the difference to the
baseline: the added instructions per step (mean over all steps and per step that sends a frame). Instruction
counts of the emulator, not Cortex-M4 cycles. Also the USART1 bytes per second and the line load at each baud rate.

Run: ``python benchmarks/bench_flight_frame.py [seconds]`` (needs arm-none-eabi-gcc, make and unicorn).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from support import firmware as S  # noqa: E402

from steval_link.emulation.runner import Emulation, EmulationOptions  # noqa: E402
from steval_link.link.decoder import decode_bytes  # noqa: E402


def window_counts(elf: Path, seconds: float) -> tuple[np.ndarray, bytes, float]:
    """Instructions from FlightControlPID_OuterLoop's entry to the next hw_sleep_until_irq, per AHRS step."""
    emu = Emulation(EmulationOptions(elf=elf, scenario="flight", duration_s=seconds, seed=1))
    b, e = emu.board, emu.elf
    counts: list[int] = []
    start: list[tuple[int, int] | None] = [None]

    def on_outer(board) -> None:
        start[0] = (board.instructions_now(), board.exception_instructions)

    def on_gpio(board) -> None:
        if start[0] is not None:
            i0, x0 = start[0]
            counts.append(board.instructions_now() - i0 - (board.exception_instructions - x0))
            start[0] = None

    b.probe(e.addr("FlightControlPID_OuterLoop"), on_outer)
    b.probe(e.addr("hw_sleep_until_irq"), on_gpio)
    data = emu.run()
    return np.asarray(counts), data, emu.board.now / 84e6


def main() -> None:
    why = S.missing()
    if why:
        print(f"skipped: {why}")
        return
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 27.0
    with tempfile.TemporaryDirectory() as tmp:
        builds = {
            "no FC frame (STV_FC_EVERY=0)": S.build_reference(Path(tmp) / "b0", "FC_EVERY=0"),
            "115200 baud (default)": S.build_reference(Path(tmp) / "b1"),
            "460800 baud": S.build_reference(Path(tmp) / "b2", "BAUD=460800"),
        }
        base = None
        for name, elf in builds.items():
            counts, data, emulated_s = window_counts(elf, seconds)
            tel = decode_bytes(data)
            n_fc = len(tel.fc)
            every = int(tel.status.fc_every[-1]) if len(tel.status) else -1
            baud = int(tel.status.baud[-1]) if len(tel.status) else 0
            streaming = tel.attitude.t_fw_s[-1] - tel.attitude.t_fw_s[0]
            first = tel.attitude.offset[0]
            rate = (len(data) - first) / streaming
            print(
                f"{name}: fc_every {every}, {n_fc} FC frames, {len(counts)} steps; window instructions per step: "
                f"mean {counts.mean():.1f} median {np.median(counts):.0f} max {counts.max()}"
            )
            print(f"  USART1 {rate:.0f} B/s = {100 * rate * 10 / baud:.1f} % of {baud} baud")
            if base is None:
                base = counts
                continue
            added = counts.mean() - base.mean()
            ref = float(np.median(base))
            sends = counts > np.median(counts) + 100 if every > 1 else np.ones(len(counts), bool)
            quiet = ~sends
            line = f"  added instructions per AHRS step: {added:.1f} on average (N = {every}); "
            line += f"{counts[sends].mean() - ref:.0f} on a step that sends a frame ({int(sends.sum())} steps)"
            if quiet.any():
                line += f", {np.median(counts[quiet]) - ref:.0f} on the others (the due check)"
            print(line)


if __name__ == "__main__":
    main()

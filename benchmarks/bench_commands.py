"""What the two-way link costs the drone, counted on the reference firmware under emulation (instruction counts of the
emulated Cortex-M4, not M4 cycles): the command check after every AHRS step when nothing arrived, the whole
stv_fw_step_end, and the handling of one command (decode + check + ack + EVENT status).

    python benchmarks/bench_commands.py        (needs arm-none-eabi-gcc, newlib-nano and unicorn)
"""

from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support import firmware as S  # noqa: E402

from steval_link.emulation.runner import Emulation, EmulationOptions  # noqa: E402
from steval_link.link.commands import CommandChannel, parse_command  # noqa: E402


def measure(elf: Path, *, commands: bool) -> dict[str, list[int]]:
    emu = Emulation(EmulationOptions(elf=elf, scenario="hand-tilts", duration_s=8.0, seed=1))
    b, e = emu.board, emu.elf
    out: dict[str, list[int]] = {"stv_cmd_next": [], "stv_fw_step_end": [], "stv_cmd_execute": []}
    open_calls: dict[str, tuple[int, int]] = {}
    returns: dict[int, str] = {}

    def entry(name):
        def hook(board):
            lr = board.reg(board.regs.LR) & ~1
            if lr not in returns:
                returns[lr] = name
                b.probe(lr, exit_hook(name))
            open_calls[name] = (board.instructions_now(), board.exception_instructions)

        return hook

    def exit_hook(name):
        def hook(board):
            if name in open_calls:
                i0, x0 = open_calls.pop(name)
                out[name].append(board.instructions_now() - i0 - (board.exception_instructions - x0))

        return hook

    for name in out:
        b.probe(e.addr(name), entry(name))
    if commands:
        ch = CommandChannel(lambda _b: None, first_seq=1)
        for i, t in enumerate((4.0, 4.5, 5.0, 5.5, 6.0, 6.5)):
            text = ("set ki 1.0", "correction off", "status", "correction on", "reset", "set ki 0.1")[i]
            emu.send_at(ch.next_frame(parse_command(text)).frame, t)
    emu.run()
    return out


def main() -> None:
    why = S.missing()
    if why:
        print(f"skipped: {why}")
        return
    with tempfile.TemporaryDirectory() as tmp:
        elf = S.build_reference(Path(tmp) / "build")
        quiet = measure(elf, commands=False)
        busy = measure(elf, commands=True)
    q = quiet["stv_cmd_next"][5:]  # the first calls run before the dynamic return probe is in place
    print(
        f"command check per AHRS step, nothing received (stv_cmd_next): min {min(q)} median "
        f"{statistics.median(q):g} max {max(q)} instructions over {len(q)} steps"
    )
    se = quiet["stv_fw_step_end"][5:]
    print(
        f"stv_fw_step_end per step (attitude frame + status cadence + command check): median "
        f"{statistics.median(se):g} instructions"
    )
    ex = busy["stv_cmd_execute"]
    print(
        f"one command handled (check, ack, EVENT status; the first change also a status before): "
        f"{', '.join(map(str, ex))} instructions"
    )
    at_84 = statistics.median(q) / 84e6 * 1e6
    print(
        f"at 84 MHz the idle check is ≈ {at_84 * 1000:.0f} ns per 6.19 ms step "
        f"({100 * statistics.median(q) / (84e6 * 0.00619):.4f} % of the CPU)"
    )


if __name__ == "__main__":
    main()

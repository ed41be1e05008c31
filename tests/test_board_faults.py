"""The emulated board's one-line stops on tiny firmware images: an instruction fetch from unmapped memory is reported as
"execution at", a load from unmapped memory as "read of" (unicorn's UC_MEM_* access kinds named right)."""

from __future__ import annotations

import pytest

pytest.importorskip("unicorn")

from support.tiny_elf import tiny_elf  # noqa: E402

from steval_link.emulation.board import Board, UnmodelledHardware  # noqa: E402
from steval_link.emulation.board.native import core_library  # noqa: E402

NOWHERE = 0x60000000  # FSMC bank 1: not on the STM32F401

# Thumb code at 0x08000008 (arm-none-eabi-as -mcpu=cortex-m4)
READ_UNMAPPED = bytes.fromhex("4ff0c0400168fbe7")  # mov.w r0, #0x60000000; ldr r1, [r0]; b .-6
FETCH_UNMAPPED = bytes.fromhex("0048004701000060")  # ldr r0, [pc, #0]; bx r0; .word 0x60000001

MODES = [False] + ([True] if core_library() is not None else [])


def _fault(tmp_path, code: bytes, native: bool) -> str:
    path = tmp_path / "tiny.elf"
    path.write_bytes(tiny_elf(code))
    board = Board(path, sensors=None, native=native)
    with pytest.raises(UnmodelledHardware) as exc:
        board.run_until(10_000)
    return str(exc.value)


@pytest.mark.parametrize("native", MODES)
def test_a_fetch_from_unmapped_memory_is_execution(tmp_path, native):
    msg = _fault(tmp_path, FETCH_UNMAPPED, native)
    assert f"execution at 0x{NOWHERE:08x}" in msg, msg


@pytest.mark.parametrize("native", MODES)
def test_a_load_from_unmapped_memory_is_a_read(tmp_path, native):
    msg = _fault(tmp_path, READ_UNMAPPED, native)
    assert f"read of 0x{NOWHERE:08x}" in msg and "Reset_Handler" in msg, msg


# SysTick every 1 ms (RVR 83999, CSR 7); the main loop sleeps in wfi; the handler counts in RAM at 0x20000000
WFI_LOOP = bytes.fromhex("06480749016007480721016030bffde74ff00050016801310160704714e000e01f48010010e000e0")
SYSTICK_HANDLER = 0x10


@pytest.mark.parametrize("native", MODES)
def test_wfi_sleeps_to_the_next_interrupt(tmp_path, native):
    """A CPU in wfi wakes for each SysTick (the handler runs, execution continues after the wfi) and the clock
    jumps between them: 10 interrupts in 10 ms for a few hundred instructions."""
    path = tmp_path / "wfi.elf"
    path.write_bytes(tiny_elf(WFI_LOOP, {15: SYSTICK_HANDLER}))
    board = Board(path, sensors=None, native=native)
    board.run_until(84_000 * 10 + 100)
    ticks = board.ram_u32(0x20000000)
    assert ticks == 10 and board.stats.interrupts == {15: 10}
    assert board.stats.instructions < 200 and board.stats.skipped_instructions > 800_000

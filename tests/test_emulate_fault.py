"""A firmware that hangs or faults is named truthfully: the active exception, Default_Handler and the missing weak
handler, the fault status registers, the last function (reference firmware builds with make options)."""

from __future__ import annotations

import pytest
from support import firmware as S

from steval_link.emulation.board import EmulationError, FirmwareStuck
from steval_link.emulation.elf import Elf
from steval_link.emulation.runner import Emulation, EmulationOptions

pytestmark = pytest.mark.skipif(S.missing() is not None, reason=str(S.missing()))


@pytest.fixture(scope="module")
def no_systick(tmp_path_factory):
    pytest.importorskip("unicorn")
    return S.build_reference(tmp_path_factory.mktemp("no-systick"), "MISSING_SYSTICK=1")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    pytest.importorskip("unicorn")
    return S.build_reference(tmp_path_factory.mktemp("ref"))


def test_default_handler_is_named_not_one_of_its_weak_aliases(no_systick):
    e = Elf(no_systick)
    at = e.addr("Default_Handler")
    names = [s.name for s in e.aliases(at)]
    assert "SysTick_Handler" in names and "DMA1_Stream3_IRQHandler" in names
    assert e.func_at(at) == "Default_Handler"
    assert e.func_at(at + 2) == "Default_Handler+0x2"


def test_a_missing_systick_handler_names_the_exception_the_handler_and_the_last_function(no_systick):
    emu = Emulation(EmulationOptions(elf=no_systick, scenario="bench", duration_s=2.0, seed=1))
    seen = []
    emu.board.probe(emu.elf.addr("Default_Handler"), lambda b: seen.append(b.describe_cpu()))
    with pytest.raises(FirmwareStuck) as err:
        emu.run()
    msg = str(err.value)
    for part in ("Default_Handler", "exception 15 (SysTick)", "SysTick_Handler is missing", "hw_delay_ms"):
        assert part in msg and part in seen[0], (part, msg, seen)
    assert "DMA1_Stream3" not in msg


def test_an_undefined_instruction_gives_the_fault_registers(reference):
    emu = Emulation(EmulationOptions(elf=reference, scenario="bench", duration_s=2.0, seed=1))
    b = emu.board
    udf = 0x2000C000

    def jump(board):  # at main: run an undefined instruction (udf #0) placed in RAM
        board.ram_write(udf, b"\x00\xde\x00\xde")
        board.set_reg(board.regs.PC, udf | 1)

    b.probe(emu.elf.addr("main"), jump)
    with pytest.raises(EmulationError) as err:
        emu.run()
    msg = str(err.value)
    assert "UsageFault: undefined instruction, escalated to HardFault" in msg, msg
    assert "CFSR 0x00010000" in msg and "HFSR 0x40000000" in msg, msg
    assert f"pc 0x{udf:08x}" in msg and "Reset_Handler" in msg, msg

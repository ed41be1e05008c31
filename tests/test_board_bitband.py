"""Bit-band writes reach the peripheral models on both boards: USART1's (served by the C core) and another
peripheral's (GPIOB, in Python), from code running in RAM (the C core's software TLB keeps RAM executable)."""

from __future__ import annotations

import pytest
from support import firmware as S

from steval_link.emulation.board import Board, EmulationError
from steval_link.emulation.runner import Emulation, EmulationOptions

pytestmark = [
    pytest.mark.skipif(S.missing() is not None, reason=str(S.missing())),
    pytest.mark.slow,  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
]

CODE = 0x2000C000
#: str r1, [r0]; str r1, [r2]; udf #0
THUMB = bytes.fromhex("0160 1160 00de")
GPIOB_ODR_BIT5 = 0x42000000 + (0x20414 << 5) + 5 * 4
USART1_CR1_BIT12 = 0x42000000 + (0x1100C << 5) + 12 * 4


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    pytest.importorskip("unicorn")
    return S.build_reference(tmp_path_factory.mktemp("ref"))


@pytest.mark.parametrize("native", [True, False])
def test_bit_band_writes_from_ram_set_the_bits(reference, native):
    emu = Emulation(EmulationOptions(elf=reference, scenario="bench", duration_s=1.0, seed=1))
    b = emu.board = Board(emu.elf, emu.bus, native=native)
    if native and not b.native:
        pytest.skip("the board's C core is not built")

    def jump(board):  # at main, before any initialisation: run the two stores in RAM, then fault
        board.ram_write(CODE, THUMB)
        board.set_reg(board.regs.R[0], GPIOB_ODR_BIT5)
        board.set_reg(board.regs.R[1], 1)
        board.set_reg(board.regs.R[2], USART1_CR1_BIT12)
        board.set_reg(board.regs.PC, CODE | 1)

    b.probe(emu.elf.addr("main"), jump)
    with pytest.raises(EmulationError, match="undefined instruction"):
        emu.run()
    gpiob = next(p for p in b.periphs if p.name == "GPIOB")
    assert gpiob.read(0x14) == 1 << 5
    assert b.usart1.read(0x0C) == 1 << 12

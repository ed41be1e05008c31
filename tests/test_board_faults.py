"""The emulated board's one-line stops on tiny firmware images: an instruction fetch from unmapped memory is reported as
"execution at", a load from unmapped memory as "read of" (unicorn's UC_MEM_* access kinds named right)."""

from __future__ import annotations

import struct

import pytest

pytest.importorskip("unicorn")

from steval_link.emulation.board import Board, UnmodelledHardware  # noqa: E402
from steval_link.emulation.board.native import core_library  # noqa: E402

FLASH = 0x08000000
STACK_TOP = 0x20010000
NOWHERE = 0x60000000  # FSMC bank 1: not on the STM32F401

# Thumb code at 0x08000008 (arm-none-eabi-as -mcpu=cortex-m4)
READ_UNMAPPED = bytes.fromhex("4ff0c040" "0168" "fbe7")  # mov.w r0, #0x60000000; ldr r1, [r0]; b .-6
FETCH_UNMAPPED = bytes.fromhex("0048" "0047" "01000060")  # ldr r0, [pc, #0]; bx r0; .word 0x60000001

MODES = [False] + ([True] if core_library() is not None else [])


def _elf(code: bytes) -> bytes:
    """A minimal ARM ELF: one load segment (vector table + code) and the symbol ``Reset_Handler``."""
    image = struct.pack("<II", STACK_TOP, FLASH + 8 | 1) + code
    strtab = b"\0Reset_Handler\0"
    symtab = bytes(16) + struct.pack("<IIIBBH", 1, FLASH + 8 | 1, len(code), 0x12, 0, 1)
    ph_off, img_off = 52, 52 + 32
    sym_off = img_off + len(image)
    str_off = sym_off + len(symtab)
    sh_off = str_off + len(strtab)
    header = b"\x7fELF\x01\x01\x01" + bytes(9) + struct.pack(
        "<HHIIIIIHHHHHH", 2, 40, 1, FLASH + 8 | 1, ph_off, sh_off, 0x05000400, 52, 32, 1, 40, 3, 0)
    phdr = struct.pack("<8I", 1, img_off, FLASH, FLASH, len(image), len(image), 5, 4)
    shdrs = bytes(40) + struct.pack("<10I", 0, 2, 0, 0, sym_off, len(symtab), 2, 1, 4, 16)
    shdrs += struct.pack("<10I", 0, 3, 0, 0, str_off, len(strtab), 0, 0, 1, 0)
    return header + phdr + image + symtab + strtab + shdrs


def _fault(tmp_path, code: bytes, native: bool) -> str:
    path = tmp_path / "tiny.elf"
    path.write_bytes(_elf(code))
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

"""A minimal ARM ELF for the emulated board's unit tests: a vector table and a few Thumb instructions."""

from __future__ import annotations

import struct

FLASH = 0x08000000
STACK_TOP = 0x20010000
#: b . (an endless loop)
LOOP = bytes.fromhex("fee7")


#: where the code starts (after a vector table of 16 words)
CODE = FLASH + 0x40


def tiny_elf(code: bytes = LOOP, vectors: dict[int, int] | None = None) -> bytes:
    """A minimal ARM ELF: one load segment (vector table + code at :data:`CODE`) and the symbol ``Reset_Handler``
    over the code. ``vectors``: exception number → offset of its handler in ``code`` (reset: offset 0)."""
    table = [STACK_TOP, CODE | 1] + [0] * 14
    for exc, off in (vectors or {}).items():
        table[exc] = CODE + off | 1
    image = struct.pack("<16I", *table) + code
    strtab = b"\0Reset_Handler\0"
    symtab = bytes(16) + struct.pack("<IIIBBH", 1, CODE | 1, len(code), 0x12, 0, 1)
    ph_off, img_off = 52, 52 + 32
    sym_off = img_off + len(image)
    str_off = sym_off + len(symtab)
    sh_off = str_off + len(strtab)
    header = (
        b"\x7fELF\x01\x01\x01"
        + bytes(9)
        + struct.pack("<HHIIIIIHHHHHH", 2, 40, 1, CODE | 1, ph_off, sh_off, 0x05000400, 52, 32, 1, 40, 3, 0)
    )
    phdr = struct.pack("<8I", 1, img_off, FLASH, FLASH, len(image), len(image), 5, 4)
    shdrs = bytes(40) + struct.pack("<10I", 0, 2, 0, 0, sym_off, len(symtab), 2, 1, 4, 16)
    shdrs += struct.pack("<10I", 0, 3, 0, 0, str_off, len(strtab), 0, 0, 1, 0)
    return header + phdr + image + symtab + strtab + shdrs

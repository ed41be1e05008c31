"""A 32-bit little-endian ELF as the board needs it: load segments and function/object symbols (pure Python)."""

from __future__ import annotations

import bisect
import struct
from dataclasses import dataclass
from pathlib import Path

from steval_link.errors import UserError


@dataclass(frozen=True)
class Symbol:
    name: str
    addr: int
    size: int
    is_func: bool
    weak: bool = False


class Elf:
    """Segments (``(address, bytes)`` of each PT_LOAD at its load address) and symbols of a firmware ELF."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            data = self.path.read_bytes()
        except OSError as exc:
            raise UserError(f"cannot read firmware ELF {self.path}: {exc.strerror or exc}") from None
        if data[:4] != b"\x7fELF" or len(data) < 52:
            raise UserError(f"{self.path} is not an ELF file (e.g. `make -C firmware_patch reference`)")
        if data[4] != 1 or data[5] != 1 or struct.unpack_from("<H", data, 18)[0] != 40:
            raise UserError(f"{self.path} is not a 32-bit little-endian ARM ELF (the STM32F401 firmware)")
        self.segments = self._segments(data)
        self.symbols = self._symbols(data)
        self.by_name = {s.name: s for s in self.symbols}
        # one function per address (a strong name before weak aliases: ST's ~80 handlers alias Default_Handler)
        self._aliases: dict[int, list[Symbol]] = {}
        for sym in sorted((s for s in self.symbols if s.is_func and s.addr), key=lambda s: (s.weak, s.name)):
            self._aliases.setdefault(sym.addr & ~1, []).append(sym)
        self._funcs = [self._aliases[a][0] for a in sorted(self._aliases)]
        self._func_starts = [s.addr & ~1 for s in self._funcs]

    @staticmethod
    def _segments(data: bytes) -> list[tuple[int, bytes]]:
        phoff = struct.unpack_from("<I", data, 28)[0]
        phentsize, phnum = struct.unpack_from("<HH", data, 42)
        out = []
        for i in range(phnum):
            p_type, off, vaddr, paddr, filesz, memsz, _fl, _al = struct.unpack_from("<8I", data, phoff + i * phentsize)
            if p_type == 1 and filesz:
                # load (physical) address: .data's initial values live in flash, the startup code copies them
                out.append((paddr, data[off : off + filesz]))
        return out

    @staticmethod
    def _symbols(data: bytes) -> list[Symbol]:
        shoff = struct.unpack_from("<I", data, 32)[0]
        shentsize, shnum = struct.unpack_from("<HH", data, 46)
        secs = [struct.unpack_from("<10I", data, shoff + i * shentsize) for i in range(shnum)]
        out: list[Symbol] = []
        for sh in (sh for sh in secs if sh[1] == 2):  # SHT_SYMTAB
            str_off = secs[sh[6]][4]  # its string table's file offset
            for k in range(sh[5] // 16):
                name_off, value, size, info, _other, shndx = struct.unpack_from("<IIIBBH", data, sh[4] + k * 16)
                typ = info & 0xF
                if typ not in (1, 2) or shndx == 0:  # OBJECT, FUNC
                    continue
                start = str_off + name_off
                name = data[start : data.index(b"\0", start)].decode("ascii", "replace")
                out.append(Symbol(name, value, size, typ == 2, info >> 4 == 2))  # STB_WEAK
        if not out:
            raise UserError("the firmware ELF has no symbols (do not strip it: the board finds its functions by name)")
        return out

    def addr(self, name: str) -> int | None:
        """Address of a symbol (functions without the Thumb bit), or None."""
        s = self.by_name.get(name)
        return None if s is None else (s.addr & ~1 if s.is_func else s.addr)

    def func_at(self, pc: int) -> str:
        """``name+0xoff`` of the function containing pc (or ``?``); of several names, the strong one."""
        f = self.function_at(pc)
        if f is None:
            return "?"
        off = (pc & ~1) - (f.addr & ~1)
        return f"{f.name}+0x{off:x}" if off else f.name

    def function_at(self, pc: int) -> Symbol | None:
        """The function containing pc (its strong name), or None."""
        i = bisect.bisect_right(self._func_starts, pc & ~1) - 1
        if i >= 0:
            f = self._funcs[i]
            off = (pc & ~1) - (f.addr & ~1)
            if off < max(f.size, 1) or f.size == 0:
                return f
        return None

    def aliases(self, addr: int) -> list[Symbol]:
        """Every function name at ``addr`` (strong first, then the weak aliases by name)."""
        return list(self._aliases.get(addr & ~1, []))

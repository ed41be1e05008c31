"""The Cortex-M4 around unicorn: registers through unicorn's C API, exception entry and return (the FP frame), the
instruction counter, and what the board finds in the firmware's code (``cpsie`` sites, ``wfi``).

Registers go through ``uc_reg_read``/``uc_reg_write`` with ctypes: the Python binding's per-call class lookup costs
~5 µs a register.
"""

from __future__ import annotations

import ctypes
import struct

from steval_link.emulation.board.memory_map import FLASH_BASE, FLASH_SIZE, FP_FRAME_WORDS, RAM_BASE, RAM_SIZE
from steval_link.emulation.elf import Elf

#: EXC_RETURN: back to handler mode (MSP), back to thread mode (MSP), both with the FP frame
EXC_RETURN_HANDLER, EXC_RETURN_THREAD = 0xFFFFFFE1, 0xFFFFFFE9
XPSR_ALIGN = 1 << 9  # the stack was realigned by 4 bytes at exception entry
THUMB_32_PREFIXES = (0x1D, 0x1E, 0x1F)  # bits 15..11 of a 32-bit Thumb-2 encoding's first half-word
CPSIE_I = 0xB662
WFI = 0xBF30


def uclib():
    """unicorn's shared library as the Python binding loaded it (ctypes)."""
    try:
        from unicorn.unicorn_py3.unicorn import uclib as lib  # reason: the binding's layout since unicorn 2.0.2
    except ImportError:  # pragma: no cover - older layout
        from unicorn.unicorn import uclib as lib  # type: ignore  # reason: the binding's older layout
    return lib


def access_kind(access: int) -> str:
    """The words for unicorn's access kind (``UC_MEM_*``) of an invalid memory access."""
    from unicorn import unicorn_const as K  # reason: unicorn is optional (steval-link[test])

    if access in (K.UC_MEM_FETCH, K.UC_MEM_FETCH_UNMAPPED, K.UC_MEM_FETCH_PROT):
        return "execution at"
    if access in (K.UC_MEM_WRITE, K.UC_MEM_WRITE_UNMAPPED, K.UC_MEM_WRITE_PROT):
        return "write to"
    return "read of"  # UC_MEM_READ, _UNMAPPED, _PROT, _AFTER


class Registers:
    """One register at a time, and the exception frame's registers in one batch, through unicorn's C API."""

    def __init__(self, uc) -> None:
        from unicorn import arm_const as A  # reason: unicorn is optional (steval-link[test])

        lib = uclib()
        self.uch = uc._uch
        self._read, self._write = lib.uc_reg_read, lib.uc_reg_write
        self.read_batch, self.write_batch = lib.uc_reg_read_batch, lib.uc_reg_write_batch
        self._one = ctypes.c_uint32()
        self._one_p = ctypes.cast(ctypes.byref(self._one), ctypes.c_void_p)
        self.SP, self.LR, self.PC = A.UC_ARM_REG_SP, A.UC_ARM_REG_LR, A.UC_ARM_REG_PC
        self.XPSR, self.PRIMASK = A.UC_ARM_REG_XPSR, A.UC_ARM_REG_PRIMASK
        self.R = [A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3]
        # the exception frame: r0-r3, r12, lr, pc, xpsr, s0-s15, fpscr (26 words with the reserved one)
        ids = self.R + [A.UC_ARM_REG_R12, A.UC_ARM_REG_LR, A.UC_ARM_REG_PC, A.UC_ARM_REG_XPSR]
        ids += [getattr(A, f"UC_ARM_REG_S{i}") for i in range(16)] + [A.UC_ARM_REG_FPSCR]
        self.frame_ids = ids
        self.frame = self._batch(ids)
        # the same without PC and xPSR, for writing back (PC and xPSR are written one by one)
        self.wframe = self._batch(ids[:6] + ids[8:])
        self.args = self._batch(self.R + [self.LR])

    @staticmethod
    def _batch(ids: list[int]):
        n = len(ids)
        vals = (ctypes.c_uint32 * n)()
        base = ctypes.addressof(vals)
        return (ctypes.c_int32 * n)(*ids), vals, (ctypes.c_void_p * n)(*[base + 4 * i for i in range(n)])

    def get(self, reg_id: int) -> int:
        self._read(self.uch, reg_id, self._one_p)
        return self._one.value

    def set(self, reg_id: int, value: int) -> None:
        self._one.value = value & 0xFFFFFFFF
        self._write(self.uch, reg_id, self._one_p)

    def read_args(self):
        """r0-r3 and lr (a replaced function's arguments and return address)."""
        ids, vals, ptrs = self.args
        self.read_batch(self.uch, ids, ptrs, 5)
        return vals


class Exceptions:
    """Exception entry and return on the main stack with the FP frame (the Python model; the C core has its own)."""

    def __init__(self, board) -> None:
        self.board = board
        self.regs = board.regs

    def take(self, exc: int) -> None:
        """Exception entry: push the FP frame on MSP, EXC_RETURN in LR, IPSR = exc, PC = vector."""
        b, r = self.board, self.regs
        ids, vals, ptrs = r.frame
        r.read_batch(r.uch, ids, ptrs, 25)
        sp = r.get(r.SP)
        xpsr = vals[7]
        align = sp & 4
        sp -= align + FP_FRAME_WORDS * 4
        vals[7] = (xpsr & ~XPSR_ALIGN) | (XPSR_ALIGN if align else 0)
        off = sp - RAM_BASE
        if not 0 <= off <= RAM_SIZE - FP_FRAME_WORDS * 4:
            b.stop_with_error(f"stack overflow: exception {exc} at sp 0x{sp:08x} in {b.where()}")
            return
        ctypes.memmove(ctypes.addressof(b.ram) + off, vals, 100)
        struct.pack_into("<I", b.ram, off + 100, 0)
        nvic = b.nvic
        handler_mode = bool(nvic.active)
        if not handler_mode:
            b.exc_started = b.instructions_now()
        r.set(r.SP, sp)
        r.set(r.LR, EXC_RETURN_HANDLER if handler_mode else EXC_RETURN_THREAD)
        r.set(r.XPSR, (xpsr & 0xF8000000) | (1 << 24) | exc)
        vector = struct.unpack_from("<I", b.flash, b.vtor() + 4 * exc)[0]
        nvic.pending.discard(exc)
        nvic.active.append(exc)
        ints = b.stats.interrupts
        ints[exc] = ints.get(exc, 0) + 1
        r.set(r.PC, vector | 1)

    def leave(self) -> None:
        """Exception return (unicorn's interrupt 8 on a branch to EXC_RETURN): pop the frame, chain a pending one."""
        b, r = self.board, self.regs
        exc_return = r.get(r.PC) | 0xF0000000
        nvic = b.nvic
        if not nvic.active:
            b.stop_with_error(f"exception return without an active exception in {b.where()}")
            return
        nvic.active.pop()
        if not nvic.active:
            b.exception_instructions += b.instructions_now() - b.exc_started
        sp = r.get(r.SP)
        extended = not exc_return & 0x10
        words = FP_FRAME_WORDS if extended else 8
        raw = struct.unpack_from(f"<{words}I", b.ram, sp - RAM_BASE)
        sp += 4 * words
        xpsr = raw[7]
        if xpsr & XPSR_ALIGN:
            sp += 4
        b.refresh_levels()
        ids, w, ptrs = r.wframe
        w[0:6] = raw[0:6]
        if extended:
            w[6:23] = raw[8:25]
        r.write_batch(r.uch, ids, ptrs, 23 if extended else 6)
        r.set(r.SP, sp)
        r.set(r.XPSR, xpsr & ~XPSR_ALIGN)
        r.set(r.PC, raw[6] | 1)
        if nvic.pending:
            nxt = nvic.next_exception(r.get(r.PRIMASK))
            if nxt is not None:
                self.take(nxt)


def thumb_count(flash, address: int, size: int) -> int:
    """Instructions in a Thumb block of ``size`` bytes (16- or 32-bit encodings)."""
    off = address & (FLASH_SIZE - 1) if address < FLASH_BASE + FLASH_SIZE else None
    if off is None or address < FLASH_BASE and address >= FLASH_SIZE:
        return max(size // 2, 1)
    raw = bytes(memoryview(flash).cast("B")[off : off + size])
    n = i = 0
    while i < size:
        hw = raw[i] | raw[i + 1] << 8 if i + 1 < len(raw) else 0
        i += 4 if (hw >> 11) in THUMB_32_PREFIXES else 2
        n += 1
    return n


def cpsie_sites(flash, e: Elf) -> list[int]:
    """Addresses right after each ``cpsie i`` / ``msr primask, rN`` in the firmware's code."""
    raw = flash.raw
    funcs = [s for s in e.symbols if s.is_func and FLASH_BASE <= s.addr < FLASH_BASE + FLASH_SIZE]
    end = max(((s.addr & ~1) - FLASH_BASE + s.size for s in funcs), default=0)  # the end of the code in flash
    out = []
    for off in range(0, end - 1, 2):
        hw = raw[off] | raw[off + 1] << 8
        if hw == CPSIE_I:
            out.append(FLASH_BASE + off + 2)
        elif (hw & 0xFFF0) == 0xF380 and off + 3 < end:
            hw2 = raw[off + 2] | raw[off + 3] << 8
            if (hw2 & 0xFF00) == 0x8800 and (hw2 & 0xFF) == 0x10:  # msr primask
                out.append(FLASH_BASE + off + 4)
    return out


def wfi_sites(flash, e: Elf) -> list[int]:
    """Addresses of each ``wfi`` in the firmware's functions (16-bit encoding, at an instruction boundary)."""
    raw = flash.raw
    out = []
    for s in e.symbols:
        if not (s.is_func and FLASH_BASE <= s.addr < FLASH_BASE + FLASH_SIZE and s.size):
            continue
        off, end = (s.addr & ~1) - FLASH_BASE, (s.addr & ~1) - FLASH_BASE + s.size
        while off + 1 < end:
            hw = raw[off] | raw[off + 1] << 8
            if hw == WFI:
                out.append(FLASH_BASE + off)
            off += 4 if (hw >> 11) in THUMB_32_PREFIXES else 2
    return sorted(set(out))

"""The Cortex-M4's system control space: the NVIC's state and registers, SysTick, SCB, DWT ``CYCCNT``, DBGMCU.

:class:`Nvic` is the Python model of the interrupt controller's state (pending, enabled, active, priorities); the C
core (``_core.c``) keeps the same state in C behind the same methods (``native.NativeNvic``).
"""

from __future__ import annotations

from enum import IntEnum

from steval_link.emulation.board.memory_map import (
    EXC_PENDSV,
    EXC_SYSTICK,
    IRQ_BASE,
    SCS_BASE,
    SCS_SIZE,
    EmulationError,
    Peripheral,
)


class ScsReg(IntEnum):
    DWT_CTRL = 0x1000
    DWT_CYCCNT = 0x1004
    SYST_CSR = 0xE010
    SYST_RVR = 0xE014
    SYST_CVR = 0xE018
    NVIC_ISER = 0xE100
    NVIC_ICER = 0xE180
    NVIC_ISPR = 0xE200
    NVIC_ICPR = 0xE280
    NVIC_IABR = 0xE300
    NVIC_IPR = 0xE400
    CPUID = 0xED00
    ICSR = 0xED04
    VTOR = 0xED08
    AIRCR = 0xED0C
    SHPR1 = 0xED18
    DBGMCU_IDCODE = 0x42000


NVIC_WORDS = 0x20  # bytes of each ISER/ICER/ISPR/ICPR/IABR bank
#: the NVIC's banks: Nvic.word's bank, first offset, set (True) or clear (False) on write (None: read only)
NVIC_BANKS = (
    ("enabled", ScsReg.NVIC_ISER, True),
    ("enabled", ScsReg.NVIC_ICER, False),
    ("pending", ScsReg.NVIC_ISPR, True),
    ("pending", ScsReg.NVIC_ICPR, False),
    ("active", ScsReg.NVIC_IABR, None),
)
#: the priority words: first offset, end, the exception number of the first byte
PRIO_WORDS = ((ScsReg.NVIC_IPR, 0xE4F0, IRQ_BASE), (ScsReg.SHPR1, 0xED24, 4))
CPUID_M4 = 0x410FC241
IDCODE_F401 = 0x10006423  # STM32F401xB/C
AIRCR_VECTKEY, AIRCR_VECTKEYSTAT = 0x05FA, 0xFA050000
AIRCR_SYSRESETREQ = 1 << 2
ICSR_PENDSVSET, ICSR_PENDSTSET, ICSR_PENDSTCLR = 1 << 28, 1 << 26, 1 << 25
SYST_ENABLE, SYST_TICKINT, SYST_COUNTFLAG_BIT = 1 << 0, 1 << 1, 16
SYST_RELOAD_MASK = 0xFFFFFF


class Nvic:
    """Pending/enabled/active exceptions, priorities, and the choice of the next one to take.

    Exception numbers (IRQn + 16) for pending and active, IRQn for enabled."""

    def __init__(self) -> None:
        self.enabled: set[int] = set()
        self.pending: set[int] = set()
        self.active: list[int] = []  # stack of active exception numbers
        self.prio = bytearray(256)  # by exception number
        self.prigroup = 0

    def pend(self, exc: int) -> None:
        self.pending.add(exc)

    def unpend(self, exc: int) -> None:
        self.pending.discard(exc)

    def is_pending(self, exc: int) -> bool:
        return exc in self.pending

    def current(self) -> int:
        """The active exception (0 in thread mode)."""
        return self.active[-1] if self.active else 0

    def word(self, bank: str, i: int) -> int:
        """Bits 32·i .. 32·i + 31 of the IRQ numbers enabled, pending or active (``bank``)."""
        base = i * 32
        if bank == "enabled":
            return sum(1 << b for b in range(32) if base + b in self.enabled)
        held = self.pending if bank == "pending" else self.active
        return sum(1 << b for b in range(32) if base + b + IRQ_BASE in held)

    def set_word(self, bank: str, i: int, mask: int, on: bool) -> None:
        """Set (``on``) or clear the IRQ numbers of ``mask`` in word ``i`` of the enabled or pending bits."""
        base = i * 32
        bits = {base + b for b in range(32) if mask >> b & 1}
        if bank == "pending":
            bits = {b + IRQ_BASE for b in bits}
            self.pending = self.pending | bits if on else self.pending - bits
        else:
            self.enabled = self.enabled | bits if on else self.enabled - bits

    def _group(self, p: int) -> int:
        return p >> (self.prigroup + 1) if self.prigroup >= 4 else p >> 4

    def next_exception(self, primask: int) -> int | None:
        """The pending exception that preempts the current execution priority, or None."""
        if primask & 1 or not self.pending:
            return None
        best = None
        for e in self.pending:
            if e >= IRQ_BASE and (e - IRQ_BASE) not in self.enabled:
                continue
            if best is None or (self.prio[e], e) < (self.prio[best], best):
                best = e
        if best is None:
            return None
        if self.active:
            current = min(self._group(self.prio[a]) for a in self.active)
            if self._group(self.prio[best]) >= current:
                return None
        return best


class Scs(Peripheral):
    """System control space: SysTick, NVIC registers, SCB, DWT, CoreDebug (0xE0000000-0xE00FFFFF).

    ``systick_next`` (instruction count of SysTick's next wrap, or None while disabled) belongs to the board's
    event scheduler (Python or the C core)."""

    name = "SCS"

    def __init__(self, board):
        super().__init__(board, SCS_BASE, SCS_SIZE, reset={ScsReg.CPUID: CPUID_M4})
        self.systick_next: int | None = None
        self.countflag = 0
        self.cyccnt_base = 0  # CYCCNT = now - cyccnt_base (counting) ...
        self.cyccnt_frozen: int | None = 0  # ... or this value while disabled

    def stored(self, off):
        return self.read(off)

    def systick_period(self) -> int:
        return (self.regs.get(ScsReg.SYST_RVR, 0) & SYST_RELOAD_MASK) + 1

    def systick_fire(self) -> None:
        """SysTick wrapped (the Python event loop)."""
        self.countflag = 1
        self.systick_next = (self.systick_next or self.board.now) + self.systick_period()
        if self.regs.get(ScsReg.SYST_CSR, 0) & SYST_TICKINT:
            self.board.nvic.pend(EXC_SYSTICK)

    def cyccnt(self) -> int:
        return self.cyccnt_frozen if self.cyccnt_frozen is not None else self.board.now - self.cyccnt_base

    def read(self, off):
        nvic = self.board.nvic
        if off == ScsReg.SYST_CSR:
            v = self.regs.get(off, 0) | (self.countflag << SYST_COUNTFLAG_BIT)
            self.countflag = 0
            return v
        if off == ScsReg.SYST_CVR:
            if self.systick_next is None:
                return self.regs.get(off, 0)
            return max(0, self.systick_next - self.board.now - 1) % self.systick_period()
        for bank, start, _ in NVIC_BANKS:
            if start <= off < start + NVIC_WORDS:
                return nvic.word(bank, (off - start) // 4)
        for start, end, first in PRIO_WORDS:
            if start <= off < end:
                i = off - start + first
                return int.from_bytes(bytes(nvic.prio[i : i + 4]), "little")
        if off == ScsReg.ICSR:  # VECTACTIVE, PENDSTSET
            return nvic.current() | (ICSR_PENDSTSET if nvic.is_pending(EXC_SYSTICK) else 0)
        if off == ScsReg.AIRCR:
            return AIRCR_VECTKEYSTAT | (nvic.prigroup << 8)
        if off == ScsReg.DWT_CYCCNT:
            return self.cyccnt() & 0xFFFFFFFF
        if off == ScsReg.DBGMCU_IDCODE:
            return IDCODE_F401
        return self.regs.get(off, 0)

    def write(self, off, value):
        nvic = self.board.nvic
        board = self.board
        if off == ScsReg.SYST_CSR:
            was = self.regs.get(off, 0) & SYST_ENABLE
            self.regs[off] = value & 7
            if value & SYST_ENABLE and not was:
                self.systick_next = board.now + self.systick_period()
                board.reschedule()
            elif not value & SYST_ENABLE:
                self.systick_next = None
            return
        if off == ScsReg.SYST_CVR:  # any write clears it, the count restarts
            if self.systick_next is not None:
                self.systick_next = board.now + self.systick_period()
                board.reschedule()
            return
        for bank, start, on in NVIC_BANKS:
            if start <= off < start + NVIC_WORDS and on is not None:
                nvic.set_word(bank, (off - start) // 4, value, on)
                if on:
                    board.irq_check()
                return
        for start, end, first in PRIO_WORDS:
            if start <= off < end:
                i = off - start + first
                nvic.prio[i : i + 4] = value.to_bytes(4, "little")
                return
        if off == ScsReg.ICSR:
            if value & ICSR_PENDSTSET:
                nvic.pend(EXC_SYSTICK)
            if value & ICSR_PENDSTCLR:
                nvic.unpend(EXC_SYSTICK)
            if value & ICSR_PENDSVSET:
                nvic.pend(EXC_PENDSV)
            board.irq_check()
            return
        if off == ScsReg.AIRCR:
            if (value >> 16) == AIRCR_VECTKEY:
                nvic.prigroup = (value >> 8) & 7
                if value & AIRCR_SYSRESETREQ:
                    board.stop_with(EmulationError(f"the firmware requested a system reset (in {board.where()})"))
            return
        if off == ScsReg.DWT_CTRL:  # CYCCNTENA
            on = bool(value & 1)
            if on and self.cyccnt_frozen is not None:
                self.cyccnt_base = board.now - self.cyccnt_frozen
                self.cyccnt_frozen = None
            elif not on and self.cyccnt_frozen is None:
                self.cyccnt_frozen = self.cyccnt()
        elif off == ScsReg.DWT_CYCCNT:
            if self.cyccnt_frozen is not None:
                self.cyccnt_frozen = value
            else:
                self.cyccnt_base = board.now - value
        super().write(off, value)

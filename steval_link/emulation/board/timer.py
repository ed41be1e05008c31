"""General-purpose timers (TIM2, TIM4, TIM9) with update events; TIM9's update drives the firmware's 807.7 Hz tick."""

from __future__ import annotations

from enum import IntEnum

from steval_link.emulation.board.memory_map import IRQ_BASE, Peripheral


class TimReg(IntEnum):
    CR1 = 0x00
    DIER = 0x0C
    SR = 0x10
    EGR = 0x14
    CNT = 0x24
    PSC = 0x28
    ARR = 0x2C
    CCR1 = 0x34
    CCR2 = 0x38
    CCR3 = 0x3C
    CCR4 = 0x40


CEN, URS = 1 << 0, 1 << 2  # CR1
UIF = 1 << 0  # SR
UG = 1 << 0  # EGR


class Timer(Peripheral):
    """TIMx with update events: counter clock 84 MHz / (PSC + 1), update every ARR + 1 counts when CEN is set.

    ``next_update``: the instruction count of the next update event, or None."""

    name = "TIM"

    def __init__(self, board, base, irq: int | None, name: str):
        super().__init__(board, base, name=name)
        self.irq = irq
        self.next_update: int | None = None
        self.updates = 0
        self.first_update: int | None = None

    @property
    def period(self) -> int:
        return (self.regs.get(TimReg.PSC, 0) + 1) * (self.regs.get(TimReg.ARR, 0) + 1)

    def write(self, off, value):
        if off == TimReg.SR:  # rc_w0
            super().write(off, self.regs.get(TimReg.SR, 0) & value)
            self.irq_line()
            return
        super().write(off, value)
        if off == TimReg.CR1:
            running = bool(value & CEN) and self.regs.get(TimReg.ARR, 0) > 0
            if running and self.next_update is None:
                self.next_update = self.board.now + self.period
                self.board.reschedule()
            elif not running:
                self.next_update = None
        elif off == TimReg.DIER:
            self.irq_line()
        elif off == TimReg.EGR and value & UG:  # reload, update flag (unless URS)
            if not self.regs.get(TimReg.CR1, 0) & URS:
                self.regs[TimReg.SR] = self.regs.get(TimReg.SR, 0) | UIF
                self.irq_line()

    def read(self, off):
        if off == TimReg.CNT and self.next_update is not None:
            psc = self.regs.get(TimReg.PSC, 0) + 1
            return (self.period - (self.next_update - self.board.now)) // psc
        return self.regs.get(off, 0)

    def update(self) -> None:
        """An update event (the board's event loop)."""
        self.updates += 1
        if self.first_update is None:
            self.first_update = self.board.now
        self.next_update = (self.next_update or self.board.now) + max(self.period, 1)
        self.regs[TimReg.SR] = self.regs.get(TimReg.SR, 0) | UIF
        self.irq_line()

    def irq_line(self) -> None:
        if self.irq is not None and self.regs.get(TimReg.SR, 0) & self.regs.get(TimReg.DIER, 0) & 0xFF:
            self.board.nvic.pend(self.irq + IRQ_BASE)

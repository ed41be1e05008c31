"""USART1 (PA9 TX, PA10 RX): the transmitter and receiver with the baud rate's byte timing (the Python model).

The C core (``_core.c``) has the same model; this one runs when the extension is not built, and in unit tests.
"""

from __future__ import annotations

from collections import deque
from enum import IntEnum

from steval_link.emulation.board.memory_map import IRQ_BASE, Peripheral


class UsartReg(IntEnum):
    SR = 0x00
    DR = 0x04
    BRR = 0x08
    CR1 = 0x0C
    CR2 = 0x10
    CR3 = 0x14
    GTPR = 0x18


# SR bits
TXE, TC, RXNE, ORE = 1 << 7, 1 << 6, 1 << 5, 1 << 3
# CR1 bits
UE, TXEIE, TCIE, RXNEIE, TE, RE = 1 << 13, 1 << 7, 1 << 6, 1 << 5, 1 << 3, 1 << 2
SR_RESET = TXE | TC
#: BRR when the firmware has not set one (115200 baud at 84 MHz)
BRR_DEFAULT = 729
#: 8N1: start bit, 8 data bits, stop bit
BITS_PER_BYTE = 10


class Usart(Peripheral):
    """USART1: transmitter and receiver, 10 bit times per byte (8N1) at the BRR's baud rate.

    TX: TXE is set while DR is empty (a write goes straight to an idle shift register), TC when the shift register
    is idle too. Every byte leaves at an exact emulated time (instruction count); the board collects them.

    RX (the host → drone line, PA10): :meth:`inject` queues bytes that start on the line at a given emulated time;
    each takes 10 bit times, back to back when they queue up. A byte that completes while the receiver is enabled
    (CR1 UE and RE) lands in the receive register and sets RXNE; if RXNE was still set it is lost and ORE is set
    (the STM32F401's overrun: the receive register keeps the older byte). Reading DR clears RXNE; reading SR then DR
    clears ORE. RXNEIE raises the USART1 interrupt while RXNE or ORE is set. Bytes that complete while the receiver
    is off are lost (counted in :attr:`rx_lost`), as on the wire.
    """

    name = "USART1"

    def __init__(self, board, base, irq):
        super().__init__(board, base, reset={UsartReg.SR: SR_RESET})
        self.irq = irq
        self.dr_full: int | None = None
        self.shift_done: int | None = None  # instruction count when the byte in the shift register has left
        self.shift_byte = 0
        self.tc = 1  # the TC flag (cleared by a DR write or a 0 written to it)
        # RX
        self.rx_queue: deque[tuple[int, int]] = deque()  # (earliest start, byte) not yet complete, by start time
        self.rx_done: int | None = None  # instruction count when the queue's head is complete on the RX line
        self._rx_line_free = 0  # when the last byte completed
        self.rx_dr: int | None = None  # the receive register (RXNE while not None)
        self.rx_last = 0  # what DR reads with RXNE clear
        self.rx_ore = False
        self._ore_sr_read = False  # SR read with ORE set: the next DR read clears ORE
        self.rx_received = 0  # bytes that reached the receive register
        self.rx_overruns = 0  # bytes lost to an overrun
        self.rx_lost = 0  # bytes that completed while the receiver was disabled
        self.rx_log: list[tuple[int, int]] = []  # (byte, instruction count) of every byte completed on the line

    def byte_cycles(self) -> int:
        # 16x oversampling: a bit time = BRR cycles of PCLK2 (= the 84 MHz core clock)
        return BITS_PER_BYTE * (self.regs.get(UsartReg.BRR, 0) or BRR_DEFAULT)

    def _sr(self) -> int:
        sr = self.regs.get(UsartReg.SR, SR_RESET) & ~(TXE | TC | RXNE | ORE)
        if self.dr_full is None:
            sr |= TXE
            if self.shift_done is None and self.tc:
                sr |= TC
        if self.rx_dr is not None:
            sr |= RXNE
        if self.rx_ore:
            sr |= ORE
        return sr

    def bitband_base(self, off):
        return self.regs.get(off, 0) if off == UsartReg.SR else self.read(off)

    def read(self, off):
        if off == UsartReg.SR:
            sr = self._sr()
            self._ore_sr_read = self.rx_ore
            return sr
        if off == UsartReg.DR:
            value = self.rx_dr if self.rx_dr is not None else self.rx_last
            if self.rx_dr is not None:
                self.rx_last = self.rx_dr
            self.rx_dr = None
            if self._ore_sr_read:
                self.rx_ore = False
                self._ore_sr_read = False
            self.irq_line()
            return value
        return self.regs.get(off, 0)

    def write(self, off, value):
        if off == UsartReg.DR:
            value &= 0xFF
            self.tc = 0
            if self.shift_done is None:
                self._start(value)
            else:
                self.dr_full = value
            self.irq_line()
            return
        if off == UsartReg.SR:  # TC and RXNE are rc_w0
            if not value & TC:
                self.tc = 0
            if not value & RXNE:
                self.rx_dr = None
            self.irq_line()
            return
        super().write(off, value)
        if off == UsartReg.CR1:
            self.irq_line()

    def _start(self, byte: int) -> None:
        self.shift_byte = byte
        self.shift_done = self.board.now + self.byte_cycles()
        self.board.reschedule()

    def shift_complete(self) -> None:
        """The byte in the shift register has left (the board's event loop)."""
        self.board.uart_out(self.shift_byte, self.shift_done)
        self.shift_done = None
        if self.dr_full is not None:
            b, self.dr_full = self.dr_full, None
            self._start(b)
        else:
            self.tc = 1
        self.irq_line()

    # -- RX
    def inject(self, data: bytes, t: int) -> None:
        """Queue ``data`` to arrive on the RX line, the first byte starting at instruction count ``t`` (not before
        now, and not before the bytes queued before it are through)."""
        t = max(int(t), self.board.now)
        new = [(t, b) for b in bytes(data)]
        if self.rx_queue and self.rx_queue[-1][0] > t:  # scheduled out of order: keep the queue by start time
            self.rx_queue = deque(sorted(list(self.rx_queue) + new, key=lambda x: x[0]))
        else:
            self.rx_queue.extend(new)
        self._rx_schedule()

    def _rx_schedule(self) -> None:
        """The next byte's completion: the queue's head, on the line from its start or when the line is free."""
        if not self.rx_queue:
            self.rx_done = None
            return
        self.rx_done = max(self.rx_queue[0][0], self._rx_line_free) + self.byte_cycles()
        self.board.reschedule()

    def rx_complete(self) -> None:
        """The byte on the RX line is complete (the board's event loop): into the receive register, or an overrun."""
        t = self.rx_done
        _, byte = self.rx_queue.popleft()
        self._rx_line_free = t
        self.rx_log.append((byte, t))
        cr1 = self.regs.get(UsartReg.CR1, 0)
        if not (cr1 & UE and cr1 & RE):
            self.rx_lost += 1
        elif self.rx_dr is not None:
            self.rx_ore = True
            self.rx_overruns += 1
        else:
            self.rx_dr = byte
            self.rx_received += 1
        self._rx_schedule()
        self.irq_line()

    def irq_line(self) -> None:
        cr1 = self.regs.get(UsartReg.CR1, 0)
        sr = self._sr()
        if (cr1 & TXEIE and sr & TXE) or (cr1 & TCIE and sr & TC) or (cr1 & RXNEIE and sr & (RXNE | ORE)):
            self.board.nvic.pend(self.irq + IRQ_BASE)
        else:
            self.board.nvic.unpend(self.irq + IRQ_BASE)

"""An emulated STM32F401 board (STEVAL-FCU001V1) that runs the firmware ELF unchanged, in unicorn (Cortex-M4).

What is modelled, and how:

- **CPU**: unicorn's Cortex-M4 (Thumb-2, FPv4-SP). One instruction = one cycle of the 84 MHz core clock: every
  emulated time (SysTick, DWT ``CYCCNT``, TIM9, the UART bit clock) is counted in *instructions*, not in real M4
  cycles (no wait states, no pipeline: an M4 needs somewhat more cycles than instructions).
- **NVIC** (unicorn has none): pending/enabled/active bits, priorities (IPR, SHPR, AIRCR.PRIGROUP), PRIMASK,
  preemption, tail-chaining; exception entry pushes the 26-word FP frame and sets EXC_RETURN, the return (unicorn
  raises interrupt 8 on a branch to EXC_RETURN in handler mode) pops it.
- **Register models**: RCC (ready flags follow their enables, SWS follows SW: HAL computes 84 MHz), FLASH, PWR,
  GPIOA..H (ODR/BSRR, IDR reads 0), SYSCFG, EXTI, SysTick, DWT ``CYCCNT``, SCB, TIM2/TIM4/TIM9 (TIM9 update events
  from PSC/ARR), USART1 (DR → shift register, TXE/TC with the baud rate's timing, TXE/TC interrupts; RX: bytes
  injected at emulated times arrive at the baud rate's pace, RXNE/ORE, the RXNE interrupt), SPI1/SPI2 (always
  ready), ADC1 (one conversion on SWSTART), the unique ID, and the peripheral bit-band alias.
- **Function-level replacements** (by symbol): ``Sensor_IO_Read``/``Sensor_IO_Write`` answer from the sensor
  register models (:mod:`steval_link.emulation.sensors`), so ST's drivers and scaling run unchanged;
  ``hci_send_req`` (the only path to the BlueNRG chip) returns success with a zeroed reply, so the BLE init runs
  its real code (or the reply of ``hci_handler``, :mod:`steval_link.emulation.bluenrg`). The replaced calls are
  reported to optional observers.
- **Idle skipping**: when the main loop polls with nothing to do (``isTimerEventExist`` with no flag set),
  ``HAL_Delay`` waits for the tick, or a ``wfi`` sleeps in thread mode, the clock jumps to the next event. No
  payload changes (the polled state only changes in interrupts).

Anything else the firmware touches (an address outside every model) stops the run with
:class:`UnmodelledHardware`, one line naming the function and address. Nothing here holds module-level mutable
state.

Why one module of this size: the CPU, the NVIC and the peripheral models share one unicorn instance, one
instruction clock and the hooks on the hot path (an interrupt per UART byte); each model is a small class here,
and splitting them across modules would spread that shared state, not reduce it.
"""

from __future__ import annotations

import ctypes
import struct
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

from steval_link import constants as C
from steval_link.emulation.elf import Elf
from steval_link.errors import UserError

CPU_HZ = C.CPU_HZ
FLASH_BASE, FLASH_SIZE = 0x08000000, 256 * 1024
RAM_BASE, RAM_SIZE = 0x20000000, 64 * 1024
PERIPH_BASE = 0x40000000
BITBAND_PERIPH = 0x42000000
SCS_BASE = 0xE0000000

# exception numbers (IRQn + 16)
EXC_SYSTICK = 15
IRQ_TIM2 = 28
IRQ_TIM9 = 24
IRQ_USART1 = 37
IRQ_BASE = 16

FP_FRAME_WORDS = 26


class EmulationError(UserError):
    """The firmware did something the board cannot continue from (one line)."""


class UnmodelledHardware(EmulationError):
    """The firmware accessed an address no model covers."""


class FirmwareStuck(EmulationError):
    """The watchdog fired: no progress (a fault handler, an endless wait)."""


# ---- the C instruction counter ---------------------------------------------------------------------------------

class _ICount(ctypes.Structure):
    _fields_ = [("n", ctypes.c_uint64), ("limit", ctypes.c_uint64), ("stop", ctypes.c_void_p)]


def _uclib():
    try:
        from unicorn.unicorn_py3.unicorn import uclib
    except ImportError:  # pragma: no cover - older layout
        from unicorn.unicorn import uclib  # type: ignore
    return uclib


def _native_hook() -> int | None:
    """Address of the C counting hook (``_icount``), or None when the extension is not built."""
    try:
        from steval_link.emulation import _icount  # the optional C extension (built when a compiler exists)
    except ImportError:
        return None
    lib = ctypes.CDLL(_icount.__file__)
    return ctypes.cast(lib.steval_icount_hook, ctypes.c_void_p).value


# ---- peripherals -------------------------------------------------------------------------------------------------

class Peripheral:
    """A peripheral's register file: 32-bit words by offset; subclasses model the registers that do something."""

    name = "periph"

    def __init__(self, board: "Board", base: int, size: int = 0x400, reset: dict[int, int] | None = None):
        self.board = board
        self.base = base
        self.size = size
        self.regs: dict[int, int] = dict(reset or {})

    def read(self, off: int) -> int:
        return self.regs.get(off, 0)

    def write(self, off: int, value: int) -> None:
        self.regs[off] = value & 0xFFFFFFFF


class Rcc(Peripheral):
    name = "RCC"

    def __init__(self, board, base):
        super().__init__(board, base, reset={0x00: 0x83, 0x04: 0x24003010, 0x74: 0x0E000000})

    def read(self, off):
        v = self.regs.get(off, 0)
        if off == 0x00:  # CR: HSIRDY, HSERDY, PLLRDY, PLLI2SRDY follow HSION, HSEON, PLLON, PLLI2SON
            for on, rdy in ((0, 1), (16, 17), (24, 25), (26, 27)):
                v = (v | (1 << rdy)) if v & (1 << on) else (v & ~(1 << rdy))
        elif off == 0x08:  # CFGR: SWS = SW
            v = (v & ~0xC) | ((v & 3) << 2)
        elif off == 0x74:  # CSR: LSIRDY follows LSION
            v = (v | 2) if v & 1 else v & ~2
        elif off == 0x70:  # BDCR: LSERDY follows LSEON
            v = (v | 2) if v & 1 else v & ~2
        return v


class Pwr(Peripheral):
    name = "PWR"

    def read(self, off):
        v = self.regs.get(off, 0)
        return v | (1 << 14) if off == 0x04 else v  # CSR.VOSRDY


class Gpio(Peripheral):
    name = "GPIO"

    def read(self, off):
        if off == 0x10:  # IDR: inputs read low (no buttons, no RC receiver)
            return 0
        return self.regs.get(off, 0)

    def write(self, off, value):
        if off == 0x18:  # BSRR
            odr = self.regs.get(0x14, 0)
            odr = (odr | (value & 0xFFFF)) & ~((value >> 16) & 0xFFFF)
            self.regs[0x14] = odr & 0xFFFF
            return
        super().write(off, value)


class Spi(Peripheral):
    name = "SPI"

    def read(self, off):
        if off == 0x08:  # SR: TXE, RXNE, not busy
            return 0x3
        return self.regs.get(off, 0)


class Adc(Peripheral):
    """ADC1: a conversion completes at once on SWSTART; DR holds the battery divider's reading."""

    name = "ADC1"
    #: 12-bit reading of the battery sense divider: the firmware's VBAT = counts·3.3/4095·(10k + 20k)/20k = 3.90 V, a
    #: charged 1S LiPo
    VBAT_COUNTS = 3226

    def read(self, off):
        if off == 0x00:
            return self.regs.get(0, 0)
        if off == 0x4C:  # DR: reading clears EOC
            self.regs[0] = self.regs.get(0, 0) & ~2
            return self.VBAT_COUNTS
        return self.regs.get(off, 0)

    def write(self, off, value):
        if off == 0x08 and value & (1 << 30):  # CR2.SWSTART
            self.regs[0] = self.regs.get(0, 0) | 0x2 | 0x10  # EOC, STRT
            value &= ~(1 << 30)
        if off == 0x00:  # SR: rc_w0
            value = self.regs.get(0, 0) & value
        super().write(off, value)


class Timer(Peripheral):
    """TIMx with update events: counter clock 84 MHz / (PSC + 1), update every ARR + 1 counts when CEN is set."""

    name = "TIM"

    def __init__(self, board, base, irq: int | None, name: str):
        super().__init__(board, base)
        self.irq = irq
        self.name = name
        self.next_update: int | None = None  # instruction count of the next update event
        self.updates = 0
        self.first_update: int | None = None

    @property
    def period(self) -> int:
        return (self.regs.get(0x28, 0) + 1) * (self.regs.get(0x2C, 0) + 1)

    def write(self, off, value):
        if off == 0x10:  # SR: rc_w0
            value = self.regs.get(0x10, 0) & value
            super().write(off, value)
            self._irq_line()
            return
        super().write(off, value)
        if off == 0x00:
            running = bool(value & 1) and self.regs.get(0x2C, 0) > 0
            if running and self.next_update is None:
                self.next_update = self.board.now + self.period
                self.board.reschedule()
            elif not running:
                self.next_update = None
        elif off == 0x0C:
            self._irq_line()
        elif off == 0x14 and value & 1:  # EGR.UG: reload, update flag (unless URS)
            if not self.regs.get(0x00, 0) & 4:
                self.regs[0x10] = self.regs.get(0x10, 0) | 1
                self._irq_line()

    def read(self, off):
        if off == 0x24 and self.next_update is not None:  # CNT
            psc = self.regs.get(0x28, 0) + 1
            return (self.period - (self.next_update - self.board.now)) // psc
        return self.regs.get(off, 0)

    def update(self) -> None:
        """An update event (board event loop)."""
        self.updates += 1
        if self.first_update is None:
            self.first_update = self.board.now
        self.next_update = (self.next_update or self.board.now) + max(self.period, 1)
        self.regs[0x10] = self.regs.get(0x10, 0) | 1
        self._irq_line()
        if self is self.board.tim9:
            for ob in self.board.tick_observers:
                ob(self.board)

    def _irq_line(self) -> None:
        if self.irq is not None and self.regs.get(0x10, 0) & self.regs.get(0x0C, 0) & 0xFF:
            self.board.nvic.set_pending(self.irq)


class Usart(Peripheral):
    """USART1: transmitter and receiver, 10 bit times per byte (8N1) at the BRR's baud rate.

    TX: TXE is set while DR is empty (a write goes straight to an idle shift register), TC when the shift register
    is idle too. Every byte leaves at an exact emulated time (instruction count); the board collects them.

    RX (the host → drone line, PA10): :meth:`inject` queues bytes that start on the line at a given emulated time;
    each takes 10 bit times, back to back when they queue up. A byte that completes while the receiver is enabled
    (CR1 UE and RE) lands in the receive register and sets RXNE; if RXNE was still set it is lost and ORE is set
    (the STM32F401's overrun: the receive register keeps the older byte). Reading DR clears RXNE; reading SR then DR
    clears ORE. RXNEIE (CR1 bit 5) raises the USART1 interrupt while RXNE or ORE is set. Bytes that complete while
    the receiver is off are lost (counted in :attr:`rx_lost`), as on the wire.
    """

    name = "USART1"

    def __init__(self, board, base, irq):
        super().__init__(board, base, reset={0x00: 0xC0})
        self.irq = irq
        self.dr_full: int | None = None
        self.shift_done: int | None = None  # instruction count when the byte in the shift register has left
        self.shift_byte = 0
        # RX
        self.rx_queue: deque[tuple[int, int]] = deque()  # (earliest start, byte) not yet complete, by start time
        self.rx_done: int | None = None  # instruction count when the queue's head is complete on the RX line
        self._rx_line_free = 0  # when the last byte completed
        self.rx_byte = 0
        self.rx_dr: int | None = None  # the receive register (RXNE while not None)
        self.rx_ore = False
        self._ore_sr_read = False  # SR read with ORE set: the next DR read clears ORE
        self.rx_received = 0  # bytes that reached the receive register
        self.rx_overruns = 0  # bytes lost to an overrun
        self.rx_lost = 0  # bytes that completed while the receiver was disabled
        self.rx_log: list[tuple[int, int]] = []  # (byte, instruction count) of every byte completed on the line

    def byte_cycles(self) -> int:
        brr = self.regs.get(0x08, 0) or 729
        return 10 * brr  # 16x oversampling: bit time = BRR cycles of PCLK2 (= the 84 MHz core clock)

    def _sr(self) -> int:
        sr = self.regs.get(0x00, 0xC0) & ~0xE8
        if self.dr_full is None:
            sr |= 0x80
            if self.shift_done is None:
                sr |= 0x40 if self.regs.get("tc", 1) else 0
        if self.rx_dr is not None:
            sr |= 0x20
        if self.rx_ore:
            sr |= 0x08
        return sr

    def read(self, off):
        if off == 0x00:
            sr = self._sr()
            self._ore_sr_read = self.rx_ore
            return sr
        if off == 0x04:
            value = self.rx_dr if self.rx_dr is not None else self.regs.get("rx_last", 0)
            if self.rx_dr is not None:
                self.regs["rx_last"] = self.rx_dr
            self.rx_dr = None
            if self._ore_sr_read:
                self.rx_ore = False
                self._ore_sr_read = False
            self._irq_line()
            return value
        return self.regs.get(off, 0)

    def write(self, off, value):
        if off == 0x04:
            value &= 0xFF
            self.regs["tc"] = 0
            if self.shift_done is None:
                self._start(value)
            else:
                self.dr_full = value
            self._irq_line()
            return
        if off == 0x00:  # SR: TC and RXNE are rc_w0
            if not value & 0x40:
                self.regs["tc"] = 0
            if not value & 0x20:
                self.rx_dr = None
            self._irq_line()
            return
        super().write(off, value)
        if off == 0x0C:
            self._irq_line()

    def _start(self, byte: int) -> None:
        self.shift_byte = byte
        self.shift_done = self.board.now + self.byte_cycles()
        self.board.reschedule()

    def shift_complete(self) -> None:
        """The byte in the shift register has left (board event loop)."""
        t = self.shift_done
        self.board.uart_out(self.shift_byte, t)
        self.shift_done = None
        if self.dr_full is not None:
            b, self.dr_full = self.dr_full, None
            self._start(b)
        else:
            self.regs["tc"] = 1
        self._irq_line()

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
        """The byte on the RX line is complete (board event loop): into the receive register, or an overrun."""
        t = self.rx_done
        _, self.rx_byte = self.rx_queue.popleft()
        self._rx_line_free = t
        self.rx_log.append((self.rx_byte, t))
        cr1 = self.regs.get(0x0C, 0)
        if not (cr1 & 0x2000 and cr1 & 0x04):
            self.rx_lost += 1
        elif self.rx_dr is not None:
            self.rx_ore = True
            self.rx_overruns += 1
        else:
            self.rx_dr = self.rx_byte
            self.rx_received += 1
        self._rx_schedule()
        self._irq_line()

    def _irq_line(self) -> None:
        cr1 = self.regs.get(0x0C, 0)
        sr = self._sr()
        if (cr1 & 0x80 and sr & 0x80) or (cr1 & 0x40 and sr & 0x40) or (cr1 & 0x20 and sr & 0x28):
            self.board.nvic.set_pending(self.irq)
        else:
            self.board.nvic.clear_pending(self.irq)


class Nvic:
    """Pending/enabled/active exceptions, priorities, and the choice of the next one to take."""

    def __init__(self) -> None:
        self.enabled: set[int] = set()
        self.pending: set[int] = set()
        self.active: list[int] = []  # stack of active exception numbers
        self.prio = bytearray(256)  # by exception number
        self.prigroup = 0

    def set_pending(self, irq: int) -> None:
        self.pending.add(irq + IRQ_BASE)

    def clear_pending(self, irq: int) -> None:
        self.pending.discard(irq + IRQ_BASE)

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
    """System control space: SysTick, NVIC registers, SCB, DWT, CoreDebug (0xE0000000-0xE00FFFFF)."""

    name = "SCS"

    def __init__(self, board):
        super().__init__(board, SCS_BASE, 0x100000, reset={0xED00: 0x410FC241})
        self.systick_next: int | None = None
        self.cyccnt_base = 0  # CYCCNT = now - cyccnt_base (counting) ...
        self.cyccnt_frozen: int | None = 0  # ... or this value while disabled

    # SysTick
    def _systick_period(self) -> int:
        return (self.regs.get(0xE014, 0) & 0xFFFFFF) + 1

    def systick_fire(self) -> None:
        self.regs["countflag"] = 1
        self.systick_next = (self.systick_next or self.board.now) + self._systick_period()
        if self.regs.get(0xE010, 0) & 2:
            self.board.nvic.pending.add(EXC_SYSTICK)

    def read(self, off):
        nvic = self.board.nvic
        if off == 0xE010:
            v = self.regs.get(off, 0) | (self.regs.pop("countflag", 0) << 16)
            return v
        if off == 0xE018:
            if self.systick_next is None:
                return self.regs.get(off, 0)
            return max(0, self.systick_next - self.board.now - 1) % self._systick_period()
        if 0xE100 <= off < 0xE120 or 0xE180 <= off < 0xE1A0:  # ISER/ICER
            base = (off & 0x1F) * 8
            return sum(1 << i for i in range(32) if base + i in nvic.enabled)
        if 0xE200 <= off < 0xE220 or 0xE280 <= off < 0xE2A0:  # ISPR/ICPR
            base = (off & 0x1F) * 8
            return sum(1 << i for i in range(32) if base + i + IRQ_BASE in nvic.pending)
        if 0xE300 <= off < 0xE320:  # IABR
            base = (off & 0x1F) * 8
            return sum(1 << i for i in range(32) if base + i + IRQ_BASE in nvic.active)
        if 0xE400 <= off < 0xE4F0:
            i = off - 0xE400 + IRQ_BASE
            return int.from_bytes(nvic.prio[i:i + 4], "little")
        if 0xED18 <= off < 0xED24:
            i = off - 0xED18 + 4
            return int.from_bytes(nvic.prio[i:i + 4], "little")
        if off == 0xED04:  # ICSR: VECTACTIVE, PENDSTSET
            v = nvic.active[-1] if nvic.active else 0
            return v | ((1 << 26) if EXC_SYSTICK in nvic.pending else 0)
        if off == 0xED0C:
            return 0xFA050000 | (nvic.prigroup << 8)
        if off == 0x1004:  # DWT CYCCNT
            return self.cyccnt() & 0xFFFFFFFF
        if off == 0x42000:  # DBGMCU IDCODE: STM32F401xB/C
            return 0x10006423
        return self.regs.get(off, 0)

    def cyccnt(self) -> int:
        return self.cyccnt_frozen if self.cyccnt_frozen is not None else self.board.now - self.cyccnt_base

    def write(self, off, value):
        nvic = self.board.nvic
        if off == 0xE010:
            was = self.regs.get(off, 0) & 1
            self.regs[off] = value & 7
            if value & 1 and not was:
                self.systick_next = self.board.now + self._systick_period()
                self.board.reschedule()
            elif not value & 1:
                self.systick_next = None
            return
        if off == 0xE018:  # VAL: any write clears it, the count restarts
            if self.systick_next is not None:
                self.systick_next = self.board.now + self._systick_period()
                self.board.reschedule()
            return
        if 0xE100 <= off < 0xE120:
            base = (off & 0x1F) * 8
            nvic.enabled |= {base + i for i in range(32) if value >> i & 1}
            self.board.irq_check()
            return
        if 0xE180 <= off < 0xE1A0:
            base = (off & 0x1F) * 8
            nvic.enabled -= {base + i for i in range(32) if value >> i & 1}
            return
        if 0xE200 <= off < 0xE220:
            base = (off & 0x1F) * 8
            nvic.pending |= {base + i + IRQ_BASE for i in range(32) if value >> i & 1}
            self.board.irq_check()
            return
        if 0xE280 <= off < 0xE2A0:
            base = (off & 0x1F) * 8
            nvic.pending -= {base + i + IRQ_BASE for i in range(32) if value >> i & 1}
            return
        if 0xE400 <= off < 0xE4F0:
            nvic.prio[off - 0xE400 + IRQ_BASE:off - 0xE400 + IRQ_BASE + 4] = value.to_bytes(4, "little")
            return
        if 0xED18 <= off < 0xED24:
            nvic.prio[off - 0xED18 + 4:off - 0xED18 + 8] = value.to_bytes(4, "little")
            return
        if off == 0xED04:
            if value & (1 << 26):
                nvic.pending.add(EXC_SYSTICK)
            if value & (1 << 25):
                nvic.pending.discard(EXC_SYSTICK)
            if value & (1 << 28):
                nvic.pending.add(14)
            self.board.irq_check()
            return
        if off == 0xED0C:
            if (value >> 16) == 0x05FA:
                nvic.prigroup = (value >> 8) & 7
                if value & 4:
                    raise EmulationError(f"the firmware requested a system reset (in {self.board.where()})")
            return
        if off == 0x1000:  # DWT CTRL: CYCCNTENA
            on = bool(value & 1)
            if on and self.cyccnt_frozen is not None:
                self.cyccnt_base = self.board.now - self.cyccnt_frozen
                self.cyccnt_frozen = None
            elif not on and self.cyccnt_frozen is None:
                self.cyccnt_frozen = self.cyccnt()
        elif off == 0x1004:
            if self.cyccnt_frozen is not None:
                self.cyccnt_frozen = value
            else:
                self.cyccnt_base = self.board.now - value
        super().write(off, value)


# ---- the board ---------------------------------------------------------------------------------------------------

@dataclass
class StepCount:
    """Instructions of one AHRS step (main loop), as counted by the emulator (not M4 cycles)."""

    step: int
    instructions: int


@dataclass
class BoardStats:
    instructions: int = 0
    interrupts: dict[int, int] = field(default_factory=dict)
    skipped_instructions: int = 0
    slices: int = 0


class Board:
    """The STEVAL-FCU001V1's MCU running one firmware ELF.

    Args:
        elf: the firmware (path or :class:`Elf`).
        sensors: the sensor bus (:class:`steval_link.emulation.sensors.SensorBus`) answering ``Sensor_IO_*``.
        skip_idle: jump the clock over idle polling (no payload changes; off only to check exactly that).
    """

    def __init__(self, elf: Elf | str, sensors, *, skip_idle: bool = True, native: bool | None = None):
        from unicorn import UC_ARCH_ARM, UC_MODE_MCLASS, UC_MODE_THUMB, Uc
        from unicorn import arm_const as A

        self.elf = elf if isinstance(elf, Elf) else Elf(elf)
        self.sensors = sensors
        self._A = A
        uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(A.UC_CPU_ARM_CORTEX_M4)
        self.uc = uc
        self.now = 0  # instructions since reset (= 84 MHz cycles of this model)
        self.stats = BoardStats()
        self.nvic = Nvic()
        self.out: deque[tuple[int, int]] = deque()  # (byte, instruction count when it left the line)
        self.fault: EmulationError | None = None
        self.call_observers: dict[str, list[Callable]] = {}
        self._next_event = 0
        self._slice_start = 0
        self._skip_base = 0
        self._run_end = 0
        self._resumed_idle = False
        #: called with the board at each TIM9 update event (the runner's remote control)
        self.tick_observers: list[Callable] = []
        #: instructions executed inside exception handlers (entry to the return to thread mode)
        self.exception_instructions = 0
        self._exc_started = 0
        self.usart_enabled_at = None

        self._map_memory()
        self._setup_regs()
        self._make_peripherals()
        self._install_counter(native)
        self._install_hooks(skip_idle)
        self._reset()

    # -- memory and peripherals
    def _map_memory(self) -> None:
        uc = self.uc
        self._flash = ctypes.create_string_buffer(FLASH_SIZE)
        self._ram = ctypes.create_string_buffer(RAM_SIZE)
        flash_ptr = ctypes.addressof(self._flash)
        ctypes.memset(flash_ptr, 0xFF, FLASH_SIZE)
        for addr, data in self.elf.segments:
            if FLASH_BASE <= addr and addr + len(data) <= FLASH_BASE + FLASH_SIZE:
                ctypes.memmove(flash_ptr + addr - FLASH_BASE, data, len(data))
            elif RAM_BASE <= addr and addr + len(data) <= RAM_BASE + RAM_SIZE:
                ctypes.memmove(ctypes.addressof(self._ram) + addr - RAM_BASE, data, len(data))
            else:
                raise UserError(f"{self.elf.path}: a segment at 0x{addr:08x} ({len(data)} B) lies outside the "
                                "STM32F401VC's 256 KB flash / 64 KB RAM")
        uc.mem_map_ptr(FLASH_BASE, FLASH_SIZE, 5, flash_ptr)
        uc.mem_map_ptr(0, FLASH_SIZE, 5, flash_ptr)  # boot alias
        uc.mem_map_ptr(RAM_BASE, RAM_SIZE, 7, ctypes.addressof(self._ram))
        self._ram_mv = memoryview(self._ram).cast("B")  # (ctypes' .raw copies the whole buffer)
        # system memory, OTP, option bytes (read only; the UID lives in system memory at 0x1FFF7A10)
        self._sysmem = ctypes.create_string_buffer(0x8000)
        ctypes.memmove(ctypes.addressof(self._sysmem) + 0x7A10, struct.pack("<III", 0x00380021, 0x3437510B,
                                                                              0x34353532), 12)
        uc.mem_map_ptr(0x1FFF0000, 0x8000, 1, ctypes.addressof(self._sysmem))

    def ram_u32(self, addr: int) -> int:
        return struct.unpack_from("<I", self._ram, addr - RAM_BASE)[0]

    def ram_write(self, addr: int, data: bytes) -> None:
        ctypes.memmove(ctypes.addressof(self._ram) + addr - RAM_BASE, data, len(data))

    def instructions_now(self) -> int:
        """Instructions executed so far (inside a hook: up to the current one)."""
        return self.stats.instructions + self._ic.n

    def probe(self, addr: int, fn: Callable) -> None:
        """Call ``fn(board)`` whenever the CPU reaches ``addr`` (a function entry), with the clock in sync."""
        from unicorn import UC_HOOK_CODE

        def hook(uc, address, size, user):
            self._sync_now()
            fn(self)

        self.uc.hook_add(UC_HOOK_CODE, hook, begin=addr, end=addr)

    def ram_read(self, addr: int, n: int) -> bytes:
        return bytes(self._ram_mv[addr - RAM_BASE:addr - RAM_BASE + n])

    def _make_peripherals(self) -> None:
        P = PERIPH_BASE
        self.rcc = Rcc(self, P + 0x23800)
        self.tim9 = Timer(self, P + 0x14000, IRQ_TIM9, "TIM9")
        self.tim2 = Timer(self, P + 0x0000, IRQ_TIM2, "TIM2")
        self.tim4 = Timer(self, P + 0x0800, None, "TIM4")
        self.usart1 = Usart(self, P + 0x11000, IRQ_USART1)
        self.scs = Scs(self)
        periphs: list[Peripheral] = [self.rcc, self.tim9, self.tim2, self.tim4, self.usart1]
        periphs.append(Pwr(self, P + 0x7000))
        flash_if = Peripheral(self, P + 0x23C00)
        flash_if.name = "FLASH"
        periphs.append(flash_if)
        for i, port in enumerate("ABCDE"):
            g = Gpio(self, P + 0x20000 + 0x400 * i)
            g.name = f"GPIO{port}"
            periphs.append(g)
        gh = Gpio(self, P + 0x21C00)
        gh.name = "GPIOH"
        periphs.append(gh)
        for name, off in (("SYSCFG", 0x13800), ("EXTI", 0x13C00), ("CRC", 0x23000), ("DMA1", 0x26000),
                          ("DMA2", 0x26400), ("TIM3", 0x0400), ("TIM5", 0x0C00), ("TIM1", 0x10000),
                          ("TIM10", 0x14400), ("TIM11", 0x14800), ("IWDG", 0x3000), ("WWDG", 0x2C00),
                          ("RTC", 0x2800), ("USART2", 0x4400), ("USART6", 0x11400), ("I2C1", 0x5400),
                          ("I2C2", 0x5800), ("I2C3", 0x5C00), ("DBGMCU", None)):
            if off is None:
                continue
            p = Peripheral(self, P + off)
            p.name = name
            periphs.append(p)
        for name, off in (("SPI1", 0x13000), ("SPI2", 0x3800), ("SPI3", 0x3C00), ("SPI4", 0x13400)):
            s = Spi(self, P + off)
            s.name = name
            periphs.append(s)
        adc = Adc(self, P + 0x12000)
        periphs.append(adc)
        self.periphs = sorted(periphs, key=lambda p: p.base)
        self._by_page = {p.base >> 10: p for p in self.periphs}
        uc = self.uc
        for p in self.periphs:
            uc.mmio_map(p.base, p.size, self._mmio_read, p, self._mmio_write, p)
        uc.mmio_map(BITBAND_PERIPH, 0x2000000, self._bb_read, None, self._bb_write, None)
        uc.mmio_map(SCS_BASE, 0x100000, self._mmio_read, self.scs, self._mmio_write, self.scs)

    def _mmio_read(self, uc, off, size, p: Peripheral):
        self.now = self._slice_start + self._ic.n + self._skip_base
        word = p.read(off & ~3)
        sh = (off & 3) * 8
        return (word >> sh) & ((1 << (8 * size)) - 1)

    def _mmio_write(self, uc, off, size, value, p: Peripheral):
        self.now = self._slice_start + self._ic.n + self._skip_base
        if size != 4:
            sh = (off & 3) * 8
            mask = ((1 << (8 * size)) - 1) << sh
            old = p.regs.get(off & ~3, 0) if not isinstance(p, Scs) else p.read(off & ~3)
            value = (old & ~mask) | ((value << sh) & mask)
        p.write(off & ~3, value)

    def _bb_target(self, off: int) -> tuple[Peripheral, int, int]:
        addr = PERIPH_BASE + (off >> 5)
        bit = (off >> 2) & 7 | ((addr & 3) << 3)
        p = self._by_page.get(addr >> 10)
        if p is None:
            self._unmodelled(addr, "bit-band access to")
        return p, (addr & ~3) - p.base, bit

    def _bb_read(self, uc, off, size, user):
        self.now = self._slice_start + self._ic.n + self._skip_base
        p, reg, bit = self._bb_target(off)
        return (p.read(reg) >> bit) & 1

    def _bb_write(self, uc, off, size, value, user):
        self.now = self._slice_start + self._ic.n + self._skip_base
        p, reg, bit = self._bb_target(off)
        old = p.read(reg) if not isinstance(p, Usart) or reg != 0 else p.regs.get(0, 0)
        p.write(reg, (old | (1 << bit)) if value & 1 else (old & ~(1 << bit)))

    def _unmodelled(self, addr: int, what: str = "access to") -> None:
        self.fault = UnmodelledHardware(
            f"the firmware touched hardware the emulated board does not model: {what} 0x{addr:08x} in "
            f"{self.where()} (pc 0x{self.pc():08x}, t = {self.now / CPU_HZ:.6f} s)")
        self.request_stop()

    # -- CPU helpers
    def pc(self) -> int:
        return self.reg(self._PC)

    def where(self) -> str:
        return self.elf.func_at(self.pc())

    # -- the counter
    def _install_counter(self, native: bool | None) -> None:
        from unicorn import UC_HOOK_BLOCK, UC_HOOK_CODE

        uclib = _uclib()
        self._ic = _ICount(0, 1, ctypes.cast(uclib.uc_emu_stop, ctypes.c_void_p).value)
        hook = _native_hook() if native in (None, True) else None
        if native and hook is None:
            raise UserError("the C instruction counter (steval_link.emulation._icount) is not built")
        self.native = hook is not None
        if hook is not None:
            h = ctypes.c_size_t()
            err = uclib.uc_hook_add(self.uc._uch, ctypes.byref(h), UC_HOOK_CODE, ctypes.c_void_p(hook),
                                    ctypes.byref(self._ic), ctypes.c_uint64(1), ctypes.c_uint64(0))
            if err:
                raise EmulationError(f"unicorn refused the instruction counter hook (error {err})")
        else:
            sizes: dict[int, int] = {}
            ic = self._ic
            flash = self._flash

            def count_block(uc, address, size, user):
                n = sizes.get(address)
                if n is None:
                    n = _thumb_count(flash, address, size)
                    sizes[address] = n
                ic.n += n
                if ic.n >= ic.limit:
                    uc.emu_stop()

            self.uc.hook_add(UC_HOOK_BLOCK, count_block)

    def request_stop(self) -> None:
        """Stop the CPU at the next instruction (to take an interrupt, to report a fault)."""
        self._ic.limit = min(self._ic.limit, self._ic.n + 1)

    def _sync_now(self) -> None:
        self.now = self._slice_start + self._ic.n + self._skip_base

    # -- hooks: exception return, replaced functions, idle skip, unmapped memory
    def _install_hooks(self, skip_idle: bool) -> None:
        from unicorn import UC_HOOK_CODE, UC_HOOK_INTR, UC_HOOK_MEM_INVALID

        uc = self.uc
        uc.hook_add(UC_HOOK_INTR, self._on_intr)
        uc.hook_add(UC_HOOK_MEM_INVALID, self._on_invalid)
        e = self.elf
        replaced = {"Sensor_IO_Read": self._sensor_read, "Sensor_IO_Write": self._sensor_write,
                    "hci_send_req": self._hci_send_req}
        for name, fn in replaced.items():
            a = e.addr(name)
            if a is not None:
                uc.hook_add(UC_HOOK_CODE, self._replacement(name, fn), begin=a, end=a)
        # PRIMASK cleared (cpsie i, msr primask): take what became pending
        for a in _cpsie_sites(self._flash, e):
            uc.hook_add(UC_HOOK_CODE, self._after_unmask, begin=a, end=a)
        # fault handlers and the default handler loop forever: stop with their name
        for name in ("HardFault_Handler", "MemManage_Handler", "BusFault_Handler", "UsageFault_Handler",
                     "Default_Handler", "Error_Handler", "_Error_Handler"):
            a = e.addr(name)
            if a is not None:
                uc.hook_add(UC_HOOK_CODE, self._fault_handler(name), begin=a, end=a)
        self._idle_state = None
        if skip_idle:
            self._setup_idle(e)

    def _replacement(self, name: str, fn: Callable):
        observers = self.call_observers.setdefault(name, [])

        R0 = self._R[0]
        PC = self._PC
        set_reg = self.set_reg
        ids = [self._R[0], self._R[1], self._R[2], self._R[3], self._LR]
        arg_ids = (ctypes.c_int32 * 5)(*ids)
        arg_vals = (ctypes.c_uint32 * 5)()
        base = ctypes.addressof(arg_vals)
        arg_ptrs = (ctypes.c_void_p * 5)(*[base + 4 * i for i in range(5)])
        read_batch, uch = self._c_read_batch, self._uch

        def hook(uc, address, size, user):
            read_batch(uch, arg_ids, arg_ptrs, 5)
            r0, r1, r2, r3, lr = arg_vals
            self._sync_now()
            rv = fn(r0, r1, r2, r3)
            for ob in observers:
                ob(self, r0, r1, r2, r3)
            set_reg(R0, rv)
            set_reg(PC, lr | 1)

        return hook

    def _sensor_read(self, handle, reg, buf, n) -> int:
        device = self._ram_byte(handle + 3)  # DrvContextTypeDef.spiDevice
        data = self.sensors.read(device, reg & 0x7F, n & 0xFFFF, self)
        if RAM_BASE <= buf and buf + len(data) <= RAM_BASE + RAM_SIZE:
            ctypes.memmove(ctypes.addressof(self._ram) + buf - RAM_BASE, data, len(data))
        else:
            self.uc.mem_write(buf, data)
        return 0

    def _sensor_write(self, handle, reg, buf, n) -> int:
        device = self._ram_byte(handle + 3)
        self.sensors.write(device, reg & 0x7F, bytes(self.uc.mem_read(buf, n & 0xFFFF)), self)
        return 0

    def _ram_byte(self, addr: int) -> int:
        if RAM_BASE <= addr < RAM_BASE + RAM_SIZE:
            return ctypes.c_uint8.from_buffer(self._ram, addr - RAM_BASE).value
        return self.uc.mem_read(addr, 1)[0]

    def _hci_send_req(self, req, is_async, _r2, _r3) -> int:
        ogf, ocf, _event, cparam, clen, rparam, rlen = struct.unpack("<HHiIiIi", self.uc.mem_read(req, 24))
        reply = b""
        if self.hci_handler is not None:  # e.g. emulation.bluenrg: GATT handles, RSSI, the notifications sent
            params = bytes(self.uc.mem_read(cparam, clen)) if cparam and 0 < clen <= 1024 else b""
            reply = self.hci_handler(ogf, ocf, params, self) or b""
        if rparam and rlen > 0:
            self.uc.mem_write(rparam, (bytes(reply) + bytes(rlen))[:rlen])
        self.hci_requests += 1
        return 0

    hci_requests = 0
    #: ``handler(ogf, ocf, command parameters, board) -> reply bytes`` for ``hci_send_req`` (None: zeroed replies)
    hci_handler: Callable | None = None

    def _fault_handler(self, name: str):
        def hook(uc, address, size, user):
            self._sync_now()
            lr = uc.reg_read(self._A.UC_ARM_REG_SP)
            try:
                stacked_pc = struct.unpack("<I", uc.mem_read(lr + 24, 4))[0]
                origin = f" (interrupted {self.elf.func_at(stacked_pc)}, pc 0x{stacked_pc:08x})"
            except Exception:  # noqa: BLE001 - best effort description
                origin = ""
            what = {"Default_Handler": "an interrupt without a handler"}.get(name, name)
            active = self.nvic.active[-1] if self.nvic.active else 0
            self.fault = FirmwareStuck(f"the firmware entered {what} (exception {active}){origin} at "
                                       f"t = {self.now / CPU_HZ:.6f} s")
            self.request_stop()
        return hook

    def _after_unmask(self, uc, address, size, user):
        if self.nvic.pending:
            self.request_stop()

    def irq_check(self) -> None:
        """A register write may have made an interrupt takeable: stop soon to deliver it."""
        if self.nvic.pending:
            self.request_stop()

    def _on_invalid(self, uc, access, address, size, value, user):
        from unicorn import UC_MEM_WRITE, UC_MEM_WRITE_UNMAPPED

        self._sync_now()
        kind = "write to" if access in (UC_MEM_WRITE_UNMAPPED, UC_MEM_WRITE) else "read of"
        if access not in (19, 20, 21) and access >= 22:  # fetch / protection: execution went astray
            kind = "execution at" if access in (21, 25) else kind
        self._unmodelled(address, kind)
        return False

    # -- idle skipping
    def _setup_idle(self, e: Elf) -> None:
        from unicorn import UC_HOOK_CODE

        uc = self.uc
        names = ("tim9_event_flag", "HCI_ProcessEvent", "set_connectable", "tim")
        addrs = [e.addr(n) for n in names]
        poll = e.addr("isTimerEventExist")
        if poll is not None and all(a is not None for a in addrs):
            flag, hci, conn, tim = addrs
            sizes = {n: e.by_name[n].size for n in names}
            tim_event = tim + 16  # tUserTimer.event_cnt (interval, target_tick, flag, flag2, event_cnt)

            fmt = {1: "<B", 2: "<H", 4: "<I"}
            checks = [(fmt.get(min(sizes[n], 4), "<I"), a - RAM_BASE)
                      for n, a in (("tim9_event_flag", flag), ("HCI_ProcessEvent", hci), ("set_connectable", conn))]
            checks.append(("<I", tim_event - RAM_BASE))
            ram = self._ram
            unpack_from = struct.unpack_from

            def idle(uc, address, size, user):
                if self.nvic.pending:
                    return
                for f, off in checks:
                    if unpack_from(f, ram, off)[0]:
                        return
                self._skip_to_event()

            uc.hook_add(UC_HOOK_CODE, idle, begin=poll, end=poll)
        delay = e.by_name.get("HAL_Delay")
        get_tick = e.addr("HAL_GetTick")
        if delay is not None and get_tick is not None:
            lo, hi = delay.addr & ~1, (delay.addr & ~1) + max(delay.size, 2)
            LR = self._LR

            def delay_poll(uc, address, size, user):
                if lo <= (self.reg(LR) & ~1) < hi and not self.nvic.pending:
                    self._skip_to_event()

            uc.hook_add(UC_HOOK_CODE, delay_poll, begin=get_tick, end=get_tick)
        # a firmware that sleeps with `wfi` (unicorn runs it as a no-op): the clock jumps to the next event
        for a in _wfi_sites(self._flash, e):
            uc.hook_add(UC_HOOK_CODE, self._on_wfi, begin=a, end=a)

    def _on_wfi(self, uc, address, size, user):
        """``wfi`` in thread mode with no interrupt pending: skip to the next event. Its interrupt is taken here
        when PRIMASK allows, else at the ``cpsie i`` after the ``wfi`` (as the chip wakes with PRIMASK set)."""
        if not self.nvic.active and self.nvic.next_exception(0) is None:
            self._skip_to_event()

    def _u(self, addr: int, size: int) -> int:
        off = addr - RAM_BASE
        return int.from_bytes(self._ram_mv[off:off + min(size, 4)], "little") if 0 <= off < RAM_SIZE else 1

    def _skip_to_event(self) -> None:
        """Called in a code hook when the CPU (thread mode) has nothing to do until the next event.

        The clock jumps to that event; it fires here and its interrupt is taken at once (PC redirected inside the
        hook), so an idle CPU goes from event to event without leaving the emulation. At the end of the current
        run the CPU stops instead.
        """
        if self.nvic.active:
            return
        if self._resumed_idle:
            # back from the handler taken here: this visit runs normally (the poll sees what the handler did)
            self._resumed_idle = False
            return
        ic = self._ic
        now = self._slice_start + ic.n + self._skip_base
        nxt = self._earliest()
        if nxt is None or nxt >= self._run_end:
            if self._run_end > now:
                self.stats.skipped_instructions += self._run_end - now
                self._skip_base += self._run_end - now
            ic.limit = ic.n + 1
            return
        if nxt > now:
            self.stats.skipped_instructions += nxt - now
            self._skip_base += nxt - now
        self.now = self._slice_start + ic.n + self._skip_base
        self._fire_events()
        if self.nvic.pending:
            exc = self.nvic.next_exception(self.reg(self._PRIMASK))
            if exc is not None:
                # the polled instruction did not run: it runs again after the handler
                ic.n -= 1
                self._skip_base += 1
                self._take(exc)
                self._resumed_idle = True
        end = self._earliest()
        end = self._run_end if end is None else min(end, self._run_end)
        self._next_event = end
        ic.limit = max(end - self._slice_start - self._skip_base + 1, ic.n + 1)

    # -- registers through unicorn's C API (the Python binding's per-call class lookup costs ~5 µs a register)
    def _setup_regs(self) -> None:
        A = self._A
        uclib = _uclib()
        self._uch = self.uc._uch
        self._c_read, self._c_write = uclib.uc_reg_read, uclib.uc_reg_write
        self._c_read_batch, self._c_write_batch = uclib.uc_reg_read_batch, uclib.uc_reg_write_batch
        self._one = ctypes.c_uint32()
        self._one_p = ctypes.cast(ctypes.byref(self._one), ctypes.c_void_p)
        # the exception frame: r0-r3, r12, lr, pc, xpsr, s0-s15, fpscr (26 words with the reserved one)
        ids = [A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3, A.UC_ARM_REG_R12,
               A.UC_ARM_REG_LR, A.UC_ARM_REG_PC, A.UC_ARM_REG_XPSR]
        ids += [getattr(A, f"UC_ARM_REG_S{i}") for i in range(16)] + [A.UC_ARM_REG_FPSCR]
        n = len(ids)
        self._frame_ids = (ctypes.c_int32 * n)(*ids)
        self._frame_vals = (ctypes.c_uint32 * n)()
        base = ctypes.addressof(self._frame_vals)
        self._frame_ptrs = (ctypes.c_void_p * n)(*[base + 4 * i for i in range(n)])
        # the same without PC and xPSR, for writing back (PC and xPSR are written one by one)
        wids = ids[:6] + ids[8:]
        self._wframe_ids = (ctypes.c_int32 * len(wids))(*wids)
        self._wframe_vals = (ctypes.c_uint32 * len(wids))()
        wbase = ctypes.addressof(self._wframe_vals)
        self._wframe_ptrs = (ctypes.c_void_p * len(wids))(*[wbase + 4 * i for i in range(len(wids))])
        self._SP, self._LR, self._PC = A.UC_ARM_REG_SP, A.UC_ARM_REG_LR, A.UC_ARM_REG_PC
        self._XPSR, self._PRIMASK = A.UC_ARM_REG_XPSR, A.UC_ARM_REG_PRIMASK
        self._R = [A.UC_ARM_REG_R0, A.UC_ARM_REG_R1, A.UC_ARM_REG_R2, A.UC_ARM_REG_R3]

    def reg(self, reg_id: int) -> int:
        self._c_read(self._uch, reg_id, self._one_p)
        return self._one.value

    def set_reg(self, reg_id: int, value: int) -> None:
        self._one.value = value & 0xFFFFFFFF
        self._c_write(self._uch, reg_id, self._one_p)

    def _take(self, exc: int) -> None:
        """Exception entry: push the FP frame on MSP, EXC_RETURN in LR, IPSR = exc, PC = vector."""
        vals = self._frame_vals
        self._c_read_batch(self._uch, self._frame_ids, self._frame_ptrs, 25)
        sp = self.reg(self._SP)
        xpsr = vals[7]
        align = sp & 4
        sp -= align + FP_FRAME_WORDS * 4
        vals[7] = (xpsr & ~(1 << 9)) | ((1 << 9) if align else 0)
        off = sp - RAM_BASE
        if not 0 <= off <= RAM_SIZE - FP_FRAME_WORDS * 4:
            self.fault = EmulationError(f"stack overflow: exception {exc} at sp 0x{sp:08x} in {self.where()}")
            self.request_stop()
            return
        ctypes.memmove(ctypes.addressof(self._ram) + off, vals, 100)
        struct.pack_into("<I", self._ram, off + 100, 0)
        handler_mode = bool(self.nvic.active)
        if not handler_mode:
            self._exc_started = self.instructions_now()
        self.set_reg(self._SP, sp)
        self.set_reg(self._LR, 0xFFFFFFE1 if handler_mode else 0xFFFFFFE9)
        self.set_reg(self._XPSR, (xpsr & 0xF8000000) | (1 << 24) | exc)
        vtor = self.scs.regs.get(0xED08, 0) & (FLASH_SIZE - 1)
        vector = struct.unpack_from("<I", self._flash, vtor + 4 * exc)[0]
        self.nvic.pending.discard(exc)
        self.nvic.active.append(exc)
        ints = self.stats.interrupts
        ints[exc] = ints.get(exc, 0) + 1
        self.set_reg(self._PC, vector | 1)

    def _on_intr(self, uc, intno, user):
        if intno != 8:
            self._sync_now()
            self.fault = EmulationError(f"the CPU raised exception {intno} in {self.where()} "
                                        f"(pc 0x{self.pc():08x}, t = {self.now / CPU_HZ:.6f} s)")
            self.request_stop()
            return
        self._return_from_exception()

    def _return_from_exception(self) -> None:
        exc_return = self.reg(self._PC) | 0xF0000000
        if not self.nvic.active:
            self.fault = EmulationError(f"exception return without an active exception in {self.where()}")
            self.request_stop()
            return
        self.nvic.active.pop()
        if not self.nvic.active:
            self.exception_instructions += self.instructions_now() - self._exc_started
        sp = self.reg(self._SP)
        extended = not exc_return & 0x10
        words = FP_FRAME_WORDS if extended else 8
        off = sp - RAM_BASE
        raw = struct.unpack_from(f"<{words}I", self._ram, off)
        sp += 4 * words
        xpsr = raw[7]
        if xpsr & (1 << 9):
            sp += 4
        self._refresh_levels()
        w = self._wframe_vals
        w[0:6] = raw[0:6]
        if extended:
            w[6:23] = raw[8:25]
            self._c_write_batch(self._uch, self._wframe_ids, self._wframe_ptrs, 23)
        else:
            self._c_write_batch(self._uch, self._wframe_ids, self._wframe_ptrs, 6)
        self.set_reg(self._SP, sp)
        self.set_reg(self._XPSR, xpsr & ~(1 << 9))
        self.set_reg(self._PC, raw[6] | 1)
        if self.nvic.pending:
            nxt = self.nvic.next_exception(self.reg(self._PRIMASK))
            if nxt is not None:
                self._take(nxt)

    def _refresh_levels(self) -> None:
        self.usart1._irq_line()
        self.tim9._irq_line()

    # -- reset and the event loop
    def _reset(self) -> None:
        A = self._A
        sp, reset = struct.unpack("<II", bytes(self._flash.raw[:8]))
        self.uc.reg_write(A.UC_ARM_REG_SP, sp)
        self.uc.reg_write(A.UC_ARM_REG_PC, reset | 1)
        self._pc = reset | 1
        self._slice_start = 0
        self._skip_base = 0

    def reschedule(self) -> None:
        """A peripheral scheduled an event possibly earlier than the current slice's end: stop there."""
        t = self._earliest()
        if t is not None and t < self._next_event:
            self._next_event = t
            self._ic.limit = min(self._ic.limit, max(t - self._slice_start - self._skip_base + 1, self._ic.n + 1))

    def _earliest(self) -> int | None:
        ts = [t for t in (self.scs.systick_next, self.tim9.next_update, self.tim2.next_update,
                          self.usart1.shift_done, self.usart1.rx_done) if t is not None]
        return min(ts) if ts else None

    def uart_out(self, byte: int, t: int) -> None:
        self.out.append((byte, t))

    def run_until(self, t_end: int, *, max_slice: int = CPU_HZ // 1000) -> None:
        """Run until the instruction clock reaches ``t_end`` (events and interrupts on the way)."""
        uc = self.uc
        ic = self._ic
        self._run_end = t_end
        while self.now < t_end:
            if self.fault is not None:
                raise self.fault
            self._fire_events()
            if self.nvic.pending:
                nxt = self.nvic.next_exception(self.reg(self._PRIMASK))
                if nxt is not None:
                    self._take(nxt)
            ev = self._earliest()
            end = min(t_end, self.now + max_slice, ev if ev is not None else t_end)
            self._next_event = end
            self._slice_start = self.now
            self._skip_base = 0
            ic.n = 0
            ic.limit = max(end - self.now, 1) + 1  # the hook that reaches the limit stops before its instruction
            pc = self.reg(self._PC)
            self.stats.slices += 1
            try:
                uc.emu_start(pc | 1, 0xFFFFFFFE)
            except Exception as exc:  # noqa: BLE001 - unicorn errors become one line
                self._sync_now()
                if self.fault is not None:
                    raise self.fault from None
                raise EmulationError(f"the CPU stopped in {self.where()} (pc 0x{self.pc():08x}, "
                                     f"t = {self.now / CPU_HZ:.6f} s): {exc}") from None
            executed = ic.n - 1 if ic.n >= ic.limit else ic.n
            self.stats.instructions += executed
            self.now = self._slice_start + executed + self._skip_base
            ic.n = 0
            self._slice_start = self.now
            self._skip_base = 0
            if self.fault is not None:
                raise self.fault

    def _fire_events(self) -> None:
        now = self.now
        for _ in range(64):
            fired = False
            if self.usart1.shift_done is not None and self.usart1.shift_done <= now:
                self.usart1.shift_complete()
                fired = True
            if self.usart1.rx_done is not None and self.usart1.rx_done <= now:
                self.usart1.rx_complete()
                fired = True
            if self.scs.systick_next is not None and self.scs.systick_next <= now:
                self.scs.systick_fire()
                fired = True
            for tim in (self.tim9, self.tim2):
                if tim.next_update is not None and tim.next_update <= now:
                    tim.update()
                    fired = True
            if not fired:
                return


def _thumb_count(flash, address: int, size: int) -> int:
    """Instructions in a Thumb block of ``size`` bytes (16- or 32-bit encodings)."""
    off = address & (FLASH_SIZE - 1) if address < FLASH_BASE + FLASH_SIZE else None
    if off is None or address < FLASH_BASE and address >= FLASH_SIZE:
        return max(size // 2, 1)
    raw = bytes(memoryview(flash).cast("B")[off:off + size])
    n = i = 0
    while i < size:
        hw = raw[i] | raw[i + 1] << 8 if i + 1 < len(raw) else 0
        i += 4 if (hw >> 11) in (0x1D, 0x1E, 0x1F) else 2
        n += 1
    return n


def _cpsie_sites(flash, e: Elf) -> list[int]:
    """Addresses right after each ``cpsie i`` / ``msr primask, rN`` in the firmware's code."""
    raw = flash.raw
    end = 0
    for s in e.symbols:
        if s.is_func and FLASH_BASE <= s.addr < FLASH_BASE + FLASH_SIZE:
            end = max(end, (s.addr & ~1) - FLASH_BASE + s.size)
    out = []
    for off in range(0, end - 1, 2):
        hw = raw[off] | raw[off + 1] << 8
        if hw == 0xB662:
            out.append(FLASH_BASE + off + 2)
        elif (hw & 0xFFF0) == 0xF380 and off + 3 < end:
            hw2 = raw[off + 2] | raw[off + 3] << 8
            if (hw2 & 0xFF00) == 0x8800 and (hw2 & 0xFF) == 0x10:  # msr primask
                out.append(FLASH_BASE + off + 4)
    return out


def _wfi_sites(flash, e: Elf) -> list[int]:
    """Addresses of the ``wfi`` instructions (0xBF30) in the firmware's functions, decoded from each function's
    start (16- and 32-bit Thumb encodings), so that no half of a 32-bit instruction is taken for one."""
    raw = flash.raw
    out = []
    for s in e.symbols:
        if not (s.is_func and FLASH_BASE <= s.addr < FLASH_BASE + FLASH_SIZE):
            continue
        off, end = (s.addr & ~1) - FLASH_BASE, (s.addr & ~1) - FLASH_BASE + s.size
        while off + 1 < end:
            hw = raw[off] | raw[off + 1] << 8
            if hw == 0xBF30:
                out.append(FLASH_BASE + off)
            off += 4 if (hw >> 11) in (0x1D, 0x1E, 0x1F) else 2
    return sorted(set(out))

"""The STM32F401VC's memory map, its exception numbers, the board's errors, and the simple register models.

A :class:`Peripheral` is a register file of 32-bit words by offset; the models here (RCC, PWR, GPIO, SPI, ADC1)
only make the ready/status bits the HAL waits for follow their enables. The peripherals with timing (timers,
USART1, SysTick/NVIC) have their own modules.
"""

from __future__ import annotations

from steval_link.errors import UserError

FLASH_BASE, FLASH_SIZE = 0x08000000, 256 * 1024
RAM_BASE, RAM_SIZE = 0x20000000, 64 * 1024


def in_ram(addr: int, n: int) -> bool:
    """``n`` bytes at ``addr`` lie in the RAM."""
    return RAM_BASE <= addr and addr + n <= RAM_BASE + RAM_SIZE


SYSMEM_BASE, SYSMEM_SIZE = 0x1FFF0000, 0x8000
#: the 96-bit unique ID (in system memory)
UID_ADDR = 0x1FFF7A10
UID_WORDS = (0x00380021, 0x3437510B, 0x34353532)
PERIPH_BASE = 0x40000000
BITBAND_PERIPH, BITBAND_SIZE = 0x42000000, 0x2000000
SCS_BASE, SCS_SIZE = 0xE0000000, 0x100000
PERIPH_PAGE = 0x400

# exception numbers (IRQn + 16)
IRQ_BASE = 16
EXC_PENDSV = 14
EXC_SYSTICK = 15
# IRQn
IRQ_TIM9 = 24
IRQ_TIM2 = 28
IRQ_USART1 = 37

#: the exception frame with the FP context: r0-r3, r12, lr, pc, xPSR, s0-s15, FPSCR, reserved
FP_FRAME_WORDS = 26
#: unicorn's interrupt number for an exception return (a branch to EXC_RETURN in handler mode)
INTNO_EXC_RETURN = 8


class EmulationError(UserError):
    """The firmware did something the board cannot continue from (one line)."""


class UnmodelledHardware(EmulationError):
    """The firmware accessed an address no model covers."""


class FirmwareStuck(EmulationError):
    """The watchdog fired: no progress (a fault handler, an endless wait)."""


class Peripheral:
    """A peripheral's register file: 32-bit words by offset; subclasses model the registers that do something."""

    name = "periph"
    #: words whose read has no side effect and changes only by this model's read/write (the C core serves them)
    c_readable: tuple[int, ...] = ()
    #: words the C core also writes (its mirror holds them; Python takes them back before its own access)
    c_owned: tuple[int, ...] = ()

    def __init__(
        self, board, base: int, size: int = PERIPH_PAGE, reset: dict[int, int] | None = None, name: str | None = None
    ):
        self.board = board
        self.base = base
        self.size = size
        self.regs: dict[int, int] = dict(reset or {})
        if name is not None:
            self.name = name

    def read(self, off: int) -> int:
        return self.regs.get(off, 0)

    def write(self, off: int, value: int) -> None:
        self.regs[off] = value & 0xFFFFFFFF

    def stored(self, off: int) -> int:
        """The word a byte or half-word write modifies: as last written."""
        return self.regs.get(off, 0)

    def bitband_base(self, off: int) -> int:
        """The word a bit-band write modifies: as read."""
        return self.read(off)


class Rcc(Peripheral):
    name = "RCC"
    CR = 0x00
    PLLCFGR = 0x04
    CFGR = 0x08
    BDCR = 0x70
    CSR = 0x74

    def __init__(self, board, base):
        super().__init__(board, base, reset={self.CR: 0x83, self.PLLCFGR: 0x24003010, self.CSR: 0x0E000000})

    def read(self, off):
        v = self.regs.get(off, 0)
        if off == self.CR:  # HSIRDY, HSERDY, PLLRDY, PLLI2SRDY follow HSION, HSEON, PLLON, PLLI2SON
            for on, rdy in ((0, 1), (16, 17), (24, 25), (26, 27)):
                v = (v | (1 << rdy)) if v & (1 << on) else (v & ~(1 << rdy))
        elif off == self.CFGR:  # SWS = SW
            v = (v & ~0xC) | ((v & 3) << 2)
        elif off in (self.CSR, self.BDCR):  # LSIRDY follows LSION, LSERDY follows LSEON
            v = (v | 2) if v & 1 else v & ~2
        return v


class Pwr(Peripheral):
    name = "PWR"
    CSR = 0x04
    VOSRDY = 1 << 14

    def read(self, off):
        v = self.regs.get(off, 0)
        return v | self.VOSRDY if off == self.CSR else v


class Gpio(Peripheral):
    name = "GPIO"
    IDR = 0x10
    ODR = 0x14
    BSRR = 0x18
    c_readable = (IDR,)

    def read(self, off):
        if off == self.IDR:  # inputs read low (no buttons, no RC receiver)
            return 0
        return self.regs.get(off, 0)

    def write(self, off, value):
        if off == self.BSRR:
            odr = self.regs.get(self.ODR, 0)
            odr = (odr | (value & 0xFFFF)) & ~((value >> 16) & 0xFFFF)
            self.regs[self.ODR] = odr & 0xFFFF
            return
        super().write(off, value)


class Spi(Peripheral):
    name = "SPI"
    SR = 0x08
    TXE_RXNE = 0x3

    def read(self, off):
        if off == self.SR:  # TXE, RXNE, not busy
            return self.TXE_RXNE
        return self.regs.get(off, 0)


class Adc(Peripheral):
    """ADC1: a conversion completes at once on SWSTART; DR holds the battery divider's reading."""

    name = "ADC1"
    SR = 0x00
    CR2 = 0x08
    DR = 0x4C
    c_readable = c_owned = (SR, CR2)
    #: 12-bit reading of the battery sense divider: the firmware's VBAT = counts·3.3/4095·(10k + 20k)/20k = 3.90 V, a
    #: charged 1S LiPo
    VBAT_COUNTS = 3226
    EOC, STRT, SWSTART = 1 << 1, 1 << 4, 1 << 30

    def read(self, off):
        if off == self.DR:  # reading clears EOC
            self.regs[self.SR] = self.regs.get(self.SR, 0) & ~self.EOC
            return self.VBAT_COUNTS
        return self.regs.get(off, 0)

    def write(self, off, value):
        if off == self.CR2 and value & self.SWSTART:
            self.regs[self.SR] = self.regs.get(self.SR, 0) | self.EOC | self.STRT
            value &= ~self.SWSTART
        if off == self.SR:  # rc_w0
            value = self.regs.get(self.SR, 0) & value
        super().write(off, value)


#: register files with no behaviour: name → offset from PERIPH_BASE
PLAIN = (
    ("FLASH", 0x23C00),
    ("SYSCFG", 0x13800),
    ("EXTI", 0x13C00),
    ("CRC", 0x23000),
    ("DMA1", 0x26000),
    ("DMA2", 0x26400),
    ("TIM3", 0x0400),
    ("TIM5", 0x0C00),
    ("TIM1", 0x10000),
    ("TIM10", 0x14400),
    ("TIM11", 0x14800),
    ("IWDG", 0x3000),
    ("WWDG", 0x2C00),
    ("RTC", 0x2800),
    ("USART2", 0x4400),
    ("USART6", 0x11400),
    ("I2C1", 0x5400),
    ("I2C2", 0x5800),
    ("I2C3", 0x5C00),
)
#: GPIOx at 0x20000 + 0x400 · (x - A)
GPIOS = tuple((f"GPIO{x}", 0x20000 + 0x400 * (ord(x) - ord("A"))) for x in "ABCDEH")
SPIS = (("SPI1", 0x13000), ("SPI2", 0x3800), ("SPI3", 0x3C00), ("SPI4", 0x13400))
RCC_OFF, PWR_OFF, ADC1_OFF = 0x23800, 0x7000, 0x12000
USART1_OFF = 0x11000
#: the timers: name, offset from PERIPH_BASE, IRQn (TIM4: none); the C core's ``tim[]`` in this order
TIMERS = (("TIM9", 0x14000, IRQ_TIM9), ("TIM2", 0x0000, IRQ_TIM2), ("TIM4", 0x0800, None))


def simple_peripherals(board) -> list[Peripheral]:
    """The models without timing: RCC, PWR, ADC1, GPIOs, SPIs and the plain register files."""
    P = PERIPH_BASE
    out: list[Peripheral] = [Rcc(board, P + RCC_OFF), Pwr(board, P + PWR_OFF), Adc(board, P + ADC1_OFF)]
    out += [Gpio(board, P + off, name=name) for name, off in GPIOS]
    out += [Spi(board, P + off, name=name) for name, off in SPIS]
    out += [Peripheral(board, P + off, name=name) for name, off in PLAIN]
    return out


def bitband_target(off: int) -> tuple[int, int]:
    """The peripheral address (word aligned) and bit of a bit-band alias offset (from BITBAND_PERIPH)."""
    addr = PERIPH_BASE + (off >> 5)
    return addr & ~3, (off >> 2) & 7 | ((addr & 3) << 3)

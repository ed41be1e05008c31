"""An emulated STM32F401 board (STEVAL-FCU001V1) that runs the firmware ELF unchanged, in unicorn (Cortex-M4).

What is modelled, and where:

- **CPU** (:mod:`.cpu`): unicorn's Cortex-M4 (Thumb-2, FPv4-SP). One instruction = one cycle of the 84 MHz core
  clock: every emulated time (SysTick, DWT ``CYCCNT``, TIM9, the UART bit clock) is counted in *instructions*, not
  in real M4 cycles (no wait states, no pipeline: an M4 needs somewhat more cycles than instructions). Exception
  entry pushes the 26-word FP frame and sets EXC_RETURN; the return (unicorn raises interrupt 8 on a branch to
  EXC_RETURN in handler mode) pops it.
- **NVIC, SysTick, SCB, DWT** (:mod:`.scs`; unicorn has no NVIC): pending/enabled/active bits, priorities (IPR,
  SHPR, AIRCR.PRIGROUP), PRIMASK, preemption, tail-chaining.
- **Timers** (:mod:`.timer`): TIM2/TIM4/TIM9 update events from PSC/ARR.
- **USART1** (:mod:`.usart`): DR → shift register, TXE/TC with the baud rate's timing, TXE/TC interrupts; RX: bytes
  injected at emulated times arrive at the baud rate's pace, RXNE/ORE, the RXNE interrupt.
- **Memory map and simple models** (:mod:`.memory_map`): flash, RAM, system memory with the unique ID, RCC (ready
  flags follow their enables, SWS follows SW: HAL computes 84 MHz), FLASH, PWR, GPIOA..H, SYSCFG, EXTI, SPI1..4
  (always ready), ADC1 (one conversion on SWSTART), the peripheral bit-band alias.
- **Function-level replacements** (:mod:`.calls`): ``Sensor_IO_Read``/``Sensor_IO_Write`` (the SPI sensors),
  ``hci_send_req`` (the BlueNRG glue), the fault handlers.
- **Idle skipping** (:mod:`.core`): when the main loop polls with nothing to do (``isTimerEventExist`` with no flag
  set), ``HAL_Delay`` waits for the tick, or the CPU sleeps in ``wfi``, the clock jumps to the next event. No
  payload changes (the polled state only changes in interrupts).
- **Poll skipping** (C core only): a blocking transmit's TXE/TC loop that repeats unchanged (two USART1 SR reads at
  one instruction, same value, registers and stack top, nothing else in between) jumps whole passes to the next
  event; the passes count as executed instructions, every byte keeps its instruction count.
- **Fault diagnosis** (:mod:`.fault`): a hang or a fault named in one sentence (the active exception, a missing weak
  handler behind ``Default_Handler``, the fault status registers, the last function).
- **The C core** (``steval_link/emulation/_core.c``, optional; :mod:`.native`): the instruction counter, the event
  scheduler, USART1, SysTick, the NVIC, the timers, exception entry/return, idle skipping and the SPI sensor reads run
  inside unicorn's hooks; Python is called for TIM9's tick (the runner's remote control, the next sensor sample),
  the other peripherals, the replaced BLE calls and the probes. The firmware sees the same registers at the same
  instruction counts as with the Python models (``tests/test_emulate_digest.py``). Without a C compiler the Python
  models above run (about 6x slower; the instruction clock at block granularity, so times differ slightly).

Anything else the firmware touches (an address outside every model) stops the run with
:class:`UnmodelledHardware`, one line naming the function and address.
"""

from steval_link.emulation.board.core import BoardStats, PythonBoard
from steval_link.emulation.board.memory_map import (
    EXC_SYSTICK,
    IRQ_BASE,
    IRQ_TIM2,
    IRQ_TIM9,
    IRQ_USART1,
    EmulationError,
    FirmwareStuck,
    UnmodelledHardware,
)
from steval_link.emulation.board.native import NativeBoard, core_library
from steval_link.emulation.board.scs import Nvic
from steval_link.emulation.board.usart import Usart
from steval_link.errors import UserError


class Board(PythonBoard):
    """The board: :class:`NativeBoard` (the C core) when it is built, else :class:`PythonBoard`.

    ``native``: True requires the C core, False takes the Python models, None (default) the C core when built.
    """

    def __new__(cls, elf, sensors, *, skip_idle: bool = True, native: bool | None = None):
        if native is not False and core_library() is not None:
            return NativeBoard(elf, sensors, skip_idle=skip_idle)
        if native:
            raise UserError(
                "the board's C core (steval_link.emulation._core) is not built: pip install -e . with a C compiler"
            )
        return PythonBoard(elf, sensors, skip_idle=skip_idle)


__all__ = [
    "Board",
    "BoardStats",
    "EXC_SYSTICK",
    "IRQ_BASE",
    "IRQ_TIM2",
    "IRQ_TIM9",
    "IRQ_USART1",
    "EmulationError",
    "FirmwareStuck",
    "UnmodelledHardware",
    "NativeBoard",
    "Nvic",
    "PythonBoard",
    "Usart",
]

"""An emulated STM32F401 board (STEVAL-FCU001V1) that runs the firmware ELF unchanged, in unicorn (Cortex-M4).

One instruction = one cycle of the 84 MHz clock: SysTick, DWT ``CYCCNT``, TIM9 and the UART bit clock count
instructions, not real M4 cycles. docs/explanation/emulated-board.md tells the whole model; by module:

- :mod:`.cpu`: the CPU, exception entry (the 26-word FP frame) and return (unicorn's interrupt 8 on EXC_RETURN).
- :mod:`.scs`: NVIC, SysTick, SCB and DWT (unicorn has no NVIC): priorities, PRIMASK, preemption, tail-chaining.
- :mod:`.timer`: TIM2/TIM4/TIM9 update events. :mod:`.usart`: USART1 TX/RX at the baud rate's pace, its flags
  and interrupts.
- :mod:`.memory_map`: flash, RAM, the unique ID, RCC, FLASH, PWR, GPIOs, SYSCFG, EXTI, SPIs, ADC1, the bit-band alias.
- :mod:`.calls`: ``Sensor_IO_Read``/``Write``, ``hci_send_req`` and the fault handlers replaced by Python.
- :mod:`.core`: idle skipping (the main loop's poll, ``HAL_Delay``, ``wfi``: the clock jumps to the next event).
- :mod:`.fault`: a hang or a fault named in one sentence.
- ``_core.c`` (:mod:`.native`): the C core runs all of the above in unicorn's hooks, and skips a blocking transmit's
  unchanged TXE/TC polling passes. Python is called for the probes, the BLE calls and the peripherals without a C
  model; TIM9's updates (sensor sample, remote bytes) come from tables the runner hands over per window. The
  firmware sees the same registers at the same instruction counts as with the Python models
  (``tests/test_emulate_digest.py``), which run when no C compiler is there (slower; the clock at block granularity).

Anything else the firmware touches stops the run with :class:`UnmodelledHardware`, one line naming it.
"""

from steval_link.emulation.board.core import PythonBoard
from steval_link.emulation.board.memory_map import (
    IRQ_BASE,
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
    "IRQ_BASE",
    "IRQ_USART1",
    "EmulationError",
    "FirmwareStuck",
    "UnmodelledHardware",
    "NativeBoard",
    "Nvic",
    "PythonBoard",
    "Usart",
]

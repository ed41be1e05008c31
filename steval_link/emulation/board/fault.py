"""Why the firmware stopped, in one sentence: the active exception by number and name, ``Default_Handler`` and the
missing handler when the pc is there, the fault status registers a Cortex-M4 would hold after a fault, and the
last function the firmware was in (ELF symbols).

ST's startup gives every vector a weak alias of ``Default_Handler`` (about 80 names at one address); a handler the
firmware forgot stays an alias, and its interrupt spins in ``Default_Handler``. The name comes from the vector's
exception number (the CMSIS names of the STM32F401), not from whichever alias the symbol table lists first.
"""

from __future__ import annotations

import struct

from steval_link.emulation.board.memory_map import SCS_BASE


def _numbered(names: str) -> dict[int, str]:
    """Names in number order from 0, ``-`` where the number has none."""
    return {i: n for i, n in enumerate(names.split()) if n != "-"}


#: core exceptions: number → CMSIS name (the handler is NAME_Handler)
CORE_EXCEPTIONS = _numbered("- - NMI HardFault MemManage BusFault UsageFault - - - - SVC DebugMon - PendSV SysTick")
#: STM32F401 interrupts: IRQ number → CMSIS name (the handler is NAME_IRQHandler; exception = 16 + IRQ)
IRQ_NAMES = _numbered("""
WWDG PVD TAMP_STAMP RTC_WKUP FLASH RCC EXTI0 EXTI1 EXTI2 EXTI3 EXTI4 DMA1_Stream0 DMA1_Stream1 DMA1_Stream2
DMA1_Stream3 DMA1_Stream4 DMA1_Stream5 DMA1_Stream6 ADC - - - - EXTI9_5 TIM1_BRK_TIM9 TIM1_UP_TIM10
TIM1_TRG_COM_TIM11 TIM1_CC TIM2 TIM3 TIM4 I2C1_EV I2C1_ER I2C2_EV I2C2_ER SPI1 SPI2 USART1 USART2 - EXTI15_10
RTC_Alarm OTG_FS_WKUP - - - - DMA1_Stream7 - SDIO TIM5 SPI3 - - - - DMA2_Stream0 DMA2_Stream1 DMA2_Stream2
DMA2_Stream3 DMA2_Stream4 - - - - - - OTG_FS DMA2_Stream5 DMA2_Stream6 DMA2_Stream7 USART6 I2C3_EV I2C3_ER
- - - - - - - FPU - - SPI4
""")
#: SCB fault status and address registers
CFSR, HFSR, MMFAR, BFAR = 0xE000ED28, 0xE000ED2C, 0xE000ED34, 0xE000ED38
#: unicorn's (QEMU's) exception numbers → (fault, CFSR bit, what): what the M4 records for the same event
CPU_FAULTS = {
    1: ("UsageFault", 1 << 16, "undefined instruction"),
    3: ("BusFault", 1 << 8, "instruction fetch bus error"),
    4: ("BusFault", 1 << 9, "precise data bus error"),
    7: ("HardFault", 0, "breakpoint (bkpt) without a debugger"),
    17: ("UsageFault", 1 << 19, "coprocessor access (FPU off)"),
    18: ("UsageFault", 1 << 17, "invalid state (a branch to an address without the Thumb bit)"),
    22: ("UsageFault", 1 << 24, "unaligned access"),
    23: ("UsageFault", 1 << 25, "division by zero"),
}
HFSR_FORCED, HFSR_DEBUGEVT = 1 << 30, 1 << 31
#: unicorn errors that end emu_start instead of raising an exception: UC_ERR_INSN_INVALID → QEMU's EXCP_UDEF
UC_ERROR_FAULTS = {10: 1}
#: the stacked frame: r0 r1 r2 r3 r12 lr pc xpsr
STACKED_LR, STACKED_PC = 20, 24


def exception_name(exc: int) -> str:
    """``15 (SysTick)``, ``53 (USART1)``, ``71 (IRQ 55)``."""
    if exc in CORE_EXCEPTIONS:
        return f"{exc} ({CORE_EXCEPTIONS[exc]})"
    if exc >= 16:
        return f"{exc} ({IRQ_NAMES.get(exc - 16, f'IRQ {exc - 16}')})"
    return str(exc)


def handler_name(exc: int) -> str | None:
    """The CMSIS handler name of exception ``exc`` (``SysTick_Handler``, ``USART1_IRQHandler``), or None."""
    if exc in CORE_EXCEPTIONS:
        return CORE_EXCEPTIONS[exc] + "_Handler"
    if exc - 16 in IRQ_NAMES:
        return IRQ_NAMES[exc - 16] + "_IRQHandler"
    return None


def _state(board) -> tuple[int, int, int, int]:
    r = board.regs
    return board.pc(), board.reg(r.XPSR) & 0x1FF, board.reg(r.SP), board.reg(r.LR)


def _handler_clause(board, pc: int, exc: int) -> str:
    """`` handling exception 15 (SysTick): SysTick_Handler is missing (...)`` (or `` in thread mode``)."""
    e = board.elf
    if exc == 0:
        return " in thread mode"
    out = f" handling exception {exception_name(exc)}"
    f = e.function_at(pc)
    try:
        vector = struct.unpack_from("<I", board.flash, (board.vtor() + 4 * exc) % len(board.flash))[0] & ~1
    except struct.error:
        return out
    if f is None or vector != f.addr & ~1:
        return out
    names = [s.name for s in e.aliases(vector)]
    own = handler_name(exc)
    weak = [s.name for s in e.aliases(vector) if s.weak]
    if own is not None and own != f.name and (own in weak or own not in e.by_name):
        how = f"a weak alias of {f.name}" if own in weak else "not in the firmware"
        others = len([n for n in weak if n != own])
        shared = f", as {others} other handler name{'s are' if others != 1 else ' is'}" if others else ""
        return out + f": {own} is missing ({how}{shared})"
    if len(names) > 1 and f.name == "Default_Handler":
        return out + f": the exception has no handler of its own (its vector points to {f.name})"
    return out


def _last_function(board, exc: int, sp: int) -> str:
    """The stacked pc and lr of the exception frame at sp ("" in thread mode, or when it cannot be read)."""
    if exc == 0:
        return ""
    try:
        lr, pc = struct.unpack("<II", bytes(board.uc.mem_read(sp + STACKED_LR, 8)))
    except Exception:  # noqa: BLE001 - an unreadable frame is left out of the sentence
        return ""
    return f"; the firmware was last in {board.elf.func_at(pc)} (stacked pc 0x{pc:08x}, lr 0x{lr:08x})"


def describe_cpu(board) -> str:
    """Where the CPU is and why, e.g. for a hang: ``the CPU is in Default_Handler (pc ...) handling exception 15
    (SysTick): SysTick_Handler is missing (...); the firmware was last in hw_delay_ms+0x10 (stacked pc ...)``."""
    pc, exc, sp, _lr = _state(board)
    where = f"in {board.elf.func_at(pc)} (pc 0x{pc:08x})"
    return f"the CPU is {where}{_handler_clause(board, pc, exc)}{_last_function(board, exc, sp)}"


def describe_fault(board, intno: int, t_s: float) -> str:
    """The sentence for a CPU exception unicorn raised (the board stops there instead of entering the handler), with
    the CFSR and HFSR a Cortex-M4 records for it. A configurable fault whose enable bit (SHCSR) is clear escalates to
    HardFault (HFSR.FORCED), as on the chip after reset."""
    pc, exc, sp, lr = _state(board)
    where = board.elf.func_at(pc)
    fault = CPU_FAULTS.get(intno)
    if fault is None:
        return (
            f"the CPU raised exception {intno} in {where} (pc 0x{pc:08x}, t = {t_s:.6f} s)"
            + (f" while handling exception {exception_name(exc)}" if exc else "")
            + _last_function(board, exc, sp)
        )
    kind, cfsr, what = fault
    shcsr = board.scs.regs.get(0xED24, 0)
    enabled = {"MemManage": 1 << 16, "BusFault": 1 << 17, "UsageFault": 1 << 18}.get(kind, 0)
    hfsr = HFSR_DEBUGEVT if intno == 7 else 0
    if kind != "HardFault" and not shcsr & enabled:
        hfsr |= HFSR_FORCED
        what += ", escalated to HardFault"
    return (
        f"the firmware faulted in {where} at t = {t_s:.6f} s: {kind}: {what} (CFSR 0x{cfsr:08x}, HFSR 0x{hfsr:08x}; "
        f"MMFAR, BFAR not valid; pc 0x{pc:08x}, lr 0x{lr:08x} in {board.elf.func_at(lr)}"
        + (f", while handling exception {exception_name(exc)}" if exc else "")
        + ")"
        + _last_function(board, exc, sp)
    )


def describe_fault_handler(board, name: str) -> str:
    """The firmware entered one of its fault handlers (``HardFault_Handler``...) or ``Default_Handler``: the
    exception, the missing handler, the fault registers the firmware would read there, the stacked pc/lr."""
    pc, exc, sp, _lr = _state(board)
    parts = [f"the firmware entered {name} (pc 0x{pc:08x}){_handler_clause(board, pc, exc)}"]
    if exc in (3, 4, 5, 6):
        words = {k: _scs_word(board, a) for k, a in (("CFSR", CFSR), ("HFSR", HFSR), ("MMFAR", MMFAR), ("BFAR", BFAR))}
        parts.append("; " + ", ".join(f"{k} 0x{v:08x}" for k, v in words.items()))
    parts.append(_last_function(board, exc, sp))
    return "".join(parts)


def _scs_word(board, addr: int) -> int:
    try:
        return int(board.scs.read(addr - SCS_BASE))
    except Exception:  # noqa: BLE001 - a register the model does not hold reads 0
        return 0


def describe_stop(board, err: int, error_text: str, t_s: float) -> str:
    """The sentence for a unicorn error that ended the run (an undefined instruction: the fault it is on the M4)."""
    if err in UC_ERROR_FAULTS:
        return describe_fault(board, UC_ERROR_FAULTS[err], t_s)
    pc = board.pc()
    return f"the CPU stopped in {board.elf.func_at(pc)} (pc 0x{pc:08x}, t = {t_s:.6f} s): {error_text}"

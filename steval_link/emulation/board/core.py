"""The board: unicorn's Cortex-M4 with the memory map, the peripheral models, the instruction clock and the event
loop (see the package docstring)."""

from __future__ import annotations

import ctypes
import struct
from collections import deque
from dataclasses import dataclass, field
from functools import cached_property
from types import SimpleNamespace
from typing import Callable

from steval_link import constants as C
from steval_link.emulation.board.calls import FirmwareCalls
from steval_link.emulation.board.cpu import (
    Exceptions,
    Registers,
    access_kind,
    cpsie_sites,
    thumb_count,
    wfi_sites,
)
from steval_link.emulation.board.fault import describe_cpu, describe_fault, describe_stop
from steval_link.emulation.board.memory_map import (
    BITBAND_PERIPH,
    BITBAND_SIZE,
    FLASH_BASE,
    FLASH_SIZE,
    INTNO_EXC_RETURN,
    IRQ_USART1,
    PERIPH_BASE,
    PERIPH_PAGE,
    RAM_BASE,
    RAM_SIZE,
    SYSMEM_BASE,
    SYSMEM_SIZE,
    TIMERS,
    UID_ADDR,
    UID_WORDS,
    USART1_OFF,
    EmulationError,
    Peripheral,
    UnmodelledHardware,
    bitband_target,
    in_ram,
    simple_peripherals,
)
from steval_link.emulation.board.scs import Nvic, Scs
from steval_link.emulation.board.timer import Timer
from steval_link.emulation.board.usart import Usart
from steval_link.emulation.elf import Elf
from steval_link.errors import UserError

#: the main loop's idle poll (ST's release): RAM flags that must all be clear for the CPU to have nothing to do
IDLE_POLL = "isTimerEventExist"
IDLE_FLAGS = ("tim9_event_flag", "HCI_ProcessEvent", "set_connectable")
#: tUserTimer.event_cnt (interval, target_tick, flag, flag2, event_cnt) of the firmware's `tim`
TIM_EVENT_CNT = 16
UC_PROT_RX, UC_PROT_RWX, UC_PROT_R = 5, 7, 1


@dataclass(frozen=True)
class Mark:
    """One pass of the CPU at a marked address: the board as a probe there reads it (see :meth:`PythonBoard.mark`)."""

    kind: int  #: the kind given to :meth:`PythonBoard.mark`
    now: int  #: the instruction clock
    instructions: int  #: instructions executed (idle and poll skips included, as ``instructions_now``)
    exception_instructions: int  #: of those, inside exception handlers
    cyccnt: int  #: DWT CYCCNT (not wrapped at 32 bits)
    tim9_updates: int  #: TIM9 update events so far
    ram: tuple[tuple[int, bytes], ...]  #: (address, bytes) of each range of :meth:`PythonBoard.mark_ram`

    def ram_read(self, addr: int, n: int) -> bytes:
        """``n`` bytes at ``addr`` from the marked ranges (ValueError: not marked)."""
        for a, data in self.ram:
            if a <= addr and addr + n <= a + len(data):
                return data[addr - a : addr - a + n]
        raise ValueError(f"0x{addr:08x} (+{n}) is not in the RAM ranges the board marks")


@dataclass
class BoardStats:
    instructions: int = 0
    interrupts: dict[int, int] = field(default_factory=dict)
    skipped_instructions: int = 0
    slices: int = 0


class PythonBoard:
    """The STEVAL-FCU001V1's MCU running one firmware ELF, with the Python models (the fallback of the C core:
    :class:`~steval_link.emulation.board.native.NativeBoard`).

    Args:
        elf: the firmware (path or :class:`Elf`).
        sensors: the sensor bus (:class:`steval_link.emulation.sensors.SensorBus`) answering ``Sensor_IO_*``.
        skip_idle: jump the clock over idle polling (no payload changes; off only to check exactly that).
    """

    #: the C core runs the hot path (NativeBoard)
    native = False
    cpu_hz = C.CPU_HZ
    hci_requests = 0
    #: ``handler(ogf, ocf, command parameters, board) -> reply bytes`` for ``hci_send_req`` (None: zeroed replies)
    hci_handler: Callable | None = None
    #: the models of the timed peripherals (NativeBoard: theirs, over the C core)
    timer_model, usart_model, scs_model = Timer, Usart, Scs

    def __init__(self, elf: Elf | str, sensors, *, skip_idle: bool = True):
        from unicorn import UC_ARCH_ARM, UC_MODE_MCLASS, UC_MODE_THUMB, Uc  # reason: unicorn is optional
        from unicorn import arm_const as A  # reason: unicorn is optional

        self.elf = elf if isinstance(elf, Elf) else Elf(elf)
        self.sensors = sensors
        uc = Uc(UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)
        uc.ctl_set_cpu_model(A.UC_CPU_ARM_CORTEX_M4)
        # No exit address: the runs end by the count hook's stop, and unicorn then has no translated block at the
        # exit to invalidate each time it stops.
        uc.ctl_exits_enabled(True)
        uc.ctl_set_exits([])
        self.uc = uc
        self.now = 0  # instructions since reset (= 84 MHz cycles of this model)
        self.stats = BoardStats()
        self.nvic = Nvic()
        self.out: deque[tuple[int, int]] = deque()  # (byte, instruction count when it left the line)
        self.fault: EmulationError | None = None
        self.call_observers: dict[str, list[Callable]] = {}
        #: called with the board at each TIM9 update event (the runner's remote control)
        self.tick_observers: list[Callable] = []
        #: instructions executed inside exception handlers (entry to the return to thread mode)
        self.exception_instructions = 0
        self.exc_started = 0
        self._next_event = 0
        self._slice_start = 0
        self._skip_base = 0
        self._run_end = 0
        self._resumed_idle = False
        self._mark_ram: list[tuple[int, int]] = []
        self._marks: list[Mark] = []
        self._map_memory()
        self.regs = Registers(uc)
        self.exceptions = Exceptions(self)
        self._make_peripherals()
        self._install_counter()
        self._install_hooks(skip_idle)
        self._reset()

    # -- memory
    def _map_memory(self) -> None:
        uc = self.uc
        self.flash = ctypes.create_string_buffer(FLASH_SIZE)
        self.ram = ctypes.create_string_buffer(RAM_SIZE)
        flash_ptr = ctypes.addressof(self.flash)
        ctypes.memset(flash_ptr, 0xFF, FLASH_SIZE)
        for addr, data in self.elf.segments:
            if FLASH_BASE <= addr and addr + len(data) <= FLASH_BASE + FLASH_SIZE:
                ctypes.memmove(flash_ptr + addr - FLASH_BASE, data, len(data))
            elif in_ram(addr, len(data)):
                ctypes.memmove(ctypes.addressof(self.ram) + addr - RAM_BASE, data, len(data))
            else:
                raise UserError(
                    f"{self.elf.path}: a segment at 0x{addr:08x} ({len(data)} B) lies outside the "
                    "STM32F401VC's 256 KB flash / 64 KB RAM"
                )
        uc.mem_map_ptr(FLASH_BASE, FLASH_SIZE, UC_PROT_RX, flash_ptr)
        uc.mem_map_ptr(0, FLASH_SIZE, UC_PROT_RX, flash_ptr)  # boot alias
        uc.mem_map_ptr(RAM_BASE, RAM_SIZE, UC_PROT_RWX, ctypes.addressof(self.ram))
        self._ram_mv = memoryview(self.ram).cast("B")  # (ctypes' .raw copies the whole buffer)
        # system memory, OTP, option bytes (read only; the unique ID lives in system memory)
        self._sysmem = ctypes.create_string_buffer(SYSMEM_SIZE)
        ctypes.memmove(ctypes.addressof(self._sysmem) + UID_ADDR - SYSMEM_BASE, struct.pack("<III", *UID_WORDS), 12)
        uc.mem_map_ptr(SYSMEM_BASE, SYSMEM_SIZE, UC_PROT_R, ctypes.addressof(self._sysmem))

    def ram_u32(self, addr: int) -> int:
        return struct.unpack_from("<I", self.ram, addr - RAM_BASE)[0]

    def ram_write(self, addr: int, data: bytes) -> None:
        ctypes.memmove(ctypes.addressof(self.ram) + addr - RAM_BASE, data, len(data))

    def ram_read(self, addr: int, n: int) -> bytes:
        return bytes(self._ram_mv[addr - RAM_BASE : addr - RAM_BASE + n])

    # -- peripherals
    def _make_peripherals(self) -> None:
        P = PERIPH_BASE
        self.tim9, self.tim2, self.tim4 = (self.timer_model(self, P + off, irq, name) for name, off, irq in TIMERS)
        self.usart1 = self.usart_model(self, P + USART1_OFF, IRQ_USART1)
        self.scs = self.scs_model(self)
        periphs: list[Peripheral] = [self.tim9, self.tim2, self.tim4, self.usart1] + simple_peripherals(self)
        self.rcc = next(p for p in periphs if p.name == "RCC")
        self.periphs = sorted(periphs, key=lambda p: p.base)
        self._by_page = {p.base // PERIPH_PAGE: p for p in self.periphs}
        uc = self.uc
        rd, wr = self.guarded(self._mmio_read), self.guarded(self._mmio_write)
        for p in self.periphs:
            if p is self.usart1:
                self._map_usart(uc, p)
            else:
                self._map_python(uc, p, rd, wr)
        self._map_bitband(uc)
        self._map_python(uc, self.scs, rd, wr)

    def _map_python(self, uc, p: Peripheral, rd, wr) -> None:
        uc.mmio_map(p.base, p.size, rd, p, wr, p)

    def _map_bitband(self, uc) -> None:
        uc.mmio_map(BITBAND_PERIPH, BITBAND_SIZE, self.guarded(self._bb_read), None, self.guarded(self._bb_write), None)

    def _map_usart(self, uc, usart) -> None:
        uc.mmio_map(usart.base, usart.size, self._mmio_read, usart, self._mmio_write, usart)

    def _mmio_read(self, uc, off, size, p: Peripheral):
        self.sync_now()
        word = p.read(off & ~3)
        return (word >> ((off & 3) * 8)) & ((1 << (8 * size)) - 1)

    def _mmio_write(self, uc, off, size, value, p: Peripheral):
        self.sync_now()
        if size != 4:
            sh = (off & 3) * 8
            mask = ((1 << (8 * size)) - 1) << sh
            value = (p.stored(off & ~3) & ~mask) | ((value << sh) & mask)
        p.write(off & ~3, value)

    def _bb_target(self, off: int) -> tuple[Peripheral, int, int] | None:
        addr, bit = bitband_target(off)
        p = self._by_page.get(addr // PERIPH_PAGE)
        if p is None:
            self._unmodelled(PERIPH_BASE + (off >> 5), "bit-band access to")
            return None
        return p, addr - p.base, bit

    def _bb_read(self, uc, off, size, user):
        self.sync_now()
        t = self._bb_target(off)
        return 0 if t is None else (t[0].read(t[1]) >> t[2]) & 1

    def _bb_write(self, uc, off, size, value, user):
        self.sync_now()
        t = self._bb_target(off)
        if t is not None:
            p, reg, bit = t
            old = p.bitband_base(reg)
            p.write(reg, (old | (1 << bit)) if value & 1 else (old & ~(1 << bit)))

    def _unmodelled(self, addr: int, what: str = "access to") -> None:
        self.stop_with(
            UnmodelledHardware(
                f"the firmware touched hardware the emulated board does not model: {what} 0x{addr:08x} in "
                f"{self.where()} (pc 0x{self.pc():08x}, t = {self.now / C.CPU_HZ:.6f} s)"
            )
        )

    # -- the CPU
    def reg(self, reg_id: int) -> int:
        return self.regs.get(reg_id)

    def set_reg(self, reg_id: int, value: int) -> None:
        self.regs.set(reg_id, value)

    def pc(self) -> int:
        return self.regs.get(self.regs.PC)

    def where(self) -> str:
        return self.elf.func_at(self.pc())

    def describe_cpu(self) -> str:
        """Where the CPU is and why, in one sentence: the active exception, a missing handler, the last function."""
        return describe_cpu(self)

    def vtor(self) -> int:
        return self.scs.regs.get(0xED08, 0) & (FLASH_SIZE - 1)

    def instructions_now(self) -> int:
        """Instructions executed so far (inside a hook: up to the current one)."""
        return self.stats.instructions + self._ic.n

    def probe(self, addr: int, fn: Callable) -> None:
        """Call ``fn(board)`` whenever the CPU reaches ``addr`` (a function entry), with the clock in sync."""

        def hook(uc, address, size, user):
            self.sync_now()
            fn(self)

        self.code_hook(addr, hook)

    def mark_ram(self, ranges: list[tuple[int, int]]) -> None:
        """The RAM ranges (address, bytes) each :class:`Mark` copies. Set before the run."""
        for addr, n in ranges:
            if not in_ram(addr, n):
                raise ValueError(f"0x{addr:08x} (+{n}) is not in RAM")
        self._mark_ram = list(ranges)

    def mark(self, addr: int, kind: int) -> None:
        """Record a :class:`Mark` of ``kind`` whenever the CPU reaches ``addr``; :meth:`take_marks` hands them over.
        Unlike :meth:`probe`, no Python runs at the pass on the C core."""
        self.probe(addr, lambda board: self._marks.append(self._mark_now(kind)))

    def _mark_now(self, kind: int) -> Mark:
        ram = tuple((a, self.ram_read(a, n)) for a, n in self._mark_ram)
        counters = (self.now, self.instructions_now(), self.exception_instructions, self.scs.cyccnt())
        return Mark(kind, *counters, self.tim9.updates, ram)

    def take_marks(self) -> list[Mark]:
        """The marks since the last call, in order."""
        out, self._marks = self._marks, []
        return out

    def code_hook(self, addr: int, fn: Callable) -> None:
        """Call ``fn(uc, address, size, user)`` before the instruction at ``addr``."""
        from unicorn import UC_HOOK_CODE  # reason: unicorn is optional

        self.uc.hook_add(UC_HOOK_CODE, self.guarded(fn), begin=addr, end=addr)

    def guarded(self, fn: Callable) -> Callable:
        """``fn`` as a hook: an exception stops the run and is raised by :meth:`run_until` (the C core calls
        unicorn itself, past the Python binding that would keep it). The Python path needs no wrapper."""
        if not self.native:
            return fn

        def hook(*args):
            try:
                return fn(*args)
            except Exception as exc:  # noqa: BLE001 - raised again by run_until
                self.stop_with(exc)
                return 0

        return hook

    def stop_with(self, exc: BaseException) -> None:
        """Stop the CPU at the next instruction and raise ``exc`` from :meth:`run_until` (the first one counts)."""
        if self.fault is None:
            self.fault = exc
        self.request_stop()

    def stop_with_error(self, message: str) -> None:
        self.stop_with(EmulationError(message))

    # -- the counter
    def _install_counter(self) -> None:
        from unicorn import UC_HOOK_BLOCK  # reason: unicorn is optional

        # instructions in this slice, and the count at which to stop
        self._ic = ic = SimpleNamespace(n=0, limit=1)
        sizes: dict[int, int] = {}
        flash = self.flash

        def count_block(uc, address, size, user):
            n = sizes.get(address)
            if n is None:
                n = sizes[address] = thumb_count(flash, address, size)
            ic.n += n
            if ic.n >= ic.limit:
                uc.emu_stop()

        self.uc.hook_add(UC_HOOK_BLOCK, count_block)

    def request_stop(self) -> None:
        """Stop the CPU at the next instruction (to take an interrupt, to report a fault)."""
        self._ic.limit = min(self._ic.limit, self._ic.n + 1)

    def sync_now(self) -> None:
        self.now = self._slice_start + self._ic.n + self._skip_base

    # -- hooks: exception return, replaced functions, idle skip, unmapped memory
    def _install_hooks(self, skip_idle: bool) -> None:
        from unicorn import UC_HOOK_CODE, UC_HOOK_INTR, UC_HOOK_MEM_INVALID  # reason: unicorn is optional

        uc = self.uc
        uc.hook_add(UC_HOOK_INTR, self.guarded(self._on_intr))
        uc.hook_add(UC_HOOK_MEM_INVALID, self.guarded(self._on_invalid))
        FirmwareCalls(self).install()
        # PRIMASK cleared (cpsie i, msr primask): take what became pending
        for a in cpsie_sites(self.flash, self.elf):
            uc.hook_add(UC_HOOK_CODE, lambda uc, address, size, user: self.irq_check(), begin=a, end=a)
        if skip_idle:
            self._setup_idle(self.elf)
            # wfi sleeps to the next event (without skip_idle it runs as unicorn's no-op: the CPU spins through it)
            for a in wfi_sites(self.flash, self.elf):
                uc.hook_add(UC_HOOK_CODE, self.guarded(self._on_wfi), begin=a, end=a)

    def irq_check(self) -> None:
        """A register write may have made an interrupt takeable: stop soon to deliver it."""
        if self.nvic.pending:
            self.request_stop()

    def _on_invalid(self, uc, access, address, size, value, user):
        self.sync_now()
        self._unmodelled(address, access_kind(access))
        return False

    def _on_intr(self, uc, intno, user):
        if intno != INTNO_EXC_RETURN:
            self.sync_now()
            self.stop_with_error(describe_fault(self, intno, self.now / C.CPU_HZ))
            return
        self.exceptions.leave()

    def refresh_levels(self) -> None:
        """The level-triggered interrupt lines, again (after an exception return)."""
        self.usart1.irq_line()
        self.tim9.irq_line()

    # -- idle skipping
    def idle_sites(self, e: Elf) -> list[tuple[int, list[tuple[int, int]], tuple[int, int] | None]]:
        """Where the CPU waits with nothing to do: (address, RAM words that must all be 0 as (offset, bytes), the
        caller's range its LR must be in, or None). The main loop's poll, ``HAL_Delay``'s tick read, ``wfi``."""
        out = []
        addrs = [e.addr(n) for n in IDLE_FLAGS + ("tim",)]
        poll = e.addr(IDLE_POLL)
        if poll is not None and all(a is not None for a in addrs):
            words = [
                (a - RAM_BASE, min(e.by_name[n].size, 4) if e.by_name[n].size in (1, 2, 4) else 4)
                for n, a in zip(IDLE_FLAGS, addrs)
            ]
            words.append((addrs[-1] + TIM_EVENT_CNT - RAM_BASE, 4))
            out.append((poll, words, None))
        delay, get_tick = e.by_name.get("HAL_Delay"), e.addr("HAL_GetTick")
        if delay is not None and get_tick is not None:
            lo = delay.addr & ~1
            out.append((get_tick, [], (lo, lo + max(delay.size, 2))))
        return out

    def _setup_idle(self, e: Elf) -> None:
        from unicorn import UC_HOOK_CODE  # reason: unicorn is optional

        ram, LR, nvic, unpack_from, skip = self.ram, self.regs.LR, self.nvic, struct.unpack_from, self._skip_to_event
        fmt = {1: "<B", 2: "<H", 4: "<I"}
        for addr, words, caller in self.idle_sites(e):
            checks = [(fmt[n], off) for off, n in words]

            def idle(uc, address, size, user, checks=checks, caller=caller):
                if nvic.pending:
                    return
                for f, off in checks:
                    if unpack_from(f, ram, off)[0]:
                        return
                if caller is not None and not caller[0] <= (self.reg(LR) & ~1) < caller[1]:
                    return
                skip()

            self.uc.hook_add(UC_HOOK_CODE, self.guarded(idle), begin=addr, end=addr)

    def _on_wfi(self, uc, address, size, user):
        """``wfi`` in thread mode with no interrupt to take: skip to the next event. Its interrupt is taken here
        when PRIMASK allows, else at the ``cpsie i`` after the ``wfi`` (as the chip wakes with PRIMASK set); back
        from the handler, the ``wfi`` runs (unicorn: a no-op). The same rule as the reference firmware's board."""
        if not self.nvic.active and self.nvic.next_exception(0) is None:
            self._skip_to_event()

    def _skip_to_event(self) -> None:
        """Called in a code hook when the CPU (thread mode) has nothing to do until the next event.

        The clock jumps to that event; it fires here and its interrupt is taken at once (PC redirected inside the
        hook), so an idle CPU goes from event to event without leaving the emulation. At the end of the current
        run the CPU stops instead. The polled instruction runs again after the handler, normally (it sees what the
        handler did).
        """
        if self.nvic.active:
            return
        if self._resumed_idle:
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
            exc = self.nvic.next_exception(self.reg(self.regs.PRIMASK))
            if exc is not None:  # the polled instruction did not run: it runs again after the handler
                ic.n -= 1
                self._skip_base += 1
                self._resumed_idle = True
                self.exceptions.take(exc)
        end = self._earliest()
        end = self._run_end if end is None else min(end, self._run_end)
        self._next_event = end
        ic.limit = max(end - self._slice_start - self._skip_base + 1, ic.n + 1)

    # -- reset and the event loop
    def _reset(self) -> None:
        sp, reset = struct.unpack_from("<II", self.flash, 0)
        self.set_reg(self.regs.SP, sp)
        self.set_reg(self.regs.PC, reset | 1)
        self._slice_start = 0
        self._skip_base = 0

    def reschedule(self) -> None:
        """A peripheral scheduled an event possibly earlier than the current slice's end: stop there."""
        t = self._earliest()
        if t is not None and t < self._next_event:
            self._next_event = t
            self._ic.limit = min(self._ic.limit, max(t - self._slice_start - self._skip_base + 1, self._ic.n + 1))

    @cached_property
    def _events(self) -> tuple:
        """The scheduled events in firing order: (model, the attribute holding its time or None, what fires it)."""
        u, scs = self.usart1, self.scs
        return (
            (u, "shift_done", u.shift_complete),
            (u, "rx_done", u.rx_complete),
            (scs, "systick_next", scs.systick_fire),
            (self.tim9, "next_update", self._tim9_update),
            (self.tim2, "next_update", self.tim2.update),
        )

    def _earliest(self) -> int | None:
        times = (getattr(model, attr) for model, attr, _ in self._events)
        return min((t for t in times if t is not None), default=None)

    def uart_out(self, byte: int, t: int) -> None:
        self.out.append((byte, t))

    def take_output(self) -> tuple[bytes, int | None, int | None]:
        """The USART1 bytes that left the line since the last call, with the instruction counts at which the first
        and the last one left (None, None if none)."""
        if not self.out:
            return b"", None, None
        data = bytes(x for x, _ in self.out)
        first, last = self.out[0][1], self.out[-1][1]
        self.out.clear()
        return data, first, last

    def run_until(self, t_end: int, *, max_slice: int = C.CPU_HZ // 1000) -> None:
        """Run until the instruction clock reaches ``t_end`` (events and interrupts on the way)."""
        uc = self.uc
        ic = self._ic
        self._run_end = t_end
        while self.now < t_end:
            if self.fault is not None:
                raise self.fault
            self._fire_events()
            if self.nvic.pending:
                nxt = self.nvic.next_exception(self.reg(self.regs.PRIMASK))
                if nxt is not None:
                    self.exceptions.take(nxt)
            ev = self._earliest()
            end = min(t_end, self.now + max_slice, ev if ev is not None else t_end)
            self._next_event = end
            self._slice_start = self.now
            self._skip_base = 0
            ic.n = 0
            ic.limit = max(end - self.now, 1) + 1  # the hook that reaches the limit stops before its instruction
            pc = self.pc()
            self.stats.slices += 1
            try:
                uc.emu_start(pc | 1, 0xFFFFFFFE)
            except Exception as exc:  # noqa: BLE001 - unicorn errors become one line
                self.sync_now()
                if self.fault is not None:
                    raise self.fault from None
                err = getattr(exc, "errno", None)
                raise EmulationError(describe_stop(self, err, str(exc), self.now / C.CPU_HZ)) from None
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
            for model, attr, fire in self._events:
                t = getattr(model, attr)
                if t is not None and t <= now:
                    fire()
                    fired = True
            if not fired:
                return

    def _tim9_update(self) -> None:
        self.tim9.update()
        for ob in self.tick_observers:
            ob(self)

"""The board with its hot path in C (``steval_link.emulation._core``; what runs where: the board package's docstring).

Its state is a ``core_t`` allocated here and mirrored with ctypes (:class:`CoreState`; ``core_sizeof`` checks the
layout). The models whose state lives there stand behind the Python models' interfaces: :class:`NativeNvic`
(scs.Nvic), :class:`NativeUsart` (usart.Usart), :class:`NativeTimer` (timer.Timer), :class:`NativeScs` (scs.Scs with
SysTick's schedule in C).
"""

from __future__ import annotations

import ctypes

import numpy as np

from steval_link import constants as C
from steval_link.emulation.board.calls import FirmwareCalls
from steval_link.emulation.board.core import Mark, PythonBoard
from steval_link.emulation.board.cpu import cpsie_sites, uclib, wfi_sites
from steval_link.emulation.board.fault import describe_fault, describe_stop
from steval_link.emulation.board.memory_map import (
    BITBAND_PERIPH,
    BITBAND_SIZE,
    IRQ_BASE,
    PERIPH_BASE,
    RAM_BASE,
    RAM_SIZE,
    TIMERS,
    USART1_OFF,
    EmulationError,
    Peripheral,
)
from steval_link.emulation.board.scs import SYST_TICKINT, Nvic, Scs, ScsReg
from steval_link.emulation.board.usart import SR_RESET, UsartReg

I64, U64, I32, U32 = ctypes.c_int64, ctypes.c_uint64, ctypes.c_int32, ctypes.c_uint32
U8, P = ctypes.c_uint8, ctypes.c_void_p
#: "no event" in an instruction-count field
NONE = -1
# sizes of the C core's tables (as in _core.c)
MAX_IDLE, MAX_IDLE_WORDS, MAX_MIRROR, MAX_SITES, SENSOR_DEVICES = 4, 8, 10, 512, 3
#: bytes of the stack's top the TXE/TC poll skip compares between two status reads
POLL_STACK = 256
#: py_event kinds: TIM9's tick, output buffer full, a sensor read for Python, a Python code hook, a mirrored access,
#: a bit-band access outside USART1, the mark buffer full
EV_TICK, EV_OUT_FULL, EV_SENSOR, EV_CODE, EV_MMIO, EV_BITBAND, EV_MARKS_FULL = 1, 2, 3, 4, 5, 6, 7
#: code site kinds: after cpsie, idle poll, wfi, Sensor_IO_Read, a Python hook, a mark
K_UNMASK, K_IDLE, K_WFI, K_SENSOR, K_PY, K_MARK = 1, 2, 3, 4, 5, 6
#: marks: RAM ranges, int64 words and capacity of the C buffer (drained into Python when full)
MAX_MARK_RANGES, MARK_WORDS, MARK_CAPACITY = 8, 6, 4096
#: fault codes: a Python exception, stack overflow, bad exception return, CPU exception, unicorn error
F_PYTHON, F_STACK, F_RETURN, F_CPU_EXC, F_EMU = 1, 2, 3, 4, 5
#: bytes: host → drone queue, output buffer (drained into Board.out when full), RX log
RX_CAPACITY, OUT_CAPACITY, RXLOG_CAPACITY = 1 << 16, 1 << 14, 1 << 16


class Mirror(ctypes.Structure):
    """``mirror_t``: a Python peripheral's page whose ``served`` words C reads from ``vals``."""

    _fields_ = [("core", P), ("page", I64), ("vals", U32 * 256), ("served", U8 * 256)]


class CTimer(ctypes.Structure):
    """``ctimer_t``: a timer in the C core."""

    _fields_ = [("core", P), ("irq", I64), ("next", I64), ("updates", I64), ("first_update", I64), ("regs", U32 * 256)]


def _same(typ, names: str) -> list[tuple]:
    """Fields of one type: ``names`` separated by spaces, in order."""
    return [(n, typ) for n in names.split()]


class CoreState(ctypes.Structure):
    """``core_t`` of _core.c, field by field."""

    _fields_ = [
        *_same(U64, "n limit"),
        *_same(P, "uc emu_start emu_stop reg_read reg_write reg_read_batch reg_write_batch py_event ram flash"),
        ("rid", I64 * 9),
        ("frame_ids", I32 * 26),
        ("wframe_ids", I32 * 24),
        *_same(I64, "now slice_start skip_base run_end next_event max_slice instructions skipped slices fault"),
        *_same(I64, "fault_arg resumed_idle"),
        *_same(U64 * 4, "pending enabled"),
        ("prio", U8 * 256),
        *_same(I64, "prigroup n_active"),
        ("active", I64 * 64),
        ("counts", I64 * 256),
        *_same(I64, "exc_instructions exc_started vtor systick_next systick_period systick_tickint countflag"),
        ("tim", CTimer * 3),
        ("uregs", U32 * 256),
        *_same(I64, "dr_full shift_done shift_byte tc rx_done rx_line_free rx_dr rx_last rx_ore ore_sr_read"),
        *_same(I64, "rx_received rx_overruns rx_lost"),
        *_same(P, "rx_t rx_b"),
        *_same(I64, "rx_cap rx_head rx_len"),
        *_same(P, "rxlog_t rxlog_b"),
        *_same(I64, "rxlog_cap rxlog_len"),
        *_same(P, "out_t out_b"),
        *_same(I64, "out_cap out_len n_idle"),
        *_same(I64 * MAX_IDLE, "idle_addr idle_n_words"),
        *_same((I64 * MAX_IDLE_WORDS) * MAX_IDLE, "idle_off idle_size"),
        *_same(I64 * MAX_IDLE, "idle_lo idle_hi"),
        ("sensor_img", (U8 * 128) * SENSOR_DEVICES),
        ("sensor_fast", I64 * SENSOR_DEVICES),
        *_same(I64, "sensor_valid sensor_reads n_sites"),
        *_same(I64 * MAX_SITES, "site_addr site_kind site_arg"),
        *_same(I64, "hook_addr hook_size"),
        ("site_map", U8 * (0x40000 // 16)),
        ("mirror", Mirror * MAX_MIRROR),
        *_same(I64, "mmio_write mmio_value poll_skip last_pc io_epoch poll_pc poll_now poll_sr poll_epoch polled"),
        *_same(I64, "poll_stack_len"),
        ("poll_ids", I32 * 16),
        ("poll_regs", U32 * 16),
        ("poll_stack", U8 * POLL_STACK),
        *_same(I64, "scs_page cyccnt_on cyccnt_base usart_base"),
        *_same(P, "plan_img plan_ram"),
        *_same(I64, "plan_u0 plan_n plan_until plan_addr plan_len adc_page adc_dr"),
        *_same(P, "mark_w mark_b"),
        *_same(I64, "mark_cap mark_len mark_bytes n_mark_ranges"),
        *_same(I64 * MAX_MARK_RANGES, "mark_off mark_size"),
        ("cyccnt_frozen", I64),
    ]


def _opt(t: int) -> int | None:
    return None if t == NONE else t


def _raw(t: int | None) -> int:
    return NONE if t is None else int(t)


class _InCore:
    """An attribute of a Python model kept in the C core's state, ``model.st.<field>``; ``optional``: NONE is None."""

    def __init__(self, field: str, optional: bool = False) -> None:
        self.field = field
        self.optional = optional

    def __get__(self, model, owner=None):
        if model is None:
            return self
        value = getattr(model.st, self.field)
        return _opt(value) if self.optional else value

    def __set__(self, model, value) -> None:
        setattr(model.st, self.field, _raw(value) if self.optional else value)


def core_library() -> ctypes.CDLL | None:
    """The C core (None when the extension is not built)."""
    try:
        from steval_link.emulation import _core  # reason: the optional C extension (built when a compiler exists)
    except ImportError:
        return None
    lib = ctypes.CDLL(_core.__file__)
    lib.core_sizeof.restype = I64
    if lib.core_sizeof() != ctypes.sizeof(CoreState):
        raise EmulationError(
            f"the C core's state ({lib.core_sizeof()} B) does not match native.CoreState "
            f"({ctypes.sizeof(CoreState)} B): rebuild it (pip install -e .)"
        )
    lib.timer_read.restype = U32
    for name in ("core_run", "core_next_exception", "usart_inject", "core_add_site"):
        getattr(lib, name).restype = I64
    lib.usart_read.restype = U32
    return lib


class NativeNvic(Nvic):
    """:class:`~steval_link.emulation.board.scs.Nvic` over the C core's NVIC state."""

    def __init__(self, st: CoreState, lib, ptr) -> None:
        self.st = st
        self.lib = lib
        self.ptr = ptr
        self.prio = st.prio

    prigroup = _InCore("prigroup")

    def _bit(self, arr, i: int) -> bool:
        return bool(arr[i >> 6] >> (i & 63) & 1)

    def _put(self, arr, i: int, on: bool) -> None:
        arr[i >> 6] = arr[i >> 6] | (1 << (i & 63)) if on else arr[i >> 6] & ~(1 << (i & 63))

    def pend(self, exc: int) -> None:
        self._put(self.st.pending, exc, True)

    def unpend(self, exc: int) -> None:
        self._put(self.st.pending, exc, False)

    @property
    def pending(self) -> set[int]:
        return {e for e in range(256) if self._bit(self.st.pending, e)}

    @property
    def enabled(self) -> set[int]:
        return {e for e in range(256) if self._bit(self.st.enabled, e)}

    @property
    def active(self) -> list[int]:
        return list(self.st.active[: self.st.n_active])

    def set_word(self, bank: str, i: int, mask: int, on: bool) -> None:
        for b in range(32):
            if mask >> b & 1:
                if bank == "enabled":
                    self._put(self.st.enabled, 32 * i + b, on)
                else:
                    self._put(self.st.pending, 32 * i + b + IRQ_BASE, on)

    def next_exception(self, primask: int) -> int | None:
        e = self.lib.core_next_exception(self.ptr, I64(primask))
        return None if e < 0 else e


class NativeUsart(Peripheral):
    """USART1 in the C core: registers, TX shift register, RX queue (the Python model: usart.Usart)."""

    name = "USART1"

    def __init__(self, board, base, irq):
        super().__init__(board, base)
        self.irq = irq
        self.st = board.st
        self.lib = board.lib
        self.ptr = board.st_ptr
        self.st.uregs[UsartReg.SR // 4] = SR_RESET

    def read(self, off):
        return self.lib.usart_read(self.ptr, U32(off))

    def write(self, off, value):
        self.lib.usart_write(self.ptr, U32(off), U32(value & 0xFFFFFFFF))

    def stored(self, off):
        return 0 if off == UsartReg.DR else self.st.uregs[(off // 4) & 255]

    def bitband_base(self, off):
        return self.st.uregs[0] if off == UsartReg.SR else self.read(off)

    def inject(self, data: bytes, t: int) -> None:
        data = bytes(data)
        t = max(int(t), self.board.now)
        if not self.lib.usart_inject(self.ptr, data, I64(len(data)), I64(t)):
            raise EmulationError(f"the emulated USART1 RX queue is full ({RX_CAPACITY} bytes)")

    def rx_complete(self) -> None:
        self.lib.rx_complete(self.ptr)

    def shift_complete(self) -> None:
        self.lib.shift_complete(self.ptr)

    @property
    def rx_log(self) -> list[tuple[int, int]]:
        n = self.st.rxlog_len
        return [(self.board.rxlog_b[i], self.board.rxlog_t[i]) for i in range(n)]

    def __getattr__(self, name):
        if name in ("rx_done", "shift_done", "dr_full", "rx_dr"):
            return _opt(getattr(self.st, name))
        if name in ("rx_received", "rx_overruns", "rx_lost", "tc", "rx_last"):
            return getattr(self.st, name)
        if name == "rx_ore":
            return bool(self.st.rx_ore)
        raise AttributeError(name)


class NativeTimer(Peripheral):
    """TIMx in the C core (the Python model: timer.Timer); ``regs`` is a copy of its nonzero registers."""

    def __init__(self, board, base, irq: int | None, name: str):
        super().__init__(board, base, name=name)
        self.irq = irq
        self.index = [t[0] for t in TIMERS].index(name)
        self.t = board.st.tim[self.index]
        self.t.core, self.t.irq, self.t.next, self.t.first_update = ctypes.addressof(board.st), _raw(irq), NONE, NONE
        self.lib = board.lib
        self.ptr = board.st_ptr

    def read(self, off):
        return self.lib.timer_read(self.ptr, I64(self.index), U32(off))

    def write(self, off, value):
        self.lib.timer_write(self.ptr, I64(self.index), U32(off), U32(value & 0xFFFFFFFF))

    def stored(self, off):
        return self.t.regs[(off // 4) & 255]

    @property
    def regs(self) -> dict[int, int]:
        return {4 * i: v for i, v in enumerate(self.t.regs) if v}

    @regs.setter
    def regs(self, value) -> None:  # (Peripheral.__init__)
        pass

    @property
    def updates(self) -> int:
        return self.t.updates

    @property
    def first_update(self) -> int | None:
        return _opt(self.t.first_update)


class NativeScs(Scs):
    """The SCS registers in Python, SysTick's schedule and the VTOR the C core needs mirrored into it."""

    def __init__(self, board):
        self.st = board.st
        super().__init__(board)

    systick_next = _InCore("systick_next", optional=True)
    countflag = _InCore("countflag")

    def write(self, off, value):
        super().write(off, value)
        st = self.st
        st.systick_period = self.systick_period()
        st.systick_tickint = 1 if self.regs.get(ScsReg.SYST_CSR, 0) & SYST_TICKINT else 0
        st.vtor = self.regs.get(ScsReg.VTOR, 0)
        st.cyccnt_on, st.cyccnt_base = self.cyccnt_frozen is None, self.cyccnt_base
        st.cyccnt_frozen = self.cyccnt_frozen or 0


class NativeBoard(PythonBoard):
    """:class:`PythonBoard` with the C core (see the module docstring)."""

    native = True
    #: ``planner(board)``: the next TIM9 updates as tables, applied in C without the tick observers (see
    #: ``Emulation.plan_ticks``); None: every update calls them
    tick_planner = None
    timer_model, usart_model, scs_model = NativeTimer, NativeUsart, NativeScs

    def __init__(self, elf, sensors, *, skip_idle: bool = True):
        self.lib = core_library()
        self.st = CoreState()
        self.st_ptr = ctypes.byref(self.st)
        self._lsm6dsl_img = ctypes.addressof(self.st.sensor_img[0])  # (the C core's copy of its registers)
        self.rx_t, self.rx_b = (I64 * RX_CAPACITY)(), (U8 * RX_CAPACITY)()
        self.rxlog_t, self.rxlog_b = (I64 * RXLOG_CAPACITY)(), (U8 * RXLOG_CAPACITY)()
        self.out_t, self.out_b = (I64 * OUT_CAPACITY)(), (U8 * OUT_CAPACITY)()
        self.mark_w, self.mark_b = (I64 * (MARK_WORDS * MARK_CAPACITY))(), ctypes.create_string_buffer(0)
        self._event_cb = ctypes.CFUNCTYPE(I64, I64, I64)(self._on_event)
        self._py_hooks: list = []
        self._mirrored: list = []
        self._sensor_update = -1  # the TIM9 update whose sample the sensors' Python registers hold
        super().__init__(elf, sensors, skip_idle=skip_idle)

    # -- construction
    def _make_peripherals(self) -> None:
        from unicorn import arm_const as A  # reason: unicorn is optional

        lib = uclib()
        st = self.st
        st.uc = self.uc._uch.value if hasattr(self.uc._uch, "value") else self.uc._uch
        for name in ("emu_start", "emu_stop", "reg_read", "reg_write", "reg_read_batch", "reg_write_batch"):
            setattr(st, name, ctypes.cast(getattr(lib, "uc_" + name), P).value)
        st.py_event = ctypes.cast(self._event_cb, P).value
        st.ram, st.flash = ctypes.addressof(self.ram), ctypes.addressof(self.flash)
        r = self.regs
        st.rid[:] = [r.SP, r.LR, r.PC, r.XPSR, r.PRIMASK] + r.R
        fp = [getattr(A, f"UC_ARM_REG_D{k}") for k in range(8)] + [A.UC_ARM_REG_FPSCR]  # s0-s15 as d0-d7
        st.frame_ids[:17] = r.frame_ids[:8] + fp
        st.wframe_ids[:15] = r.frame_ids[:6] + fp
        st.max_slice = C.CPU_HZ // 1000
        st.poll_ids[:] = [getattr(A, f"UC_ARM_REG_R{i}") for i in range(13)] + [r.SP, r.LR, r.XPSR]
        st.poll_skip, st.poll_pc = 1, NONE
        st.scs_page, st.adc_page, st.usart_base = NONE, NONE, PERIPH_BASE + USART1_OFF
        for name in ("systick_next", "dr_full", "shift_done", "rx_done", "rx_dr"):
            setattr(st, name, NONE)
        st.tc = 1
        st.systick_period = 1
        addr = ctypes.addressof
        st.rx_t, st.rx_b, st.rx_cap = addr(self.rx_t), addr(self.rx_b), RX_CAPACITY
        st.rxlog_t, st.rxlog_b, st.rxlog_cap = addr(self.rxlog_t), addr(self.rxlog_b), RXLOG_CAPACITY
        st.out_t, st.out_b, st.out_cap = addr(self.out_t), addr(self.out_b), OUT_CAPACITY
        st.mark_w, st.mark_cap = addr(self.mark_w), MARK_CAPACITY
        self.nvic = NativeNvic(st, self.lib, self.st_ptr)
        super()._make_peripherals()

    def _map_usart(self, uc, usart) -> None:
        self._map_c(usart, "usart_mmio_read", "usart_mmio_write", self.st_ptr)

    def _map_c(self, p, read: str, write: str, user, what: str = "MMIO model") -> None:
        err = uclib().uc_mmio_map(
            self.uc._uch,
            ctypes.c_uint64(p.base),
            ctypes.c_size_t(p.size),
            ctypes.cast(getattr(self.lib, read), P),
            user,
            ctypes.cast(getattr(self.lib, write), P),
            user,
        )
        if err:
            raise EmulationError(f"unicorn refused the {p.name} {what} (error {err})")

    def _map_python(self, uc, p, rd, wr) -> None:
        """A Python peripheral's page: the timers are C's; its ``c_readable`` words and the SCS's DWT CYCCNT are
        read in C (a mirror), the rest goes to Python."""
        if isinstance(p, NativeTimer):
            return self._map_c(p, "timer_mmio_read", "timer_mmio_write", ctypes.byref(p.t))
        scs = isinstance(p, NativeScs)
        if not (p.c_readable or scs) or len(self._mirrored) >= MAX_MIRROR:
            return super()._map_python(uc, p, self._epoch_first(rd), self._epoch_first(wr))
        k = len(self._mirrored)
        self._mirrored.append(p)
        m = self.st.mirror[k]
        m.core, m.page = ctypes.addressof(self.st), k
        for off in p.c_readable:
            m.served[off // 4] = 1
        p.mirror = m
        self._refresh_mirror(p)
        if scs:
            self.st.scs_page = k
        if p.name == "ADC1":
            self.st.adc_page, self.st.adc_dr = k, p.VBAT_COUNTS
        self._map_c(p, "mirror_mmio_read", "mirror_mmio_write", ctypes.byref(m), "MMIO mirror")

    def _epoch_first(self, hook):
        """``hook`` (unicorn calls it, past the C core) after the poll skip's epoch moves: a poll loop around a
        Python model's access does not repeat unchanged. (The C core moves it before every call into Python.)"""

        def moved(*args):
            self.st.io_epoch += 1
            return hook(*args)

        return moved

    @staticmethod
    def _pull_mirror(p) -> None:
        """A mirrored page's ``c_owned`` words from the C core, before Python's model runs."""
        for off in p.c_owned:
            p.regs[off] = p.mirror.vals[off // 4]

    @staticmethod
    def _refresh_mirror(p) -> None:
        """The C core's copy of a mirrored page's ``c_readable`` words, after Python touched the page."""
        for off in p.c_readable:
            p.mirror.vals[off // 4] = p.read(off)

    def _map_bitband(self, uc) -> None:
        """The peripheral bit-band alias: USART1's bits in C, the others in Python (EV_BITBAND)."""
        alias = Peripheral(self, BITBAND_PERIPH, BITBAND_SIZE, name="bit-band")
        self._map_c(alias, "bb_mmio_read", "bb_mmio_write", self.st_ptr)

    def _c_hook(self, kind: int, fn: str, begin: int = 1, end: int = 0) -> None:
        h = ctypes.c_size_t()
        err = uclib().uc_hook_add(
            self.uc._uch,
            ctypes.byref(h),
            kind,
            ctypes.cast(getattr(self.lib, fn), P),
            self.st_ptr,
            ctypes.c_uint64(begin),
            ctypes.c_uint64(end),
        )
        if err:
            raise EmulationError(f"unicorn refused the C hook {fn} (error {err})")

    def _install_counter(self) -> None:
        from unicorn import UC_HOOK_CODE, UC_HOOK_TLB_FILL, UC_TLB_VIRTUAL  # reason: unicorn is optional

        self._c_hook(UC_HOOK_CODE, "core_count_hook")
        # unicorn's software TLB filled here: a RAM page is writable, not executable, unless code is fetched from it
        # (unicorn keeps every store to an executable page, or to a page under a memory hook, on its slow path)
        self.uc.ctl_set_tlb_mode(UC_TLB_VIRTUAL)
        self._c_hook(UC_HOOK_TLB_FILL, "core_tlb_fill")

    def _install_hooks(self, skip_idle: bool) -> None:
        from unicorn import UC_HOOK_INTR, UC_HOOK_MEM_INVALID  # reason: unicorn is optional

        self._c_hook(UC_HOOK_INTR, "core_intr_hook")
        for lo, hi in ((0, RAM_BASE - 1), (RAM_BASE + RAM_SIZE, 0xFFFFFFFF)):  # (none over RAM: see above)
            self.uc.hook_add(UC_HOOK_MEM_INVALID, self.guarded(self._on_invalid), begin=lo, end=hi)
        calls = FirmwareCalls(self)
        sensor_read, self._sensor_write = self.elf.addr("Sensor_IO_Read"), self.elf.addr("Sensor_IO_Write")
        # a write changes the register files: the C core's copies follow
        self.call_observers.setdefault("Sensor_IO_Write", []).append(lambda board, *args: self._sensor_images())
        calls.install(skip=("Sensor_IO_Read",) if sensor_read is not None else ())
        if sensor_read is not None:
            self._sensor_slow = calls.replacement_hook("Sensor_IO_Read")
            self._site(sensor_read, K_SENSOR)
        for a in cpsie_sites(self.flash, self.elf):
            self._site(a, K_UNMASK)
        st = self.st
        if skip_idle:
            sites = self.idle_sites(self.elf)[:MAX_IDLE]
            st.n_idle = len(sites)
            for k, (addr, words, caller) in enumerate(sites):
                st.idle_addr[k] = addr
                st.idle_n_words[k] = len(words[:MAX_IDLE_WORDS])
                for j, (off, size) in enumerate(words[:MAX_IDLE_WORDS]):
                    st.idle_off[k][j], st.idle_size[k][j] = off, size
                st.idle_lo[k], st.idle_hi[k] = caller if caller is not None else (0, 0)
                self._site(addr, K_IDLE)
            for a in wfi_sites(self.flash, self.elf):
                self._site(a, K_WFI)

    def _site(self, addr: int, kind: int, arg: int = 0) -> None:
        if not self.lib.core_add_site(self.st_ptr, I64(addr), I64(kind), I64(arg)):
            raise EmulationError(
                f"the C core cannot hook 0x{addr:08x} (outside the flash, or more than {MAX_SITES} hooks)"
            )

    def mark_ram(self, ranges: list[tuple[int, int]]) -> None:
        if len(ranges) > MAX_MARK_RANGES:
            raise ValueError(f"the C core marks at most {MAX_MARK_RANGES} RAM ranges")
        super().mark_ram(ranges)
        st = self.st
        st.n_mark_ranges = len(ranges)
        for k, (a, n) in enumerate(ranges):
            st.mark_off[k], st.mark_size[k] = a - RAM_BASE, n
        st.mark_bytes = sum(n for _, n in ranges)
        self.mark_b = ctypes.create_string_buffer(max(st.mark_bytes, 1) * MARK_CAPACITY)
        st.mark_b = ctypes.addressof(self.mark_b)

    def mark(self, addr: int, kind: int) -> None:
        self._site(addr, K_MARK, kind)

    def take_marks(self) -> list:
        self._drain_marks()
        return super().take_marks()

    def _drain_marks(self) -> None:
        """The C buffer's marks into the Python list."""
        st = self.st
        n, size = st.mark_len, st.mark_bytes
        if not n:
            return
        words = np.frombuffer(self.mark_w, np.int64, MARK_WORDS * n).reshape(n, MARK_WORDS).tolist()
        raw = ctypes.string_at(self.mark_b, size * n)
        for i, (kind, *counters) in enumerate(words):
            at, ram = i * size, []
            for a, n_bytes in self._mark_ram:
                ram.append((a, raw[at : at + n_bytes]))
                at += n_bytes
            self._marks.append(Mark(kind, *counters, tuple(ram)))
        st.mark_len = 0

    def code_hook(self, addr: int, fn) -> None:
        """Call ``fn(uc, address, size, user)`` before the instruction at ``addr`` (dispatched by the C core)."""
        self._py_hooks.append(fn)
        self._site(addr, K_PY, len(self._py_hooks) - 1)

    # -- Python called from C
    def _on_event(self, kind: int, arg: int) -> int:
        try:
            self.now = self.st.now
            if kind == EV_TICK:
                for ob in self.tick_observers:
                    ob(self)
                self._sensor_tick()
                self._plan_ticks()
            elif kind == EV_OUT_FULL:
                self._drain()
            elif kind == EV_MARKS_FULL:
                self._drain_marks()
            elif kind in (EV_MMIO, EV_BITBAND):  # one mirrored page's access, or a bit-band one (any page's bit)
                st, mmio = self.st, kind == EV_MMIO
                pages = [self._mirrored[arg]] if mmio else self._mirrored
                read, write = (self._mmio_read, self._mmio_write) if mmio else (self._bb_read, self._bb_write)
                for p in pages:
                    self._pull_mirror(p)
                if st.mmio_write:
                    write(self.uc, st.hook_addr, st.hook_size, st.mmio_value, pages[0] if mmio else None)
                else:
                    st.mmio_value = read(self.uc, st.hook_addr, st.hook_size, pages[0] if mmio else None)
                for p in pages:
                    self._refresh_mirror(p)
            elif kind == EV_CODE:
                if self.st.hook_addr == self._sensor_write:
                    self._sensor_catch_up()
                self._py_hooks[arg](self.uc, self.st.hook_addr, self.st.hook_size, None)
            elif kind == EV_SENSOR:
                self._sensor_catch_up()
                self._sensor_slow(self.uc, 0, 0, None)
                self._sensor_images()
        except BaseException as exc:  # noqa: BLE001 - raised again by run_until
            self.stop_with(exc)
        return 0

    def _sensor_tick(self) -> None:
        """At TIM9's update, the LSM6DSL's sample of the new tick into the C core's image (as the ISR's first read
        would fetch it): the ISR's reads all run in C."""
        bus, st = self.sensors, self.st
        if not st.sensor_fast[0] or self.call_observers.get("Sensor_IO_Read"):
            return
        ctypes.memmove(self._lsm6dsl_img, bus.lsm6dsl_image(self), 128)
        st.sensor_valid = self._sensor_update = st.tim[0].updates

    def _plan_ticks(self) -> None:
        """The next TIM9 updates into the C core as :attr:`tick_planner` tables them (no Python call per update)."""
        st = self.st
        st.plan_n = 0  # (a plan stands for the observers and the sensor path it knew)
        plan = self.tick_planner if len(self.tick_observers) == 1 and st.sensor_fast[0] == 1 else None
        if plan is not None and not self.call_observers.get("Sensor_IO_Read") and (plan := plan(self)) is not None:
            n, img, addr, ram, until = plan
            self._plan = img, ram  # (the C core reads them)
            st.plan_img, st.plan_ram, st.plan_addr, st.plan_len = img.ctypes.data, ram.ctypes.data, addr, ram.shape[1]
            st.plan_u0, st.plan_n, st.plan_until = st.tim[0].updates + 1, n, 1 << 62 if until is None else until

    def _sensor_catch_up(self) -> None:
        """After TIM9 updates applied in C: the LSM6DSL's Python registers with this tick's sample again."""
        if self.st.sensor_fast[0] == 1 and self.st.tim[0].updates != self._sensor_update:
            self.sensors.lsm6dsl_image(self)
            self._sensor_update = self.st.tim[0].updates

    def _sensor_images(self) -> None:
        """The sensors' register files into the C core (the LSM6DSL's valid until the next TIM9 update)."""
        bus, st = self.sensors, self.st
        devices = getattr(bus, "devices", None)
        fast = (
            devices is not None and not getattr(bus, "log_limit", 1) and not self.call_observers.get("Sensor_IO_Read")
        )
        for d in range(SENSOR_DEVICES):
            dev = devices.get(d) if devices is not None else None
            st.sensor_fast[d] = 1 if fast and dev is not None else 0
            if dev is not None:
                ctypes.memmove(ctypes.addressof(st.sensor_img[d]), bytes(dev.r), 128)
        st.sensor_valid = st.tim[0].updates if self.tim9.first_update is not None else -1

    def take_output(self) -> tuple[bytes, int | None, int | None]:
        """The USART1 bytes that left the line since the last call (one copy out of the C buffer), with the
        instruction counts at which the first and the last one left (None, None if none)."""
        st = self.st
        if self.out:  # (the buffer overflowed into out during a long run)
            self._drain()
            return super().take_output()
        n = st.out_len
        if not n:
            return b"", None, None
        data = ctypes.string_at(self.out_b, n)
        first, last = self.out_t[0], self.out_t[n - 1]
        st.out_len = 0
        return data, first, last

    def _drain(self) -> None:
        st = self.st
        n = st.out_len
        if n:
            self.out.extend(zip(bytes(self.out_b[:n]), self.out_t[:n]))
            st.out_len = 0

    # -- the board's interface, over the C state
    def sync_now(self) -> None:
        """``now`` from the counter, in Python and in the C core (a model called from Python reads it there)."""
        st = self.st
        self.now = st.now = st.slice_start + st.n + st.skip_base

    def instructions_now(self) -> int:
        return self.st.instructions + self.st.n

    exception_instructions = _InCore("exc_instructions")

    def request_stop(self) -> None:
        self.lib.core_request_stop(self.st_ptr)

    def stop_with(self, exc: BaseException) -> None:
        if not self.st.fault:
            self.st.fault = F_PYTHON
        super().stop_with(exc)

    def reschedule(self) -> None:
        self.lib.core_reschedule(self.st_ptr)

    def irq_check(self) -> None:
        self.lib.core_irq_check(self.st_ptr)

    def _reset(self) -> None:
        super()._reset()
        self.st.now = self.st.slice_start = self.st.skip_base = 0

    def _stats(self) -> None:
        st, s = self.st, self.stats
        s.instructions, s.skipped_instructions, s.slices = st.instructions, st.skipped, st.slices
        counts = np.frombuffer(st.counts, np.int64)
        s.interrupts = {int(e): int(counts[e]) for e in np.flatnonzero(counts)}

    def run_until(self, t_end: int, *, max_slice: int = C.CPU_HZ // 1000) -> None:
        """Run until the instruction clock reaches ``t_end`` (events and interrupts on the way)."""
        st = self.st
        st.max_slice = max_slice
        if self.fault is not None:
            raise self.fault
        if self.st.sensor_valid and self.call_observers.get("Sensor_IO_Read"):
            st.sensor_fast[:] = [0] * SENSOR_DEVICES
        if self.call_observers.get("Sensor_IO_Read") or len(self.tick_observers) != 1 or self.tick_planner is None:
            st.plan_n = 0
        rc = self.lib.core_run(self.st_ptr, I64(t_end))
        self.now = st.now
        if self.out:  # (bytes already drained into out: keep the order)
            self._drain()
        self._stats()
        if rc:
            raise self._fault_error()

    def _fault_error(self) -> BaseException:
        st = self.st
        if self.fault is not None:
            return self.fault
        if st.fault == F_STACK:
            self.fault = EmulationError(
                f"stack overflow: exception {st.fault_arg >> 32} at sp "
                f"0x{st.fault_arg & 0xFFFFFFFF:08x} in {self.where()}"
            )
        elif st.fault == F_RETURN:
            self.fault = EmulationError(f"exception return without an active exception in {self.where()}")
        elif st.fault == F_CPU_EXC:
            self.fault = EmulationError(describe_fault(self, st.fault_arg, self.now / C.CPU_HZ))
        else:
            from unicorn import UcError  # reason: unicorn is optional

            self.fault = EmulationError(
                describe_stop(self, st.fault_arg, str(UcError(st.fault_arg)), self.now / C.CPU_HZ)
            )
        return self.fault


__all__ = ["NativeBoard", "core_library"]

"""The C core's state as Python sees it (``core_t`` of ``_core.c`` mirrored with ctypes) and the models whose state
lives there, behind the Python models' interfaces: :class:`NativeNvic` (scs.Nvic), :class:`NativeUsart`
(usart.Usart), :class:`NativeTimer` (timer.Timer), :class:`NativeScs` (scs.Scs with SysTick's schedule in C)."""

from __future__ import annotations

import ctypes

from steval_link.emulation.board.memory_map import IRQ_BASE, TIMERS, EmulationError, Peripheral
from steval_link.emulation.board.scs import SYST_TICKINT, Scs, ScsReg
from steval_link.emulation.board.timer import TimReg
from steval_link.emulation.board.usart import BITS_PER_BYTE, BRR_DEFAULT, SR_RESET, UsartReg

I64, U64, U8, U32, I32, P = (
    ctypes.c_int64,
    ctypes.c_uint64,
    ctypes.c_uint8,
    ctypes.c_uint32,
    ctypes.c_int32,
    ctypes.c_void_p,
)
#: "no event" in an instruction-count field
NONE = -1
# sizes of the C core's tables (as in _core.c)
MAX_IDLE, MAX_IDLE_WORDS, MAX_MIRROR, MAX_SITES, SENSOR_DEVICES = 4, 8, 10, 512, 3
#: bytes of the stack's top the TXE/TC poll skip compares between two status reads
POLL_STACK = 256
#: py_event kinds: TIM9's tick, output buffer full, a sensor read for Python, a Python code hook, a mirrored access,
#: a bit-band access outside USART1
EV_TICK, EV_OUT_FULL, EV_SENSOR, EV_CODE, EV_MMIO, EV_BITBAND = 1, 2, 3, 4, 5, 6
#: code site kinds: after cpsie, idle poll, wfi, Sensor_IO_Read, a Python hook
K_UNMASK, K_IDLE, K_WFI, K_SENSOR, K_PY = 1, 2, 3, 4, 5
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
    ]


def _opt(t: int) -> int | None:
    return None if t == NONE else t


def _raw(t: int | None) -> int:
    return NONE if t is None else int(t)


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


class NativeNvic:
    """:class:`~steval_link.emulation.board.scs.Nvic`'s methods over the C core's NVIC state."""

    def __init__(self, st: CoreState, lib, ptr) -> None:
        self.st, self.lib, self.ptr = st, lib, ptr
        self.prio = st.prio

    @property
    def prigroup(self) -> int:
        return self.st.prigroup

    @prigroup.setter
    def prigroup(self, v: int) -> None:
        self.st.prigroup = v

    def _bit(self, arr, i: int) -> bool:
        return bool(arr[i >> 6] >> (i & 63) & 1)

    def _put(self, arr, i: int, on: bool) -> None:
        arr[i >> 6] = arr[i >> 6] | (1 << (i & 63)) if on else arr[i >> 6] & ~(1 << (i & 63))

    def pend(self, exc: int) -> None:
        self._put(self.st.pending, exc, True)

    def unpend(self, exc: int) -> None:
        self._put(self.st.pending, exc, False)

    def is_pending(self, exc: int) -> bool:
        return self._bit(self.st.pending, exc)

    @property
    def pending(self) -> set[int]:
        return {e for e in range(256) if self._bit(self.st.pending, e)}

    @property
    def active(self) -> list[int]:
        return list(self.st.active[: self.st.n_active])

    def current(self) -> int:
        n = self.st.n_active
        return self.st.active[n - 1] if n else 0

    def word(self, bank: str, i: int) -> int:
        if bank == "enabled":
            return (self.st.enabled[i >> 1] >> (32 * (i & 1))) & 0xFFFFFFFF
        if bank == "pending":
            return sum(1 << b for b in range(32) if self._bit(self.st.pending, 32 * i + b + IRQ_BASE))
        act = set(self.active)
        return sum(1 << b for b in range(32) if 32 * i + b + IRQ_BASE in act)

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
        self.st, self.lib, self.ptr = board.st, board.lib, board.st_ptr
        self.st.uregs[UsartReg.SR // 4] = SR_RESET

    def read(self, off):
        return self.lib.usart_read(self.ptr, U32(off))

    def write(self, off, value):
        self.lib.usart_write(self.ptr, U32(off), U32(value & 0xFFFFFFFF))

    def stored(self, off):
        return 0 if off == UsartReg.DR else self.st.uregs[(off // 4) & 255]

    def bitband_base(self, off):
        return self.st.uregs[0] if off == UsartReg.SR else self.read(off)

    def byte_cycles(self) -> int:
        return BITS_PER_BYTE * (self.st.uregs[UsartReg.BRR // 4] or BRR_DEFAULT)

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
        self.irq, self.index = irq, [t[0] for t in TIMERS].index(name)
        self.t = board.st.tim[self.index]
        self.t.core, self.t.irq, self.t.next, self.t.first_update = ctypes.addressof(board.st), _raw(irq), NONE, NONE
        self.lib, self.ptr = board.lib, board.st_ptr

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
    def next_update(self) -> int | None:
        return _opt(self.t.next)

    @property
    def updates(self) -> int:
        return self.t.updates

    @property
    def first_update(self) -> int | None:
        return _opt(self.t.first_update)

    @property
    def period(self) -> int:
        return (self.t.regs[TimReg.PSC // 4] + 1) * (self.t.regs[TimReg.ARR // 4] + 1)


class NativeScs(Scs):
    """The SCS registers in Python, SysTick's schedule and the VTOR the C core needs mirrored into it."""

    def __init__(self, board):
        self.st = board.st
        super().__init__(board)

    @property
    def systick_next(self) -> int | None:
        return _opt(self.st.systick_next)

    @systick_next.setter
    def systick_next(self, t: int | None) -> None:
        self.st.systick_next = _raw(t)

    @property
    def countflag(self) -> int:
        return self.st.countflag

    @countflag.setter
    def countflag(self, v: int) -> None:
        self.st.countflag = v

    def write(self, off, value):
        super().write(off, value)
        st = self.st
        st.systick_period = self.systick_period()
        st.systick_tickint = 1 if self.regs.get(ScsReg.SYST_CSR, 0) & SYST_TICKINT else 0
        st.vtor = self.regs.get(ScsReg.VTOR, 0)
        st.cyccnt_on, st.cyccnt_base = self.cyccnt_frozen is None, self.cyccnt_base

"""The firmware's attitude read by symbol on the emulated board, each AHRS step, as a debugger would.

Any build with its symbols keeps the filter's inputs and outputs in globals: ``acc_ahrs`` / ``gyro_ahrs`` (float
mg / mdps) and ``gTHR`` (int16) when ``ahrs_fusion_ag`` is entered; ``ahrs`` (q0..q3) and ``euler_ahrs`` (float
thx, thy, thz, rad) when the step ends. :class:`SymbolAttitude` reads them as ``SYMBOL_DTYPE`` rows for the
capture's chunks ``S`` (never frames the firmware sent). Step ``i`` is the ``i``-th call of ``ahrs_fusion_ag``.
"""

from __future__ import annotations

import math

import numpy as np

from steval_link import constants as C
from steval_link.emulation.runner import Emulation
from steval_link.link.capture import SYMBOL_DTYPE

SYMBOLS = ("acc_ahrs", "gyro_ahrs", "gTHR", "ahrs", "euler_ahrs")  #: the globals read, in the rows' order

_READ_INPUTS, _READ_Q, _READ_EULER = 1, 2, 4


class SymbolAttitude:
    """Reads the AHRS globals of ``emu``'s firmware every step (a missing global's fields stay NaN / 0).
    ``available``: the ELF has ``euler_ahrs`` or ``ahrs`` (else nothing is read); ``count``: every row so far."""

    def __init__(self, emu: Emulation) -> None:
        a = self.addr = {name: emu.elf.addr(name) for name in SYMBOLS}
        self.available = a["euler_ahrs"] is not None or a["ahrs"] is not None
        #: what each row holds: q and Euler angles by the ELF's symbols; the inputs too when a step's start was seen
        self._read = (_READ_Q if a["ahrs"] is not None else 0) | (_READ_EULER if a["euler_ahrs"] else 0)
        self._read_inputs = _READ_INPUTS if a["acc_ahrs"] and a["gyro_ahrs"] else 0
        self.count = 0
        self._rows: list[tuple] = []
        self._inputs: tuple | None = None
        if self.available:
            emu.step_start_observers.append(self._start)
            emu.step_end_observers.append(self._end)

    def _floats(self, mark, name: str, n: int) -> list[float]:
        a = self.addr[name]
        return [math.nan] * n if a is None else np.frombuffer(mark.ram_read(a, 4 * n), "<f4").tolist()

    def _start(self, mark) -> None:
        thr_addr = self.addr["gTHR"]
        thr = int.from_bytes(mark.ram_read(thr_addr, 2), "little", signed=True) if thr_addr is not None else 0
        self._inputs = (self._floats(mark, "acc_ahrs", 3), self._floats(mark, "gyro_ahrs", 3), thr)

    def _end(self, mark) -> None:
        acc, gyro, thr = self._inputs or ([math.nan] * 3, [math.nan] * 3, 0)
        read = self._read | (self._read_inputs if self._inputs else 0)
        q, euler = self._floats(mark, "ahrs", 4), self._floats(mark, "euler_ahrs", 3)
        self._rows.append((self.count, mark.now / C.CPU_HZ, acc, gyro, thr, q, euler, read))
        self.count += 1
        self._inputs = None

    def take(self) -> np.ndarray:
        """The rows read since the last call (``SYMBOL_DTYPE``)."""
        rows, self._rows = self._rows, []
        return np.array(rows, dtype=SYMBOL_DTYPE)


#: the run-time helpers of double arithmetic on a single-precision FPU (Cortex-M4F): 221117's ahrs_fusion_ag calls
#: them (gyro scale, integral step, halfT in double); 170120's, float throughout, calls none
_DOUBLE_HELPERS = ("__aeabi_f2d", "__aeabi_dmul", "__aeabi_dadd", "__aeabi_d2f", "__aeabi_ddiv", "__aeabi_dsub")


def _bl_targets(code: bytes, base: int) -> set[int]:
    """Targets of the Thumb-2 BL instructions in ``code`` (loaded at ``base``), scanned halfword by halfword."""
    h = np.frombuffer(code[: len(code) & ~1], "<u2").astype(np.int64)
    out = set()
    for i in np.flatnonzero(((h[:-1] & 0xF800) == 0xF000) & ((h[1:] & 0xD000) == 0xD000)).tolist():
        hw1, hw2 = int(h[i]), int(h[i + 1])
        s = (hw1 >> 10) & 1
        i1 = 1 - (((hw2 >> 13) & 1) ^ s)
        i2 = 1 - (((hw2 >> 11) & 1) ^ s)
        imm = (s << 24) | (i1 << 23) | (i2 << 22) | ((hw1 & 0x3FF) << 12) | ((hw2 & 0x7FF) << 1)
        imm -= (1 << 25) if s else 0
        out.add(base + 2 * i + 4 + imm)
    return out


def elf_filter_variant(elf) -> tuple[str | None, str]:
    """(The ST release whose filter an ``Elf`` has, or None; why), from the double helpers ``ahrs_fusion_ag`` calls."""
    sym = elf.by_name.get("ahrs_fusion_ag")
    if sym is None or sym.size <= 0:
        return None, "no ahrs_fusion_ag symbol with a size in the ELF"
    start = sym.addr & ~1
    code = next((data[start - a : start - a + sym.size] for a, data in elf.segments if a <= start < a + len(data)), b"")
    if len(code) < sym.size:
        return None, "ahrs_fusion_ag's code is not in the ELF's load segments"
    helpers = {elf.addr(n) & ~1: n for n in _DOUBLE_HELPERS if elf.addr(n) is not None}
    called = sorted({helpers[t] for t in _bl_targets(code, start) if t in helpers})
    if called:
        return "ST 221117", f"ahrs_fusion_ag calls the double-arithmetic helpers ({', '.join(called)}): 221117's filter"
    return "ST 170120", "ahrs_fusion_ag does float arithmetic only (no double helper called): 170120's filter"

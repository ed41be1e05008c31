"""The firmware's attitude read by symbol on the emulated board, each AHRS step, as a debugger would.

Any build with its symbols (ST's own, unpatched; a patched one; the reference firmware) keeps the filter's inputs
and outputs in globals: ``acc_ahrs`` / ``gyro_ahrs`` (float x, y, z in mg / mdps) and ``gTHR`` (int16) when
``ahrs_fusion_ag`` is entered; ``ahrs`` (q0..q3 first) and ``euler_ahrs`` (float thx, thy, thz in rad) when the step
ends. :class:`SymbolAttitude` reads them with the emulator's per-step observers (``Emulation.step_start_observers``
and ``step_end_observers``) and hands them out as rows of ``SYMBOL_DTYPE`` for the capture's chunks ``S``: what the
emulator read, never frames the firmware sent. AHRS step ``i`` (from 0) is the ``i``-th call of ``ahrs_fusion_ag``,
the step counter of the patch's frames.
"""

from __future__ import annotations

import math

import numpy as np

from steval_link import constants as C
from steval_link.emulation.runner import Emulation
from steval_link.link.capture import SYMBOL_DTYPE

__all__ = ["SYMBOLS", "SymbolAttitude"]

#: the globals read, in the order the rows hold them
SYMBOLS = ("acc_ahrs", "gyro_ahrs", "gTHR", "ahrs", "euler_ahrs")

_READ_INPUTS, _READ_Q, _READ_EULER = 1, 2, 4


class SymbolAttitude:
    """Reads the AHRS globals of ``emu``'s firmware every step (see the module docstring).

    ``available``: the ELF has ``euler_ahrs`` or ``ahrs`` (else nothing is read). ``take()`` returns the rows read
    since the last call; ``count`` is every row so far.
    """

    def __init__(self, emu: Emulation) -> None:
        e = emu.elf
        self.addr = {name: e.addr(name) for name in SYMBOLS}
        self.available = self.addr["euler_ahrs"] is not None or self.addr["ahrs"] is not None
        self.count = 0
        self._rows: list[tuple] = []
        self._inputs: tuple | None = None
        if self.available:
            emu.step_start_observers.append(self._start)
            emu.step_end_observers.append(self._end)

    def missing(self) -> list[str]:
        """The globals this ELF lacks (their fields stay NaN / 0 in the rows)."""
        return [name for name, a in self.addr.items() if a is None]

    def _floats(self, board, name: str, n: int) -> list[float]:
        a = self.addr[name]
        return [math.nan] * n if a is None else np.frombuffer(board.ram_read(a, 4 * n), "<f4").tolist()

    def _start(self, board) -> None:
        thr_addr = self.addr["gTHR"]
        thr = int.from_bytes(board.ram_read(thr_addr, 2), "little", signed=True) if thr_addr is not None else 0
        self._inputs = (self._floats(board, "acc_ahrs", 3), self._floats(board, "gyro_ahrs", 3), thr)

    def _end(self, board) -> None:
        acc, gyro, thr = self._inputs or ([math.nan] * 3, [math.nan] * 3, 0)
        read = (_READ_INPUTS if self._inputs and self.addr["acc_ahrs"] and self.addr["gyro_ahrs"] else 0) | (
            (_READ_Q if self.addr["ahrs"] is not None else 0) | (_READ_EULER if self.addr["euler_ahrs"] else 0)
        )
        q = self._floats(board, "ahrs", 4)
        euler = self._floats(board, "euler_ahrs", 3)
        self._rows.append((self.count, board.now / C.CPU_HZ, acc, gyro, thr, q, euler, read))
        self.count += 1
        self._inputs = None

    def take(self) -> np.ndarray:
        """The rows read since the last call (``SYMBOL_DTYPE``)."""
        rows = np.array(self._rows, dtype=SYMBOL_DTYPE) if self._rows else np.zeros(0, SYMBOL_DTYPE)
        self._rows = []
        return rows

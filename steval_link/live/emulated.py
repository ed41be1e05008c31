"""The emulated board as a live session's source (``steval emulate``): its USART1 bytes through the live path a
real port uses, each round one slice of the board (or :data:`ROUND_S` of them).

The capture's receive times are emulated times (s since power-up), so a replay of it sees the drone's own timing.
A BROAD trial's ground truth goes into the capture as ``T`` chunks per AHRS step, the attitude the emulator reads
by symbol as ``S`` chunks. Commands (scripted at emulated times, or typed) reach the firmware's RX.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from steval_link import constants as C
from steval_link.emulation.broad import StepTruth
from steval_link.emulation.runner import Emulation, EmulationOptions
from steval_link.emulation.symbol_attitude import SymbolAttitude, elf_filter_variant
from steval_link.link.commands import Command
from steval_link.live.sources import Chunk, LinkInfo, LinkStatus, Record, Source

__all__ = ["EmulatedSource"]

#: emulated seconds of slices per round when not paced to the wall clock (fewer, larger rounds)
ROUND_S = 0.5


class EmulatedSource(Source):
    """``emulation``: the board and its motion. ``commands``: (emulated s, command) the session sends to the
    firmware's USART1 RX at those times."""

    def __init__(
        self,
        emulation: EmulationOptions,
        *,
        realtime: bool = False,
        commands: list[tuple[float, Command]] | None = None,
        variant: str | None = None,
        variant_from: str = "variant setting",
    ) -> None:
        self.emu_options = emulation
        #: the release whose filter the replica runs (named by ``variant_from``; else the ELF's code: see open)
        self._filter = {"variant": variant, "from": variant_from} if variant is not None else None
        self.realtime = realtime
        self.commands = list(commands or [])
        self.emu: Emulation | None = None
        self.truth: StepTruth | None = None
        self.status = LinkStatus()
        self._closed = False
        self._board: threading.Thread | None = None  # runs the board a round ahead (_run_board)
        self._failed = False  # the board's run ended with an exception
        self._record: Record | None = None
        self.symbols: SymbolAttitude | None = None  # what the emulator reads by symbol each step: chunks S

    @classmethod
    def from_url(cls, url: str, *, emulation: EmulationOptions, **settings: Any) -> EmulatedSource:
        """``emulated:`` or ``emulated:ELF`` (then the board runs that ELF)."""
        elf = url.split(":", 1)[1].strip() if ":" in url else ""
        if elf and isinstance(emulation, EmulationOptions):
            emulation = replace(emulation, elf=Path(elf))
        return cls(emulation, **settings)

    def open(self, note=None) -> None:
        self.emu = Emulation(self.emu_options)  # bad ELF / scenario: one line before any file is made
        self.status.duration_s = self.emu.duration_s
        self.symbols = SymbolAttitude(self.emu)  # observers set before the first step
        if self._filter is None:
            found, why = elf_filter_variant(self.emu.elf)
            if found is not None:
                self._filter = {"variant": found, "from": "firmware ELF", "why": why}

    def describe(self) -> LinkInfo:
        emu = self.emu
        extra = {
            "source": "steval emulate",
            "emulated": True,
            "command": self.emu_options.command(),
            "elf": str(emu.elf.path),
            "scenario": emu.motion.name,
            "seed": self.emu_options.seed,
            "duration_s": emu.duration_s,
        }
        if emu.motion.trial is not None:
            extra["truth"] = (
                f"BROAD trial {emu.motion.name}: chunks T hold its ground truth per AHRS step (the "
                "middle tick of the step's input window, emulated time)"
            )
        if self._filter is not None:  # the release whose filter the replica runs
            extra["filter"] = self._filter
        if self.symbols.available:
            extra["symbols"] = (
                "chunks S hold each AHRS step's inputs and outputs as the emulator read them from the firmware's "
                "globals by symbol (acc_ahrs, gyro_ahrs, gTHR, ahrs, euler_ahrs), not frames the firmware sent"
            )
        if self.commands:
            extra["commands"] = [[t, c.describe()] for t, c in self.commands]
        return LinkInfo(
            f"emulated:{emu.elf.path.name}",
            C.BAUD,
            extra,
            discard_empty=False,
            kind="emulated",
            note=f"emulating {emu.elf.path.name} ({emu.motion.name}, {emu.duration_s:g} s)",
            own_clock=True,
            commands=list(self.commands),
        )

    def chunks(self, record: Record, clock) -> Iterator[list[Chunk]]:
        self.truth = StepTruth(self.emu) if self.emu.motion.trial is not None else None  # the truth it is fed
        self._record = record
        return self._rounds(record)

    def _rounds(self, record: Record) -> Iterator[list[Chunk]]:
        """The board's rounds, made by :meth:`_run_board` one round ahead in a thread (the session's work on a round
        overlaps the next round's emulation): each round's chunks to the capture first, in the order the board made
        them, then its USART1 and RX bytes to the session."""
        if self._closed:
            return
        rounds: queue.Queue = queue.Queue(maxsize=1)
        self._board = threading.Thread(target=self._run_board, args=(rounds,), name="emulated board", daemon=True)
        self._board.start()
        while (item := rounds.get()) is not None:
            if isinstance(item, BaseException):
                raise item
            kept, sent, t_s = item
            for c in kept:
                record(c)  # first: whatever happens next, the bytes are kept
            self.status.t_link_s = t_s
            if sent:
                yield sent
            if self._closed:
                break

    def _run_board(self, rounds: queue.Queue) -> None:
        """Slices of the board, a round at a time into ``rounds`` (one slice when paced, else :data:`ROUND_S`
        emulated): (chunks for the capture: RX bytes, USART1 bytes, the truth and symbols of its steps; chunks for
        the session; emulated s), then None at the end, or the exception that ended the run."""
        t0, t_round, t_s = time.monotonic(), 0.0, 0.0
        kept: list[Chunk] = []
        sent: list[Chunk] = []
        try:
            for data, t_s in self.emu.chunks():
                out = [Chunk("H", b, t_b) for b, t_b in self.emu.take_host_bytes()]
                out.append(Chunk("D", data, t_s))
                kept += out + self._truth(t_s)
                sent += out
                if self.realtime:
                    time.sleep(max(0.0, t_s - (time.monotonic() - t0)))
                elif t_s - t_round < ROUND_S:
                    continue
                t_round = t_s
                if not self._put(rounds, (kept, sent, t_s)):
                    return
                kept, sent = [], []
            self.status.report = self.emu.report()
            if self._put(rounds, (kept, sent, t_s)) and self._put(rounds, (self._truth(t_s), [], t_s)):
                self._put(rounds, None)
        except BaseException as exc:  # to the session's thread, after the chunks made before it (truth: close)
            self._failed = True
            if self._put(rounds, (kept, [], t_s)):
                self._put(rounds, exc)

    def _put(self, rounds: queue.Queue, item) -> bool:
        """``item`` into ``rounds`` when the session takes it; False when the source was closed first."""
        while not self._closed:
            with contextlib.suppress(queue.Full):
                rounds.put(item, timeout=0.1)
                return True
        return False

    def _truth(self, t_s: float) -> list[Chunk]:
        """The ``T`` (a trial's truth) and ``S`` (attitude read by symbol) chunks of the steps since the last call."""
        rows = self.truth.take() if self.truth is not None else ()
        out = [Chunk("T", rows, t_s)] if len(rows) else []
        symbols = self.symbols.available
        read = self.symbols.take() if symbols else ()
        out += [Chunk("S", read[i : i + 4096].tobytes(), t_s) for i in range(0, len(read), 4096)]
        self.status.symbol_rows = self.symbols.count if symbols else 0
        return out

    def write(self, frame: bytes, at_s: float | None = None) -> None:
        """Onto the firmware's RX: at emulated time ``at_s``, or with the next slice (thread-safe)."""
        if at_s is None:
            self.emu.send(frame)
        else:
            self.emu.send_at(frame, at_s)

    def close(self) -> None:
        """Stop the board after its slice (a round it made that the session did not take is not recorded)."""
        self._closed = True
        if self._board is not None:
            self._board.join()
        if self._failed:  # the truth of the steps of the slice that failed
            with contextlib.suppress(Exception):  # (the capture is closed by the session whatever happens)
                for c in self._truth(self.status.t_link_s):
                    self._record(c)
        if self.emu is not None and self.status.report is None:
            self.status.report = self.emu.report()

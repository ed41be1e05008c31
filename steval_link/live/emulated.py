"""The emulated board as a live session's source (``steval emulate``): its USART1 bytes, timed in emulated s since
power-up; a BROAD trial's truth as ``T`` chunks, the attitude read by symbol as ``S`` chunks. Commands (scripted at
emulated times, or typed) reach the firmware's RX.

Unpaced, the board runs in its own thread from :meth:`EmulatedSource.open` on, a bounded queue ahead of the session:
the C core runs without the interpreter lock, so the session starts, and its pipeline works on one round, while the
board runs the next. It waits before the first scripted command's time until the session has sent the script. Paced
to the wall clock (``realtime``), it runs in the session's thread, so that a typed command reaches it at the time
shown.
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
from steval_link.link.capture import SYMBOL_DTYPE
from steval_link.link.commands import Command
from steval_link.live.sources import Chunk, LinkInfo, LinkStatus, Record, Source

__all__ = ["EmulatedSource"]

#: emulated seconds of slices per round when not paced to the wall clock (fewer, larger rounds)
ROUND_S = 0.5
#: slices the board's thread may run ahead of the session (0.05 emulated s each)
AHEAD_SLICES = 64


class EmulatedSource(Source):
    """``emulation``: the board and its motion; ``commands``: (emulated s, command) sent to the firmware's RX then."""

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
        self.truth = self._record = None  # the trial's truth (set by open()) and the capture (by chunks())
        self.symbols: SymbolAttitude | None = None  # what the emulator reads by symbol each step: chunks S
        self.status = LinkStatus()
        self._closed = False
        self._stop = threading.Event()  # the board's thread: stop after this slice
        self._board: threading.Thread | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=AHEAD_SLICES)
        self._held: list[Chunk] = []  # recorded after close() stopped the board, not yet handed to the session
        self._held_error: BaseException | None = None  # the board's error that close() found in the queue
        self._abandoned = False  # close() stopped draining the queue
        self._script_sent = threading.Event()  # the session sent the scripted commands: the board may pass them

    @classmethod
    def from_url(cls, url: str, *, emulation: EmulationOptions, **settings: Any) -> EmulatedSource:
        """``emulated:`` or ``emulated:ELF`` (then the board runs that ELF)."""
        elf = url.split(":", 1)[1].strip() if ":" in url else ""
        if elf and isinstance(emulation, EmulationOptions):
            emulation = replace(emulation, elf=Path(elf))
        return cls(emulation, **settings)

    def open(self, note=None) -> None:
        """The board (a bad ELF or scenario: one line before any file is made); unpaced, it starts running."""
        if self.emu is not None:
            return
        self.emu = Emulation(self.emu_options)
        self.status.duration_s = self.emu.duration_s
        self.symbols = SymbolAttitude(self.emu)  # observers set before the first step
        self.truth = StepTruth(self.emu) if self.emu.motion.trial is not None else None  # the truth it is fed
        if self._filter is None:
            found, why = elf_filter_variant(self.emu.elf)
            if found is not None:
                self._filter = {"variant": found, "from": "firmware ELF", "why": why}
        if not self.realtime:
            if self.commands:  # (sent by the session, numbered by its prompt's channel)
                self.emu.hold(min(t for t, _ in self.commands), self._script_sent)
            self._board = threading.Thread(target=self._run_board, name="steval-board", daemon=True)
            self.status.started_s = time.monotonic()
            self._board.start()

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
        self._record = record
        return self._rounds(record)

    def _rounds(self, record: Record) -> Iterator[list[Chunk]]:
        """Slice by slice, each chunk to the capture first; to the session each slice when paced, else each ROUND_S."""
        t0, t_round = time.monotonic(), 0.0
        pending: list[Chunk] = []
        if self._closed:
            return
        for chunks in self._slices() if self.realtime else self._slices_ahead():
            pending += self._take(chunks)
            t_s = self.status.t_link_s
            if self.realtime:
                time.sleep(max(0.0, t_s - (time.monotonic() - t0)))
            elif t_s - t_round < ROUND_S:
                continue
            t_round = t_s
            yield pending
            pending = []
            if self._closed:
                break
        if pending:
            yield pending
        if self._held:
            yield self._held
            self._held = []
        if self._held_error is not None:
            raise self._held_error

    def _slices(self) -> Iterator[list[Chunk]]:
        """Each slice's chunks (H, D, then the steps' T and S); at the end an ``end`` chunk with the report."""
        t_s = 0.0
        try:
            for data, t_s in self.emu.chunks(stop=self._stop):
                out = [Chunk("H", sent, t_sent_s) for sent, t_sent_s in self.emu.take_host_bytes()]
                yield [*out, Chunk("D", data, t_s), *self._steps(t_s)]
        except Exception:  # the steps before it, then the error
            yield self._steps(t_s)
            raise
        yield [*self._steps(t_s), Chunk("end", self.emu.report(), t_s)]

    def _slices_ahead(self) -> Iterator[list[Chunk]]:
        """:meth:`_slices` from the board's own thread (the session sent its script before the first round)."""
        self._script_sent.set()
        while (item := self._queue.get()) is not None:
            if isinstance(item, BaseException):
                raise item
            yield item

    def _run_board(self) -> None:
        """The board's thread: every slice into the queue, then None (or the error). A session that stopped
        reading drains the queue in close()."""
        try:
            for chunks in self._slices():
                self._put(chunks)
        except BaseException as exc:  # noqa: BLE001 - raised in the session's thread
            self._put(exc)
            return
        self._put(None)

    def _put(self, item) -> None:
        """Into the queue, unless close() gave up draining it (a second Ctrl-C)."""
        while not self._abandoned:
            with contextlib.suppress(queue.Full):
                self._queue.put(item, timeout=0.1)
                return

    def _steps(self, t_s: float | None) -> list[Chunk]:
        """The truth rows (T) and the symbol rows (S) of the steps since the last call."""
        out = []
        rows = self.truth.take() if self.truth is not None else ()
        if len(rows):
            out.append(Chunk("T", rows, t_s))
        if self.symbols.available:
            read = self.symbols.take()
            out += [Chunk("S", read[i : i + 4096].tobytes(), t_s) for i in range(0, len(read), 4096)]
        return out

    def _take(self, chunks: list[Chunk]) -> list[Chunk]:
        """Each chunk to the capture first (whatever happens next, it is kept); those for the session."""
        out = []
        for c in chunks:
            if c.kind == "end":
                self.status.report = c.data
                continue
            self._record(c)
            if c.kind in ("H", "D"):
                out.append(c)
            if c.kind == "D":
                self.status.t_link_s = c.t_s
            elif c.kind == "S":
                self.status.symbol_rows += len(c.data) // SYMBOL_DTYPE.itemsize
        return out

    def write(self, frame: bytes, at_s: float | None = None) -> None:
        """Onto the firmware's RX with the board's next slice: at emulated time ``at_s``, or then (thread-safe)."""
        self.emu.send(frame, at_s)

    def close(self) -> None:
        """Stop the board after its slice; what it made until then goes to the capture (and to the session, if it
        reads on)."""
        self._closed = True
        self._stop.set()
        self._script_sent.set()  # (a board that waits for the script stops)
        try:
            while self._board is not None and (self._board.is_alive() or not self._queue.empty()):
                try:
                    item = self._queue.get(timeout=0.1)
                except queue.Empty:
                    continue
                if isinstance(item, BaseException):
                    self._held_error = item
                elif item is not None:
                    with contextlib.suppress(Exception):  # (the session says why the capture failed)
                        self._held += self._take(item)
            if self._record is not None and self._board is None:
                with contextlib.suppress(Exception):
                    self._take(self._steps(self.status.t_link_s))  # the steps of the last slice, paced
        finally:
            self._abandoned = True
        if self.emu is not None and self.status.report is None:
            self.status.report = self.emu.report()

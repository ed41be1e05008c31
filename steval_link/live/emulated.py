"""The emulated board as a live session's source (``steval emulate``): its USART1 bytes, timed in emulated s since
power-up; a BROAD trial's truth as ``T`` chunks, the attitude read by symbol as ``S`` chunks. Commands (scripted at
emulated times, or typed) reach the firmware's RX."""

from __future__ import annotations

import contextlib
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
        self.truth = self._record = None  # the trial's truth and the capture, once chunks() starts
        self.symbols: SymbolAttitude | None = None  # what the emulator reads by symbol each step: chunks S
        self.status = LinkStatus()
        self._closed = False

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
        """Slice by slice, each chunk to the capture first; to the session each slice when paced, else each ROUND_S."""
        t0, t_round = time.monotonic(), 0.0
        pending: list[Chunk] = []
        if self._closed:
            return
        for data, t_s in self.emu.chunks():
            out = [Chunk("H", sent, t_sent_s) for sent, t_sent_s in self.emu.take_host_bytes()]
            out.append(Chunk("D", data, t_s))
            for c in out:
                record(c)  # first: whatever happens next, the bytes are kept
            self.status.t_link_s = t_s
            self._truth(record)
            pending += out
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
        self._truth(record)  # the steps of the last slice
        self.status.report = self.emu.report()

    def _truth(self, record: Record) -> None:
        rows = self.truth.take() if self.truth is not None else ()
        if len(rows):
            record(Chunk("T", rows, self.status.t_link_s))
        symbols = self.symbols.available
        read = self.symbols.take() if symbols else ()
        for i in range(0, len(read), 4096):
            record(Chunk("S", read[i : i + 4096].tobytes(), self.status.t_link_s))
        self.status.symbol_rows = self.symbols.count if symbols else 0

    def write(self, frame: bytes, at_s: float | None = None) -> None:
        """Onto the firmware's RX: at emulated time ``at_s``, or with the next slice (thread-safe)."""
        if at_s is None:
            self.emu.send(frame)
        else:
            self.emu.send_at(frame, at_s)

    def close(self) -> None:
        self._closed = True
        with contextlib.suppress(Exception):  # the capture is closed by the session whatever happens
            if self._record is not None:
                self._truth(self._record)  # the steps of the last slice, whatever stopped the session
        if self.emu is not None and self.status.report is None:
            self.status.report = self.emu.report()

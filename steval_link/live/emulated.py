"""The emulated board as a live session's source (``steval emulate``): its USART1 bytes through the live path a
real port uses.

Flow (one way, the same objects as ``steval live``)::

    Emulation.chunks() ──► capture.write  [first]  ──► LivePipeline.feed (decoder → estimators → viewer)

Each round of the session runs the board for one slice. The capture's receive times are emulated times (s since
power-up), so a replay or ``steval compare`` of the capture sees the drone's own timing; the live view runs as fast
as the emulator (``realtime=True`` paces it to the wall clock). A BROAD trial's ground truth goes into the capture
as ``T`` chunks, per AHRS step; the attitude the emulator reads by symbol each step (``emulation/symbol_attitude.py``)
as ``S`` chunks. Commands (``--commands`` at emulated times, or typed) reach the firmware's RX.
"""

from __future__ import annotations

import shlex
import time
from typing import Any

from steval_link import constants as C
from steval_link.emulation.runner import Emulation, EmulationOptions
from steval_link.emulation.step_truth import StepTruth
from steval_link.emulation.symbol_attitude import SymbolAttitude, elf_filter_variant
from steval_link.errors import UserError
from steval_link.link.capture import CHUNK_SYMBOLS
from steval_link.link.commands import Command
from steval_link.live.health import pipeline_health
from steval_link.live.pipeline import LivePipeline
from steval_link.live.sources import CaptureFields, Source
from steval_link.live.summary import pipeline_counts

__all__ = ["EmulatedSource"]


class EmulatedSource(Source):
    """``emulation``: the board and its motion. ``commands``: (emulated s, command) sent to the firmware's USART1
    RX at those times (``--commands``, read from ``commands_file``, which the capture header's command names)."""

    kind = "emulated"

    def __init__(
        self,
        emulation: EmulationOptions,
        *,
        realtime: bool = False,
        commands: list[tuple[float, Command]] | None = None,
        commands_file: str | None = None,
        variant: str | None = None,
        variant_from: str = "variant setting",
    ) -> None:
        self.emu_options = emulation
        self.variant = variant  # the release's filter the replica runs (named by variant_from; else the ELF's code)
        self.variant_from = variant_from
        self.realtime = realtime
        self.commands = list(commands or [])
        self.commands_file = commands_file
        self.emu: Emulation | None = None
        self.pipeline: LivePipeline | None = None
        self.truth: StepTruth | None = None
        self.symbols: SymbolAttitude | None = None
        self.t_emu_s = 0.0  # emulated time of the last chunk: the stop event is stamped with it, as the frames are

    def open(self, session) -> None:
        self.session = session
        self.emu = Emulation(self.emu_options)  # bad ELF / scenario: one line before any file is made

    def describe(self) -> str:
        emu = self.emu
        return f"emulating {emu.elf.path.name} ({emu.motion.name}, {emu.duration_s:g} s)"

    def capture_fields(self) -> CaptureFields:
        emu = self.emu
        extra = {
            "source": "steval emulate",
            "emulated": True,
            "command": self.emu_options.command(emu.duration_s),
            "elf": str(emu.elf.path),
            "scenario": emu.motion.name,
            "seed": self.emu_options.seed,
            "duration_s": emu.duration_s,
        }
        self.truth = StepTruth(emu) if emu.motion.trial is not None else None  # the truth it is fed: chunks T
        if self.truth is not None:
            extra["truth"] = (
                f"BROAD trial {emu.motion.name}: chunks T hold its ground truth per AHRS step (the "
                "middle tick of the step's input window, emulated time)"
            )
        self.symbols = SymbolAttitude(emu)  # what the emulator reads by symbol each step: chunks S
        if self.variant is not None:
            extra["filter"] = {"variant": self.variant, "from": self.variant_from}
        else:
            found, why = elf_filter_variant(emu.elf)
            if found is not None:
                self.variant, self.variant_from = found, "firmware ELF"
                extra["filter"] = {"variant": found, "from": "firmware ELF", "why": why}
        if self.symbols.available:
            extra["symbols"] = (
                "chunks S hold each AHRS step's inputs and outputs as the emulator read them from the firmware's "
                "globals by symbol (acc_ahrs, gyro_ahrs, gTHR, ahrs, euler_ahrs), not frames the firmware sent"
            )
        if self.commands:
            extra["commands"] = [[t, c.describe()] for t, c in self.commands]
            if self.commands_file:
                extra["command"] += " " + shlex.join(["--commands", str(self.commands_file)])
        return CaptureFields(f"emulated:{emu.elf.path.name}", C.BAUD, extra, discard_empty=False)

    def attach(self, session) -> None:
        self.pipeline = LivePipeline.for_session(session)
        if self.pipeline.mahony is not None and self.variant is not None:
            self.pipeline.mahony.follower.force_variant(self.variant)
        self._wall0 = session.clock.wall0_s
        self._t0 = time.monotonic()
        self._chunks = self.emu.chunks()
        self._scheduled = False

    def round(self) -> bool:
        emu, pipe, session, capture = self.emu, self.pipeline, self.session, self.session.capture
        if not self._scheduled:  # the script, once the prompt's channel is there to number its frames
            for t_s, command in self.commands:
                emu.send_at(session.console.channel.next_frame(command).frame, t_s)
            self._scheduled = True
        got = next(self._chunks, None)
        if got is None:
            return False
        data, self.t_emu_s = got
        wall0 = self._wall0
        for sent, t_sent_s in emu.take_host_bytes():  # what went on the RX line in this slice
            capture.write_host(sent, t_sent_s)
            pipe.feed_host(sent, wall0 + t_sent_s)
        capture.write(data, self.t_emu_s)  # first: whatever happens next, the bytes are kept
        self._write_truth()
        pipe.feed([(data, wall0 + self.t_emu_s)])
        session.console.poll(pipe.notes)
        if session.viewer is not None:
            session.viewer.log_link(pipe.decoder.stats, wall0 + self.t_emu_s)
        for _ in range(len(pipe.texts)):
            session.display.note("firmware: " + pipe.texts.popleft()[:200])
        if self.realtime:
            ahead = self.t_emu_s - (time.monotonic() - self._t0)
            if ahead > 0:
                time.sleep(ahead)
        return True

    def write(self, frame: bytes) -> None:
        self.emu.send(frame)  # queued for the next slice (thread-safe)

    def _write_truth(self) -> None:
        rows = self.truth.take() if self.truth is not None else ()
        if len(rows):
            self.session.capture.write_truth(rows.step, rows.t_s, rows.q_wxyz, rows.movement, self.t_emu_s)
        read = self.symbols.take() if self.symbols is not None and self.symbols.available else ()
        for i in range(0, len(read), 4096):
            self.session.capture.write_chunk(CHUNK_SYMBOLS, read[i : i + 4096].tobytes(), self.t_emu_s)

    def finish(self, error: BaseException | None) -> None:
        try:
            self._write_truth()  # the steps of the last slice
        except Exception:  # noqa: BLE001 - the capture is closed by the session whatever happens
            pass
        try:
            if self.pipeline is not None:
                self.pipeline.flush_view()
        except Exception:  # noqa: BLE001
            pass

    def t_stop_s(self) -> float | None:
        return self.t_emu_s

    def error_of(self, error: BaseException) -> BaseException:
        if isinstance(error, UserError):
            return UserError(f"{error} (the capture {self.session.capture.path} holds everything until then)")
        return error

    def health(self, now_mono_s: float) -> str:
        wall_s = now_mono_s - self._t0
        speed = self.t_emu_s / wall_s if wall_s > 0 else 0.0
        head = f"emulated {self.t_emu_s:6.2f}/{self.emu.duration_s:g} s ({speed:.2f}x)"
        return pipeline_health(head, self.pipeline)

    def summary_fields(self) -> dict[str, Any]:
        pipe = self.pipeline
        port = pipe.mahony.describe() if pipe is not None and pipe.mahony is not None else None
        if port and self.variant is not None:
            port = f"{port} with {self.variant}'s filter"
        read = self.symbols.count if self.symbols is not None and self.symbols.available else 0
        if read:
            what = f"the emulator read the attitude of {read} AHRS steps by symbol (chunks S"
            frames = pipeline_counts(pipe).get("attitude") if pipe is not None else 0
            port = f"{port}; {what})" if port and frames else f"{what}: steval compare shows them)"
            if not frames and self.variant is not None:
                port += f"; {self.variant}'s filter (from the {self.variant_from})"
        return {**pipeline_counts(pipe), "report": self.emu.report(), "filter_note": port}

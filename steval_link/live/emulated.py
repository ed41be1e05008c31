"""``steval emulate``: the emulated board's USART1 bytes through the live path a real port uses.

Flow (one way, the same objects as ``steval live``)::

    Emulation.chunks() ──► CaptureWriter.write  [first]  ──► LivePipeline.feed (decoder → estimators → viewer)

The capture's receive times are emulated times (s since power-up), so a replay or ``steval compare`` of the capture
sees the drone's own timing; the live view runs as fast as the emulator (``realtime=True`` paces it to the wall
clock). Ctrl-C stops cleanly: the capture keeps every byte emulated so far.
"""

from __future__ import annotations

import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, TextIO

from steval_link.emulation.runner import Emulation, EmulationOptions, EmulationReport
from steval_link.emulation.step_truth import StepTruth
from steval_link.errors import UserError
from steval_link.link.capture import CaptureWriter, default_capture_path
from steval_link.link.commands import Command
from steval_link.link.plausibility import held_back_sentence
from steval_link.live.console import PROMPT_HELP, CommandConsole
from steval_link.live.health import HealthDisplay
from steval_link.live.pipeline import LivePipeline, LiveViewer
from steval_link.live.session import (
    LiveOptions,
    _stdin_is_tty,
    close_outputs,
    install_stop_signals,
    restore_signals,
)


@dataclass
class EmulateSummary:
    capture_path: Path
    rrd_path: Path | None
    wall_s: float
    report: EmulationReport
    attitude: int
    status: int
    text: int
    crc_failures: int
    frames_missing: int
    port_note: str | None
    stopped_by: str
    values_sentence: str | None = None  # the frames kept with NaN or out-of-range values, in words
    held_back: str | None = None  # CRC-valid frames the decoder held back, in words

    def lines(self) -> list[str]:
        r = self.report
        speed = r.emulated_s / self.wall_s if self.wall_s > 0 else float("nan")
        head = (
            f"emulated {r.emulated_s:.2f} s in {self.wall_s:.2f} s wall ({speed:.2f}x real time): "
            f"{self.attitude} attitude, {self.status} status, {self.text} text frames, "
            f"{self.frames_missing} missing, {self.crc_failures} CRC failures"
            + (f"; {self.port_note}" if self.port_note else "")
            + (f" (stopped: {self.stopped_by})" if self.stopped_by != "end" else "")
        )
        out = [head] + [x for x in (self.values_sentence, self.held_back) if x] + r.lines()[1:]
        tail = f"capture {self.capture_path}"
        if self.rrd_path:
            tail += f", rerun {self.rrd_path}"
        out.append(tail)
        return out


class EmulateSession:
    """One ``steval emulate`` run."""

    def __init__(
        self,
        emu_options: EmulationOptions,
        live: LiveOptions,
        *,
        realtime: bool = False,
        stream: TextIO | None = None,
        tty: bool | None = None,
        viewer_factory: Callable[[LiveOptions, str], LiveViewer] | None = None,
        commands: list[tuple[float, Command]] | None = None,
        commands_file: str | None = None,
        check_outputs: Callable[[], None] | None = None,
    ) -> None:
        """``viewer_factory``: as :class:`~steval_link.live.session.LiveSession`'s (required when ``live`` uses
        Rerun; the caller checks the sinks first). ``commands``: (emulated s, command) sent to the firmware's
        USART1 RX at those times (``--commands``, read from ``commands_file``, which the capture header's command
        names); typed commands go out at the next slice. ``check_outputs``: the CLI's checks of the outputs, run
        once the ELF is read (the input first) and before any file is made."""
        if live.uses_rerun and viewer_factory is None:
            raise ValueError("a session that uses Rerun (a view or --rrd) needs a viewer_factory")
        self.viewer_factory = viewer_factory
        self.emu_options = emu_options
        self.live = live
        self.realtime = realtime
        self.display = HealthDisplay(stream or sys.stderr, tty=tty)
        self._stop: str | None = None
        self.commands = list(commands or [])
        self.commands_file = commands_file
        self.check_outputs = check_outputs

    def request_stop(self, reason: str = "stopped") -> None:
        if self._stop is None:
            self._stop = reason

    @property
    def stop_requested(self) -> bool:
        return self._stop is not None

    def run(self) -> EmulateSummary:
        opts = self.live
        emu = Emulation(self.emu_options)  # bad ELF / scenario: one line before any file is made
        if self.check_outputs is not None:
            self.check_outputs()
        capture_path = Path(opts.out) if opts.out else default_capture_path(opts.recordings_dir)
        extra = {
            "source": "steval emulate",
            "emulated": True,
            "command": self.emu_options.command(emu.duration_s),
            "elf": str(emu.elf.path),
            "scenario": emu.motion.name,
            "seed": self.emu_options.seed,
            "duration_s": emu.duration_s,
            "estimators": list(opts.estimators),
        }
        truth = StepTruth(emu) if emu.motion.trial is not None else None  # the truth it is fed: chunks T
        if truth is not None:
            extra["truth"] = (
                f"BROAD trial {emu.motion.name}: chunks T hold its ground truth per AHRS step (the "
                "middle tick of the step's input window, emulated time)"
            )
        if self.commands:
            extra["commands"] = [[t, c.describe()] for t, c in self.commands]
            if self.commands_file:
                extra["command"] += " " + shlex.join(["--commands", str(self.commands_file)])
        try:
            capture_path.parent.mkdir(parents=True, exist_ok=True)
            capture = CaptureWriter(capture_path, port=f"emulated:{emu.elf.path.name}", baud=opts.baud, extra=extra)
        except FileExistsError:
            raise UserError(f"{capture_path} already exists; choose another --out (captures are never overwritten)")
        except OSError as exc:
            raise UserError(f"cannot write the capture {capture_path}: {exc.strerror or exc}") from None
        wall0 = capture.header["start_time_unix_s"]
        viewer = None
        error: BaseException | None = None
        old = self._install_signals()
        t0 = time.monotonic()
        pipe = None
        t_emu_s = 0.0  # emulated time of the last chunk: the stop event is stamped with it, as the frames are
        last_t_s = 0.0
        try:
            self.display.note(
                f"emulating {emu.elf.path.name} ({emu.motion.name}, {emu.duration_s:g} s); recording "
                f"to {capture_path}" + (f" and {opts.rrd}" if opts.rrd else "") + " (Ctrl-C to stop)"
            )
            if opts.uses_rerun:
                viewer = self.viewer_factory(opts, capture_path.stem)
            pipe = LivePipeline.for_viewer(opts.estimators, viewer, t0_unix_s=wall0, baud=capture.header["baud"])
            prompt = opts.prompt if opts.prompt is not None else _stdin_is_tty()
            console = self.console = CommandConsole(emu.send, self.display.note, enabled=prompt)
            if prompt:
                self.display.note(PROMPT_HELP)
            for t_s, command in self.commands:
                emu.send_at(console.channel.next_frame(command).frame, t_s)
            for data, t_emu_s in emu.chunks():
                for sent, t_sent_s in emu.take_host_bytes():  # what went on the RX line in this slice
                    capture.write_host(sent, t_sent_s)
                    pipe.feed_host(sent, wall0 + t_sent_s)
                capture.write(data, t_emu_s)  # first: whatever happens next, the bytes are kept
                last_t_s = t_emu_s
                if truth is not None:
                    self._write_truth(capture, truth, t_emu_s)
                pipe.feed([(data, wall0 + t_emu_s)])
                console.poll(pipe.notes)
                if viewer is not None:
                    viewer.log_link(pipe.decoder.stats, wall0 + t_emu_s)
                now = time.monotonic()
                for _ in range(len(pipe.texts)):
                    self.display.note("firmware: " + pipe.texts.popleft()[:200])
                self.display.show(
                    console.decorate(self._health(emu, pipe, t_emu_s, now - t0)),
                    now,
                    force=console.take_typing_change(),
                )
                if self.realtime:
                    ahead = t_emu_s - (time.monotonic() - t0)
                    if ahead > 0:
                        time.sleep(ahead)
                if self._stop is not None:
                    break
        except KeyboardInterrupt:
            self.request_stop("interrupted")
        except BaseException as exc:  # noqa: BLE001 - close the files first, then re-raise
            error = exc
        finally:
            try:
                if truth is not None:
                    self._write_truth(capture, truth, last_t_s)  # the steps of the last slice
            except Exception:  # noqa: BLE001 - the capture is closed below whatever happens
                pass
            try:
                if pipe is not None:
                    pipe.flush_view()
            except Exception:  # noqa: BLE001
                pass
            console = getattr(self, "console", None)
            if console is not None:
                console.close()
            close_outputs(
                capture,
                viewer,
                self.display,
                self._stop or (type(error).__name__ if error else "end"),
                t_stop_s=t_emu_s,
            )
            self._restore_signals(old)
        if error is not None:
            if isinstance(error, UserError):
                raise UserError(f"{error} (the capture {capture_path} holds everything until then)") from None
            raise error
        s = pipe.decoder.stats
        h = pipe.health
        port = pipe.mahony.describe() if pipe.mahony is not None else None
        held = held_back_sentence(s.implausible, s.held_values) if s.implausible else None
        return EmulateSummary(
            capture_path,
            opts.rrd,
            time.monotonic() - t0,
            emu.report(),
            h.attitude,
            h.status,
            h.text,
            s.crc_failures,
            s.frames_missing,
            port,
            self._stop or "end",
            h.values_sentence(),
            held,
        )

    @staticmethod
    def _write_truth(capture: CaptureWriter, truth: StepTruth, t_s: float | None) -> None:
        rows = truth.take()
        if len(rows):
            capture.write_truth(rows.step, rows.t_s, rows.q_wxyz, rows.movement, t_s)

    @staticmethod
    def _health(emu: Emulation, pipe: LivePipeline, t_emu_s: float, wall_s: float) -> str:
        s = pipe.decoder.stats
        speed = t_emu_s / wall_s if wall_s > 0 else 0.0
        parts = [
            f"emulated {t_emu_s:6.2f}/{emu.duration_s:g} s ({speed:.2f}x)",
            f"frames {pipe.health.attitude}",
            f"missing {s.frames_missing}",
            f"CRC {s.crc_failures}",
        ]
        if pipe.health.values_bad:
            parts.insert(2, pipe.health.values_sentence())
        if s.implausible:
            parts.append(f"held back {s.implausible}")
        if pipe.mahony is not None:
            parts.append(pipe.mahony.describe())
        return " | ".join(parts)

    def _install_signals(self):
        return install_stop_signals(self)

    @staticmethod
    def _restore_signals(old) -> None:
        restore_signals(old)

"""What a live session did (:class:`LiveSummary`), whatever its source, and the lines that say it: one line for a
serial port or a replay, the emulated board's lines (its report), one line for BLE."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from steval_link.analysis.step_cost import step_cost
from steval_link.errors import UserError
from steval_link.link.load import load_telemetry
from steval_link.link.plausibility import held_back_sentence
from steval_link.live.health import _fmt_bytes, _fmt_duration, stat

__all__ = ["LiveSummary", "pipeline_counts"]


@dataclass
class LiveSummary:
    """The summary of one session; ``kind`` says which source's fields are filled and how :meth:`lines` reads."""

    capture_path: Path
    rrd_path: Path | None
    seconds: float  # wall time of the session
    streaming_s: float = 0.0  # from the first to the last attitude frame, less the time disconnected
    bytes_total: int = 0
    attitude: int = 0
    status: int = 0
    text: int = 0
    frames_missing: int = 0
    crc_failures: int = 0
    bytes_skipped: int = 0
    nonfinite: int = 0
    disconnects: int = 0
    offline_s: float = 0.0
    live_dropped_bytes: int = 0
    filter_note: str | None = None  # what the ST filter's Python replica did (bit-exact, differs, not seeded)
    stopped_by: str = "end"
    capture_discarded: bool = False  # no byte came: the header-only file was removed
    implausible: int = 0  # CRC-valid frames the decoder's plausibility checks held back
    values_sentence: str | None = None  # the frames kept with NaN or out-of-range values, in words
    held_values: int = 0  # of ``implausible``: protocol v1 frames held back for their values
    kind: str = "serial"  # serial (a port or a replay), emulated, ble
    report: Any = None  # emulated: the board's EmulationReport
    counts: dict[str, int] = field(default_factory=dict)  # ble: notifications per characteristic
    rows_held: int = 0  # ble: estimator rows held over notifications sent and lost
    connections: int = 0
    cadence: Any = None  # ble: the motion cadence as the health line last said it
    failures: list[str] = field(default_factory=list)  # outputs that failed during the run (left out of the list)
    lost_for_good: bool = False  # the port was lost and did not come back before the end
    records_part: str | None = None  # "text telemetry: N records, series a, b, c" (None: no record)
    pace: float = 1.0  # a replay played X times faster (replay://FILE?speed=X): its rate is X times the drone's

    @property
    def losses(self) -> int:
        """Links lost (BLE's word for :attr:`disconnects`)."""
        return self.disconnects

    def lines(self) -> list[str]:
        if self.kind == "emulated":
            return self._emulated_lines()
        if self.kind == "ble":
            return [self._ble_line()]
        return [self._serial_line()]

    def line(self) -> str:
        return "\n".join(self.lines())

    def _held_back(self) -> str | None:
        return held_back_sentence(self.implausible, self.held_values) if self.implausible else None

    def _outputs(self) -> str:
        out = f"capture {self.capture_path}"
        if self.capture_discarded:
            out = "no byte received, so no capture file was kept"
        elif self.kind == "serial":
            out += f" ({_fmt_bytes(self.bytes_total)})"
        return out + (f", rerun {self.rrd_path}" if self.rrd_path else "")

    def _serial_line(self) -> str:
        rate = self.attitude / self.streaming_s if self.streaming_s > 0.5 else float("nan")
        parts = [
            f"{_fmt_duration(self.seconds)}",
            f"{self.attitude} attitude frames" + ("" if math.isnan(rate) else f" ({self._rate(rate)})"),
            f"{self.frames_missing} missing",
            f"{self.crc_failures} CRC failures",
            f"{_fmt_bytes(self.bytes_skipped)} skipped",
        ]
        if self.values_sentence:
            parts.append(self.values_sentence)
        elif self.nonfinite:
            parts.append(f"{self.nonfinite} with NaN/inf")
        if self.implausible:
            parts.append(self._held_back())
        if self.disconnects:
            lost = f"{self.disconnects} disconnect{'s' if self.disconnects > 1 else ''} ({self.offline_s:.1f} s"
            parts.append(lost + ("; the port did not come back)" if self.lost_for_good else ")"))
        if self.live_dropped_bytes:
            parts.append(f"{_fmt_bytes(self.live_dropped_bytes)} not shown live (in the capture)")
        if self.records_part:
            parts.append(self.records_part)
        if self.filter_note:
            parts.append(self.filter_note)
        return "recorded " + ", ".join(parts) + "; " + self._outputs()

    def _rate(self, rate_hz: float) -> str:
        """The frame rate as it arrived, and the drone's own when a replay ran faster."""
        if self.pace == 1.0:
            return f"{rate_hz:.1f} Hz"
        return f"{rate_hz:.1f} Hz at {self.pace:g}× pace: {rate_hz / self.pace:.1f} Hz in the drone's time"

    def _emulated_lines(self) -> list[str]:
        r = self.report
        speed = r.emulated_s / self.seconds if self.seconds > 0 else float("nan")
        head = (
            f"emulated {r.emulated_s:.2f} s in {self.seconds:.2f} s wall ({speed:.2f}x real time): "
            f"{self.attitude} attitude, {self.status} status, {self.text} text frames, "
            f"{self.frames_missing} missing, {self.crc_failures} CRC failures"
            + (f"; {self.filter_note}" if self.filter_note else "")
            + (f" (stopped: {self.stopped_by})" if self.stopped_by != "end" else "")
        )
        said = [x for x in (self.values_sentence, self._held_back()) if x]
        # the AHRS step cost as replay and compare say it (the capture's status frames), not the run's own counts
        board = [x for x in r.lines()[1:] if not x.startswith("instructions per AHRS step")]
        cost = self._step_cost()
        return [head, *said, *board, *([cost] if cost else []), self._outputs()]

    def _step_cost(self) -> str | None:
        if self.capture_discarded or not Path(self.capture_path).is_file():
            return None
        try:
            cost = step_cost(load_telemetry(self.capture_path))
        except (UserError, OSError):
            return None
        return None if cost is None else cost.sentence()

    def _ble_line(self) -> str:
        c = self.counts
        where = "no capture (nothing received)" if self.capture_discarded else f"capture {self.capture_path}"
        what = self.cadence.describe() if self.cadence is not None else "no motion cadence (too few samples)"
        return (
            f"steval: {self.seconds:.1f} s over BLE: {c.get('motion', 0)} motion, {c.get('environment', 0)} "
            f"environment, {c.get('arming', 0)} arming notifications; {what}; {self.connections} "
            f"connection(s), {self.losses} lost; stopped: {self.stopped_by}; {where}"
        )


def pipeline_counts(pipe) -> dict[str, Any]:
    """The summary's counters of a :class:`~steval_link.live.pipeline.LivePipeline` (None: a session that ended
    before it was made: zeros)."""
    if pipe is None:
        return {}
    s, h = pipe.decoder.stats, pipe.health
    names = ("frames_missing", "crc_failures", "bytes_skipped", "implausible", "held_values")
    return {
        **{name: stat(s, name) for name in names},
        **{name: getattr(h, name) for name in ("attitude", "status", "text", "nonfinite")},
        "values_sentence": h.values_sentence(),
        "records_part": h.records_part(),
    }

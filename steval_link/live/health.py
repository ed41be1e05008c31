"""A live session's counters (:class:`LinkHealth`), health line (:class:`HealthDisplay`) and :class:`LiveSummary`."""

from __future__ import annotations

import collections
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from steval_link.analysis.link_stats import step_cost
from steval_link.errors import UserError
from steval_link.link.load import load_telemetry
from steval_link.link.plausibility import held_back_sentence, values_bad_sentence

#: Health line refresh on a terminal / plain health lines otherwise, s.
HEALTH_TTY_INTERVAL_S = 0.25
HEALTH_PLAIN_INTERVAL_S = 5.0
#: Series names of text telemetry kept for the health line and the summary.
MAX_SERIES_NAMES = 64


@dataclass
class LinkHealth:
    """Counters and rates of the live link, for the health line and the summary (times: host s, Unix epoch)."""

    attitude: int = 0
    text: int = 0
    nonfinite: int = 0  # attitude frames with a non-finite value
    values_bad: int = 0  # attitude frames with NaN or out-of-range values (the ``values_bad`` flag)
    inputs_bad: bool = False  # some of those have bad filter inputs (acc, gyro) too
    first_bad_step: int | None = None  # AHRS step of the first of them
    first_bad_t_s: float | None = None  # its firmware time, s (t_us / 10⁶, mod 2³² µs)
    first_frame_s: float | None = None  # host receive time of the first attitude frame
    last_frame_s: float | None = None
    records: int = 0  # records of text telemetry
    series: dict[str, None] = field(default_factory=dict)  # their series names, in the order they came (bounded)
    _times: collections.deque = field(default_factory=lambda: collections.deque(maxlen=512))  # (t, frames so far)

    def count_record(self, names: tuple[str, ...]) -> None:
        self.records += 1
        if len(self.series) < MAX_SERIES_NAMES:
            self.series.update(dict.fromkeys(names))

    def records_part(self, most: int = 6) -> str | None:
        """'text telemetry: N records, series a, b, c' (at most ``most`` names); None without records."""
        if not self.records:
            return None
        names = list(self.series)
        more = f" and {len(names) - most} more" if len(names) > most else ""
        return f"text telemetry: {self.records} records, series {', '.join(names[:most])}{more}"

    def count(self, n_attitude: int, t_first_s: float, t_last_s: float) -> None:
        """``n_attitude`` (≥ 1) frames received between host times ``t_first_s`` and ``t_last_s``."""
        if self.first_frame_s is None:
            self.first_frame_s = t_first_s
        self.last_frame_s = t_last_s
        self.attitude += n_attitude
        self._times.append((t_last_s, self.attitude))

    def count_bad(self, bad, inputs_bad, step, t_us) -> bool:
        """Count the frames flagged ``bad`` (``inputs_bad``: bad acc/gyro); True if the session's first bad is here."""
        if not (k := int(np.count_nonzero(bad))):
            return False
        self.values_bad += k
        self.inputs_bad = self.inputs_bad or bool(np.any(inputs_bad & bad))
        if self.first_bad_step is not None:
            return False
        i = int(np.argmax(bad))
        self.first_bad_step, self.first_bad_t_s = int(step[i]), int(t_us[i]) / 1e6
        return True

    def values_sentence(self) -> str | None:
        """The sentence about the frames with bad values (None: none), as every summary says it."""
        if not self.values_bad:
            return None
        return values_bad_sentence(self.values_bad, self.first_bad_step, self.first_bad_t_s, inputs=self.inputs_bad)

    def rate_hz(self, now_s: float, window_s: float = 2.0) -> float:
        """Attitude frames per second received over the last ``window_s`` (NaN while too little is known)."""
        if self.last_frame_s is None or now_s - self.last_frame_s > 1.0:
            return 0.0
        recent = [(t, n) for t, n in self._times if now_s - t <= window_s]
        if len(recent) < 2 or recent[-1][0] - recent[0][0] < 0.2:
            return float("nan")
        return (recent[-1][1] - recent[0][1]) / (recent[-1][0] - recent[0][0])


def _fmt_bytes(n: float) -> str:
    for unit in ("B", "kB", "MB"):
        if n < 1000:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} GB"


def _fmt_duration(s: float) -> str:
    if s < 60:
        return f"{s:.1f} s"
    m, sec = divmod(int(round(s)), 60)
    h, m = divmod(m, 60)
    return f"{h}h{m:02d}m{sec:02d}s" if h else f"{m}m{sec:02d}s"


class HealthDisplay:
    """The health line on ``stream``: one line rewritten in place on a terminal, periodic plain lines otherwise."""

    def __init__(self, stream: TextIO, *, tty: bool | None = None) -> None:
        self.stream = stream
        self.tty = stream.isatty() if tty is None else tty
        self.interval_s = HEALTH_TTY_INTERVAL_S if self.tty else HEALTH_PLAIN_INTERVAL_S
        self._last, self._dirty = -math.inf, False  # the last health line's time; it is on the terminal

    def note(self, text: str) -> None:
        """A message on its own line (events: connected, disconnected...)."""
        self.close()
        self.stream.write(f"steval: {text}\n")
        self.stream.flush()

    def show(self, line: str, now_mono: float, *, force: bool = False) -> None:
        if not force and now_mono - self._last < self.interval_s:
            return
        self._last = now_mono
        if not self.tty:
            return self.note(line)
        width = max(20, shutil.get_terminal_size((160, 24)).columns - 1)  # a wrapped line cannot be redrawn
        self.stream.write("\r\x1b[2K" + line[:width])
        self._dirty = True
        self.stream.flush()

    def close(self) -> None:
        """Clear the health line on a terminal."""
        if self.tty and self._dirty:
            self.stream.write("\r\x1b[2K")
            self.stream.flush()
            self._dirty = False


def pipeline_health(head: str, pipe, serial=None) -> str:
    """A health line: ``head``, ``pipe``'s counts, the replica's state; a ``serial`` status adds bytes and losses."""
    s, h = pipe.decoder.stats, pipe.health
    parts = [head, f"frames {h.attitude}", h.values_sentence(), f"missing {s.frames_missing}", f"CRC {s.crc_failures}"]
    if serial is not None:
        parts.append(f"skipped {_fmt_bytes(s.bytes_skipped)}")
    parts.append(f"held back {s.implausible}" if s.implausible else None)
    if serial is not None:
        parts.append(f"disconnects {serial.disconnects}" if serial.disconnects else None)
        lag = serial.live_dropped_bytes
        parts.append(f"live lag: {_fmt_bytes(lag)} not shown" if lag else None)
    records = h.records_part(most=3)
    parts.append(records)
    if pipe.mahony is not None and (pipe.binary or not records):  # text alone has no bit-exact inputs
        parts.append(pipe.mahony.describe())
    if serial is not None:
        parts.append(f"rec {_fmt_bytes(serial.bytes_total)}")
    return " | ".join(p for p in parts if p)


def emulated_health(status, pipe, wall_s: float) -> str:
    """The health line of the emulated board: emulated time, its speed against the wall clock, the frames."""
    speed = status.t_link_s / wall_s if wall_s > 0 else 0.0
    return pipeline_health(f"emulated {status.t_link_s:6.2f}/{status.duration_s:g} s ({speed:.2f}x)", pipe)


def emulated_summary(status, pipe, flt: dict) -> dict:
    """The emulated board's summary: its report; a filter note of the replica, its release ``flt``, the symbol reads."""
    read = status.symbol_rows
    note = pipe.mahony.describe() if pipe is not None and pipe.mahony is not None else None
    if note and flt:
        note = f"{note} with {flt['variant']}'s filter"
    if read:
        what = f"the emulator read the attitude of {read} AHRS steps by symbol (chunks S"
        frames = pipeline_counts(pipe).get("attitude") if pipe is not None else 0
        note = f"{note}; {what})" if note and frames else f"{what}: steval compare shows them)"
        if not frames and flt:
            note += f"; {flt['variant']}'s filter (from the {flt['from']})"
    return {**pipeline_counts(pipe), "report": status.report, "filter_note": note}


def ble_health(pipe) -> str:
    """The health line of a BLE link: notifications per characteristic and the motion cadence ("": none yet)."""
    c = pipe.ble.counts if pipe is not None else {}
    if not any(c.values()):
        return ""
    cad = pipe.grid.cadence()
    what = cad.describe() if cad is not None else "finding the motion cadence"
    return (
        f"BLE {c.get('motion', 0)} motion / {c.get('environment', 0)} env / {c.get('arming', 0)} arming "
        f"notifications; {what}"
    )


def ble_summary(status, pipe) -> dict:
    """The summary fields of a BLE link."""
    link = {"connections": status.connections, "disconnects": status.disconnects}
    if pipe is None:
        return link
    return {**link, "counts": dict(pipe.ble.counts), "rows_held": pipe.grid.rows_held, "cadence": pipe.grid.cadence()}


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
        n, gone = self.disconnects, "; the port did not come back" if self.lost_for_good else ""
        dropped = _fmt_bytes(self.live_dropped_bytes)
        parts = [
            _fmt_duration(self.seconds),
            f"{self.attitude} attitude frames" + ("" if math.isnan(rate) else f" ({self._rate(rate)})"),
            f"{self.frames_missing} missing",
            f"{self.crc_failures} CRC failures",
            f"{_fmt_bytes(self.bytes_skipped)} skipped",
            self.values_sentence or (f"{self.nonfinite} with NaN/inf" if self.nonfinite else None),
            self._held_back(),
            f"{n} disconnect{'s' if n > 1 else ''} ({self.offline_s:.1f} s{gone})" if n else None,
            f"{dropped} not shown live (in the capture)" if self.live_dropped_bytes else None,
            self.records_part,
            self.filter_note,
        ]
        return "recorded " + ", ".join(p for p in parts if p) + "; " + self._outputs()

    def _rate(self, rate_hz: float) -> str:
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
        return [head, *said, *board, *filter(None, [self._step_cost()]), self._outputs()]

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
            f"connection(s), {self.disconnects} lost; stopped: {self.stopped_by}; {where}"
        )


def pipeline_counts(pipe) -> dict[str, Any]:
    """The summary's counters of a ``LivePipeline`` (None: a session that ended before it was made: zeros)."""
    if pipe is None:
        return {}
    s, h = pipe.decoder.stats, pipe.health
    names = ("status", "frames_missing", "crc_failures", "bytes_skipped", "implausible", "held_values")
    return {
        **{name: getattr(s, name) for name in names},
        **{name: getattr(h, name) for name in ("attitude", "text", "nonfinite")},
        "values_sentence": h.values_sentence(),
        "records_part": h.records_part(),
    }

"""Link health of a live session: counters (:class:`LinkHealth`) and the health line on stderr
(:class:`HealthDisplay`)."""

from __future__ import annotations

import collections
import math
import shutil
from typing import TextIO

import numpy as np

from steval_link.link.plausibility import values_bad_sentence

#: Health line refresh on a terminal / plain health lines otherwise, s.
HEALTH_TTY_INTERVAL_S = 0.25


HEALTH_PLAIN_INTERVAL_S = 5.0
#: Series names of text telemetry kept for the health line and the summary.
MAX_SERIES_NAMES = 64


class LinkHealth:
    """Counters and rates of the live link, for the health line and the summary (times: host s, Unix epoch)."""

    def __init__(self) -> None:
        self.attitude = 0
        self.status = 0
        self.text = 0
        self.nonfinite = 0  # attitude frames with a non-finite value
        self.values_bad = 0  # attitude frames with NaN or out-of-range values (the ``values_bad`` flag)
        self.inputs_bad = False  # some of those have bad filter inputs (acc, gyro) too
        self.first_bad_step: int | None = None  # AHRS step of the first of them
        self.first_bad_t_s: float | None = None  # its firmware time, s (t_us / 10⁶, mod 2³² µs)
        self._times: collections.deque[tuple[float, int]] = collections.deque(maxlen=512)
        self.first_frame_s: float | None = None  # host receive time of the first attitude frame
        self.last_frame_s: float | None = None
        self.last_text: str | None = None
        self.records = 0  # records of text telemetry
        self.series: dict[str, None] = {}  # their series names, in the order they came (bounded)

    def count_record(self, names: tuple[str, ...]) -> None:
        """A record of text telemetry with these series."""
        self.records += 1
        if len(self.series) < MAX_SERIES_NAMES:
            self.series.update(dict.fromkeys(names))

    def records_part(self, most: int = 6) -> str | None:
        """'text telemetry: N records, series a, b, c' (at most ``most`` names, then how many more); None without
        records."""
        if not self.records:
            return None
        names = list(self.series)
        more = f" and {len(names) - most} more" if len(names) > most else ""
        return f"text telemetry: {self.records} records, series {', '.join(names[:most])}{more}"

    def count(self, n_attitude: int, t_first_s: float, t_last_s: float) -> None:
        """``n_attitude`` frames received between host times ``t_first_s`` and ``t_last_s``."""
        if n_attitude:
            if self.first_frame_s is None:
                self.first_frame_s = t_first_s
            self.last_frame_s = t_last_s
            self.attitude += n_attitude
            self._times.append((t_last_s, self.attitude))

    def count_bad(self, bad, inputs_bad, step, t_us) -> bool:
        """Count the frames flagged ``bad`` ((N,) bool) of a batch with these ``step`` and ``t_us``;
        ``inputs_bad`` (N,) bool marks bad acc/gyro. True when the first bad frame of the session is among them."""
        bad = np.asarray(bad, dtype=bool)
        k = int(np.count_nonzero(bad))
        if not k:
            return False
        self.values_bad += k
        self.inputs_bad = self.inputs_bad or bool(np.any(np.asarray(inputs_bad, dtype=bool) & bad))
        if self.first_bad_step is not None:
            return False
        i = int(np.argmax(bad))
        self.first_bad_step = int(step[i])
        self.first_bad_t_s = int(t_us[i]) / 1e6
        return True

    def values_sentence(self) -> str | None:
        """The sentence about the frames with bad values (None when there is none), as every summary says it."""
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
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} GB"


def _fmt_duration(s: float) -> str:
    s = max(0.0, s)
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
        self._last = -math.inf
        self._dirty = False

    def note(self, text: str) -> None:
        """A message on its own line (events: connected, disconnected...)."""
        if self.tty and self._dirty:
            self.stream.write("\r\x1b[2K")
            self._dirty = False
        self.stream.write(f"steval: {text}\n")
        self.stream.flush()

    def show(self, line: str, now_mono: float, *, force: bool = False) -> None:
        if not force and now_mono - self._last < self.interval_s:
            return
        self._last = now_mono
        if self.tty:
            width = max(20, shutil.get_terminal_size((160, 24)).columns - 1)  # a wrapped line cannot be redrawn
            self.stream.write("\r\x1b[2K" + line[:width])
            self._dirty = True
        else:
            self.stream.write(f"steval: {line}\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self._dirty:
            self.stream.write("\r\x1b[2K")
            self.stream.flush()
            self._dirty = False


def pipeline_health(head: str, pipe, *, after_crc=(), before_replica=(), last=()) -> str:
    """A health line: ``head``, the frames, bad values, missing frames and CRC failures of ``pipe`` (a
    :class:`~steval_link.live.pipeline.LivePipeline`), ``after_crc``, the frames held back, ``before_replica``, what
    the ST filter's Python replica did, ``last``."""
    s, h = pipe.decoder.stats, pipe.health
    parts = [head, f"frames {h.attitude}", f"missing {stat(s, 'frames_missing')}", f"CRC {stat(s, 'crc_failures')}"]
    if h.values_bad:
        parts.insert(2, h.values_sentence())
    parts += after_crc
    if stat(s, "implausible"):
        parts.append(f"held back {stat(s, 'implausible')}")
    parts += before_replica
    records = h.records_part(most=3)
    if records:
        parts.append(records)
    if pipe.mahony is not None and (pipe.binary or not records):  # text alone has no bit-exact inputs
        parts.append(pipe.mahony.describe())
    return " | ".join([*parts, *last])


def stat(stats, name: str) -> int:
    """A decoder counter (0 when there are no stats yet or the decoder has no such counter)."""
    return int(getattr(stats, name, 0) or 0) if stats is not None else 0


def emulated_health(status, pipe, wall_s: float) -> str:
    """The health line of the emulated board: emulated time, its speed against the wall clock, the frames."""
    speed = status.t_link_s / wall_s if wall_s > 0 else 0.0
    head = f"emulated {status.t_link_s:6.2f}/{status.duration_s:g} s ({speed:.2f}x)"
    return pipeline_health(head, pipe)


def ble_health(pipe) -> str:
    """The health line of a BLE link: the notifications of each characteristic and the motion cadence ("": none
    yet)."""
    c = pipe.ble.counts if pipe is not None and pipe.ble is not None else {}
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
    ble = pipe.ble if pipe is not None else None
    return {
        "counts": dict(ble.counts) if ble is not None else {},
        "rows_held": pipe.grid.rows_held if ble is not None else 0,
        "connections": status.connections,
        "disconnects": status.disconnects,
        "cadence": pipe.grid.cadence() if ble is not None else None,
    }

"""Counters the firmware sends modulo a power of two, unwrapped: ``seq`` (u16) into full AHRS steps
(:class:`SeqUnwrapper`) and ``t_us`` (u32 µs, wraps every 71.6 min) into firmware seconds since boot
(:class:`TimeUnwrapper`). One implementation for both paths: the bulk decoder runs them over a whole stream, the
live path keeps them across batches.
"""

from __future__ import annotations

import numpy as np

from steval_link.link.protocol import SEQ_MODULUS, T_US_MODULUS

__all__ = ["SeqUnwrapper", "TimeUnwrapper"]

_HALF = T_US_MODULUS // 2


class TimeUnwrapper:
    """Firmware seconds since boot from ``t_us`` values in stream order, across calls.

    A value below the previous one by more than half the range is the counter wrapping (``t_us`` only grows while
    the firmware runs); a smaller step back is taken as it comes (a repeated or slightly earlier time), never as
    71.6 minutes gone.
    """

    def __init__(self) -> None:
        self.wraps = 0
        self.last: int | None = None

    def seconds(self, t_us) -> np.ndarray:
        """(N,) float64 seconds of these ``t_us`` values, in order (state carried to the next call)."""
        raw = np.asarray(t_us, dtype=np.int64) % T_US_MODULUS
        if raw.size == 0:
            return np.zeros(0, dtype=np.float64)
        prev = np.empty_like(raw)
        prev[0] = raw[0] if self.last is None else self.last
        prev[1:] = raw[:-1]
        wraps = self.wraps + np.cumsum((prev - raw) > _HALF)
        self.wraps = int(wraps[-1])
        self.last = int(raw[-1])
        return (raw + wraps * T_US_MODULUS) / 1e6

    def nearest(self, t_us: int) -> float:
        """Seconds of one ``t_us`` near the latest value seen (a status frame's time, which repeats the time of
        the attitude frame before it), without changing the state: the wrap count giving the time closest to the
        latest one (so a value just before or just after a wrap is placed right)."""
        v = int(t_us) % T_US_MODULUS
        if self.last is None:
            return v / 1e6
        wraps = self.wraps
        if v - self.last > _HALF and wraps > 0:
            wraps -= 1  # from before the latest wrap
        elif self.last - v > _HALF:
            wraps += 1  # already past the next wrap
        return (v + wraps * T_US_MODULUS) / 1e6


class SeqUnwrapper:
    """Full AHRS step numbers from the u16 ``seq`` of binary attitude frames, in stream order, across calls.

    A step forward of less than half the range is frames passing (gaps included); a repeated ``seq`` is the same
    step; a step back (or forward by half the range or more) is a firmware restart: counting starts again from the
    frame's ``seq``. A status frame names its step in full (:meth:`status`), which gives back the high bits the
    ``seq`` lacks (a stream joined mid-flight, after a restart). The bulk decoder also corrects the rows before the
    status frame; the live path can only correct from there on.
    """

    def __init__(self) -> None:
        #: full step of the latest binary frame (None before the first)
        self.last: int | None = None

    def steps(self, seq) -> tuple[np.ndarray, np.ndarray]:
        """(steps (N,) int64, restart (N,) bool: this frame begins a new firmware run) for these ``seq`` values."""
        raw = np.asarray(seq, dtype=np.int64) % SEQ_MODULUS
        n = raw.size
        if n == 0:
            return np.zeros(0, np.int64), np.zeros(0, bool)
        prev = np.empty_like(raw)
        prev[0] = raw[0] if self.last is None else self.last % SEQ_MODULUS
        prev[1:] = raw[:-1]
        advance = (raw - prev) % SEQ_MODULUS
        restart = advance >= SEQ_MODULUS // 2
        inc = np.where(restart, 0, advance)
        cs = np.cumsum(inc)
        seg = np.cumsum(restart)  # 0: continues the previous call's run
        first = np.flatnonzero(restart)  # the row where each later run starts
        base0 = raw[0] if self.last is None else self.last
        steps = base0 + cs
        if first.size:
            later = seg > 0
            starts = first[seg[later] - 1]
            steps[later] = raw[starts] + (cs[later] - cs[starts])
        self.last = int(steps[-1])
        return steps, restart

    def status(self, step: int) -> None:
        """A status frame names the full step of the attitude frame just before it: take it when it agrees."""
        if self.last is None or self.last % SEQ_MODULUS == step % SEQ_MODULUS:
            self.last = int(step)

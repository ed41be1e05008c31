"""Steps and times of a stream's rows: ``seq`` (u16) into full AHRS steps (:class:`SeqUnwrapper`), ``t_us`` (u32
µs, wraps every 71.6 min) into firmware seconds (:class:`TimeUnwrapper`), host times from the chunks'
(:func:`host_times`). One implementation for the whole stream (``Telemetry``) and the live path (:class:`StreamClock`).
"""

from __future__ import annotations

import numpy as np

from steval_link.link.protocol import SEQ_MODULUS, T_US_MODULUS

_HALF = T_US_MODULUS // 2


class TimeUnwrapper:
    """Firmware seconds since boot from ``t_us`` values in stream order, across calls: a drop by more than half the
    range is a wrap, a smaller step back is taken as it comes."""

    def __init__(self) -> None:
        self.wraps = 0
        self.last: int | None = None

    def seconds(self, t_us) -> np.ndarray:
        """(N,) float64 seconds of these ``t_us`` values, in order (state carried to the next call)."""
        raw = np.asarray(t_us, dtype=np.int64) % T_US_MODULUS
        if raw.size == 0:
            return np.zeros(0, dtype=np.float64)
        prev = np.concatenate([[raw[0] if self.last is None else self.last], raw[:-1]])
        wraps = self.wraps + np.cumsum((prev - raw) > _HALF)
        self.wraps = int(wraps[-1])
        self.last = int(raw[-1])
        return (raw + wraps * T_US_MODULUS) / 1e6

    def nearest(self, t_us: int) -> float:
        """Seconds of one ``t_us`` (a status frame's) at the wrap count closest to the latest value; no state change."""
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
    """Full AHRS steps from the u16 ``seq`` of binary attitude frames, across calls: a step back (or forward by half
    the range or more) is a firmware restart, counted again from its ``seq``; :meth:`status` gives the high bits."""

    def __init__(self) -> None:
        #: full step of the latest binary frame (None before the first)
        self.last: int | None = None

    def steps(self, seq) -> tuple[np.ndarray, np.ndarray]:
        """(steps (N,) int64, restart (N,) bool: this frame begins a new firmware run) for these ``seq`` values."""
        raw = np.asarray(seq, dtype=np.int64) % SEQ_MODULUS
        n = raw.size
        if n == 0:
            return np.zeros(0, np.int64), np.zeros(0, bool)
        prev = np.concatenate([[raw[0] if self.last is None else self.last % SEQ_MODULUS], raw[:-1]])
        advance = (raw - prev) % SEQ_MODULUS
        restart = advance >= SEQ_MODULUS // 2
        cs = np.cumsum(np.where(restart, 0, advance))
        seg = np.cumsum(restart)  # 0: continues the previous call's run
        first = np.flatnonzero(restart)  # the row where each later run starts
        steps = (raw[0] if self.last is None else self.last) + cs
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


def host_times(last_byte, chunk_times, baud: int | None, total: int, *, before_s: float = -np.inf) -> np.ndarray:
    """Host time of each frame's ``last_byte``: its chunk's (offsets, times; None: NaN) less the bytes after it at
    ``baud``, never before the previous chunk's."""
    if chunk_times is None or len(chunk_times[0]) == 0:
        return np.full(len(last_byte), np.nan)
    c_off = np.asarray(chunk_times[0], dtype=np.int64)
    c_t = np.asarray(chunk_times[1], dtype=np.float64)
    k = np.clip(np.searchsorted(c_off, last_byte, side="right") - 1, 0, len(c_off) - 1)
    t = c_t[k].copy()
    if baud:
        c_end = np.append(c_off[1:], total)
        t -= (c_end[k] - (last_byte + 1)) * (10.0 / baud)
        # a byte cannot have arrived before the previous chunk was received
        prev = np.where(k > 0, c_t[np.maximum(k - 1, 0)], before_s)
        t = np.maximum(t, prev)
    return t


class StreamClock:
    """Firmware and host times of a live stream's rows by the bulk path's rules, on the capture's base
    (``t0_unix_s``; default: the first chunk's time). Call :meth:`chunk` for each chunk before decoding it."""

    def __init__(self, t0_unix_s: float | None = None, baud: int | None = None) -> None:
        self.t0_unix_s, self.baud = t0_unix_s, baud
        self.total = 0  # bytes of the stream so far
        self._offsets: list[int] = []
        self._times: list[float] = []
        self._before_s = -np.inf  # time of the chunk before the first kept one
        self.fw = TimeUnwrapper()

    def host_of(self, t_unix_s: float) -> float:
        """A host time (s, Unix epoch) on the capture's base (as the recorder stores chunk times)."""
        if self.t0_unix_s is None:
            self.t0_unix_s = float(t_unix_s)
        return float(t_unix_s) - self.t0_unix_s

    def chunk(self, nbytes: int, t_unix_s: float) -> None:
        """A chunk of ``nbytes`` received at ``t_unix_s`` (an empty one is not kept, as in a capture)."""
        t_s = self.host_of(t_unix_s)
        if nbytes:
            self._offsets.append(self.total)
            self._times.append(t_s)
            self.total += nbytes

    def host_s(self, last_byte) -> np.ndarray:
        """Host times of frames ending at stream offsets ``last_byte`` (:func:`host_times` over the chunks)."""
        chunks = (self._offsets, self._times)
        return host_times(np.asarray(last_byte), chunks, self.baud, self.total, before_s=self._before_s)

    def fw_s(self, t_us, restart=None) -> np.ndarray:
        """Firmware seconds of these ``t_us`` (stream order); counting starts again at each ``restart`` row."""
        restart = np.zeros(len(t_us), bool) if restart is None else np.asarray(restart, bool)
        cuts = sorted({0, len(t_us), *np.flatnonzero(restart).tolist()})
        out = [np.zeros(0)]
        for a, b in zip(cuts[:-1], cuts[1:]):
            if restart[a]:
                self.fw = TimeUnwrapper()  # a firmware restart: its own time from boot
            out.append(self.fw.seconds(t_us[a:b]))
        return np.concatenate(out)

    def prune(self, pending_bytes: int) -> None:
        """Forget the chunks before the one holding the first of the ``pending_bytes`` not decoded yet."""
        k = int(np.searchsorted(self._offsets, self.total - pending_bytes, side="right")) - 1
        if k > 0:
            self._before_s = self._times[k - 1]  # a frame's time is never before the previous chunk's
            del self._offsets[:k], self._times[:k]

"""The times and steps of a stream's rows, one implementation for the bulk path (``Telemetry``) and the live one.

Counters the firmware sends modulo a power of two, unwrapped: ``seq`` (u16) into full AHRS steps
(:class:`SeqUnwrapper`) and ``t_us`` (u32 µs, wraps every 71.6 min) into firmware seconds since boot
(:class:`TimeUnwrapper`); host receive times of frames from the times of the chunks that brought their bytes
(:func:`host_times`). The bulk decoder runs them over a whole stream; the live path keeps them across chunks
(:class:`StreamClock`), so its rows carry the times ``load_telemetry`` gives the same capture.
"""

from __future__ import annotations

import numpy as np

from steval_link.link.protocol import SEQ_MODULUS, T_US_MODULUS

__all__ = ["SeqUnwrapper", "StreamClock", "TimeUnwrapper", "host_times"]

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


def host_times(last_byte, chunk_times, baud: int | None, total: int, *, before_s: float = -np.inf) -> np.ndarray:
    """(N,) float64 host receive time of each frame, s on the chunks' base, from the offset of its ``last_byte``.

    ``chunk_times``: (offsets, times) of the received chunks in stream order (None: NaN times). A frame takes its
    chunk's time; with ``baud`` the bytes after it in the chunk are taken off (10 bits each), but never before the
    previous chunk came (``before_s``: the time of the chunk before the first one given). ``total``: the bytes of
    the stream so far (the end of the last chunk).
    """
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
    """Firmware and host times of a live stream's rows, by the bulk path's rules, on the capture's base.

    ``t0_unix_s``: the capture's start (its header's ``start_time_unix_s``; default: the first chunk's time), so
    ``t_host_s`` is s since capture start as in the capture's chunks; ``baud`` as in its header. Call
    :meth:`chunk` for each chunk before decoding it, then :meth:`host_s` for frames (by their last byte) and
    :meth:`fw_s` for attitude and status ``t_us`` in stream order; :meth:`prune` keeps the chunks still needed.
    """

    def __init__(self, t0_unix_s: float | None = None, baud: int | None = None) -> None:
        self.t0_unix_s = t0_unix_s
        self.baud = baud
        self.total = 0  # bytes of the stream so far
        self._offsets: list[int] = []
        self._times: list[float] = []
        self._before_s = -np.inf  # time of the chunk before the first kept one
        self.fw = TimeUnwrapper()

    def chunk(self, nbytes: int, t_unix_s: float) -> float:
        """A chunk of ``nbytes`` received at ``t_unix_s``; returns its time on the capture's base, s."""
        if self.t0_unix_s is None:
            self.t0_unix_s = float(t_unix_s)
        t_s = self.host_of(t_unix_s)
        if nbytes:  # the capture keeps no empty chunk
            self._offsets.append(self.total)
            self._times.append(t_s)
            self.total += nbytes
        return t_s

    def host_of(self, t_unix_s: float) -> float:
        """A host time (s, Unix epoch) on the capture's base (as the recorder stores chunk times)."""
        return float(t_unix_s) - (self.t0_unix_s if self.t0_unix_s is not None else float(t_unix_s))

    def host_s(self, last_byte) -> np.ndarray:
        """Host times of frames ending at stream offsets ``last_byte`` (:func:`host_times` over the chunks)."""
        return host_times(
            np.asarray(last_byte, dtype=np.int64),
            (self._offsets, self._times),
            self.baud,
            self.total,
            before_s=self._before_s,
        )

    def fw_s(self, t_us, restart=None) -> np.ndarray:
        """Firmware seconds of these ``t_us`` (stream order); counting starts again at each ``restart`` row."""
        if restart is None or not np.any(restart):
            return self.fw.seconds(t_us)
        t_us = np.asarray(t_us)
        out = np.empty(len(t_us), dtype=np.float64)
        cuts = [0, *np.flatnonzero(restart).tolist(), len(t_us)]
        for a, b in zip(cuts[:-1], cuts[1:]):
            if a > 0:
                self.fw = TimeUnwrapper()  # a firmware restart: its own time from boot
            out[a:b] = self.fw.seconds(t_us[a:b])
        return out

    def prune(self, pending_bytes: int) -> None:
        """Forget the chunks before the one holding the first of the ``pending_bytes`` not decoded yet (the time
        of the one before it stays: a frame's time is never before the previous chunk's)."""
        k = int(np.searchsorted(self._offsets, self.total - pending_bytes, side="right")) - 1
        if k > 0:
            self._before_s = self._times[k - 1]
            del self._offsets[:k], self._times[:k]

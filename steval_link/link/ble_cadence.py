"""The motion stream's cadence from its ticks (8 ms units): the sender's own rate, ST's congestion skips (30
updates after a failed notification), gaps, or a poller's reads, with the sender's number of each sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from steval_link.constants import AHRS_PERIOD_S
from steval_link.link.ble_payloads import TICK_S

#: the stock firmware sends at most one motion notification per main-loop AHRS step (5 TIM9 ticks of 104000 cycles
#: at 84 MHz: 6.190 ms) and tries at every step; a measured interval within :data:`STEP_SNAP` of it is that step
#: (known exactly), and missing notifications are then counted from the ticks' phase (sub-tick precise)
STEP_PERIOD_S = AHRS_PERIOD_S
STEP_SNAP = 0.02  #: relative
#: a tick delta is a gap (notifications missing) from 1.5 periods plus one tick (the 8 ms quantisation) on
GAP_PERIODS = 1.5

#: :attr:`Cadence.kind`: what the ticks show
STEADY, CONGESTION, GAPS, POLLED = "steady", "congestion", "gaps", "polled"


@dataclass(frozen=True, slots=True)
class Cadence:
    """The motion stream's cadence. ``kind``: ``steady`` (the sender's own rate, nothing dropped), ``congestion``
    (ST's AHRS step with notifications missing), ``gaps`` (another cadence with gaps), ``polled`` (samples received
    twice: reads of the characteristic, nothing dropped)."""

    kind: str
    interval_s: float  #: the sender's interval (polled: the mean interval between distinct samples), s
    dropped: int  #: motion samples missing between the first and the last received
    gaps: int  #: tick deltas of 1.5 periods or more plus the tick's quantisation (:func:`gap_mask`), if any dropped
    repeats: int  #: samples received again (same tick and payload), counted once
    span_s: float  #: first to last sample, drone clock, s
    exact: bool  #: the interval is ST's AHRS step (known exactly), not a measurement

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.interval_s

    def _decimals(self, value: float) -> int:
        """Decimals worth showing for ``value`` measured over the span (two ticks of blur), at most 2."""
        if self.exact or not self.span_s > 0:
            return 2
        blur = abs(value) * 2 * TICK_S / self.span_s
        return int(min(2, max(0, np.floor(-np.log10(blur))))) if blur > 0 else 2

    def describe(self) -> str:
        """One phrase for the summary and the health line ("motion every 20.0 ms (50.0 Hz, ...), 0 dropped")."""
        ms, hz = self.interval_s * 1e3, self.rate_hz
        every = f"every {ms:.{self._decimals(ms)}f} ms"
        rate = f"{hz:.{self._decimals(hz)}f} Hz"
        if self.kind == POLLED:
            return (
                f"motion read {every} on average ({rate}: reads of the characteristic, {_n(self.repeats)} "
                f"repeated read(s) of one sample counted once), 0 dropped"
            )
        if self.kind == STEADY:
            return f"motion {every} ({rate}, the sender's own rate), 0 dropped"
        where = f" in {_n(self.gaps)} gap(s)" if self.gaps else ""
        why = (
            "congestion: ST's firmware skips motion updates while the radio is full"
            if self.kind == CONGESTION
            else "gaps in the sender's own cadence"
        )
        return f"motion {every} ({rate}) with {_n(self.dropped)} dropped{where} ({why})"


def _n(k: int) -> str:
    """An integer with a space between thousands (1 212)."""
    return f"{int(k):,}".replace(",", " ")


def gap_mask(d_ticks: np.ndarray, period_ticks: float) -> np.ndarray:
    """Tick deltas that are gaps: 1.5 periods and more beyond a tick of quantisation and a period's own spread."""
    return (d_ticks >= GAP_PERIODS * period_ticks + 1) & (d_ticks > np.floor(period_ticks) + 1)


def period_ticks(d_ticks) -> float | None:
    """The sender's period in ticks: the mean of the tick deltas that are not gaps, from the bulk (within a tick
    above the median) on (unbiased by the 8 ms quantisation: it telescopes to the span). None: no delta above 0."""
    d = np.maximum(np.asarray(d_ticks, dtype=np.int64), 0)
    if d.size == 0:
        return None
    bulk = d[d <= np.median(d) + 1]
    p = float(bulk.mean()) if bulk.size else 0.0
    for _ in range(4):
        if not p > 0:
            break
        keep = d[~gap_mask(d, p)]
        q = float(keep.mean()) if keep.size else p
        if q == p:
            break
        p = q
    if not p > 0:
        total = float(d.sum())
        return total / d.size if total > 0 else None
    return p


def repeats_are_reads(ticks, repeat, t_host_s=None) -> bool:
    """Whether repeated motion notifications are a poller's reads rather than samples: true when, counted as
    samples, the stream is not faster than one 8 ms tick on both the drone's ticks and the arrival times."""
    t = np.asarray(ticks, dtype=np.int64)
    rep = np.asarray(repeat, dtype=bool)
    n = len(t)
    if n < 2 or not rep.any():
        return False
    step_ticks = float(t[-1] - t[0]) / (n - 1)
    if step_ticks >= 1.0:
        return True
    if t_host_s is None:
        return False
    h = np.asarray(t_host_s, dtype=np.float64)
    host_span = float(h[-1] - h[0])
    return not (host_span > 0 and host_span / (n - 1) < 1.5 * TICK_S)


def motion_cadence(ticks, repeats: int = 0, breaks=()) -> Cadence | None:
    """The cadence of unwrapped ticks (one per distinct sample), ``repeats`` removed, ``breaks`` the samples after a
    reconnection (no drop before them); None below 2 samples or on one tick. The period (:func:`period_ticks`) is
    ST's step within :data:`STEP_SNAP`, else a least-squares fit; drops come from the ticks' phase at ST's step
    (:func:`sample_numbers`), else from the runs around each gap (:class:`RunNumberer`)."""
    t = np.asarray(ticks, dtype=np.int64)
    n = len(t)
    if n < 2 or t[-1] <= t[0]:
        return None
    d = np.diff(t)
    brk = np.zeros(n, bool)  # the samples that follow a reconnection (never the first)
    b = np.asarray(breaks, dtype=np.int64).reshape(-1)
    brk[b[(b > 0) & (b < n)]] = True
    p = period_ticks(d[~brk[1:]]) if brk.any() else period_ticks(d)
    if p is None:
        return None
    span_s = float(t[-1] - t[0]) * TICK_S
    if repeats > 0 and p >= 1:
        return Cadence(POLLED, span_s / (n - 1), 0, 0, int(repeats), span_s, False)
    exact = abs(p * TICK_S - STEP_PERIOD_S) <= STEP_SNAP * STEP_PERIOD_S
    if exact:
        interval = STEP_PERIOD_S
        k = sample_numbers(t, interval)
    else:
        k = RunNumberer(p).numbers(t)
        for _ in range(2):  # the period from all samples at their numbers (least squares): precise over the span
            fit = float(np.polyfit(k, t + 0.5, 1)[0]) if k[-1] > 1 else p
            if not abs(fit - p) < 0.05 * p or fit == p:
                break
            p = fit
            k = RunNumberer(p).numbers(t)
        interval = p * TICK_S
    jump = np.diff(k) - 1
    dropped = int(jump[~brk[1:]].sum())
    gaps = int(np.count_nonzero(gap_mask(np.maximum(d, 0), p) & ~brk[1:])) if dropped else 0
    kind = STEADY if not dropped else CONGESTION if exact else GAPS
    return Cadence(kind, interval, dropped, gaps, int(repeats), span_s, exact)


class RunNumberer:
    """The sender's sample numbers of a stream with gaps, in batches, for any period but ST's step: a run after a
    gap starts at the number the two runs' phases (mean of tick + ½ − i·period) say."""

    def __init__(self, period_ticks: float) -> None:
        self.p = float(period_ticks)  #: the period, ticks (live: refined as the stream goes on)
        self.k: int | None = None  #: the last number given
        self.tick: int | None = None  #: the last tick seen
        self._k0 = 0  # the current run's first number
        self._sum_t = 0.0  # Σ (tick + ½) over the current run
        self._sum_i = 0  # Σ (k − k0) over the current run
        self._n = 0

    def numbers(self, ticks) -> np.ndarray:
        t = np.asarray(ticks, dtype=np.int64)
        out = np.zeros(len(t), np.int64)
        if len(t) == 0:
            return out
        d = np.diff(t, prepend=t[0] if self.tick is None else self.tick)
        gap = gap_mask(np.maximum(d, 0), self.p)
        if self.tick is None:
            gap[0] = False
        bounds = np.concatenate([[0], np.flatnonzero(gap), [len(t)]])
        for s, e in zip(bounds[:-1], bounds[1:]):
            if e <= s:
                continue
            i = np.arange(e - s)
            if self.k is None:
                k0 = 0
                self._k0, self._sum_t, self._sum_i, self._n = 0, 0.0, 0, 0
            elif gap[s]:  # a new run: placed by the phases of the run before and of this one
                phase_a = (self._sum_t - self.p * self._sum_i) / self._n - self._k0 * self.p  # number 0's time
                phase_b = float(np.mean(t[s:e] + 0.5 - i * self.p))  # this run's first sample's time
                k0 = max(self.k + 1, int(round((phase_b - phase_a) / self.p)))
                self._k0, self._sum_t, self._sum_i, self._n = k0, 0.0, 0, 0
            else:  # the current run goes on
                k0 = self.k + 1
            out[s:e] = k0 + i
            self._sum_t += float(np.sum(t[s:e] + 0.5))
            self._sum_i += int(np.sum(out[s:e] - self._k0))
            self._n += e - s
            self.k, self.tick = int(out[e - 1]), int(t[e - 1])
        return out


def sender_phase(t: np.ndarray, interval: float) -> float:
    """The sender's phase t0 (sample k at ``t0 + k·interval``, s): the intersection of the [tick, tick + 8 ms)
    that the first 64 samples allow."""
    w = min(len(t), 64)
    i = np.arange(w)
    lo, hi = float(np.max(t[:w] - i * interval)), float(np.min(t[:w] + TICK_S - i * interval))
    return (lo + hi) / 2 if lo < hi else float(t[0]) + TICK_S / 2


def sample_numbers(ticks, interval: float, t0: float | None = None, prev: int | None = None) -> np.ndarray:
    """The smallest increasing sample numbering the ticks allow; ``t0``: the sender's phase (None: from these
    ticks); ``prev``: the number of the sample before (None: the first is 0)."""
    t = np.asarray(ticks, dtype=np.float64) * TICK_S
    if len(t) == 0:
        return np.zeros(0, np.int64)
    lo = np.ceil((t - (sender_phase(t, interval) if t0 is None else t0)) / interval - 1e-9).astype(np.int64)
    if prev is None:
        lo[0], prev = 0, -1
    # k_i = max(k_{i-1} + 1, lo_i): with j_i = k_i - i, j is the running maximum of lo_i - i
    j = np.arange(len(t))
    return np.maximum.accumulate(np.maximum(lo, prev + 1 + j) - j) + j

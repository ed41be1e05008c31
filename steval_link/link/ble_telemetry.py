"""A BLE capture as the one model: notifications → frames → the sender's samples on one grid (:class:`LiveGrid`,
live and replayed alike) → :class:`~steval_link.link.telemetry.Telemetry` with the link's facts (:class:`BleStream`).

The motion stream's cadence comes from its ticks (8 ms units): the sender's own rate, ST's congestion skips (30
updates after a failed notification), gaps, or a poller's reads, with the sender's number of each sample.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from steval_link.constants import AHRS_PERIOD_S
from steval_link.errors import UserError
from steval_link.link.ble_payloads import (
    TICK_S,
    BleArmingFrame,
    BleConsoleFrame,
    BleDecoder,
    BleEnvFrame,
    BleLayout,
    BleMotionFrame,
    ble_items,
    layout_named,
)
from steval_link.link.frames import DecoderStats
from steval_link.link.telemetry import AttitudeArrays, Telemetry, TelemetryParts

#: the stock firmware tries a motion notification every AHRS step (6.190 ms); an interval within :data:`STEP_SNAP`
#: of it is that step, known exactly (notifications missing are then counted from the ticks' phase)
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
    """The sender's period in ticks: the mean of the tick deltas that are not gaps (unbiased by the 8 ms quantisation:
    it telescopes to the span), found from the bulk within a tick above the median. None: no delta above 0."""
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


def repeats_are_reads(ticks, repeat, t_host_s) -> bool:
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
    dropped = int((np.diff(k) - 1)[~brk[1:]].sum())
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
            if self.k is None:  # the first run (the sums start at 0)
                k0 = 0
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
    """The sender's phase t0 (sample k at ``t0 + k·interval``, s) the first 64 samples' [tick, tick + 8 ms) allow."""
    w = min(len(t), 64)
    i = np.arange(w)
    lo, hi = float(np.max(t[:w] - i * interval)), float(np.min(t[:w] + TICK_S - i * interval))
    return (lo + hi) / 2 if lo < hi else float(t[0]) + TICK_S / 2


def sample_numbers(ticks, interval: float, t0: float | None = None, prev: int | None = None) -> np.ndarray:
    """The smallest increasing numbering the ticks allow at phase ``t0`` (None: theirs), after number ``prev``."""
    t = np.asarray(ticks, dtype=np.float64) * TICK_S
    if len(t) == 0:
        return np.zeros(0, np.int64)
    lo = np.ceil((t - (sender_phase(t, interval) if t0 is None else t0)) / interval - 1e-9).astype(np.int64)
    if prev is None:
        lo[0], prev = 0, -1
    # k_i = max(k_{i-1} + 1, lo_i): with j_i = k_i - i, j is the running maximum of lo_i - i
    j = np.arange(len(t))
    return np.maximum.accumulate(np.maximum(lo, prev + 1 + j) - j) + j


NOT_BIT_EXACT = (
    "BLE data: the drone's own attitude is not sent over BLE, and the host filters run on single ISR "
    "samples (before the firmware's gyro IIR filter and 5-sample boxcar) with dt from the cadence of "
    "the 8 ms ticks, "
    "so the ST-Mahony replica cannot be bit-exact with the firmware here; the angles are the host "
    "estimators' own."
)
EULER_NOTE = (
    "BLE data in the euler layout: the motion notifications carry the drone's own attitude (its Euler angles, as "
    "its firmware sent them), shown as the firmware's; they carry no sensor values, so the host estimators have no "
    "input."
)


def link_notes(acc_mg, layout: BleLayout) -> list[str]:
    """What a BLE stream's rows are, one sentence each (the layout's note, or why the acc fields contradict it)."""
    other = motion_payload_note(acc_mg, layout)
    if layout.sends_attitude:
        return [EULER_NOTE, other] if other else [EULER_NOTE]
    return [other] if other else [NOT_BIT_EXACT]


#: one motion sample received: its row in the model, tick (8 ms, unwrapped), arrival and the payload's fields
SAMPLE_DTYPE = np.dtype(
    [("row", "<i8"), ("tick", "<i8"), ("t_host_s", "<f8"), ("acc", "<f4", 3), ("gyro", "<f4", 3), ("mag", "<f4", 3)]
)
ENV_DTYPE = np.dtype(
    [("t_host_s", "<f8"), ("t_fw_s", "<f8")]
    + [(k, "<f4") for k in ("pressure_hpa", "battery_pct", "temperature_c", "rssi_dbm")]
)
ARMING_DTYPE = np.dtype([("t_host_s", "<f8"), ("t_fw_s", "<f8"), ("armed", "?")])


@dataclass
class BleStream:
    """The link's own facts of a BLE capture (``Telemetry.link``), as data."""

    layout: BleLayout
    cadence: Cadence | None  #: the motion stream's cadence (None below 2 samples or on one tick)
    dt_s: float  #: the estimators' dt: the cadence's interval (ST's step when none is found)
    rows_held: int  #: rows that hold the last sample over a notification sent and lost
    samples: np.ndarray  #: one SAMPLE_DTYPE record per motion sample received (a repeated read counted once)
    environment: np.ndarray  #: ENV_DTYPE records
    arming: np.ndarray  #: ARMING_DTYPE records
    counts: dict[str, int]  #: notifications per characteristic name
    bad_payloads: int = 0  #: notifications of the wrong length (skipped)
    unknown: int = 0  #: notifications of an unknown characteristic id (skipped)
    repeated_reads: int = 0  #: motion samples received again (a poller's read of an unchanged value)

    @property
    def sensors(self) -> bool:
        """The rows carry sensor values (the euler layout sends the drone's attitude instead)."""
        return not self.layout.sends_attitude

    def notes(self) -> list[str]:
        """What the rows are, one sentence each (:func:`link_notes`)."""
        return link_notes(self.samples["acc"], self.layout)

    def motion_table(self) -> dict[str, np.ndarray]:
        """One row per motion sample received, for CSV/Parquet/MAT (env and arming values held from their last)."""
        s = self.samples
        t_fw = s["tick"] * TICK_S
        tab = {"t_host_s": s["t_host_s"], "tick": s["tick"], "t_fw_s": t_fw}
        for name, unit in (("acc", "mg"), ("gyro", "mdps"), ("mag", "mgauss")):
            for i, ax in enumerate("xyz"):
                tab[f"{name}_{ax}_{unit}"] = s[name][:, i]
        env, arm = self.environment, self.arming
        for key in ("pressure_hpa", "battery_pct", "temperature_c", "rssi_dbm"):
            tab[key] = _held(t_fw, env["t_fw_s"], env[key])
        tab["armed"] = _held(t_fw, arm["t_fw_s"], arm["armed"])
        return tab


def _held(t_at: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` at each time of ``t_at``: its last value at or before it (NaN before the first)."""
    out = np.full(len(t_at), np.nan, dtype=np.float32)
    if len(t):
        i = np.searchsorted(t, t_at, side="right") - 1
        ok = i >= 0
        out[ok] = np.asarray(v, dtype=np.float32)[i[ok]]
    return out


def ble_telemetry(src, layout: str | None = None) -> Telemetry:
    """A BLE capture (a ``link.load.Recording``: its ``B`` chunks and ``reconnect`` events) as :class:`Telemetry`
    whose ``link`` is the :class:`BleStream`. ``layout``: the motion payload's (None: the header's
    ``extra.ble_layout``, else stock). UserError without motion notifications."""
    extra = (src.header or {}).get("extra") or {}
    lay = layout_named(layout or (str(extra.get("ble_layout") or "stock") if isinstance(extra, dict) else "stock"))
    dec, grid = BleDecoder(), LiveGrid(lay)
    motion, env, arm, text = [], [], [], []
    for cid, payload, t in ble_items(src.chunks or {}, src.events or []):
        f = None if cid is None else dec.feed(cid, payload, t)
        if cid is None or isinstance(f, BleMotionFrame):
            motion.append(f)
        elif isinstance(f, BleEnvFrame):
            env.append((f.t_host_s, f.tick * TICK_S, f.pressure_hpa, f.battery_pct, f.temperature_c, f.rssi_dbm))
        elif isinstance(f, BleArmingFrame):
            arm.append((f.t_host_s, f.tick * TICK_S, f.armed))
        elif isinstance(f, BleConsoleFrame):
            text.append((f.t_host_s, f"[{f.stream}] {f.text}"))
    grid.add(motion)
    a = grid.rows(final=True)
    if a is None:
        raise UserError(
            f"{src.path}: a BLE capture without motion notifications ({sum(dec.counts.values())} other "
            "notifications): nothing to replay."
        )
    kept = [f for f in motion if f is not None and not (grid.reads and f.repeat)]
    samples = np.array([(0, f.tick, f.t_host_s, f.acc_mg, f.gyro_mdps, f.mag_mgauss) for f in kept], dtype=SAMPLE_DTYPE)
    samples["row"] = np.searchsorted(a.step, grid.numbers)
    env, arm = np.array(env, dtype=ENV_DTYPE), np.array(arm, dtype=ARMING_DTYPE)
    facts = (samples, env, arm, dict(dec.counts), dec.bad_payloads, dec.unknown, grid.repeats)
    stream = BleStream(lay, grid.found, float(grid.dt_s), grid.rows_held, *facts)
    source = dict(path=str(src.path), kind="stv", link="ble", header=src.header, warnings=list(src.warnings))
    tel = Telemetry.from_parts(TelemetryParts(), DecoderStats(), source=source, events=src.events)
    tel.attitude, tel.text, tel.link = a, text, stream
    return tel


def motion_payload_note(acc_mg, layout: BleLayout) -> str | None:
    """One sentence when the acc fields contradict the layout, else None. Stock: hardly a sample near 1 g and every
    value in an angle's range is no accelerometer. Euler: nearly every sample near 1 g is one."""
    acc = np.asarray(acc_mg, dtype=np.float64).reshape(-1, 3)
    if len(acc) < 2:
        return None
    norm = np.linalg.norm(acc, axis=1)
    near_1g = float(np.mean(np.abs(norm - 1000.0) <= ONE_G_BAND_MG))
    if layout.sends_attitude:
        if near_1g < SENSOR_1G_SHARE:
            return None
        return (
            f"The motion notifications look like raw sensors, not angles: their acc fields are near 1 g in "
            f"{100 * near_1g:.1f} % of the samples (median |acc| {float(np.median(norm)):.0f} mg, as an accelerometer "
            "reads), so the euler layout may be reading an accelerometer as angles (ST's unmodified firmware sends "
            "the stock layout)."
        )
    if near_1g >= NEAR_1G_SHARE or float(np.nanmax(np.abs(acc))) > ANGLE_RANGE_MAX:
        return None
    return (
        f"the motion notifications are not raw sensors: their acc fields are near 1 g in {100 * near_1g:.1f} % of "
        f"the samples (median |acc| {float(np.median(norm)):.0f} mg, where an accelerometer reads about 1000 mg at "
        "rest) and stay in an angle's range, as a modified firmware sending its own Euler angles there does (the "
        "euler layout reads them so)"
    )


#: |acc| within this of 1000 mg is near 1 g, mg
ONE_G_BAND_MG = 250.0
#: a stream with fewer samples near 1 g than this share has no accelerometer in its acc fields
NEAR_1G_SHARE = 0.01
#: a stream with at least this share of samples near 1 g has an accelerometer in its acc fields
SENSOR_1G_SHARE = 0.9
#: the largest field an angle ×scale reaches (degrees x 100: 18000)
ANGLE_RANGE_MAX = 18000.0


#: motion samples that fix the cadence (and the estimators' dt) live; fewer when 3 s of drone time pass or at the end
LOCK_SAMPLES = 64
LOCK_SPAN_S = 3.0
#: motion ticks kept for the live interval (its precision grows with the span)
TICKS_KEPT = 20_000


class LiveGrid:
    """Motion frames → one row per sender sample, a round at a time (live) or all at once (:func:`ble_telemetry`).
    The first :data:`LOCK_SAMPLES` samples fix the cadence, dt and the numbering (:meth:`rows` holds them back until
    then); a row holds the last sample only over a notification the ticks show as sent and lost.

    Rows are the one attitude model: ``step`` the sender's sample number, not bit-exact (BLE carries no AHRS input).
    Stock rows carry the sensors and no attitude (NaN); euler rows the drone's attitude (rad) and no sensors."""

    def __init__(self, layout: BleLayout) -> None:
        self.layout = layout
        self._pending: list = []  # motion frames (or None: a reconnection) before the cadence is found
        self._cadence: Cadence | None = None
        self.reads = False  #: repeats are reads of one sample
        #: the cadence the first samples show (None: too few; the grid then runs at ST's step)
        self.found: Cadence | None = None
        #: the sender's numbers of the samples :meth:`rows` placed last
        self.numbers = np.zeros(0, np.int64)
        self._t0_s = 0.0  # the sender's phase (drone time of sample 0), s
        self._last_k: int | None = None
        self._numberer: RunNumberer | None = None
        self._last_tick = 0
        self._last_sample: np.ndarray | None = None  # acc, gyro and mag of the last sample
        self._ticks: deque[int] = deque(maxlen=TICKS_KEPT)
        self._numbers: deque[int] = deque(maxlen=TICKS_KEPT)
        self.rows_held = self.gaps = self.repeats = 0  #: rows held over lost samples, gaps, repeated reads
        #: (N, 3) magnetometer of the rows :meth:`rows` gave last, mgauss
        self.mag_mgauss = np.zeros((0, 3), np.float32)

    def add(self, frames: list) -> None:
        """Motion frames in arrival order; None where the link was lost and found again."""
        self._pending.extend(frames)

    @property
    def dt_s(self) -> float | None:
        """The estimators' dt once the cadence is found."""
        return None if self._cadence is None else self._cadence.interval_s

    def rows(self, final: bool = False) -> AttitudeArrays | None:
        """The rows of the samples pending (None: held until the cadence is found, or none)."""
        if self._cadence is None and not self._ready(final):
            return None
        frames, self._pending = self._pending, []
        mo = [f for f in frames if f is not None]
        if self._cadence is None and mo:  # the first samples tell whether repeats are reads
            self.reads = repeats_are_reads([f.tick for f in mo], [f.repeat for f in mo], [f.t_host_s for f in mo])
        breaks, kept = [], []  # breaks: the kept samples that follow a reconnection
        for f in frames:
            if f is None:
                breaks.append(len(kept))
            elif self.reads and f.repeat:
                self.repeats += 1
            else:
                kept.append(f)
        if self._cadence is None and kept:
            self._lock(kept, breaks, len(mo) - len(kept))
        if not kept or self._cadence is None:
            return None
        return self._grid(kept, np.unique(np.asarray(breaks, dtype=np.int64)))

    def _ready(self, final: bool) -> bool:
        ticks = [f.tick for f in self._pending if f is not None]
        span_s = (ticks[-1] - ticks[0]) * TICK_S if len(ticks) >= 8 else 0.0
        return final or len(ticks) >= LOCK_SAMPLES or span_s >= LOCK_SPAN_S

    def _lock(self, kept: list, breaks: list[int], repeats: int) -> None:
        """The cadence of the first samples (``repeats`` reads left out) fixes dt and how samples are numbered."""
        ticks = np.array([f.tick for f in kept], np.int64)
        c = self.found = motion_cadence(ticks, repeats, breaks)
        if c is None:  # a single sample (or one tick): ST's step, as the stock firmware sends
            c = Cadence(STEADY, STEP_PERIOD_S, 0, 0, repeats, 0.0, True)
        self._cadence = c
        self._t0_s = sender_phase(ticks * TICK_S, c.interval_s) if c.kind != POLLED else 0.0
        self._numberer = RunNumberer(c.interval_s / TICK_S)

    def _grid(self, mo: list, breaks: np.ndarray) -> AttitudeArrays:
        """This round's rows: one per sender sample since the last round's (a lost one holds the last sample)."""
        c, n = self._cadence, len(mo)
        tick = np.array([f.tick for f in mo], np.int64)
        t_fw = tick * TICK_S
        dt = c.interval_s
        if not c.exact and c.kind != POLLED:  # the period measured so far (its precision grows with the span)
            dt = self._period_s()
            self._numberer.p = dt / TICK_S
        first = self._last_k is None
        if c.kind == POLLED:
            k = np.arange(n, dtype=np.int64) + (0 if first else self._last_k + 1)
        elif c.exact:  # ST's step, known exactly: the smallest numbering the ticks' phase allows
            k = sample_numbers(tick, dt, self._t0_s, None if first else self._last_k)
        else:
            k = self._numberer.numbers(tick)
        self.numbers = k
        self._ticks.extend(tick.tolist())
        self._numbers.extend(k.tolist())
        prev = k[0] - 1 if first else self._last_k
        grid = np.arange(prev + 1, k[-1] + 1)
        before = np.concatenate([[prev], k[:-1]])
        for b in breaks[breaks < n].tolist():
            grid = grid[(grid <= before[b]) | (grid >= k[b])]  # never sent: the link was down
        src = np.searchsorted(k, grid, side="right") - 1  # the last sample received at or before each row
        sensors = np.array([(*f.acc_mg, *f.gyro_mdps, *f.mag_mgauss) for f in mo], np.float32).reshape(-1, 9)
        rows = sensors[np.maximum(src, 0)]  # acc, gyro, mag
        rows[src < 0] = self._last_sample  # rows before this round's first sample: held from the last round's
        self.rows_held += len(grid) - n
        if c.kind != POLLED:
            d = np.diff(tick, prepend=tick[0] if first else self._last_tick)
            gap = gap_mask(np.maximum(d, 0), dt / TICK_S)
            gap[breaks[breaks < n]] = False
            self.gaps += int(np.count_nonzero(gap))
        t_rows = t_fw + TICK_S / 2 if c.kind == POLLED else self._t0_s + grid * dt
        host = np.array([f.t_host_s for f in mo], np.float64)
        t_host = np.interp(t_rows, t_fw, host) if n > 1 else np.full(len(grid), host[0])
        self._last_k, self._last_tick, self._last_sample = int(k[-1]), int(tick[-1]), sensors[-1]
        self.mag_mgauss = rows[:, 6:]
        acc, gyro, ang = rows[:, :3], rows[:, 3:6], np.full((len(rows), 3), np.nan, np.float32)
        if self.layout.sends_attitude:  # angles in the acc fields; no sensor values: the estimators skip the rows
            acc, gyro, ang = ang, ang.copy(), acc / np.float32(self.layout.angle_scale)
        k_rows = grid if c.kind != POLLED else k
        return AttitudeArrays.of(k_rows, t_rows, t_host, acc, gyro, ang, values_bad=np.zeros(len(acc), bool))

    def _period_s(self) -> float:
        """The sender's interval so far, s: the ticks' least-squares slope on their numbers, or the cadence's own."""
        if len(self._numbers) > LOCK_SAMPLES and self._numbers[-1] - self._numbers[0] > 1:
            k = np.asarray(self._numbers, dtype=np.float64)
            return float(np.polyfit(k, np.asarray(self._ticks, dtype=np.float64), 1)[0]) * TICK_S
        return self._cadence.interval_s

    def cadence(self) -> Cadence | None:
        """The cadence as found so far: the kind from the first samples and the rows held since, the interval
        measured over the motion ticks kept (ST's step exactly when the stream runs at it; a poller's mean)."""
        c = self._cadence
        if c is None:
            return None
        ticks = self._ticks
        span_s = (ticks[-1] - ticks[0]) * TICK_S if len(ticks) > 1 else c.span_s
        if c.exact:
            interval = c.interval_s
        elif c.kind == POLLED:
            interval = span_s / (len(ticks) - 1) if len(ticks) > 1 and span_s > 0 else c.interval_s
        else:
            interval = self._period_s()
        kind = POLLED if c.kind == POLLED else STEADY if not self.rows_held else CONGESTION if c.exact else GAPS
        gaps = self.gaps if self.rows_held else 0
        held = self.rows_held
        return replace(c, kind=kind, interval_s=interval, dropped=held, gaps=gaps, repeats=self.repeats, span_s=span_s)

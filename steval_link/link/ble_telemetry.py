"""A BLE capture's notifications as arrays with units in the names (:class:`BleTelemetry`,
:func:`decode_notifications`), and its motion samples on a uniform time grid for the estimators
(:func:`uniform_inputs`: dt from the cadence found, :mod:`steval_link.link.ble_cadence`).

Payloads and ticks: :mod:`steval_link.link.ble_payloads`. Pure functions and small classes over numpy arrays; no I/O.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from steval_link.link.ble_cadence import (
    CONGESTION,
    GAPS,
    POLLED,
    STEADY,
    STEP_PERIOD_S,
    Cadence,
    RunNumberer,
    break_mask,
    cadence_numbers,
    gap_mask,
    motion_cadence,
    repeats_are_reads,
    sender_phase,
)
from steval_link.link.ble_payloads import (
    TICK_S,
    BleArmingFrame,
    BleConsoleFrame,
    BleDecoder,
    BleEnvFrame,
    BleLayout,
    BleMotionFrame,
)
from steval_link.link.telemetry import AttitudeArrays

__all__ = [
    "NOT_BIT_EXACT",
    "EULER_NOTE",
    "link_notes",
    "BleTelemetry",
    "decode_notifications",
    "UniformInputs",
    "uniform_inputs",
    "motion_payload_note",
    "attitude_rows",
    "layout_rows",
    "LiveGrid",
]


NOT_BIT_EXACT = (
    "BLE data: the drone's own attitude is not sent over BLE, and the host filters run on single ISR "
    "samples (before the firmware's gyro IIR filter and 5-sample boxcar) with dt from the cadence of "
    "the 8 ms ticks, "
    "so the ST-Mahony port cannot be bit-exact with the firmware here; the angles are the host "
    "estimators' own."
)
EULER_NOTE = (
    "BLE data in the euler layout: the motion notifications carry the drone's own attitude (its Euler angles, as "
    "its firmware sent them), shown as the firmware's; they carry no sensor values, so the host estimators have no "
    "input."
)


def link_notes(acc_mg, layout: BleLayout) -> list[str]:
    """What a BLE stream's rows are, said once: the euler layout's note, or the stock layout's (the drone's attitude
    is not sent) and, when its acc fields cannot be an accelerometer's, that sentence too."""
    if layout.sends_attitude:
        return [EULER_NOTE]
    other = motion_payload_note(acc_mg, layout)
    return [other] if other else [NOT_BIT_EXACT]


@dataclass
class BleTelemetry:
    """Every notification of a BLE capture as arrays (units in the names). ``t_fw_s`` = unwrapped tick × 8 ms
    (the drone's clock, 8 ms resolution); ``t_host_s`` = arrival, s since the capture started."""

    motion_t_host_s: np.ndarray
    motion_tick: np.ndarray  #: (N,) int64, unwrapped
    motion_t_fw_s: np.ndarray
    acc_mg: np.ndarray  #: (N,3) float32
    gyro_mdps: np.ndarray  #: (N,3) float32 (payload × 100)
    mag_mgauss: np.ndarray  #: (N,3) float32
    env_t_host_s: np.ndarray
    env_t_fw_s: np.ndarray
    pressure_hpa: np.ndarray
    battery_pct: np.ndarray
    temperature_c: np.ndarray
    rssi_dbm: np.ndarray
    arming_t_host_s: np.ndarray
    arming_t_fw_s: np.ndarray
    armed: np.ndarray
    console: list[tuple[float, str, str]] = field(default_factory=list)  #: (t_host_s, "stdout"/"stderr", text)
    counts: dict[str, int] = field(default_factory=dict)  #: notifications per characteristic name
    bad_payloads: int = 0  #: notifications of the wrong length (skipped)
    unknown: int = 0  #: notifications of an unknown characteristic id (skipped)
    repeated_reads: int = 0  #: motion samples received again (same tick and payload: a read of an unchanged value)
    #: motion rows that are the first after a reconnection (the link was lost before them: the samples in between
    #: were never sent, so that gap is no drop); set from the capture's events (``analysis.ble.load_ble``)
    motion_breaks: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __len__(self) -> int:
        return len(self.motion_tick)

    def cadence(self) -> Cadence | None:
        """The motion stream's cadence (:func:`motion_cadence`), None below 2 samples."""
        return motion_cadence(self.motion_tick, self.repeated_reads, self.motion_breaks)

    @property
    def interval_s(self) -> float | None:
        c = self.cadence()
        return None if c is None else c.interval_s

    def dropped_estimate(self) -> int:
        """Motion samples missing between the first and the last (:attr:`Cadence.dropped`)."""
        c = self.cadence()
        return 0 if c is None else c.dropped

    def motion_table(self) -> dict[str, np.ndarray]:
        """One row per motion notification, for CSV/Parquet (env and arming values held from their last one)."""
        tab = {"t_host_s": self.motion_t_host_s, "tick": self.motion_tick, "t_fw_s": self.motion_t_fw_s}
        for name, arr in (("acc", self.acc_mg), ("gyro", self.gyro_mdps), ("mag", self.mag_mgauss)):
            unit = {"acc": "mg", "gyro": "mdps", "mag": "mgauss"}[name]
            for i, ax in enumerate("xyz"):
                tab[f"{name}_{ax}_{unit}"] = arr[:, i]
        for key, t, v in (
            ("pressure_hpa", self.env_t_fw_s, self.pressure_hpa),
            ("battery_pct", self.env_t_fw_s, self.battery_pct),
            ("temperature_c", self.env_t_fw_s, self.temperature_c),
            ("rssi_dbm", self.env_t_fw_s, self.rssi_dbm),
            ("armed", self.arming_t_fw_s, self.armed.astype(np.float32)),
        ):
            tab[key] = _held(self.motion_t_fw_s, t, v)
        return tab


def _held(t_at: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` at each time of ``t_at``: its last value at or before it (NaN before the first)."""
    out = np.full(len(t_at), np.nan, dtype=np.float32)
    if len(t):
        i = np.searchsorted(t, t_at, side="right") - 1
        ok = i >= 0
        out[ok] = np.asarray(v, dtype=np.float32)[i[ok]]
    return out


def decode_notifications(records: Iterable[tuple[float, int, bytes]]) -> BleTelemetry:
    """``(t_host_s, char id, payload)`` in arrival order → :class:`BleTelemetry`, through the one notification
    decoder (:class:`~steval_link.link.ble_payloads.BleDecoder`). Wrong-length notifications are counted and skipped
    (never raise); a motion payload equal to the previous one is one sample read twice (``repeated_reads``) only
    when the stream is a poller's (:func:`~steval_link.link.ble_cadence.repeats_are_reads`), else a sample."""
    dec = BleDecoder()
    frames = [f for f in (dec.feed(c, p, t) for t, c, p in records) if f is not None]
    return telemetry_of_frames(frames, dec)


def telemetry_of_frames(frames: list, dec: BleDecoder) -> BleTelemetry:
    """The arrays of decoded BLE frames (the counters of their decoder ``dec``)."""
    mo = [f for f in frames if isinstance(f, BleMotionFrame)]
    en = [f for f in frames if isinstance(f, BleEnvFrame)]
    ar = [f for f in frames if isinstance(f, BleArmingFrame)]
    repeat = np.array([f.repeat for f in mo], dtype=bool)
    ticks = np.array([f.tick for f in mo], dtype=np.int64)
    reads = repeats_are_reads(ticks, repeat, [f.t_host_s for f in mo])
    if reads:
        mo = [f for f in mo if not f.repeat]
    m = np.array([(f.t_host_s, f.tick, *f.acc_mg, *f.gyro_mdps, *f.mag_mgauss) for f in mo], np.float64)
    m = m.reshape(-1, 11)
    e = np.array([(f.t_host_s, f.tick, f.pressure_hpa, f.battery_pct, f.temperature_c, f.rssi_dbm) for f in en])
    e = e.reshape(-1, 6)
    a = np.array([(f.t_host_s, f.tick, f.armed) for f in ar], np.float64).reshape(-1, 3)
    mtick = m[:, 1].astype(np.int64)
    return BleTelemetry(
        motion_t_host_s=m[:, 0].copy(),
        motion_tick=mtick,
        motion_t_fw_s=mtick * TICK_S,
        acc_mg=m[:, 2:5].astype(np.float32),
        gyro_mdps=m[:, 5:8].astype(np.float32),
        mag_mgauss=m[:, 8:11].astype(np.float32),
        env_t_host_s=e[:, 0].copy(),
        env_t_fw_s=e[:, 1] * TICK_S,
        pressure_hpa=e[:, 2].astype(np.float32),
        battery_pct=e[:, 3].astype(np.float32),
        temperature_c=e[:, 4].astype(np.float32),
        rssi_dbm=e[:, 5].astype(np.float32),
        arming_t_host_s=a[:, 0].copy(),
        arming_t_fw_s=a[:, 1] * TICK_S,
        armed=a[:, 2].astype(bool),
        console=[(f.t_host_s, f.stream, f.text) for f in frames if isinstance(f, BleConsoleFrame)],
        counts=dict(dec.counts),
        bad_payloads=dec.bad_payloads,
        unknown=dec.unknown,
        repeated_reads=int(repeat.sum()) if reads else 0,
    )


@dataclass
class UniformInputs:
    """Motion samples on a uniform time grid for the estimators (fixed dt = ``dt_s``)."""

    t_s: np.ndarray  #: (M,) firmware time of each row, s (from the ticks)
    acc_mg: np.ndarray  #: (M,3) float32
    gyro_mdps: np.ndarray  #: (M,3) float32
    filled: np.ndarray  #: (M,) bool: True for rows held over a dropped notification
    dt_s: float
    source_row: np.ndarray  #: (M,) int64: the motion notification each row holds
    cadence: Cadence | None = None  #: the cadence the grid follows


def uniform_inputs(ble: BleTelemetry, cadence: Cadence | None = None) -> UniformInputs:
    """The estimators' inputs with dt from the cadence found (:func:`motion_cadence`): one row per sender sample
    (:func:`cadence_numbers`); a dropped notification's row holds the last sample received. A steady or polled
    stream has one row per sample received and none held; the samples a lost link never sent
    (:attr:`BleTelemetry.motion_breaks`) have no rows (the estimators step once over that gap)."""
    n = len(ble)
    c = cadence if cadence is not None else ble.cadence()
    if n == 0 or c is None:
        z = np.zeros((n, 3), np.float32)
        return UniformInputs(
            ble.motion_t_fw_s.copy(),
            ble.acc_mg.copy() if n else z,
            ble.gyro_mdps.copy() if n else z,
            np.zeros(n, bool),
            0.0,
            np.arange(n),
            c,
        )
    dt = c.interval_s
    k = cadence_numbers(ble.motion_tick, c)
    rows = np.ones(k[-1] + 1, bool)
    for b in np.flatnonzero(break_mask(n, ble.motion_breaks)):
        rows[k[b - 1] + 1 : k[b]] = False  # never sent: the link was down
    numbers = np.flatnonzero(rows)
    src = np.searchsorted(k, numbers, side="right") - 1  # the last sample received at or before
    filled = np.ones(len(numbers), bool)
    filled[np.searchsorted(numbers, k)] = False
    if c.kind == POLLED:  # reads at the host's moments: each row at its own tick (mid-tick)
        t_grid = ble.motion_t_fw_s + TICK_S / 2
    else:
        t_grid = sender_phase(ble.motion_t_fw_s, dt) + numbers * dt
    return UniformInputs(t_grid, ble.acc_mg[src], ble.gyro_mdps[src], filled, float(dt), src, c)


def motion_payload_note(acc_mg, layout: BleLayout) -> str | None:
    """One sentence when the stock layout's acc fields cannot be an accelerometer's: hardly a sample near 1 g (a raw
    accelerometer reads about 1000 mg at rest, and near it most of a flight) and every value in an angle's range
    (rad x 1000, or degrees x 100); None when they can, or when the layout already says what they hold."""
    acc = np.asarray(acc_mg, dtype=np.float64).reshape(-1, 3)
    if layout.sends_attitude or len(acc) < 2:
        return None
    norm = np.linalg.norm(acc, axis=1)
    near_1g = float(np.mean(np.abs(norm - 1000.0) <= ONE_G_BAND_MG))
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
#: the largest field an angle ×scale reaches (degrees x 100: 18000)
ANGLE_RANGE_MAX = 18000.0


def layout_rows(acc_mg, gyro_mdps, layout: BleLayout):
    """(acc_mg, gyro_mdps, thx, thy, thz) of motion rows under ``layout``: the stock layout's sensors with no
    attitude (NaN); the euler layout's attitude (rad) with no sensor values (NaN: the estimators skip the rows)."""
    acc = np.asarray(acc_mg, dtype=np.float32).reshape(-1, 3)
    n = len(acc)
    nan = np.full(n, np.nan, np.float32)
    if not layout.sends_attitude:
        return acc, np.asarray(gyro_mdps, dtype=np.float32).reshape(-1, 3), nan, nan.copy(), nan.copy()
    ang = acc / np.float32(layout.angle_scale)
    none = np.full((n, 3), np.nan, np.float32)
    return none, none.copy(), ang[:, 0].copy(), ang[:, 1].copy(), ang[:, 2].copy()


def attitude_rows(t_fw_s, t_host_s, k, acc_mg, gyro_mdps, layout: BleLayout) -> AttitudeArrays:
    """The motion samples on the estimators' grid as the one attitude model (:class:`AttitudeArrays`): ``k`` the
    sender's sample numbers (``step``), no throttle, no firmware quaternion, rows not bit-exact (BLE carries no AHRS
    input); the firmware's angles only when the layout sends them."""
    acc, gyro, thx, thy, thz = layout_rows(acc_mg, gyro_mdps, layout)
    n = len(acc)
    k = np.asarray(k, dtype=np.int64)
    t_fw_s = np.asarray(t_fw_s, dtype=np.float64)
    return AttitudeArrays(
        step=k,
        seq=(k % (1 << 16)).astype(np.uint16),
        t_us=(np.round(t_fw_s * 1e6).astype(np.int64) % (1 << 32)).astype(np.uint32),
        t_fw_s=t_fw_s,
        t_host_s=np.asarray(t_host_s, dtype=np.float64),
        acc_mg=acc,
        gyro_mdps=gyro,
        thr=np.zeros(n, np.int16),
        q_wxyz=np.full((n, 4), np.nan, np.float32),
        thz_rad=thz,
        thx_rad=thx,
        thy_rad=thy,
        exact=np.zeros(n, bool),
        offset=np.full(n, -1, np.int64),
        values_bad=np.zeros(n, bool),
    )


#: motion samples that fix the cadence (and the estimators' dt) live; fewer when 3 s of drone time pass or at the end
LOCK_SAMPLES = 64
LOCK_SPAN_S = 3.0
#: motion ticks kept for the live interval (its precision grows with the span)
TICKS_KEPT = 20_000


class LiveGrid:
    """:func:`uniform_inputs` a round at a time (``steval live --ble``): motion frames → the rows of the sender's
    samples on one grid. The cadence is found from the first :data:`LOCK_SAMPLES` samples (until then
    :meth:`rows` holds them back), which fixes dt and the numbering (a replay's, :func:`cadence_numbers`): one row
    per sender sample, a row held over a notification only when the ticks show it was sent and lost; a repeat is
    a read (one sample) or a sample of its own as :func:`repeats_are_reads` finds on the first samples."""

    def __init__(self, layout: BleLayout) -> None:
        self.layout = layout
        self._pending: list = []  # motion frames (or None: a reconnection) before the cadence is found
        self._cadence: Cadence | None = None
        self._reads = False  # repeats are reads of one sample
        self._t0_s = 0.0  # the sender's phase (drone time of sample 0), s
        self._last_k: int | None = None
        self._numberer: RunNumberer | None = None
        self._last_tick = 0
        self._last_sample: tuple[np.ndarray, np.ndarray] | None = None
        self._ticks: deque[int] = deque(maxlen=TICKS_KEPT)
        self._numbers: deque[int] = deque(maxlen=TICKS_KEPT)
        self.rows_held = 0
        self.gaps = 0
        self.repeats = 0
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
        if self._cadence is None:
            self._lock(frames)
        breaks, kept = [], []
        for f in frames:
            if f is None:
                breaks.append(len(kept))
            elif self._reads and f.repeat:
                self.repeats += 1
            else:
                kept.append(f)
        if not kept or self._cadence is None:
            return None
        return self._grid(kept, np.unique(np.asarray(breaks, dtype=np.int64)))

    def _ready(self, final: bool) -> bool:
        ticks = [f.tick for f in self._pending if f is not None]
        if final or len(ticks) >= LOCK_SAMPLES:
            return True
        return len(ticks) >= 8 and (ticks[-1] - ticks[0]) * TICK_S >= LOCK_SPAN_S

    def _lock(self, frames: list) -> None:
        """The cadence of the first samples fixes dt and how samples are numbered."""
        mo = [f for f in frames if f is not None]
        if not mo:
            return
        rep = np.array([f.repeat for f in mo], bool)
        ticks = np.array([f.tick for f in mo], np.int64)
        self._reads = repeats_are_reads(ticks, rep, [f.t_host_s for f in mo])
        keep = ~rep if self._reads else np.ones(len(mo), bool)
        brk, i = [], 0  # the kept samples that follow a reconnection
        for f in frames:
            if f is None:
                brk.append(i)
            elif not (self._reads and f.repeat):
                i += 1
        c = motion_cadence(ticks[keep], int((~keep).sum()), brk)
        if c is None:  # a single sample (or one tick): ST's step, as the stock firmware sends
            c = Cadence(STEADY, STEP_PERIOD_S, 0, 0, int((~keep).sum()), 0.0, True)
        self._cadence = c
        t = ticks[keep] * TICK_S
        self._t0_s = sender_phase(t, c.interval_s) if c.kind != POLLED else 0.0
        self._numberer = RunNumberer(c.interval_s / TICK_S)

    def _grid(self, mo: list, breaks: np.ndarray) -> AttitudeArrays:
        """This round's rows: one per sender sample since the last round's; a row of a notification the ticks show
        as sent and lost holds the last sample (numbering as :func:`cadence_numbers`, a round at a time)."""
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
            lo = np.ceil((t_fw - self._t0_s) / dt - 1e-9).astype(np.int64)
            if first:
                lo[0] = 0
            prev, j = -1 if first else self._last_k, np.arange(n)
            k = np.maximum.accumulate(np.maximum(lo, prev + 1 + j) - j) + j
        else:
            k = self._numberer.numbers(tick)
        self._ticks.extend(tick.tolist())
        self._numbers.extend(k.tolist())
        prev = k[0] - 1 if first else self._last_k
        grid = np.arange(prev + 1, k[-1] + 1)
        before = np.concatenate([[prev], k[:-1]])
        for b in breaks[breaks < n].tolist():
            grid = grid[(grid <= before[b]) | (grid >= k[b])]  # never sent: the link was down
        src = np.searchsorted(k, grid, side="right") - 1  # the last sample received at or before each row
        acc = np.array([f.acc_mg for f in mo], np.float32).reshape(-1, 3)
        gyro = np.array([f.gyro_mdps for f in mo], np.float32).reshape(-1, 3)
        mag = np.array([f.mag_mgauss for f in mo], np.float32).reshape(-1, 3)
        acc_rows, gyro_rows, mag_rows = acc[np.maximum(src, 0)], gyro[np.maximum(src, 0)], mag[np.maximum(src, 0)]
        if (src < 0).any():  # rows before this round's first sample: held from the last round's
            acc_rows[src < 0], gyro_rows[src < 0], mag_rows[src < 0] = self._last_sample
        self.rows_held += len(grid) - n
        if c.kind != POLLED:
            d = np.diff(tick, prepend=tick[0] if first else self._last_tick)
            gap = gap_mask(np.maximum(d, 0), dt / TICK_S)
            gap[breaks[breaks < n]] = False
            self.gaps += int(np.count_nonzero(gap))
        t_rows = t_fw + TICK_S / 2 if c.kind == POLLED else self._t0_s + grid * dt
        host = np.array([f.t_host_s for f in mo], np.float64)
        t_host = np.interp(t_rows, t_fw, host) if n > 1 else np.full(len(grid), host[0])
        self._last_k, self._last_tick = int(k[-1]), int(tick[-1])
        self._last_sample = (acc[-1], gyro[-1], mag[-1])
        self.mag_mgauss = mag_rows
        return attitude_rows(t_rows, t_host, grid if c.kind != POLLED else k, acc_rows, gyro_rows, self.layout)

    def _period_s(self) -> float:
        """The sender's interval measured so far, s: the least-squares slope of the ticks kept against their sample
        numbers once they span more than the samples that found the cadence; until then the cadence's own."""
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

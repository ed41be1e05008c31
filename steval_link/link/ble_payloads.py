"""The BLE notifications of ST's stock firmware (release 170120, ``Src/sensor_service.c``): UUIDs, payload layouts,
decoding into arrays with units in the names, tick unwrapping, the motion stream's cadence (the sender's own rate,
ST's congestion skips, gaps, or a poller's reads: :func:`motion_cadence`) with its dropped notifications, and the
uniform estimator inputs (dt from the cadence found).

What the unmodified drone sends while a central is connected (from the main loop, once per AHRS step for each
characteristic, skipping 30 motion updates after a failed one: ``ACC_BLUENRG_CONGESTION``):

=========== ======================================== ===== ==================================================
char id     characteristic (UUID)                    bytes layout (little endian)
=========== ======================================== ===== ==================================================
1 motion    ``00e00000-0001-11e1-ac36-0002a5d5c51b`` 20    u16 tick, acc i16×3 mg, gyro i16×3 mdps/100, mag
                                                           i16×3 mgauss
2 env       ``001d0000-0001-11e1-ac36-0002a5d5c51b`` 12    u16 tick, i32 pressure hPa×100, u16 battery ‰,
                                                           i16 temperature 0.1 °C, i16 RSSI dBm×10
3 arming    ``20000000-0001-11e1-ac36-0002a5d5c51b`` 3     u16 tick, u8 armed
4 stdout    ``00000001-000e-11e1-ac36-0002a5d5c51b`` ≤20   console text
5 stderr    ``00000002-000e-11e1-ac36-0002a5d5c51b`` ≤20   console text
=========== ======================================== ===== ==================================================

The tick is ``HAL_GetTick() >> 3``: 8 ms units, wrapping every 2^16 ticks (524.288 s). The motion sample is the
ISR's last single sample after offset removal (acc z keeps +1000 mg), *before* the gyro IIR filter and the 5-sample
boxcar, so it is not the AHRS input: a host port of the firmware's filter cannot be bit-exact on BLE data.
(The ST app labels the environment's battery and RSSI as BlueST "temperature/humidity" bits; the firmware sends
battery = VBAT·100/4.2 in ‰ clipped to 1000 and RSSI·10.)

Pure functions and small classes over numpy arrays; no I/O.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from steval_link.constants import AHRS_PERIOD_S
from steval_link.link.capture import CHUNK_BLE

__all__ = [
    "SERVICE_UUID",
    "CHAR_UUIDS",
    "CHAR_NAMES",
    "CHAR_MOTION",
    "CHAR_ENV",
    "CHAR_ARMING",
    "CHAR_STDOUT",
    "CHAR_STDERR",
    "DEVICE_NAME_PREFIX",
    "TICK_S",
    "TICK_WRAP",
    "char_id_of_uuid",
    "MotionSample",
    "EnvSample",
    "decode_motion",
    "decode_env",
    "decode_arming",
    "unwrap_ticks",
    "TickUnwrapper",
    "BleTelemetry",
    "decode_notifications",
    "nominal_interval_s",
    "uniform_inputs",
    "UniformInputs",
    "BadPayload",
    "ble_records",
    "is_ble_source",
    "ble_chunk",
    "sample_numbers",
    "STEP_PERIOD_S",
    "Cadence",
    "motion_cadence",
    "period_ticks",
    "cadence_numbers",
    "gap_mask",
    "RunNumberer",
    "STEADY",
    "CONGESTION",
    "GAPS",
    "POLLED",
]

#: the HW sensor service of ST's firmware (BlueST)
SERVICE_UUID = "00000000-0001-11e1-9ab4-0002a5d5c51b"
CHAR_MOTION, CHAR_ENV, CHAR_ARMING, CHAR_STDOUT, CHAR_STDERR = 1, 2, 3, 4, 5
#: characteristic id (the capture's ``B`` chunk byte) → UUID
CHAR_UUIDS: dict[int, str] = {
    CHAR_MOTION: "00e00000-0001-11e1-ac36-0002a5d5c51b",
    CHAR_ENV: "001d0000-0001-11e1-ac36-0002a5d5c51b",
    CHAR_ARMING: "20000000-0001-11e1-ac36-0002a5d5c51b",
    CHAR_STDOUT: "00000001-000e-11e1-ac36-0002a5d5c51b",
    CHAR_STDERR: "00000002-000e-11e1-ac36-0002a5d5c51b",
}
CHAR_NAMES: dict[int, str] = {
    CHAR_MOTION: "motion",
    CHAR_ENV: "environment",
    CHAR_ARMING: "arming",
    CHAR_STDOUT: "stdout",
    CHAR_STDERR: "stderr",
}
#: the firmware advertises "DRN1" + its version digits (release 170120: "DRN1110")
DEVICE_NAME_PREFIX = "DRN1"
#: one tick of ``HAL_GetTick() >> 3``, s
TICK_S = 0.008
TICK_WRAP = 1 << 16

_MOTION = struct.Struct("<H3h3h3h")
_ENV = struct.Struct("<HiHhh")
_ARMING = struct.Struct("<HB")
MOTION_BYTES, ENV_BYTES, ARMING_BYTES = _MOTION.size, _ENV.size, _ARMING.size


class BadPayload(ValueError):
    """A notification whose length does not match its characteristic."""


def char_id_of_uuid(uuid: str) -> int | None:
    """The characteristic id of a UUID (any case), None for one this tool does not read."""
    u = str(uuid).lower()
    for k, v in CHAR_UUIDS.items():
        if v == u:
            return k
    return None


@dataclass(frozen=True, slots=True)
class MotionSample:
    tick: int
    acc_mg: tuple[int, int, int]
    gyro_mdps: tuple[int, int, int]  #: the payload's mdps/100 × 100 (the firmware truncates toward zero)
    mag_mgauss: tuple[int, int, int]


@dataclass(frozen=True, slots=True)
class EnvSample:
    tick: int
    pressure_hpa: float
    battery_pct: float
    temperature_c: float
    rssi_dbm: float


def _check(payload: bytes, n: int, what: str) -> None:
    if len(payload) != n:
        raise BadPayload(f"{what} notification of {len(payload)} bytes (expected {n})")


def decode_motion(payload: bytes) -> MotionSample:
    """One AccGyroMag notification (20 bytes)."""
    _check(payload, MOTION_BYTES, "motion")
    v = _MOTION.unpack(payload)
    return MotionSample(v[0], v[1:4], (v[4] * 100, v[5] * 100, v[6] * 100), v[7:10])


def decode_env(payload: bytes) -> EnvSample:
    """One environment notification (12 bytes)."""
    _check(payload, ENV_BYTES, "environment")
    tick, p, b, t, r = _ENV.unpack(payload)
    return EnvSample(tick, p / 100.0, b / 10.0, t / 10.0, r / 10.0)


def decode_arming(payload: bytes) -> tuple[int, bool]:
    """One arming notification (3 bytes): (tick, armed)."""
    _check(payload, ARMING_BYTES, "arming")
    tick, armed = _ARMING.unpack(payload)
    return tick, bool(armed)


def unwrap_ticks(ticks, t_host_s=None) -> np.ndarray:
    """u16 ticks → int64 ticks since the first wrap-free start. Consecutive ticks step forward modulo 2^16; with
    host times, a gap longer than a wrap period (524 s, e.g. a long disconnect) adds the whole wraps the host clock
    says passed."""
    t = np.asarray(ticks, dtype=np.int64) & 0xFFFF
    if t.size == 0:
        return t
    d = np.diff(t) % TICK_WRAP
    # a small step backwards (samples of the same connection event delivered out of order) stays backwards
    d = np.where(d > TICK_WRAP - 256, d - TICK_WRAP, d)
    if t_host_s is not None:
        h = np.diff(np.asarray(t_host_s, dtype=np.float64))
        period = TICK_WRAP * TICK_S
        extra = np.round((np.nan_to_num(h, nan=0.0) - d * TICK_S) / period)
        d = d + np.maximum(extra, 0).astype(np.int64) * TICK_WRAP
    return t[0] + np.concatenate([[0], np.cumsum(d)])


class TickUnwrapper:
    """The live counterpart of :func:`unwrap_ticks`: one u16 tick at a time."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.value = 0

    def __call__(self, tick: int, dt_host_s: float | None = None) -> int:
        tick &= 0xFFFF
        if self.last is None:
            self.value = tick
        else:
            d = (tick - self.last) % TICK_WRAP
            if d > TICK_WRAP - 256:
                d -= TICK_WRAP
            if dt_host_s is not None and dt_host_s == dt_host_s:
                d += max(0, round((dt_host_s - d * TICK_S) / (TICK_WRAP * TICK_S))) * TICK_WRAP
            self.value += d
        self.last = tick
        return self.value


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


def ble_chunk(char_id: int, payload: bytes) -> bytes:
    """The payload of a capture's ``B`` chunk: the characteristic id, then the notification's bytes."""
    return bytes([char_id]) + bytes(payload)


def ble_records(chunks: dict[int, list[tuple[float, bytes]]]) -> list[tuple[float, int, bytes]]:
    """``(t_host_s, char id, payload)`` of a capture's ``B`` chunks (``Capture.chunks`` / ``Source.chunks``)."""
    return [(t, p[0], p[1:]) for t, p in chunks.get(CHUNK_BLE, []) if p]


def is_ble_source(src) -> bool:
    """A capture recorded over BLE (``B`` chunks, or ``extra.link`` = "ble" in its header)."""
    chunks = getattr(src, "chunks", None) or {}
    extra = (getattr(src, "header", None) or {}).get("extra") or {}
    return bool(chunks.get(CHUNK_BLE)) or (isinstance(extra, dict) and extra.get("link") == "ble")


def decode_notifications(records: Iterable[tuple[float, int, bytes]]) -> BleTelemetry:
    """``(t_host_s, char id, payload)`` in arrival order → :class:`BleTelemetry`. Wrong-length notifications are
    counted and skipped (never raise); a motion payload equal to the previous one (same tick, same values: a poller
    reading an unchanged characteristic) is one sample, counted in ``repeated_reads``."""
    mo: list[tuple] = []
    en: list[tuple] = []
    ar: list[tuple] = []
    console: list[tuple[float, str, str]] = []
    counts = {n: 0 for n in CHAR_NAMES.values()}
    bad = unknown = repeated = 0
    last_motion = None
    for t, cid, payload in records:
        name = CHAR_NAMES.get(cid)
        if name is None:
            unknown += 1
            continue
        counts[name] += 1
        try:
            if cid == CHAR_MOTION:
                _check(payload, MOTION_BYTES, "motion")
                if bytes(payload) == last_motion:  # the same sample read again (same tick and values)
                    repeated += 1
                    continue
                last_motion = bytes(payload)
                mo.append((t, *_MOTION.unpack(payload)))
            elif cid == CHAR_ENV:
                _check(payload, ENV_BYTES, "environment")
                en.append((t, *_ENV.unpack(payload)))
            elif cid == CHAR_ARMING:
                _check(payload, ARMING_BYTES, "arming")
                ar.append((t, *_ARMING.unpack(payload)))
            else:
                console.append((t, name, bytes(payload).decode("utf-8", "replace")))
        except BadPayload:
            bad += 1
    m = np.array(mo, dtype=np.float64).reshape(-1, 11)
    e = np.array(en, dtype=np.float64).reshape(-1, 6)
    a = np.array(ar, dtype=np.float64).reshape(-1, 3)
    # one clock for all three: the ticks of every characteristic unwrapped together, in arrival order
    order = [(r[0], k, j) for k, rows in enumerate((mo, en, ar)) for j, r in enumerate(rows)]
    order.sort(key=lambda x: x[0])  # stable: arrival order kept for equal host times
    rows_of = (m, e, a)
    all_ticks = np.array([rows_of[k][j, 1] for _, k, j in order], dtype=np.int64)
    all_t = np.array([t for t, _, _ in order], dtype=np.float64)
    unwrapped = unwrap_ticks(all_ticks, all_t) if len(order) else np.zeros(0, np.int64)
    ticks_of: list[np.ndarray] = [np.zeros(len(r), np.int64) for r in rows_of]
    for (_, k, j), u in zip(order, unwrapped):
        ticks_of[k][j] = u
    mtick = ticks_of[0]

    return BleTelemetry(
        motion_t_host_s=m[:, 0].copy(),
        motion_tick=mtick,
        motion_t_fw_s=mtick * TICK_S,
        acc_mg=m[:, 2:5].astype(np.float32),
        gyro_mdps=(m[:, 5:8] * 100).astype(np.float32),
        mag_mgauss=m[:, 8:11].astype(np.float32),
        env_t_host_s=e[:, 0].copy(),
        env_t_fw_s=ticks_of[1] * TICK_S,
        pressure_hpa=(e[:, 2] / 100).astype(np.float32),
        battery_pct=(e[:, 3] / 10).astype(np.float32),
        temperature_c=(e[:, 4] / 10).astype(np.float32),
        rssi_dbm=(e[:, 5] / 10).astype(np.float32),
        arming_t_host_s=a[:, 0].copy(),
        arming_t_fw_s=ticks_of[2] * TICK_S,
        armed=a[:, 2].astype(bool),
        console=console,
        counts=counts,
        bad_payloads=bad,
        unknown=unknown,
        repeated_reads=repeated,
    )


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
    """The motion stream's cadence found in its ticks (:func:`motion_cadence`).

    ``kind``: ``steady`` (one interval throughout: the sender's own rate, nothing dropped), ``congestion`` (ST's
    AHRS step period with notifications missing: the stock firmware skipping updates while the radio is full),
    ``gaps`` (another cadence with gaps of its own: only those count as dropped), ``polled`` (the same sample
    received twice: reads of the characteristic, not notifications; nothing is dropped).
    """

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
        """One phrase for the summary and the health line, e.g. "motion every 20.0 ms (50.0 Hz, the sender's own
        rate), 0 dropped" or "motion every 6.19 ms (161.54 Hz) with 1 212 dropped in 40 gaps (congestion ...)"."""
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
    """Tick deltas that are gaps: at least 1.5 periods beyond one tick of quantisation (and beyond one period's
    own spread, a tick either side)."""
    return (d_ticks >= GAP_PERIODS * period_ticks + 1) & (d_ticks > np.floor(period_ticks) + 1)


def period_ticks(d_ticks) -> float | None:
    """The sender's period in ticks from consecutive tick deltas: the mean of the deltas that are not gaps.

    Start from the bulk (deltas within one tick above the median: the quantisation of one period gives its floor or
    its ceiling), then drop the gaps (:func:`gap_mask`) and iterate. The mean of a run's deltas telescopes to the
    run's span, so it is not biased by the 8 ms quantisation. None when every delta is 0 or there is none."""
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


def _break_mask(n: int, breaks) -> np.ndarray:
    """(n,) bool: True at the samples that follow a reconnection (never the first)."""
    m = np.zeros(n, bool)
    b = np.asarray(breaks, dtype=np.int64).reshape(-1)
    b = b[(b > 0) & (b < n)]
    m[b] = True
    return m


def motion_cadence(ticks, repeats: int = 0, breaks=()) -> Cadence | None:
    """The cadence of a motion stream from its unwrapped ticks (8 ms units, one per distinct sample, in order), the
    count of repeated samples already removed (:attr:`BleTelemetry.repeated_reads`) and the samples that are the
    first after a reconnection (``breaks``, indices: the gap before them is no drop, nothing was sent). None below
    2 samples or when all share one tick.

    - Period: :func:`period_ticks`; within :data:`STEP_SNAP` of ST's AHRS step it is that step (exact); any other
      is refined by a least-squares fit of the ticks against the sample numbers (precise over the whole span).
    - Gaps: deltas of 1.5 periods or more plus the tick's quantisation (:func:`gap_mask`).
    - ``polled`` when samples came twice (repeats) and the period is at least a tick: reads, nothing dropped; the
      interval is the mean over the whole span.
    - At ST's step: the missing notifications from the ticks' phase (:func:`sample_numbers`, sub-tick precise, so
      single drops count too); ``congestion`` if any, else ``steady``.
    - Any other period: each gap's missing samples from the phases of the runs either side (:class:`RunNumberer`);
      ``gaps`` if any, else ``steady`` (the sender's own rate: a jittered delta of a tick or two is not a drop).
    """
    t = np.asarray(ticks, dtype=np.int64)
    n = len(t)
    if n < 2 or t[-1] <= t[0]:
        return None
    d = np.diff(t)
    brk = _break_mask(n, breaks)
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
        k = _run_numbers(t, p)
        for _ in range(2):  # the period from all samples at their numbers (least squares): precise over the span
            fit = float(np.polyfit(k, t + 0.5, 1)[0]) if k[-1] > 1 else p
            if not abs(fit - p) < 0.05 * p or fit == p:
                break
            p = fit
            k = _run_numbers(t, p)
        interval = p * TICK_S
    jump = np.diff(k) - 1
    dropped = int(jump[~brk[1:]].sum())
    gaps = int(np.count_nonzero(gap_mask(np.maximum(d, 0), p) & ~brk[1:])) if dropped else 0
    kind = STEADY if not dropped else CONGESTION if exact else GAPS
    return Cadence(kind, interval, dropped, gaps, int(repeats), span_s, exact)


class RunNumberer:
    """The sender's sample numbers of a stream with gaps, in batches of ticks (the whole capture for a replay, a
    round at a time live): the rule of :func:`cadence_numbers` for any period but ST's step.

    Samples between gaps (:func:`gap_mask`) are consecutive: a run. A run's phase, the mean of tick + ½ − i·period
    over its samples, smooths out the 8 ms quantisation and the sender's own jitter (a main loop that cannot hit the
    period exactly); a run after a gap starts at the number the two runs' phases say, so a gap counts the periods
    that really passed (a single tick delta is blurred by up to two ticks). Live, the run after a gap is known only
    as far as the batch goes."""

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


def _run_numbers(ticks, period_ticks: float) -> np.ndarray:
    return RunNumberer(period_ticks).numbers(ticks)


def cadence_numbers(ticks, cadence: Cadence | None) -> np.ndarray:
    """The sender's sample number of each received sample (0 for the first) under ``cadence``: consecutive for
    reads; at ST's step from the ticks' phase (:func:`sample_numbers`); otherwise from the phase of each run between
    gaps (:class:`RunNumberer`). (A steady stream's numbers are consecutive but across a reconnection.)"""
    t = np.asarray(ticks, dtype=np.int64)
    n = len(t)
    if cadence is None or cadence.kind == POLLED or n < 2:
        return np.arange(n, dtype=np.int64)
    if cadence.exact:
        return sample_numbers(t, cadence.interval_s)
    return _run_numbers(t, cadence.interval_s / TICK_S)


def nominal_interval_s(ticks, repeats: int = 0) -> float | None:
    """The sender's interval between motion samples, s (:func:`motion_cadence`); None below 2 samples."""
    c = motion_cadence(ticks, repeats)
    return None if c is None else c.interval_s


def _phase(t: np.ndarray, interval: float) -> float:
    """The sender's clock phase t0 (sample k at ``t0 + k·interval``) from the first 64 samples, taken as
    consecutive: the intersection of the intervals [tick, tick + 8 ms) that their ticks allow."""
    w = min(len(t), 64)
    i = np.arange(w)
    lo, hi = float(np.max(t[:w] - i * interval)), float(np.min(t[:w] + TICK_S - i * interval))
    return (lo + hi) / 2 if lo < hi else float(t[0]) + TICK_S / 2


def sample_numbers(ticks, interval: float) -> np.ndarray:
    """The sender's sample number of each received notification (0 for the first): the smallest increasing
    numbering that the ticks allow, so a drop is placed where the ticks first prove it (within a sample or two)."""
    t = np.asarray(ticks, dtype=np.float64) * TICK_S
    if len(t) == 0:
        return np.zeros(0, np.int64)
    t0 = _phase(t, interval)
    lo = np.ceil((t - t0) / interval - 1e-9).astype(np.int64)
    lo[0] = 0
    # k_i = max(k_{i-1} + 1, lo_i): with j_i = k_i - i, j is the running maximum of lo_i - i
    return np.maximum.accumulate(lo - np.arange(len(t))) + np.arange(len(t))


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
    for b in np.flatnonzero(_break_mask(n, ble.motion_breaks)):
        rows[k[b - 1] + 1 : k[b]] = False  # never sent: the link was down
    numbers = np.flatnonzero(rows)
    src = np.searchsorted(k, numbers, side="right") - 1  # the last sample received at or before
    filled = np.ones(len(numbers), bool)
    filled[np.searchsorted(numbers, k)] = False
    if c.kind == POLLED:  # reads at the host's moments: each row at its own tick (mid-tick)
        t_grid = ble.motion_t_fw_s + TICK_S / 2
    else:
        t_grid = _phase(ble.motion_t_fw_s, dt) + numbers * dt
    return UniformInputs(t_grid, ble.acc_mg[src], ble.gyro_mdps[src], filled, float(dt), src, c)

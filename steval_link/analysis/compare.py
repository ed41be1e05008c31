"""``steval compare``: how the firmware's own angles compare with the Python port, the EKFs and accelerometer tilt.

One capture in, one :class:`ComparisonReport` out (ETH lecture 4, exercise 8 and the EKF project):

* **ST-Mahony port** — the bit-exact port re-run over the capture's inputs
  (:func:`steval_link.estimators.st_mahony.replay_firmware`): it starts at power-up (a capture from step 0) or from
  the filter-state snapshot of a status frame, and restarts from the next snapshot after any dropped frame. The
  report counts bit-exact steps, names the first step that differs and *diagnoses* it: the port is re-run from the
  same seed with alternative settings (the other normalisation variant, KI 1.0, no correction, kp variants,
  dt = 1/161.5 s, the firmware defaults) and the one that reproduces the firmware is named; a mismatch right after
  dropped frames, or one nothing explains, is called out as such.
* **Other estimators** (``ekf3``, ``mekf``, ``accel`` by default) run from power-up over the same inputs.

Every trace is compared with the firmware's ``thx`` (pitch, about x) and ``thy`` (roll, about y): RMS and max |Δ|
in degrees, angle differences wrapped to ±180°. Firmware NaN rows (``asin`` out of range at extreme rates) are
counted and excluded, never fatal. Rate, jitter, drop, CRC and AHRS-cycle statistics and the filter settings from
the status frames complete the report.

Text-mode captures carry rounded angles and inputs and no quaternion: the port cannot be bit-exact there, so
it is not run; the firmware's angles are compared with the other estimators only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from itertools import combinations
from types import SimpleNamespace
from typing import Any, Sequence

import numpy as np

from steval_link import constants as C
from steval_link.estimators.runner import row_decimation, run_estimator
from steval_link.estimators.st_mahony import (
    FirmwareReplay,
    MahonySettings,
    MahonyState,
    bits_equal,
    replay_firmware,
)
from steval_link.estimators.st_mahony import (
    run as mahony_run,
)
from steval_link.link import protocol as P

__all__ = [
    "DEFAULT_COMPARE_ESTIMATORS",
    "PORT_TRACE",
    "AngleStats",
    "TraceComparison",
    "PortComparison",
    "RateStats",
    "ComparisonReport",
    "compare_capture",
    "format_report",
    "angle_diff_rad",
]

#: Estimators ``steval compare`` runs next to the port by default (missing ones are reported, not fatal).
DEFAULT_COMPARE_ESTIMATORS: tuple[str, ...] = ("ekf3", "mekf", "accel")

#: Trace name of the seeded port (``st-mahony`` is the registry estimator run from power-up, if requested).
PORT_TRACE = "st-mahony-port"

#: Rows after the first mismatch over which an alternative setting must reproduce the firmware to be named.
DIAGNOSIS_WINDOW_ROWS = 600

_LABELS = {
    "st-mahony-port": "ST-Mahony port",
    "st-mahony": "ST-Mahony from power-up",
    "accel": "accel-only tilt",
    "ekf3": "EKF (3-state)",
    "mekf": "MEKF",
    "vqf": "VQF",
}

_DT_REAL_S = float(np.float32(1.0 / 161.5))


def angle_diff_rad(a, b) -> np.ndarray:
    """``a − b`` wrapped to [−π, π), float64 (so 179° vs −179° is 2°, not 358°); NaN where either is NaN."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    return (d + math.pi) % (2.0 * math.pi) - math.pi


def _num(x) -> float | None:
    """JSON-friendly float: None for NaN/inf."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class AngleStats:
    """Differences of one angle against the firmware's, in degrees, over ``n`` rows where both are finite."""

    n: int
    rms_deg: float
    max_abs_deg: float
    mean_deg: float

    @classmethod
    def of(cls, diff_rad: np.ndarray) -> AngleStats:
        d = np.degrees(diff_rad[np.isfinite(diff_rad)])
        if d.size == 0:
            return cls(0, math.nan, math.nan, math.nan)
        return cls(int(d.size), float(np.sqrt(np.mean(d * d))), float(np.max(np.abs(d))), float(np.mean(d)))

    def as_dict(self) -> dict[str, Any]:
        return {"n": self.n, "rms_deg": _num(self.rms_deg), "max_abs_deg": _num(self.max_abs_deg),
                "mean_deg": _num(self.mean_deg)}


@dataclass(frozen=True)
class TraceComparison:
    """One estimator's angles against the firmware's.

    Attributes:
        name: registry name (``st-mahony`` for the seeded port).
        label: human-readable name.
        available: False when the estimator could not run here (``note`` says why); the stats are then empty.
        pitch: differences of thx (about x), degrees. roll: differences of thy (about y), degrees.
        n_invalid: rows the estimator flagged invalid (or did not cover, e.g. port rows before a seed); excluded.
        note: why it is unavailable, or a remark about the trace.
    """

    name: str
    label: str
    available: bool
    pitch: AngleStats
    roll: AngleStats
    n_invalid: int = 0
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "label": self.label, "available": self.available,
                "pitch_thx": self.pitch.as_dict(), "roll_thy": self.roll.as_dict(),
                "n_invalid": self.n_invalid, "note": self.note}


@dataclass(frozen=True)
class PortComparison:
    """The bit-exact port against the firmware.

    Attributes:
        rows: attitude rows considered (binary rows only). seeded: rows where the port had a known state.
        bit_exact: seeded rows whose q, thx and thy carry the firmware's exact bits.
        seeds: every (re)start: ``{"row", "step", "source" ("power-up"|"status"), "status_row"}``.
        first_mismatch: ``{"row", "step", "t_fw_s", "t_rel_s"}`` of the first seeded row that differs, or None.
        settings: the settings the port used (from the status frames, or overridden, or the defaults).
        diagnosis: sentences saying why the port disagrees (empty when it agrees).
        matching_variant: the alternative settings that reproduce the firmware (dict of the changed fields), or None.
        matching_bit_exact: with ``matching_variant``, bit-exact rows over the whole capture.
        unseeded_reason: why no row could be seeded (None when some were).
    """

    rows: int
    seeded: int
    bit_exact: int
    seeds: list[dict[str, Any]]
    first_mismatch: dict[str, Any] | None
    settings: dict[str, Any]
    diagnosis: list[str] = field(default_factory=list)
    matching_variant: dict[str, Any] | None = None
    matching_bit_exact: int | None = None
    unseeded_reason: str | None = None

    @property
    def all_exact(self) -> bool:
        return self.seeded > 0 and self.first_mismatch is None

    def as_dict(self) -> dict[str, Any]:
        return {
            "rows": self.rows,
            "seeded_steps": self.seeded,
            "bit_exact_steps": self.bit_exact,
            "all_exact": self.all_exact,
            "seeds": self.seeds,
            "first_mismatch": self.first_mismatch,
            "settings": self.settings,
            "diagnosis": self.diagnosis,
            "matching_variant": self.matching_variant,
            "matching_bit_exact_steps": self.matching_bit_exact,
            "unseeded_reason": self.unseeded_reason,
        }


@dataclass(frozen=True)
class RateStats:
    """Timing and link health of a capture.

    Attributes:
        duration_s: firmware time covered by the attitude rows (sum over stretches between firmware restarts).
        rate_hz: attitude rows per second. step_rate_hz: AHRS steps per second (161.5 Hz on the drone).
        period_mean_ms, period_std_ms, period_p99_ms, period_max_ms: Δt_fw between consecutive AHRS steps, ms
            (rows whose step advanced by one).
        seq_gaps, frames_missing: attitude frames lost on the way (decoder). tx_dropped: frames the firmware's
            TX queue could not take (last status frame; None without status frames). crc_failures: damaged frames.
        ahrs_cycles_min/mean/max, cpu_hz: ``ahrs_fusion_ag`` cost from the status frames (None without them);
            ``ahrs_us_*`` the same in µs at ``cpu_hz``.
    """

    duration_s: float
    rate_hz: float | None
    step_rate_hz: float | None
    period_mean_ms: float | None
    period_std_ms: float | None
    period_p99_ms: float | None
    period_max_ms: float | None
    seq_gaps: int
    frames_missing: int
    seq_resets: int
    tx_dropped: int | None
    crc_failures: int
    bytes_skipped: int
    ahrs_cycles_min: int | None = None
    ahrs_cycles_mean: float | None = None
    ahrs_cycles_max: int | None = None
    cpu_hz: int | None = None

    def _us(self, cycles) -> float | None:
        if cycles is None or not self.cpu_hz:
            return None
        return float(cycles) / self.cpu_hz * 1e6

    @property
    def ahrs_us_min(self) -> float | None:
        return self._us(self.ahrs_cycles_min)

    @property
    def ahrs_us_mean(self) -> float | None:
        return self._us(self.ahrs_cycles_mean)

    @property
    def ahrs_us_max(self) -> float | None:
        return self._us(self.ahrs_cycles_max)

    def as_dict(self) -> dict[str, Any]:
        out = {k: (_num(v) if isinstance(v, float) else v) for k, v in self.__dict__.items()}
        out.update(ahrs_us_min=_num(self.ahrs_us_min), ahrs_us_mean=_num(self.ahrs_us_mean),
                   ahrs_us_max=_num(self.ahrs_us_max))
        return out


@dataclass
class ComparisonReport:
    """Everything ``steval compare`` reports about one capture (``as_dict()`` is its ``--json`` output).

    The arrays behind the numbers (``t_rel_s``, the port replay, every estimator's estimate) are kept for plots
    (:func:`steval_link.analysis.plots.plot_comparison`) but are not part of ``as_dict()``.
    """

    source: dict[str, Any]
    rows: int
    binary_rows: int
    text_rows: int
    firmware_nan_pitch: int
    firmware_nan_roll: int
    rates: RateStats
    filter_settings: dict[str, Any] | None
    port: PortComparison | None
    traces: list[TraceComparison]
    notes: list[str] = field(default_factory=list)
    # arrays for plots (not serialised)
    t_rel_s: np.ndarray = field(default=None, repr=False)
    replay: FirmwareReplay | None = field(default=None, repr=False)
    port_rows: np.ndarray | None = field(default=None, repr=False)
    estimates: dict[str, Any] = field(default_factory=dict, repr=False)

    def trace(self, name: str) -> TraceComparison | None:
        return next((t for t in self.traces if t.name == name), None)

    def as_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "rows": {"attitude": self.rows, "binary": self.binary_rows, "text_mode": self.text_rows},
            "firmware_nan_steps": {"pitch_thx": self.firmware_nan_pitch, "roll_thy": self.firmware_nan_roll},
            "rates": self.rates.as_dict(),
            "filter_settings": self.filter_settings,
            "port": None if self.port is None else self.port.as_dict(),
            "traces": [t.as_dict() for t in self.traces],
            "notes": list(self.notes),
        }


# ----------------------------------------------------------------------------------------------- statistics


def _restart_mask(step: np.ndarray) -> np.ndarray:
    """(N-1,) True where the step counter did not advance (firmware restart)."""
    return np.diff(step) <= 0 if step.size > 1 else np.zeros(0, bool)


def relative_time_s(step, t_fw_s) -> np.ndarray:
    """Firmware time since the first row, s, kept increasing across firmware restarts (each restart continues one
    AHRS period after the last row before it) so plots never run backwards."""
    t = np.asarray(t_fw_s, dtype=np.float64)
    if t.size == 0:
        return t
    dt = np.diff(t)
    bad = (np.diff(np.asarray(step, dtype=np.int64)) <= 0) | ~np.isfinite(dt) | (dt < 0)
    if bad.any():
        dt = np.where(bad, C.AHRS_PERIOD_S, dt)
    return np.concatenate([[0.0], np.cumsum(dt)])


def rate_stats(tel) -> RateStats:
    """Rate, period jitter, drops, CRC failures and AHRS cycles of a telemetry (see :class:`RateStats`)."""
    a, s, st = tel.attitude, tel.status, tel.stats
    n = len(a)
    step = np.asarray(a.step, dtype=np.int64)
    t = np.asarray(a.t_fw_s, dtype=np.float64)
    restart = _restart_mask(step)
    dt = np.diff(t) if n > 1 else np.zeros(0)
    dstep = np.diff(step) if n > 1 else np.zeros(0, np.int64)
    ok = ~restart & np.isfinite(dt) & (dt >= 0)
    duration = float(np.sum(dt[ok])) if n > 1 else 0.0
    steps = float(np.sum(dstep[ok])) if n > 1 else 0.0
    per = dt[ok & (dstep == 1)] * 1e3
    if per.size == 0 and ok.any():  # text mode sends every k-th step: per-step period of each row pair
        per = (dt[ok] / dstep[ok]) * 1e3
    kw: dict[str, Any] = {}
    if len(s):
        n_cyc = np.asarray(s.cyc_n, dtype=np.float64)
        have = n_cyc > 0
        if have.any():
            kw["ahrs_cycles_min"] = int(np.min(s.cyc_min[have]))
            kw["ahrs_cycles_max"] = int(np.max(s.cyc_max[have]))
            kw["ahrs_cycles_mean"] = float(np.sum(s.cyc_mean[have] * n_cyc[have]) / np.sum(n_cyc[have]))
        elif np.any(s.cyc_mean > 0):
            kw["ahrs_cycles_min"] = int(np.min(s.cyc_min))
            kw["ahrs_cycles_max"] = int(np.max(s.cyc_max))
            kw["ahrs_cycles_mean"] = float(np.mean(s.cyc_mean))
        cpu = np.asarray(s.cpu_hz)[np.asarray(s.exact, bool)] if np.any(s.exact) else np.zeros(0)
        cpu = cpu[cpu > 0]
        kw["cpu_hz"] = int(cpu[-1]) if cpu.size else (C.CPU_HZ if kw.get("ahrs_cycles_mean") else None)
    return RateStats(
        duration_s=duration,
        rate_hz=(int(np.count_nonzero(ok)) / duration) if duration > 0 else None,
        step_rate_hz=(steps / duration) if duration > 0 and steps > 0 else None,
        period_mean_ms=float(np.mean(per)) if per.size else None,
        period_std_ms=float(np.std(per)) if per.size > 1 else None,
        period_p99_ms=float(np.percentile(per, 99)) if per.size else None,
        period_max_ms=float(np.max(per)) if per.size else None,
        seq_gaps=int(st.seq_gaps),
        frames_missing=int(st.frames_missing),
        seq_resets=int(getattr(st, "seq_resets", 0)),
        tx_dropped=int(s.tx_dropped[-1]) if len(s) else None,
        crc_failures=int(st.crc_failures),
        bytes_skipped=int(st.bytes_skipped),
        **kw,
    )


def _settings_dict(s: MahonySettings) -> dict[str, Any]:
    return {
        "kp_ground": float(np.float32(s.kp_ground)),
        "kp_flight": float(np.float32(s.kp_flight)),
        "ki": float(np.float32(s.ki)),
        "dt_s": float(np.float32(s.dt_s)),
        "min_thr": s.min_thr,
        "correction": s.correction,
        "fresh_squares": s.fresh_squares,
    }


def _same_settings(a: MahonySettings, b: MahonySettings) -> bool:
    return _settings_dict(a) == _settings_dict(b)


def _status_settings_list(status) -> list[MahonySettings]:
    out = []
    for j in range(len(status.ki)):
        out.append(
            MahonySettings.from_status(
                kp_ground=status.kp_ground[j], kp_flight=status.kp_flight[j], ki=status.ki[j],
                dt_s=status.dt_s[j], min_thr=status.min_thr[j], flags=status.flags[j],
            )
        )
    return out


def filter_settings_report(tel) -> dict[str, Any] | None:
    """The filter settings the (binary) status frames report, compared with the 170120 defaults; None without
    binary status frames. Text-mode status lines carry only KI and the flags (``ki`` and ``flags``)."""
    s = tel.status
    ex = np.asarray(s.exact, bool) if len(s) else np.zeros(0, bool)
    if len(s) and not ex.any():
        ki = float(s.ki[-1])
        return {"from": "text-mode status lines", "ki": _num(ki), "flags": int(s.flags[-1]),
                "differs_from_defaults": {} if not math.isfinite(ki) or np.float32(ki) == np.float32(C.KI)
                else {"ki": [_num(ki), C.KI]}, "changes": 0}
    if not ex.any():
        return None
    rows = np.flatnonzero(ex)
    settings = _status_settings_list(SimpleNamespace(**{k: np.asarray(getattr(s, k))[rows] for k in (
        "kp_ground", "kp_flight", "ki", "dt_s", "min_thr", "flags")}))
    last = settings[-1]
    d = _settings_dict(last)
    defaults = _settings_dict(MahonySettings())
    changes = sum(1 for x, y in zip(settings[:-1], settings[1:]) if not _same_settings(x, y))
    return {
        "from": "status frames",
        "status_frames": int(rows.size),
        **d,
        "flags": int(s.flags[rows[-1]]),
        "differs_from_defaults": {k: [d[k], defaults[k]] for k in d if d[k] != defaults[k]},
        "changes": changes,
    }


# ----------------------------------------------------------------------------------------------- the port


def _binary_view(tel):
    """Attitude and status rows of binary frames only (what the port can be compared with bit for bit)."""
    a, s = tel.attitude, tel.status
    rows = np.flatnonzero(np.asarray(a.exact, bool))
    srows = np.flatnonzero(np.asarray(s.exact, bool)) if len(s) else np.zeros(0, np.int64)
    att = SimpleNamespace(**{k: np.asarray(getattr(a, k))[rows] for k in (
        "step", "acc_mg", "gyro_mdps", "thr", "q_wxyz", "thx_rad", "thy_rad", "t_fw_s")})
    sta = SimpleNamespace(**{k: np.asarray(getattr(s, k))[srows] for k in (
        "step", "q_wxyz", "int_xyz", "kp_ground", "kp_flight", "ki", "dt_s", "min_thr", "flags")})
    return SimpleNamespace(attitude=att, status=sta), rows


def _describe_variant(changes: dict[str, Any], base: MahonySettings) -> str:
    """A sentence naming the firmware build that ``changes`` (field → value) describe."""
    parts = []
    for k, v in changes.items():
        if k == "ki":
            parts.append(f"KI={v:g}: was the firmware built with AHRS_KI={v:g}f (ETH exercise 4)?")
        elif k == "correction":
            parts.append("no accelerometer correction (g* = g): was the correction commented out (ETH exercise 5)?"
                         if not v else "the accelerometer correction on, though the status frames say it is off")
        elif k == "fresh_squares":
            parts.append("normalisation with the fresh squares of the updated quaternion: is this an older (2017) "
                         "ST firmware release?" if v else
                         "normalisation with the squares from before the update (release 170120)")
        elif k == "kp":
            kg, kf = v
            parts.append(f"kp_ground={kg:g}, kp_flight={kf:g} (status/default {base.kp_ground:g}, "
                         f"{base.kp_flight:g}): were AHRS_KP_BIG/AHRS_KP_NORM changed?")
        elif k == "dt_s":
            parts.append(f"dt={v:.7g} s (status/default {base.dt_s:g} s): was SENSOR_SAMPLING_TIME changed to the "
                         "real main-loop period?")
        elif k == "min_thr":
            parts.append(f"MIN_THR={v} (status/default {base.min_thr}): was the gain-switch threshold changed?")
        elif k == "defaults":
            parts.append("the firmware's default settings: the status frames report settings the filter does not "
                         "use (or the port was given other settings)")
    return "; ".join(parts)


def _cli_flags(s: MahonySettings, base: MahonySettings) -> str:
    """``steval compare`` options that run the port with ``s`` when the status frames report ``base``."""
    out = []
    for name, opt in (("ki", "--ki"), ("kp_ground", "--kp-ground"), ("kp_flight", "--kp-flight"), ("dt_s", "--dt")):
        if np.float32(getattr(s, name)) != np.float32(getattr(base, name)):
            out.append(f"{opt} {getattr(s, name):.9g}")
    if s.min_thr != base.min_thr:
        out.append(f"--min-thr {s.min_thr}")
    if s.correction != base.correction:
        out.append("--correction" if s.correction else "--no-correction")
    if s.fresh_squares != base.fresh_squares:
        out.append("--fresh-squares" if s.fresh_squares else "--stale-squares")
    return " ".join(out)


def _variants(base: MahonySettings) -> list[tuple[dict[str, Any], MahonySettings]]:
    """Single-change alternatives to ``base`` the diagnosis tries, most common student edits first."""
    out: list[tuple[dict[str, Any], MahonySettings]] = []

    def add(changes: dict[str, Any], s: MahonySettings) -> None:
        if not _same_settings(s, base) and not any(_same_settings(s, o) for _, o in out):
            out.append((changes, s))

    defaults = MahonySettings()
    add({"defaults": True}, defaults)
    for ki in (1.0, C.KI, 0.0):
        add({"ki": ki}, replace(base, ki=ki))
    add({"correction": not base.correction}, replace(base, correction=not base.correction))
    add({"fresh_squares": not base.fresh_squares}, replace(base, fresh_squares=not base.fresh_squares))
    for dt in (_DT_REAL_S, float(np.float32(C.AHRS_PERIOD_S)), C.DT_S):
        add({"dt_s": dt}, replace(base, dt_s=dt))
    kps = [(base.kp_flight, base.kp_flight), (base.kp_ground, base.kp_ground), (base.kp_flight, base.kp_ground),
           (C.KP_GROUND, C.KP_FLIGHT)]
    for kg, kf in kps:
        add({"kp": (kg, kf)}, replace(base, kp_ground=kg, kp_flight=kf))
    add({"min_thr": C.MIN_THR}, replace(base, min_thr=C.MIN_THR))
    return out


def _combine(a: tuple[dict, MahonySettings], b: tuple[dict, MahonySettings], base: MahonySettings):
    """Both changes at once (None when they touch the same field or either is 'defaults')."""
    ca, cb = a[0], b[0]
    if "defaults" in ca or "defaults" in cb or set(ca) & set(cb):
        return None
    s = base
    for ch in (ca, cb):
        for k, v in ch.items():
            s = replace(s, kp_ground=v[0], kp_flight=v[1]) if k == "kp" else replace(s, **{k: v})
    return {**ca, **cb}, s


def _window_exact(view, seed_state: MahonyState, settings: MahonySettings, r0: int, r1: int) -> int:
    """Rows from ``r0`` (the seed row) that the port reproduces bit for bit in a row, up to ``r1`` (exclusive)."""
    a = view.attitude
    q, thx, thy, _ = mahony_run(a.acc_mg[r0:r1], a.gyro_mdps[r0:r1], a.thr[r0:r1], settings=settings,
                                state=seed_state)
    ok = bits_equal(q, a.q_wxyz[r0:r1]).all(axis=1) & bits_equal(thx, a.thx_rad[r0:r1]) & bits_equal(
        thy, a.thy_rad[r0:r1])
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if bad.size else r1 - r0


def _seed_state(view, seed) -> MahonyState:
    if seed.source == "status":
        s = view.status
        return MahonyState(q_wxyz=s.q_wxyz[seed.status_row], int_xyz=s.int_xyz[seed.status_row])
    return MahonyState()


def _diagnose(
    view, rep: FirmwareReplay, settings_override: MahonySettings | None, stats
) -> tuple[list[str], dict | None, int | None, MahonySettings | None]:
    """Why the port disagrees: (sentences, matching variant, its bit-exact rows over the capture, its settings)."""
    a = view.attitude
    steps = a.step
    n = steps.size
    m = rep.first_mismatch
    seed = max((s for s in rep.seeds if s.row <= m), key=lambda s: s.row)
    breaks = np.flatnonzero(np.diff(steps) != 1) + 1
    seg_end = int(breaks[np.searchsorted(breaks, m, side="right")]) if np.any(breaks > m) else n
    r1 = min(seg_end, m + DIAGNOSIS_WINDOW_ROWS)
    base = seed.settings
    # candidates start from the last snapshot before the mismatch (the port was exact up to there), else the seed
    r0, state = seed.row, _seed_state(view, seed)
    st_steps = np.asarray(view.status.step, dtype=np.int64)
    k = np.flatnonzero((st_steps >= steps[seed.row]) & (st_steps < steps[m]))
    if k.size:
        j = int(k[np.argmax(st_steps[k])])
        r0 = seed.row + int(st_steps[j]) + 1 - int(steps[seed.row])
        state = MahonyState(q_wxyz=view.status.q_wxyz[j], int_xyz=view.status.int_xyz[j])
    need = r1 - r0
    lines: list[str] = []

    candidates = _variants(base)
    found = None
    for ch, s in candidates:
        if _window_exact(view, state, s, r0, r1) == need:
            found = (ch, s)
            break
    if found is None:
        singles = [c for c in candidates if "defaults" not in c[0]]
        for x, y in combinations(singles, 2):
            c = _combine(x, y, base)
            if c is not None and _window_exact(view, state, c[1], r0, r1) == need:
                found = c
                break
    if found is not None:
        ch, s = found
        full = replay_firmware(view, settings=s)
        lines.append(f"the capture matches {_describe_variant(ch, base)}")
        flags = _cli_flags(s, _status_base(view) or MahonySettings())
        how = f" (steval compare CAPTURE {flags})" if flags else ""
        if full.all_exact:
            lines.append(f"with these settings the port is bit-exact on all {full.n_seeded} seeded steps{how}")
        else:
            lines.append(f"with these settings the port is bit-exact on {full.n_bit_exact} of {full.n_seeded} "
                         f"seeded steps{how}")
        variant = {k: (list(v) if isinstance(v, tuple) else v) for k, v in ch.items()}
        if settings_override is not None and _same_settings(s, _status_base(view)):
            lines.append("these are the settings the status frames report: the --settings override is wrong")
        return lines, variant, full.n_bit_exact, s

    seg_start = int(breaks[np.searchsorted(breaks, seed.row, side="right") - 1]) if np.any(breaks <= seed.row) else 0
    at_restart = seed.source == "status" and m - seed.row < 2
    if at_restart:
        snap = int(view.status.step[seed.status_row])
        if seg_start > 0:
            lines.append(f"frames were dropped before that point (seq gap at step {int(steps[seg_start - 1])}→"
                         f"{int(steps[seg_start])}); the port restarted there from the status snapshot of step "
                         f"{snap}, which does not reproduce the next step")
        else:
            lines.append(f"the port started from the status snapshot of step {snap}, which does not reproduce the "
                         "next step")
        lines.extend(_snapshot_check(view, seed.status_row) or [
            "the snapshot and the attitude frames may not belong together (firmware-side race, or a damaged frame)"])
    if int(stats.crc_failures) > 0 or int(stats.bytes_skipped) > 0:
        lines.append(f"the stream had {int(stats.crc_failures)} CRC failures and {int(stats.bytes_skipped)} skipped "
                     "bytes: damaged frames are dropped, but a corrupted frame that passes its CRC would also do this")
    # a one-off disturbance or a different filter? Restart from the next snapshot after the mismatch.
    st = view.status
    k = np.flatnonzero((st.step >= steps[m]) & (st.step < steps[seg_end - 1]))
    if k.size:
        j = int(k[np.argmin(st.step[k])])
        r0 = m + int(st.step[j]) + 1 - int(steps[m])
        if r0 < seg_end:
            rr1 = min(seg_end, r0 + DIAGNOSIS_WINDOW_ROWS)
            good = _window_exact(view, MahonyState(q_wxyz=st.q_wxyz[j], int_xyz=st.int_xyz[j]), base, r0, rr1)
            if good == rr1 - r0:
                lines.append(f"restarted from the next status snapshot (step {int(st.step[j])}) the port agrees "
                             f"again for {good} steps: a one-off disturbance around step {int(steps[m])} rather "
                             "than a different filter")
                return lines, None, None, None
    if not at_restart:
        lines.append("no known setting reproduces it (tried: firmware defaults, KI 1.0/0.1/0, correction on/off, "
                     "both normalisation variants, dt 1/161.5 s and 5/807.7 s, kp variants, MIN_THR 200, and pairs "
                     "of these): unknown firmware variant — was ahrs.c or QuaternionToEuler modified, or the "
                     "firmware built with other compiler options (FMA, -O2 reordering)?")
    return lines, None, None, None


def _snapshot_check(view, j: int) -> list[str]:
    """Is status snapshot ``j`` consistent with the attitude frame of its own step? (q must be the same bits.)"""
    st, a = view.status, view.attitude
    snap = int(st.step[j])
    r = np.flatnonzero(a.step == snap)
    if r.size == 0:
        return []
    same_q = bool(bits_equal(st.q_wxyz[j], a.q_wxyz[r[0]]).all())
    ints = ", ".join(f"{float(v):.6g}" for v in st.int_xyz[j])
    if same_q:
        return [f"the snapshot of step {snap} carries the same q as that step's attitude frame, so its integral "
                f"terms exInt/eyInt/ezInt ({ints}) must be wrong: does the firmware (or the tool that wrote the "
                "capture) report the integrals of that step?"]
    return [f"the snapshot of step {snap} does not carry the q of that step's attitude frame: the snapshot was "
            "taken at another step (race between the AHRS step and the status frame in the firmware)"]


def _status_base(view) -> MahonySettings | None:
    s = view.status
    if s.step.size == 0:
        return None
    j = int(np.argmin(s.step))
    return MahonySettings.from_status(kp_ground=s.kp_ground[j], kp_flight=s.kp_flight[j], ki=s.ki[j],
                                      dt_s=s.dt_s[j], min_thr=s.min_thr[j], flags=s.flags[j])


def compare_port(
    tel, settings: MahonySettings | None = None
) -> tuple[PortComparison | None, FirmwareReplay | None, np.ndarray | None]:
    """The seeded port against the firmware's binary rows: (report, replay over the binary rows, those rows'
    indices into ``tel.attitude``); (None, None, None) when the capture has no binary attitude row."""
    view, rows = _binary_view(tel)
    if rows.size == 0:
        return None, None, None
    a = view.attitude
    rep = replay_firmware(view, settings=settings)
    used = settings
    if used is None:
        used = rep.seeds[0].settings if rep.seeds else (_status_base(view) or MahonySettings())
    seeds = [{"row": int(rows[s.row]), "step": s.step, "source": s.source,
              "status_row": None if s.status_row is None else int(s.status_row)} for s in rep.seeds]
    first = None
    diagnosis: list[str] = []
    variant = None
    variant_exact = None
    unseeded = None
    if rep.n_seeded == 0:
        if view.status.step.size == 0:
            unseeded = ("the capture does not start at step 0 (power-up) and has no status frame with a filter "
                        "snapshot, so the port has no state to start from")
        else:
            unseeded = ("no status snapshot falls inside a run of consecutive steps, so the port has no state to "
                        "start from")
    if rep.first_mismatch is not None:
        m = rep.first_mismatch
        t_rel = relative_time_s(tel.attitude.step, tel.attitude.t_fw_s)
        first = {"row": int(rows[m]), "step": int(a.step[m]), "t_fw_s": float(a.t_fw_s[m]),
                 "t_rel_s": float(t_rel[rows[m]])}
        diagnosis, variant, variant_exact, _ = _diagnose(view, rep, settings, tel.stats)
    return (
        PortComparison(
            rows=int(rows.size),
            seeded=rep.n_seeded,
            bit_exact=rep.n_bit_exact,
            seeds=seeds,
            first_mismatch=first,
            settings=_settings_dict(used),
            diagnosis=diagnosis,
            matching_variant=variant,
            matching_bit_exact=variant_exact,
            unseeded_reason=unseeded,
        ),
        rep,
        rows,
    )


# ----------------------------------------------------------------------------------------------- traces


def _trace(name: str, label: str, thx, thy, valid, fw_thx, fw_thy, note: str = "") -> TraceComparison:
    thx = np.asarray(thx, dtype=np.float64)
    thy = np.asarray(thy, dtype=np.float64)
    valid = np.asarray(valid, bool) & np.isfinite(thx) & np.isfinite(thy)
    dx = np.where(valid, angle_diff_rad(thx, fw_thx), np.nan)
    dy = np.where(valid, angle_diff_rad(thy, fw_thy), np.nan)
    return TraceComparison(name, label, True, AngleStats.of(dx), AngleStats.of(dy), int(np.count_nonzero(~valid)),
                           note)


def _unavailable(name: str, note: str) -> TraceComparison:
    empty = AngleStats(0, math.nan, math.nan, math.nan)
    return TraceComparison(name, _LABELS.get(name, name), False, empty, empty, 0, note)


def _link_notes(tel) -> list[str]:
    """A hint when the firmware's TX queue dropped frames because the baud rate cannot carry the stream."""
    s = tel.status
    if not len(s) or int(s.tx_dropped[-1]) == 0:
        return []
    ex = np.flatnonzero(np.asarray(s.exact, bool))
    baud = int(s.baud[ex[-1]]) if ex.size else 0
    if not baud:
        baud = int(((tel.source or {}).get("header") or {}).get("baud") or 0)
    need = P.ATTITUDE_FRAME_SIZE * 10 * C.AHRS_RATE_HZ + P.STATUS_FRAME_SIZE * 10
    dropped = int(s.tx_dropped[-1])
    if baud and baud < need:
        return [f"the firmware's TX queue dropped {dropped} frames: at {baud} baud the link carries at most "
                f"{baud / (10 * P.ATTITUDE_FRAME_SIZE):.0f} attitude frames/s of the {C.AHRS_RATE_HZ:.1f} the AHRS "
                f"makes (≥ {need:,.0f} baud needed; the patch's default is 115200)"]
    return [f"the firmware's TX queue dropped {dropped} frames since power-up (queue full: bursts of text or "
            "status frames); frames dropped before the capture started count too"]


def compare_capture(
    tel,
    estimators: Sequence[str] = DEFAULT_COMPARE_ESTIMATORS,
    settings: MahonySettings | None = None,
) -> ComparisonReport:
    """Compare a capture's firmware angles with the seeded ST-Mahony port and with ``estimators``.

    Args:
        tel: a :class:`steval_link.link.telemetry.Telemetry` with at least one attitude row.
        estimators: registry names run from power-up over the capture's inputs (``st-mahony`` here means the
            unseeded port from power-up; the seeded port is always compared). Names this installation lacks are
            reported as unavailable.
        settings: filter settings for the port (default: those of the status frames, else the firmware's).

    Returns:
        A :class:`ComparisonReport`; angles in the report are degrees, thx = pitch (about x), thy = roll (about y).

    Raises:
        ValueError: the telemetry has no attitude row.
    """
    a = tel.attitude
    n = len(a)
    if n == 0:
        raise ValueError("the capture has no attitude frames")
    fw_thx = np.asarray(a.thx_rad, dtype=np.float64)
    fw_thy = np.asarray(a.thy_rad, dtype=np.float64)
    exact = np.asarray(a.exact, bool)
    notes: list[str] = []
    traces: list[TraceComparison] = []

    port, rep, prow = compare_port(tel, settings)
    if port is not None:
        thx = np.full(n, np.nan)
        thy = np.full(n, np.nan)
        thx[prow] = rep.thx_rad
        thy[prow] = rep.thy_rad
        valid = np.zeros(n, bool)
        valid[prow] = rep.seeded
        note = "bit-exact" if port.all_exact else ("not seeded" if port.seeded == 0 else "")
        traces.append(_trace(PORT_TRACE, "ST-Mahony port", thx, thy, valid, fw_thx, fw_thy, note))
    if (~exact).any():
        notes.append(
            f"{int((~exact).sum())} text-mode rows: their angles and inputs are rounded and carry no quaternion, so "
            "the port cannot be bit-exact there; firmware angles are compared with the other estimators only"
        )
        if port is None:
            traces.append(_unavailable(PORT_TRACE, "text-mode capture: the bit-exact port needs binary frames"))

    estimates: dict[str, Any] = {}
    decimation = row_decimation(tel)
    for name in estimators:
        est, why = run_estimator(name, tel, decimation=decimation)
        if est is None:
            traces.append(_unavailable(name, why))
            continue
        estimates[name] = est
        label = _LABELS.get(name, name)
        traces.append(_trace(name, label, est.thx_rad, est.thy_rad, est.valid, fw_thx, fw_thy, why))

    notes.extend(_link_notes(tel))
    nan_x = int(np.count_nonzero(~np.isfinite(fw_thx)))
    nan_y = int(np.count_nonzero(~np.isfinite(fw_thy)))
    if nan_x or nan_y:
        notes.append(f"firmware NaN steps: {nan_x} pitch, {nan_y} roll (asin out of range at extreme rates); "
                     "excluded from the statistics")
    src = tel.source or {}
    return ComparisonReport(
        source={"path": src.get("path"), "kind": src.get("kind")},
        rows=n,
        binary_rows=int(exact.sum()),
        text_rows=int((~exact).sum()),
        firmware_nan_pitch=nan_x,
        firmware_nan_roll=nan_y,
        rates=rate_stats(tel),
        filter_settings=filter_settings_report(tel),
        port=port,
        traces=traces,
        notes=notes,
        t_rel_s=relative_time_s(a.step, a.t_fw_s),
        replay=rep,
        port_rows=prow,
        estimates=estimates,
    )


# ----------------------------------------------------------------------------------------------- text output


def _f(x, fmt: str = ".4f", none: str = "n/a") -> str:
    return none if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def format_report(r: ComparisonReport) -> list[str]:
    """Human-readable lines of a :class:`ComparisonReport` (plain text, aligned)."""
    lines: list[str] = []
    rt = r.rates
    kind = r.source.get("kind") or "telemetry"
    rows = f"{r.rows} attitude rows" + (f" ({r.text_rows} text-mode)" if r.text_rows else "")
    lines.append(f"capture: {r.source.get('path')} ({kind}), {rows}, {rt.duration_s:.2f} s of firmware time")
    rate = f"{rt.rate_hz:.2f} Hz" if rt.rate_hz else "n/a"
    if rt.step_rate_hz and rt.rate_hz and abs(rt.step_rate_hz - rt.rate_hz) > 0.01 * rt.rate_hz:
        rate += f" (AHRS steps {rt.step_rate_hz:.2f} Hz)"
    per = ""
    if rt.period_mean_ms is not None:
        per = (f", AHRS period {rt.period_mean_ms:.3f} ms, jitter σ {_f(rt.period_std_ms, '.3f')} ms, "
               f"p99 {_f(rt.period_p99_ms, '.3f')} ms, max {_f(rt.period_max_ms, '.3f')} ms")
    lines.append(f"rate: {rate}{per}")
    tx = "" if rt.tx_dropped is None else f", firmware TX queue dropped {rt.tx_dropped}"
    lines.append(f"drops: {rt.frames_missing} frames missing in {rt.seq_gaps} seq gaps{tx}; "
                 f"{rt.crc_failures} CRC failures, {rt.bytes_skipped} bytes skipped"
                 + (f"; {rt.seq_resets} firmware restarts" if rt.seq_resets else ""))
    if rt.ahrs_cycles_mean is not None:
        lines.append(f"AHRS step cost: {_f(rt.ahrs_us_mean, '.1f')} µs mean (min {_f(rt.ahrs_us_min, '.1f')}, max "
                     f"{_f(rt.ahrs_us_max, '.1f')}; {rt.ahrs_cycles_mean:.0f} cycles at "
                     f"{(rt.cpu_hz or 0) / 1e6:g} MHz)")
    fs = r.filter_settings
    if fs is None:
        lines.append("filter settings: no status frames (the port assumes the firmware defaults)")
    elif fs["from"] == "status frames":
        norm = "fresh squares" if fs["fresh_squares"] else "squares before update (170120)"
        diff = fs["differs_from_defaults"]
        def val(x):
            return ("on" if x else "off") if isinstance(x, bool) else f"{x:g}"

        tail = "firmware defaults" if not diff else "differs from defaults: " + ", ".join(
            f"{k} {val(v[0])} (default {val(v[1])})" for k, v in diff.items())
        lines.append(f"filter (status frames): kp_ground {fs['kp_ground']:g}, kp_flight {fs['kp_flight']:g}, "
                     f"ki {fs['ki']:g}, dt {fs['dt_s']:g} s, min_thr {fs['min_thr']}, correction "
                     f"{'on' if fs['correction'] else 'OFF'}, normalisation: {norm} — {tail}")
        if fs["changes"]:
            lines.append(f"  note: the settings changed {fs['changes']} times during the capture")
    else:
        lines.append(f"filter (text-mode status lines): ki {_f(fs['ki'], 'g')}, flags {fs['flags']}")

    lines.append("")
    p = r.port
    if p is None:
        lines.append("ST-Mahony port: not run — text-mode capture (rounded angles, no quaternion): the port "
                     "cannot be bit-exact; compare the estimators below with the firmware instead")
    else:
        seeds = ", ".join(
            ("power-up at step 0" if s["source"] == "power-up" else f"snapshot at step {s['step'] - 1}")
            for s in p.seeds[:4]) + (f", … ({len(p.seeds)} in all)" if len(p.seeds) > 4 else "")
        verdict = "bit-exact on every step" if p.all_exact else (
            "NOT bit-exact" if p.seeded else "not run")
        lines.append(f"ST-Mahony port vs firmware: {verdict} — bit-exact steps {p.bit_exact} of {p.seeded} seeded "
                     f"({p.rows} binary rows)")
        if p.seeds:
            lines.append(f"  started from: {seeds}")
        if p.seeded < p.rows and p.seeded:
            lines.append(f"  {p.rows - p.seeded} rows not covered (before the first snapshot / after drops until "
                         "the next one)")
        if p.unseeded_reason:
            lines.append(f"  {p.unseeded_reason}")
        if p.first_mismatch:
            fm = p.first_mismatch
            lines.append(f"  first difference: row {fm['row']}, step {fm['step']}, t = {fm['t_rel_s']:.3f} s into "
                         f"the capture (firmware clock {fm['t_fw_s']:.3f} s)")
            for d in p.diagnosis:
                lines.append(f"  → {d}")

    lines.append("")
    lines.append("angles vs firmware, degrees (Δ = estimator − firmware)")
    w = max([len(t.label) for t in r.traces] + [9]) + 2
    head1 = " " * w + f"{'':>7}  {'pitch (thx, about x)':^21}  {'roll (thy, about y)':^21}"
    head2 = f"{'estimator':<{w}}{'steps':>7}  {'RMS':>10} {'max |Δ|':>10}  {'RMS':>10} {'max |Δ|':>10}"
    lines += [head1, head2]
    for t in r.traces:
        if not t.available:
            lines.append(f"{t.label:<{w}}{'—':>7}  {t.note}")
            continue
        n = min(t.pitch.n, t.roll.n)
        row = (f"{t.label:<{w}}{n:>7}  {_f(t.pitch.rms_deg):>10} {_f(t.pitch.max_abs_deg):>10}  "
               f"{_f(t.roll.rms_deg):>10} {_f(t.roll.max_abs_deg):>10}")
        if t.note:
            row += f"  ({t.note})"
        lines.append(row)
    for note in r.notes:
        lines.append(f"note: {note}")
    return lines

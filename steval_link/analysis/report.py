"""What ``steval compare`` reports (:class:`ComparisonReport` and its parts, JSON-friendly with ``as_dict``), its
text form (:func:`format_report`), and the :class:`Coverage` of a score (the share of the scored rows an estimate
covered)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from steval_link.estimators.firmware_replay import FirmwareReplay, release_sentence

#: Trace name of the seeded replica (``st-mahony`` is the registry estimator run from power-up, if requested).
REPLICA_TRACE = "st-mahony-replica"


TRACE_LABELS = {
    "st-mahony-replica": "ST-Mahony replica",
    "st-mahony": "ST-Mahony from power-up",
    "accel": "accel-only tilt",
    "ekf3": "EKF (3-state)",
    "mekf": "MEKF",
    "vqf": "VQF",
}


def angle_diff_rad(a, b) -> np.ndarray:
    """``a − b`` wrapped to [−π, π), float64 (so 179° vs −179° is 2°, not 358°); NaN where either is NaN."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    return (d + math.pi) % (2.0 * math.pi) - math.pi


def on_rows(n: int, rows, values, fill=np.nan, dtype=np.float64) -> np.ndarray:
    """``n`` rows of ``fill`` with ``values`` at ``rows`` (e.g. the replica's output on the capture's rows)."""
    out = np.full(n, fill, dtype)
    out[rows] = values
    return out


def true_runs(mask) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of True rows of ``mask`` (stop exclusive)."""
    d = np.diff(np.concatenate([[0], np.asarray(mask, bool).astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def truth_on_steps(truth_step, q_wxyz, movement, steps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground-truth rows matched to frames by AHRS step: (q_wxyz (N, 4), NaN unmatched; movement (N,); matched)."""
    order = np.argsort(truth_step, kind="stable")
    t_step = np.asarray(truth_step)[order]
    idx = np.clip(np.searchsorted(t_step, steps), 0, max(len(t_step) - 1, 0))
    hit = (t_step[idx] == steps) if len(t_step) else np.zeros(len(steps), bool)
    q_true = np.full((len(steps), 4), np.nan)
    q_true[hit] = np.asarray(q_wxyz)[order][idx[hit]]
    return q_true, on_rows(len(steps), hit, np.asarray(movement)[order][idx[hit]], False, bool), hit


def json_number(x) -> float | None:
    """JSON-friendly float: None for NaN/inf."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class Coverage:
    """How much of the scored rows (movement with finite truth) one estimate covered (finite): ``diverged_at_step``
    starts its final non-finite run (``diverged_at_s``: its time, s), ``why`` it covered none. An RMSE over the finite
    rows alone flatters a filter that gives up half-way: an incomplete cell is marked, has no mean and is not ranked."""

    scored_rows: int
    covered_rows: int
    diverged_at_step: int | None = None
    diverged_at_s: float | None = None
    why: str | None = None

    @property
    def scored_fraction(self) -> float | None:
        """Covered / scored rows (None: nothing to score)."""
        return self.covered_rows / self.scored_rows if self.scored_rows else None

    @property
    def complete(self) -> bool:
        """Every scored row covered (and at least one)."""
        return self.scored_rows > 0 and self.covered_rows == self.scored_rows

    def to_json(self) -> dict:
        """The JSON fields: ``scored_fraction``, ``diverged_at_step``, ``diverged_at_s``, ``no_score_reason``."""
        f = self.scored_fraction
        return {
            "scored_fraction": None if f is None else round(f, 4),
            "scored_rows": self.scored_rows,
            "covered_rows": self.covered_rows,
            "diverged_at_step": self.diverged_at_step,
            "diverged_at_s": None if self.diverged_at_s is None else round(self.diverged_at_s, 3),
            "no_score_reason": self.why,
        }

    def cell(self, rmse_text: str) -> str:
        """A table cell: the RMSE, marked with its coverage when incomplete (``2.851 (63 %)``)."""
        if self.complete:
            return rmse_text
        if self.covered_rows == 0:
            return "no score"
        return f"{rmse_text} ({percent(self.scored_fraction)})"

    def sentence(self) -> str | None:
        """What is missing, in words (None when complete): the share covered, where it diverged, or why no score."""
        if self.complete:
            return None
        if self.covered_rows == 0:
            return f"no score: {self.why}"
        text = f"scored on {percent(self.scored_fraction)} of the {self.scored_rows} movement rows with truth"
        if self.diverged_at_step is not None:
            text += f"; diverged at step {self.diverged_at_step}{_at(self.diverged_at_s)} (non-finite from there on)"
        return text


def percent(fraction: float | None) -> str:
    """``63 %``, rounded down (99.97 % is not called 100 %)."""
    return "—" if fraction is None else f"{math.floor(fraction * 100 + 1e-9):d} %"


def _at(t_s: float | None) -> str:
    return "" if t_s is None or not math.isfinite(t_s) else f", t = {t_s:.2f} s"


def coverage_of(estimate_ok, scored, steps=None, t_s=None) -> Coverage:
    """The coverage of one estimate: its finite rows among the ``scored`` ones (``steps`` default: row index)."""
    ok = np.asarray(estimate_ok, bool).reshape(-1)
    sc = np.asarray(scored, bool).reshape(-1)
    n = ok.shape[0]
    step_of = np.arange(n) if steps is None else np.asarray(steps).reshape(-1)
    scored_rows = int(np.count_nonzero(sc))
    covered = int(np.count_nonzero(sc & ok))
    finite_at = np.flatnonzero(ok)
    first_bad = int(finite_at[-1]) + 1 if finite_at.size else 0
    diverged = first_bad < n and bool(sc[first_bad:].any())
    at_step = int(step_of[first_bad]) if diverged else None
    at_s = float(t_s[first_bad]) if diverged and t_s is not None else None
    why = None
    if covered == 0:
        if scored_rows == 0:
            why = "no movement row with ground truth"
        elif not finite_at.size:
            why = f"its estimate is not finite on any of the {n} steps"
        elif diverged and not sc[:first_bad].any():
            why = f"it diverged at step {at_step}{_at(at_s)}, before the first movement row with truth"
        else:
            why = "its estimate is not finite on any movement row with truth"
    return Coverage(scored_rows, covered, at_step, at_s, why)


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
        return {k: json_number(v) if isinstance(v, float) else v for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class TraceComparison:
    """One estimator's ``pitch`` (thx, about x) and ``roll`` (thy, about y) differences from the firmware, degrees;
    ``available`` False when it could not run (``note`` says why)."""

    name: str
    label: str
    available: bool
    pitch: AngleStats
    roll: AngleStats
    n_invalid: int = 0
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        renamed = {"pitch": "pitch_thx", "roll": "roll_thy"}
        return {renamed.get(k, k): v.as_dict() if isinstance(v, AngleStats) else v for k, v in vars(self).items()}


@dataclass(frozen=True)
class ReplicaComparison:
    """The bit-exact replica against the firmware over ``rows`` binary rows: ``seeded`` with a state, ``bit_exact``
    with the firmware's q, thx and thy bits; the first differing row; ``matching_variant``, the changed settings that
    reproduce the firmware (None: none found); ``filter``, the ST release the replica ran."""

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
    divergence: dict[str, Any] | None = None
    filter: str = "ST 170120"
    filter_from: str = "settings"
    variant_bit_exact: dict[str, int] = field(default_factory=dict)

    @property
    def all_exact(self) -> bool:
        return self.seeded > 0 and self.first_mismatch is None

    def filter_line(self) -> str:
        """The sentence naming the release: recognised, forced, or the closest when none is bit-exact."""
        first = self.first_mismatch["step"] if self.first_mismatch else None
        return release_sentence(
            self.filter,
            self.filter_from,
            self.variant_bit_exact,
            seeded=self.seeded,
            exact=self.bit_exact,
            first_mismatch_step=first,
        )

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
            "filter": self.filter,
            "filter_from": self.filter_from,
            "variant_bit_exact_steps": self.variant_bit_exact,
            "unseeded_reason": self.unseeded_reason,
            "divergence": self.divergence,
        }


@dataclass(frozen=True)
class RateStats:
    """Timing and link health of a capture: ``duration_s`` of firmware time (summed between restarts), rates, periods
    between consecutive steps, frames lost (TX queue: None without status frames) and the ``ahrs_fusion_ag`` cost."""

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
    cycles_emulated: bool = False  #: ``ahrs_cycles_*`` are an emulator's instruction counts, not M4 cycles

    def ahrs_us(self, what: str) -> float | None:
        """``ahrs_cycles_<what>`` (min, mean, max) in µs at ``cpu_hz``."""
        cycles = getattr(self, f"ahrs_cycles_{what}")
        return None if cycles is None or not self.cpu_hz else float(cycles) / self.cpu_hz * 1e6

    def as_dict(self) -> dict[str, Any]:
        out = {k: (json_number(v) if isinstance(v, float) else v) for k, v in self.__dict__.items()}
        return out | {f"ahrs_us_{k}": json_number(self.ahrs_us(k)) for k in ("min", "mean", "max")}


@dataclass
class ComparisonReport:
    """Everything ``steval compare`` reports about one capture (``as_dict()`` is its ``--json``), arrays for plots."""

    source: dict[str, Any]
    rows: int
    binary_rows: int
    text_rows: int
    firmware_nan_pitch: int
    firmware_nan_roll: int
    rates: RateStats
    filter_settings: dict[str, Any] | None
    replica: ReplicaComparison | None
    traces: list[TraceComparison]
    notes: list[str] = field(default_factory=list)
    values_bad: dict[str, Any] | None = None
    held_back: str | None = None  #: CRC-valid frames the decoder held back, in words (None: none)
    #: inclination RMSE per trace against the ground truth the capture keeps (chunks T), or None
    truth: dict[str, Any] | None = None
    ahrs_step_cost: dict[str, Any] | None = None
    ahrs_step_cost_text: str | None = None
    # arrays for plots (not serialised)
    t_rel_s: np.ndarray = field(default=None, repr=False)
    replay: FirmwareReplay | None = field(default=None, repr=False)
    replica_rows: np.ndarray | None = field(default=None, repr=False)
    estimates: dict[str, Any] = field(default_factory=dict, repr=False)

    def trace(self, name: str) -> TraceComparison | None:
        return next((t for t in self.traces if t.name == name), None)

    def as_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "rows": {"attitude": self.rows, "binary": self.binary_rows, "text_mode": self.text_rows},
            "firmware_nan_steps": {"pitch_thx": self.firmware_nan_pitch, "roll_thy": self.firmware_nan_roll},
            "rates": self.rates.as_dict(),
            "filter": None if self.replica is None else self.replica.filter,
            "filter_settings": self.filter_settings,
            "replica": None if self.replica is None else self.replica.as_dict(),
            "traces": [t.as_dict() for t in self.traces],
            "notes": list(self.notes),
            "values_bad": self.values_bad,
            "held_back": self.held_back,
            "ahrs_step_cost": self.ahrs_step_cost,
            **({"truth": self.truth} if self.truth is not None else {}),
        }


def fmt_number(x, fmt: str = ".4f", none: str = "n/a") -> str:
    """``x`` formatted with ``fmt``, or ``none`` for None, NaN and inf."""
    return none if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def format_report(r: ComparisonReport) -> list[str]:
    """Human-readable lines of a :class:`ComparisonReport` (plain text, aligned)."""
    w = max([len(t.label) for t in r.traces] + [9]) + 2
    lines = _capture_lines(r) + _filter_lines(r.filter_settings)
    lines += [""] + _replica_lines(r.replica)
    lines += [""] + _angles_table(r.traces, w) + _truth_lines(r.truth, w)
    return lines + [f"note: {note}" for note in r.notes]


def _capture_lines(r: ComparisonReport) -> list[str]:
    """The capture, its firmware-output warnings, rate and jitter, drops and the AHRS step cost."""
    rt = r.rates
    kind = r.source.get("kind") or "telemetry"
    rows = f"{r.rows} attitude rows" + (f" ({r.text_rows} text-mode)" if r.text_rows else "")
    lines = [f"capture: {r.source.get('path')} ({kind}), {rows}, {rt.duration_s:.2f} s of firmware time"]
    if r.values_bad:
        lines.append(f"firmware output: {r.values_bad['text']}")
    if r.held_back:
        lines.append(f"held back: {r.held_back}")
    rate = f"{rt.rate_hz:.2f} Hz" if rt.rate_hz else "n/a"
    if rt.step_rate_hz and rt.rate_hz and abs(rt.step_rate_hz - rt.rate_hz) > 0.01 * rt.rate_hz:
        rate += f" (AHRS steps {rt.step_rate_hz:.2f} Hz)"
    per = ""
    if rt.period_mean_ms is not None:
        per = (
            f", AHRS period {rt.period_mean_ms:.3f} ms, jitter σ {fmt_number(rt.period_std_ms, '.3f')} ms, "
            f"p99 {fmt_number(rt.period_p99_ms, '.3f')} ms, max {fmt_number(rt.period_max_ms, '.3f')} ms"
        )
    lines.append(f"rate: {rate}{per}")
    tx = "" if rt.tx_dropped is None else f", firmware TX queue dropped {rt.tx_dropped}"
    lines.append(
        f"drops: {rt.frames_missing} frames missing in {rt.seq_gaps} seq gaps{tx}; "
        f"{rt.crc_failures} CRC failures, {rt.bytes_skipped} bytes skipped"
        + (f"; {rt.seq_resets} firmware restarts" if rt.seq_resets else "")
    )
    if r.ahrs_step_cost_text:
        lines.append(r.ahrs_step_cost_text)
    return lines


def setting_text(x) -> str:
    """A filter setting as text: ``on``/``off``, a string as is, a number with ``:g``."""
    return ("on" if x else "off") if isinstance(x, bool) else x if isinstance(x, str) else f"{x:g}"


def _filter_lines(fs: dict | None) -> list[str]:
    """The filter settings the status frames (or text-mode status lines) show, and every change of them."""
    if fs is None:
        return ["filter settings: no status frames (the replica assumes the firmware defaults)"]
    if fs["from"] != "status frames":
        return [f"filter (text-mode status lines): ki {fmt_number(fs['ki'], 'g')}, flags {fs['flags']}"]
    changed = [
        f"{k} {setting_text(v[0])} (default {setting_text(v[1])})" for k, v in fs["differs_from_defaults"].items()
    ]
    tail = "differs from defaults: " + ", ".join(changed) if changed else "firmware defaults"
    lines = [
        f"filter (status frames): kp_ground {fs['kp_ground']:g}, kp_flight {fs['kp_flight']:g}, "
        f"ki {fs['ki']:g}, dt {fs['dt_s']:g} s, min_thr {fs['min_thr']}, correction "
        f"{'on' if fs['correction'] else 'OFF'} — {tail}"
    ]
    changes = fs.get("change_list", [])
    if changes:
        lines.append(
            f"  {len(changes)} change{'s' if len(changes) > 1 else ''} during the capture "
            "(settings and filter resets, as the status frames show them):"
        )
    elif fs["changes"]:
        lines.append(f"  note: the settings changed {fs['changes']} times during the capture")
    for ch in changes:
        how = "status EVENT after a host command" if ch["event"] else "status frame"
        lines.append(f"  from step {ch['step']}: {ch['text']} ({how})")
    return lines


def _replica_lines(p: ReplicaComparison | None) -> list[str]:
    """The replica's verdict: bit-exact steps, its seeds, what it did not cover, the first difference and why."""
    if p is None:
        return [
            "ST-Mahony replica: not run — text-mode capture (rounded angles, no quaternion): the replica "
            "cannot be bit-exact; compare the estimators below with the firmware instead"
        ]
    seeds = ", ".join(
        ("power-up at step 0" if s["source"] == "power-up" else f"snapshot at step {s['step'] - 1}")
        for s in p.seeds[:4]
    ) + (f", … ({len(p.seeds)} in all)" if len(p.seeds) > 4 else "")
    verdict = "bit-exact on every step" if p.all_exact else ("NOT bit-exact" if p.seeded else "not run")
    lines = [
        f"ST-Mahony replica vs firmware: {verdict} — bit-exact steps {p.bit_exact} of {p.seeded} seeded "
        f"({p.rows} binary rows)",
        f"  {p.filter_line()}",
    ]
    if p.seeds:
        lines.append(f"  started from: {seeds}")
    if p.seeded < p.rows and p.seeded:
        lines.append(
            f"  {p.rows - p.seeded} rows not covered (before the first snapshot / after drops until the next one)"
        )
    if p.unseeded_reason:
        lines.append(f"  {p.unseeded_reason}")
    if p.first_mismatch:
        fm = p.first_mismatch
        lines.append(
            f"  first difference: row {fm['row']}, step {fm['step']}, t = {fm['t_rel_s']:.3f} s into "
            f"the capture (firmware clock {fm['t_fw_s']:.3f} s)"
        )
    return lines + [f"  → {d}" for d in p.diagnosis]


def _angles_table(traces: list[TraceComparison], w: int) -> list[str]:
    """Per estimator: steps, RMS and max |Δ| from the firmware's pitch and roll, in degrees."""
    lines = [
        "angles vs firmware, degrees (Δ = estimator − firmware)",
        " " * w + f"{'':>7}  {'pitch (thx, about x)':^21}  {'roll (thy, about y)':^21}",
        f"{'estimator':<{w}}{'steps':>7}  {'RMS':>10} {'max |Δ|':>10}  {'RMS':>10} {'max |Δ|':>10}",
    ]
    for t in traces:
        if not t.available:
            lines.append(f"{t.label:<{w}}{'—':>7}  {t.note}")
            continue
        n = min(t.pitch.n, t.roll.n)
        row = (
            f"{t.label:<{w}}{n:>7}  {fmt_number(t.pitch.rms_deg):>10} {fmt_number(t.pitch.max_abs_deg):>10}  "
            f"{fmt_number(t.roll.rms_deg):>10} {fmt_number(t.roll.max_abs_deg):>10}"
        )
        lines.append(row + (f"  ({t.note})" if t.note else ""))
    return lines


def _truth_lines(truth: dict | None, w: int) -> list[str]:
    """Inclination RMSE against the ground truth the capture keeps (none: no lines)."""
    if truth is None:
        return []
    lines = [
        "",
        f"against the ground truth the capture keeps: inclination RMSE (deg) over "
        f"{truth['movement_steps']} movement steps",
    ]
    notes = truth.get("coverage_notes", {})
    for name, v in truth["rmse_deg"].items():
        if name not in notes:
            lines.append(f"  {name:<{w}}{fmt_number(v, '.3f')}")
            continue
        f = truth.get("scored_fraction", {}).get(name)  # an RMSE with the share of the scored rows it covers
        cell = "no score" if not f or v is None else f"{fmt_number(v, '.3f')} ({percent(f)})"
        lines.append(f"  {name:<{w}}{cell}  ({notes[name]})")
    if notes:
        lines.append("  an incomplete score (marked with its coverage) is not ranked with the complete ones")
    return lines


def estimator_summary(name: str, est, tel) -> dict[str, Any]:
    """One host estimator over a capture: valid rows, first invalid step, RMS difference (deg) from thx/thy."""
    a = tel.attitude
    valid = np.asarray(est.valid, bool) & np.isfinite(est.thx_rad) & np.isfinite(est.thy_rad)
    bad = np.flatnonzero(~valid)
    out: dict[str, Any] = {
        "name": str(name),
        "rows": int(valid.shape[0]),
        "valid_rows": int(np.count_nonzero(valid)),
        "first_invalid_step": int(a.step[bad[0]]) if bad.size else None,
    }
    for key, mine, fw in (("pitch", est.thx_rad, a.thx_rad), ("roll", est.thy_rad, a.thy_rad)):
        d = np.where(valid, angle_diff_rad(mine, fw), np.nan)
        d = d[np.isfinite(d)]
        out[f"rms_diff_{key}_deg"] = json_number(math.degrees(math.sqrt(np.mean(d * d)))) if d.size else None
    return out


def estimator_line(s: dict[str, Any]) -> str:
    """``estimator ekf3: 9210/9210 valid rows; RMS difference from the firmware: pitch 0.132°, roll 0.118°``."""
    first = "" if s["first_invalid_step"] is None else f" (first invalid at step {s['first_invalid_step']})"
    rms = (
        f"pitch {fmt_number(s['rms_diff_pitch_deg'], '.3f')}°, roll {fmt_number(s['rms_diff_roll_deg'], '.3f')}°"
        if s["rms_diff_pitch_deg"] is not None or s["rms_diff_roll_deg"] is not None
        else "n/a (no row where both are finite)"
    )
    rows = f"{s['valid_rows']}/{s['rows']} valid rows{first}"
    return f"estimator {s['name']}: {rows}; RMS difference from the firmware: {rms}"

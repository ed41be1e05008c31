"""Flights side by side (``steval compare A.stv B.stv ...``) on one time axis (firmware time from each first frame,
or the gyro cross-correlated), labelled by what differs ("ki 0.1" against "ki 1, correction off").

Per flight, degrees: RMS of pitch (thx, about x, nose up +) and roll (thy, about y) against accel-only tilt in the
still phases, the drift (mean error in the last still phase) and its rate (deg/min); each later flight minus the
first. Mismatches are notes, not errors. A BLE capture's angles are the ST-Mahony replica's on its raw samples."""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from steval_link import constants as C
from steval_link.analysis.diagnosis import filter_settings_report
from steval_link.analysis.link_stats import relative_time_s
from steval_link.analysis.plots import _decimate, _label_panel, _spans, require_matplotlib, save_figure
from steval_link.analysis.report import angle_diff_rad, fmt_number, json_number, true_runs
from steval_link.estimators.accel_tilt import AccelTilt
from steval_link.estimators.st_mahony import MahonySettings
from steval_link.link import protocol as P

ALIGN_MODES = ("time", "motion")
_MOTION_HOW = "motion (gyro cross-correlation with the first flight)"
#: A row is still when the gyro's norm is below this (deg/s) ...
STILL_GYRO_DPS = 3.0
#: ... and the accelerometer's norm within this of 1000 mg ...
STILL_ACC_MG = 50.0
#: ... for at least this long (s).
STILL_MIN_S = 0.3
#: The drift rate needs still rows spanning at least this long (s).
RATE_SPAN_S = 5.0
#: Durations differing by more than this (s, or 5 %) are reported.
DURATION_TOLERANCE_S = 1.0
#: The motion alignment searches lags up to this fraction of the shorter flight.
MAX_LAG_FRACTION = 0.5


#: Settings in label order, with their names in a label (a label names a setting that differs from its default).
_SETTING_WORDS = {
    "ki": "ki",
    "correction": "correction",
    "kp_ground": "kp ground",
    "kp_flight": "kp flight",
    "min_thr": "min_thr",
    "dt_s": "dt",
    "variant": "filter",
    "text_mode": "text mode",
    "inflight_tuning": "in-flight tuning",
}
_NO_FLAGS = {"text_mode": False, "inflight_tuning": False}
_FACT_KEYS = ("link", "firmware", "firmware_path", "scenario", "seed", "port")


def setting_f32(x) -> float:
    """A float32 setting as its shortest decimal (0.4, not 0.4000000059604645)."""
    return float(str(np.float32(x)))


def _setting_values(s: MahonySettings) -> dict[str, Any]:
    """A filter's settings in label order, the float32 ones as their shortest decimals."""
    keys = ("ki", "correction", "kp_ground", "kp_flight", "min_thr", "dt_s", "variant")
    return {
        k: setting_f32(getattr(s, k)) if k in ("ki", "kp_ground", "kp_flight", "dt_s") else getattr(s, k) for k in keys
    }


def _defaults() -> dict[str, Any]:
    return _setting_values(MahonySettings()) | _NO_FLAGS


def _word(key: str, value) -> str:
    """How a setting reads in a label: "ki 1", "correction off", "binary", "filter ST 221117", ..."""
    name = _SETTING_WORDS[key]
    if key == "variant":
        return f"filter {value}"
    if key == "correction":
        return f"correction {'on' if value else 'off'}"
    if key == "text_mode":
        return "text mode" if value else "binary"
    if isinstance(value, bool):
        return name if value else f"no {name}"
    return f"{name} {value:g}" if isinstance(value, float) else f"{name} {value}"


def _fact_word(key: str, value) -> str:
    """How a header fact reads in a label: "BLE", "firmware X.elf", "scenario demo", ..."""
    if key == "link":
        return "BLE" if value == "ble" else "serial"
    return f"{key.replace('_path', '')} {value}"


def labels_by_difference(flights: Sequence) -> list[str]:
    """A label per flight naming what differs: the settings that differ from their default ("ki 0.1" against
    "ki 1, correction off"), else the header facts, else the file names; a label that collides gets its file name."""
    n = len(flights)
    labels = [""] * n
    known = [f.settings for f in flights]
    defaults = _defaults()
    if all(s is not None for s in known):
        differing = [k for k in _SETTING_WORDS if len({repr(s.get(k, defaults[k])) for s in known}) > 1]
        if differing:
            for i, s in enumerate(known):
                words = [_word(k, s.get(k, defaults[k])) for k in differing if s.get(k, defaults[k]) != defaults[k]]
                labels[i] = ", ".join(words) or _word(differing[0], s.get(differing[0], defaults[differing[0]]))
    if not all(labels):
        facts = [f.facts for f in flights]
        differing = [k for k in _FACT_KEYS if len({repr(x.get(k)) for x in facts}) > 1]
        if "firmware" in differing:  # the ELF names tell them apart; else the paths may (other build folders)
            differing.remove("firmware_path")
        words: list[list[str]] = [[] for _ in flights]
        for k in differing:  # in order of priority, until the labels tell the flights apart
            for i, x in enumerate(facts):
                if x.get(k) is not None:
                    words[i].append(_fact_word(k, x[k]))
            if len({", ".join(w) for w in words}) == n:
                break
        for i in range(n):
            if not labels[i]:
                labels[i] = ", ".join(words[i])
    for i, f in enumerate(flights):
        if f.settings and f.settings.get("changes"):
            labels[i] = (labels[i] + ", " if labels[i] else "") + f"{f.settings['changes']} changes in flight"
    clash = [not label or labels.count(label) > 1 for label in labels]  # a clash or no label: the file's name
    labels = [(f"{lb} ({f.path.name})" if lb else f.path.name) if c else lb for lb, c, f in zip(labels, clash, flights)]
    # the same file twice: its position tells them apart
    return [f"{label} #{i + 1}" if labels.count(label) > 1 else label for i, label in enumerate(labels)]


@dataclass
class Flight:
    """One capture on the common time axis: ``t_s`` (N,) s since the first frame minus the lag; ``thx_rad``/``thy_rad``
    pitch (about x)/roll (about y), ``angles`` "firmware" or "st-mahony replica"; the first status's settings."""

    path: Path
    label: str
    kind: str
    angles: str
    t_s: np.ndarray
    thx_rad: np.ndarray
    thy_rad: np.ndarray
    acc_mg: np.ndarray
    gyro_mdps: np.ndarray
    q_wxyz: np.ndarray
    settings: dict[str, Any] | None
    facts: dict[str, Any]
    duration_s: float
    frames_lost: int
    warnings: list[str] = field(default_factory=list)
    lag_s: float = 0.0
    accel_thx_rad: np.ndarray = field(default=None, repr=False)
    accel_thy_rad: np.ndarray = field(default=None, repr=False)
    still: np.ndarray = field(default=None, repr=False)
    figures: dict[str, Any] = field(default_factory=dict)

    @property
    def rows(self) -> int:
        return len(self.t_s)


#: the fields of a flight in ``--json``, in order
_FLIGHT_KEYS = "label path kind angles settings facts rows duration_s frames_lost warnings figures"


@dataclass
class SideBySide:
    """Flights on one time axis, each later one's differences from ``flights[0]`` and notes; ``as_dict()`` is --json."""

    flights: list[Flight]
    align: str
    differences: list[dict[str, Any]]
    notes: list[str]

    def as_dict(self) -> dict[str, Any]:
        return {
            "align": {
                "method": self.align,
                "lags_s": [json_number(f.lag_s) for f in self.flights],
                "meaning": "each flight's times are s since its first frame minus its lag (the first: 0)",
            },
            "flights": [
                {k: getattr(f, k) for k in _FLIGHT_KEYS.split()}
                | {"path": str(f.path), "duration_s": json_number(f.duration_s), "warnings": list(f.warnings)}
                for f in self.flights
            ],
            "differences": self.differences,
            "notes": list(self.notes),
        }


def _settings_of_status(tel) -> dict[str, Any] | None:
    s = tel.status
    if not len(s):
        return None
    exact = np.asarray(s.exact, bool)
    if not exact.any():  # text-mode status lines: KI and the flags only
        flags = int(s.flags[0])
        return {
            "from": "text-mode status lines",
            "ki": setting_f32(s.ki[0]),
            "correction": not flags & P.FLAG_NO_CORRECTION,
            "text_mode": True,
            "changes": int(np.count_nonzero(np.diff(np.asarray(s.ki, np.float32)) != 0)),
        }
    rows = np.flatnonzero(exact)
    first = MahonySettings.of_status(s, int(rows[0]))
    flags = int(s.flags[rows[0]])
    changes = int((filter_settings_report(tel) or {}).get("changes") or 0)
    return {
        "from": "status frames",
        **_setting_values(first),
        "text_mode": bool(flags & P.FLAG_TEXT_MODE),
        "inflight_tuning": bool(flags & P.FLAG_INFLIGHT_TUNING),
        "flags": flags,
        "changes": changes,
    }


def _facts(header: dict[str, Any] | None, kind: str) -> dict[str, Any]:
    header = header or {}
    extra = header.get("extra") or {}
    synth = extra.get("synth") or {}
    elf = extra.get("elf") or extra.get("firmware")
    return {
        "link": kind,
        "firmware": None if elf is None else Path(str(elf)).name,
        "firmware_path": None if elf is None else str(elf),
        "scenario": extra.get("scenario") or synth.get("scenario"),
        "seed": extra.get("seed", synth.get("seed")),
        "port": header.get("port"),
        "emulated": bool(extra.get("emulated", False)),
    }


def _flight(path, kind: str, angles: str, t, angles_of, inputs, settings, facts, lost: int, warnings) -> Flight:
    """A :class:`Flight` of times ``t``, thx/thy/q of ``angles_of`` and acc/gyro of ``inputs`` (array attributes)."""
    return Flight(
        path=Path(path),
        label="",
        kind=kind,
        angles=angles,
        t_s=t,
        thx_rad=np.asarray(angles_of.thx_rad, np.float64),
        thy_rad=np.asarray(angles_of.thy_rad, np.float64),
        acc_mg=np.asarray(inputs.acc_mg, np.float32),
        gyro_mdps=np.asarray(inputs.gyro_mdps, np.float32),
        q_wxyz=np.asarray(angles_of.q_wxyz, np.float64),
        settings=settings,
        facts=facts,
        duration_s=float(t[-1]) if len(t) else 0.0,
        frames_lost=lost,
        warnings=list(warnings),
    )


def flight_of_telemetry(path, tel, warnings: Sequence[str] = ()) -> Flight:
    """A serial capture (a decoded :class:`~steval_link.link.telemetry.Telemetry` with attitude rows)."""
    a = tel.attitude
    t = relative_time_s(a.step, a.t_fw_s)
    facts = _facts((tel.source or {}).get("header"), "serial")
    return _flight(
        path, "serial", "firmware", t, a, a, _settings_of_status(tel), facts, int(tel.stats.frames_missing), warnings
    )


def flight_of_ble(path, tel, replica_estimate=None, warnings: Sequence[str] = ()) -> Flight:
    """A BLE capture's telemetry and the ST-Mahony replica's estimate over its rows (None: the rows' own angles)."""
    a = tel.attitude
    t = a.t_fw_s - a.t_fw_s[0] if len(a) else a.t_fw_s
    lost = tel.link.cadence.dropped if tel.link.cadence is not None else 0
    facts = _facts(tel.source.get("header"), "ble")
    angles, of = ("firmware", a) if replica_estimate is None else ("st-mahony replica", replica_estimate)
    return _flight(path, "ble", angles, t, of, a, None, facts, lost, warnings)


def still_mask(acc_mg: np.ndarray, gyro_mdps: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """(N,) True on the rows of still phases: gyro norm < :data:`STILL_GYRO_DPS`, accelerometer norm within
    :data:`STILL_ACC_MG` of 1000 mg, in runs lasting at least :data:`STILL_MIN_S`."""
    gyro = np.linalg.norm(np.asarray(gyro_mdps, np.float64), axis=1)
    acc = np.linalg.norm(np.asarray(acc_mg, np.float64), axis=1)
    with np.errstate(invalid="ignore"):
        quiet = (gyro < STILL_GYRO_DPS * 1000.0) & (np.abs(acc - 1000.0) < STILL_ACC_MG)
    out = np.zeros_like(quiet)
    t = np.asarray(t_s, np.float64)
    for a, b in true_runs(quiet):
        if t[b - 1] - t[a] >= STILL_MIN_S:
            out[a:b] = True
    return out


def _still_figures(f: Flight) -> dict[str, Any]:
    """RMS against accel-only tilt in still phases, drift (the error in the last still phase) and its rate."""
    still = f.still & np.isfinite(f.thx_rad) & np.isfinite(f.thy_rad)
    runs = true_runs(still)
    dt = np.diff(f.t_s, append=f.t_s[-1] + C.AHRS_PERIOD_S) if f.rows else np.zeros(0)
    out: dict[str, Any] = {"still_s": round(float(np.sum(dt[still])), 3), "still_phases": len(runs)}
    for axis, est, ref in (("pitch_thx", f.thx_rad, f.accel_thx_rad), ("roll_thy", f.thy_rad, f.accel_thy_rad)):
        err = np.degrees(angle_diff_rad(est, ref))
        e = err[still]
        t = f.t_s[still]
        fig: dict[str, Any] = dict.fromkeys(("rms_still_deg", "mean_still_deg", "drift_deg", "drift_rate_deg_per_min"))
        if e.size:
            fig["rms_still_deg"] = json_number(np.sqrt(np.mean(e * e)))
            fig["mean_still_deg"] = json_number(np.mean(e))
            a, b = runs[-1]
            fig["drift_deg"] = json_number(np.mean(err[a:b]))
            if e.size > 2 and np.ptp(t) >= RATE_SPAN_S:
                fig["drift_rate_deg_per_min"] = json_number(np.polyfit(t, e, 1)[0] * 60.0)
        out[axis] = fig
    return out


def _grid(t_s: np.ndarray, gyro_mdps: np.ndarray, dt: float) -> np.ndarray:
    """The gyro (deg/s, zero mean per axis) resampled on a uniform grid from the flight's first frame."""
    g = np.asarray(gyro_mdps, np.float64) / 1000.0
    grid = np.arange(0.0, float(t_s[-1]) + dt / 2, dt)
    out = np.stack([np.interp(grid, t_s, np.nan_to_num(g[:, k])) for k in range(3)], axis=1)
    return out - out.mean(axis=0)


def motion_lag_s(
    t_ref: np.ndarray, gyro_ref: np.ndarray, t: np.ndarray, gyro: np.ndarray, dt: float = C.AHRS_PERIOD_S
) -> tuple[float, float]:
    """The lag (s) of a flight's motion behind the reference's (the three gyro axes cross-correlated: 2 s later
    gives +2.0, aligned times are ``t − lag``) and the gyro samples' correlation at that lag (1: the same motion)."""
    if len(t_ref) < 8 or len(t) < 8:
        return 0.0, 0.0
    a = _grid(t_ref, gyro_ref, dt)
    b = _grid(t, gyro, dt)
    n = len(a) + len(b) - 1
    size = 1 << (n - 1).bit_length()
    xc = np.zeros(size)
    for k in range(3):
        xc += np.fft.irfft(np.fft.rfft(b[:, k], size) * np.conj(np.fft.rfft(a[:, k], size)), size)
    # xc[m] = sum_i b[i + m] a[i]: lags m = 0 .. len(b)-1 at the start, negative lags wrapped at the end
    max_lag = int(MAX_LAG_FRACTION * min(len(a), len(b)))
    lags = np.concatenate([np.arange(0, max_lag + 1), np.arange(-max_lag, 0)])
    vals = np.concatenate([xc[: max_lag + 1], xc[size - max_lag :]])
    m = int(lags[int(np.argmax(vals))])
    i0, i1 = max(0, -m), min(len(a), len(b) - m)  # the rows of a that b overlaps at this lag
    x, y = a[i0:i1].ravel(), b[i0 + m : i1 + m].ravel()
    norm = math.sqrt(float(np.dot(x, x)) * float(np.dot(y, y))) if x.size else 0.0
    return float(m * dt), (float(np.dot(x, y)) / norm if norm > 0 else 0.0)


def _mismatch_notes(flights: Sequence[Flight]) -> list[str]:
    notes: list[str] = []
    lo, hi = min(f.duration_s for f in flights), max(f.duration_s for f in flights)
    if hi - lo > max(DURATION_TOLERANCE_S, 0.05 * hi):
        each = ", ".join(f"{f.label} {f.duration_s:.1f} s" for f in flights)
        notes.append(f"durations differ ({each}): the differences cover the overlap only.")
    kinds = {f.kind for f in flights}
    if len(kinds) > 1:
        ble, ser = ([f.label for f in flights if f.kind == k] for k in ("ble", "serial"))
        notes.append(
            f"{', '.join(ble)} is a BLE capture and {', '.join(ser)} a serial one: the BLE angles are the "
            "host's ST-Mahony replica on raw ISR samples (dt from the 8 ms ticks), not the drone's own."
        )
    elif kinds == {"ble"}:
        notes.append("BLE captures: the angles are the host's ST-Mahony replica on raw ISR samples, not the drone's.")
    for f in flights:
        if f.frames_lost:
            notes.append(
                f"{f.label}: {f.frames_lost} frames lost on the link; its lines are interpolated across the gaps."
            )
        notes += [f"{f.label}: {w}" for w in f.warnings]
    text = [f.label for f in flights if f.settings and f.settings.get("text_mode")]
    if text and len(text) < len(flights):
        notes.append(f"{', '.join(text)}: text-mode rows (rounded angles, not every step) against binary frames.")
    return notes


def _difference(ref: Flight, f: Flight) -> dict[str, Any]:
    """``f − ref`` on ``ref``'s rows within the overlap, degrees (angles interpolated, wrapped to ±180°)."""
    overlap = min(ref.t_s[-1], f.t_s[-1]) - max(ref.t_s[0], f.t_s[0])
    out: dict[str, Any] = {"label": f.label, "against": ref.label, "overlap_s": json_number(max(0.0, overlap))}
    _, dx, dy = difference_series(ref, f)
    for axis, d in (("pitch_thx", dx), ("roll_thy", dy)):
        d = d[np.isfinite(d)]
        out[axis] = {
            "rms_deg": json_number(np.sqrt(np.mean(d * d))) if d.size else None,
            "max_abs_deg": json_number(np.max(np.abs(d))) if d.size else None,
        }
    return out


def difference_series(ref: Flight, f: Flight) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_s, pitch, roll) of ``f − ref`` in degrees on ``ref``'s rows within the overlap (plots, viewer)."""
    lo, hi = max(ref.t_s[0], f.t_s[0]), min(ref.t_s[-1], f.t_s[-1])
    rows = (ref.t_s >= lo) & (ref.t_s <= hi)
    t = ref.t_s[rows]
    dx = np.degrees(angle_diff_rad(np.interp(t, f.t_s, f.thx_rad), ref.thx_rad[rows]))
    dy = np.degrees(angle_diff_rad(np.interp(t, f.t_s, f.thy_rad), ref.thy_rad[rows]))
    return t, dx, dy


def side_by_side(flights: Sequence[Flight], *, align: str = "time", labels: Sequence[str] | None = None) -> SideBySide:
    """Put ``flights`` on one time axis, label them, and measure each against its accel-only tilt and the first."""
    if align not in ALIGN_MODES:
        raise ValueError(f"align must be one of {ALIGN_MODES}, got {align!r}")
    flights = list(flights)
    empty = [f.path for f in flights if f.rows == 0]
    if empty:
        raise ValueError(f"{empty[0]} has no rows")
    given = list(labels or [])
    for i, (f, derived) in enumerate(zip(flights, labels_by_difference(flights))):
        f.label = given[i] if i < len(given) else derived
    notes: list[str] = []
    if align == "motion":
        ref = flights[0]
        for f in flights[1:]:
            lag, r = motion_lag_s(ref.t_s, ref.gyro_mdps, f.t_s, f.gyro_mdps)
            f.lag_s = lag
            f.t_s = f.t_s - lag
            notes.append(f"motion alignment: {f.label} lags {ref.label} by {lag:+.3f} s (gyro correlation {r:.2f})")
            if r < 0.5:
                notes.append(
                    f"{f.label}: the gyro correlates weakly with {ref.label} ({r:.2f}): the motions may "
                    "not be the same, the lag may be wrong."
                )
    for f in flights:
        est = AccelTilt().run(f.acc_mg, f.gyro_mdps)
        f.accel_thx_rad, f.accel_thy_rad = np.asarray(est.thx_rad, np.float64), np.asarray(est.thy_rad, np.float64)
        f.still = still_mask(f.acc_mg, f.gyro_mdps, f.t_s)
        f.figures = _still_figures(f)
    return SideBySide(
        flights, align, [_difference(flights[0], f) for f in flights[1:]], _mismatch_notes(flights) + notes
    )


def _settings_text(s: dict[str, Any] | None) -> str:
    if s is None:
        return "settings unknown (no status frames)"
    if s.get("from") != "status frames":
        return f"ki {s['ki']:g}, correction {'on' if s['correction'] else 'off'} (text-mode status)"
    return (
        f"ki {s['ki']:g}, kp {s['kp_ground']:g}/{s['kp_flight']:g}, correction "
        f"{'on' if s['correction'] else 'off'}, min_thr {s['min_thr']}"
        + (f", {s['changes']} changes" if s.get("changes") else "")
    )


def format_side_by_side(r: SideBySide) -> list[str]:
    """The text form: flights, their figures against accel-only tilt, the differences, the notes."""
    how = "firmware time from each capture's first frame" if r.align == "time" else _MOTION_HOW
    lines = [f"{len(r.flights)} flights side by side, aligned by {how}"]
    width = max(len(f.label) for f in r.flights)
    for i, f in enumerate(r.flights):
        lag = f", lag {f.lag_s:+.3f} s" if r.align == "motion" else ""
        lines.append(
            f"  {chr(65 + i) if i < 26 else i}  {f.label:<{width}}  {f.path.name}: {f.duration_s:.1f} s, "
            f"{f.rows} rows, {f.kind}{lag}; {_settings_text(f.settings)}"
        )
    lines += [
        "against accel-only tilt in still phases (deg; drift: the last still phase; rate deg/min): pitch = "
        "thx (about x, nose up +), roll = thy (about y)",
        f"  {'flight':<{width}}  still s  RMS pitch  RMS roll  drift pitch  drift roll  rate pitch/roll",
    ]
    for f in r.flights:
        g = f.figures
        px, ry = g["pitch_thx"], g["roll_thy"]
        lines.append(
            f"  {f.label:<{width}}  {g['still_s']:7.1f}  {fmt_number(px['rms_still_deg'], '9.3f')}  "
            f"{fmt_number(ry['rms_still_deg'], '8.3f')}  {fmt_number(px['drift_deg'], '+11.3f')}  "
            f"{fmt_number(ry['drift_deg'], '+10.3f')}  {fmt_number(px['drift_rate_deg_per_min'], '+.3f')} / "
            f"{fmt_number(ry['drift_rate_deg_per_min'], '+.3f')}"
        )
    for d in r.differences:
        pitch, roll = (
            f"RMS {fmt_number(d[k]['rms_deg'], '.3f')} max {fmt_number(d[k]['max_abs_deg'], '.3f')} deg"
            for k in ("pitch_thx", "roll_thy")
        )
        lines.append(
            f"difference {d['label']} − {d['against']} over {d['overlap_s']:.1f} s: pitch {pitch}, roll {roll}"
        )
    return lines + [f"note: {n}" for n in r.notes]


#: Flight colours, in order (the viewer uses the same).
COLOURS = ["tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange", "tab:cyan"]


def plot_side_by_side(r: SideBySide, out_png) -> Path:
    """Write :func:`side_by_side_figure` as a PNG to ``out_png`` (UserError when it cannot be written)."""
    return save_figure(side_by_side_figure(r), out_png)


def side_by_side_figure(r: SideBySide):
    """Pitch and roll of every flight over the first's accel-only tilt, the differences, and the still-phase table."""
    plt = require_matplotlib()
    fig = plt.figure(figsize=(13, 11))
    grid = fig.add_gridspec(4, 1, height_ratios=[3, 3, 2, 1.0], hspace=0.38)
    fig.subplots_adjust(top=0.93, bottom=0.02, left=0.07, right=0.98)
    ax_p = fig.add_subplot(grid[0])
    ax_r = fig.add_subplot(grid[1], sharex=ax_p)
    ax_d = fig.add_subplot(grid[2], sharex=ax_p)
    ax_t = fig.add_subplot(grid[3])
    _angle_panel(ax_p, r, "thx_rad", "accel_thx_rad", "pitch = thx (rotation about x, nose up +)")
    _angle_panel(ax_r, r, "thy_rad", "accel_thy_rad", "roll = thy (rotation about y, right side down +)")
    _differences_panel(ax_d, r)
    _still_table(ax_t, r)
    fig.suptitle(textwrap.fill(" vs ".join(f.label for f in r.flights), 150), fontsize=12)
    return fig


def _angle_panel(ax, r: SideBySide, attr: str, acc_attr: str, title: str) -> None:
    """One angle of every flight over the first flight's accel-only tilt, its still phases shaded."""
    ref = r.flights[0]
    _spans(ax, ref.t_s, ref.still, f"still phases ({ref.label})")
    t, y = _decimate(ref.t_s, np.degrees(getattr(ref, acc_attr)))
    ax.plot(t, y, color="0.55", lw=0.8, label=f"accel-only tilt ({ref.label}): reference", zorder=1)
    for i, f in enumerate(r.flights):
        t, y = _decimate(f.t_s, np.degrees(getattr(f, attr)))
        ax.plot(t, y, color=COLOURS[i % len(COLOURS)], lw=1.6 if i == 0 else 1.2, label=f.label, zorder=3 + i)
    _label_panel(ax, f"{title.split(' ')[0]} {attr[:3]} (deg)", title)
    ax.legend(fontsize=8, loc="upper right")


def _differences_panel(ax, r: SideBySide) -> None:
    """Each later flight minus the first, pitch solid and roll dashed."""
    ref = r.flights[0]
    for i, f in enumerate(r.flights[1:], start=1):
        t, dx, dy = difference_series(ref, f)
        c = COLOURS[i % len(COLOURS)]
        ax.plot(*_decimate(t, dx), color=c, lw=1.2, label=f"pitch thx: {f.label} − {ref.label}")
        ax.plot(*_decimate(t, dy), color=c, lw=1.0, ls="--", label=f"roll thy: {f.label} − {ref.label}")
    ax.axhline(0, color="0.3", lw=0.6)
    _label_panel(ax, "difference (deg)", "each flight minus the first")
    ax.legend(fontsize=8, loc="upper right")
    how = "firmware time from each first frame" if r.align == "time" else "motion (gyro cross-correlation)"
    ax.set_xlabel(f"time (s), aligned by {how}")


def _still_table(ax, r: SideBySide) -> None:
    """Per flight: still time, RMS against accel-only tilt in still phases, drift and drift rate."""
    ax.axis("off")
    head = ["flight", "still (s)", "RMS pitch thx (deg)", "RMS roll thy (deg)", "drift pitch (deg)",
            "drift roll (deg)", "drift rate p / r (deg/min)"]  # fmt: skip
    rows = []
    for f in r.flights:
        g = f.figures
        px, ry = g["pitch_thx"], g["roll_thy"]
        rows.append([
            textwrap.shorten(f.label, 46, placeholder=" …"),  # the legend above has the whole label
            f"{g['still_s']:.1f}",
            fmt_number(px["rms_still_deg"], ".3f"),
            fmt_number(ry["rms_still_deg"], ".3f"),
            fmt_number(px["drift_deg"], "+.3f"),
            fmt_number(ry["drift_deg"], "+.3f"),
            f"{fmt_number(px['drift_rate_deg_per_min'], '+.2f')} / {fmt_number(ry['drift_rate_deg_per_min'], '+.2f')}",
        ])  # fmt: skip
    widths = [0.26] + [0.74 / (len(head) - 1)] * (len(head) - 1)
    table = ax.table(cellText=rows, colLabels=head, loc="center", cellLoc="center", colWidths=widths)
    table.auto_set_font_size(False)
    table.set_fontsize(8.5)
    table.scale(1, 1.4)
    for i in range(len(rows)):
        table[i + 1, 0].get_text().set_color(COLOURS[i % len(COLOURS)])
    title = "against accel-only tilt, still phases only (drift: the mean error in the last still phase)"
    ax.set_title(title, fontsize=10, loc="left")

"""``steval compare``: how the firmware's own angles compare with the Python replica, the EKFs and accelerometer tilt.

One capture in, one :class:`ComparisonReport` out (ETH lecture 4, exercise 8 and the EKF project):

* **ST-Mahony replica** — the bit-exact replica re-run over the capture's inputs
  (:func:`steval_link.estimators.firmware_replay.replay_firmware`): it starts at power-up (a capture from step 0) or
  from
  the filter-state snapshot of a status frame, and restarts from the next snapshot after any dropped frame. The
  report counts bit-exact steps, names the first step that differs and *diagnoses* it: the replica is re-run from the
  same seed with alternative settings (the other normalisation variant, KI 1.0, no correction, kp variants,
  dt = 1/161.5 s, the firmware defaults) and the one that reproduces the firmware is named; a mismatch right after
  dropped frames, or one nothing explains, is called out as such.
* **Other estimators** (``ekf3``, ``mekf``, ``accel`` by default) run from power-up over the same inputs.

Every trace is compared with the firmware's ``thx`` (pitch, about x) and ``thy`` (roll, about y): RMS and max |Δ|
in degrees, angle differences wrapped to ±180°. Firmware NaN rows (``asin`` out of range at extreme rates) are
counted and excluded, never fatal. Rate, jitter, drop, CRC and AHRS-cycle statistics and the filter settings from
the status frames complete the report.

Text-mode captures carry rounded angles and inputs and no quaternion: the replica cannot be bit-exact there, so
it is not run; the firmware's angles are compared with the other estimators only.
"""

from __future__ import annotations

__all__ = [
    "REPLICA_TRACE",
    "AngleStats",
    "ComparisonReport",
    "TraceComparison",
    "compare_capture",
    "format_report",
    "angle_diff_rad",
]

import math
from typing import Any, Sequence

import numpy as np

from steval_link.analysis.diagnosis import compare_replica, filter_settings_report
from steval_link.analysis.link_stats import link_notes, rate_stats, relative_time_s
from steval_link.analysis.report import (
    REPLICA_TRACE,
    TRACE_LABELS,
    AngleStats,
    ComparisonReport,
    TraceComparison,
    angle_diff_rad,
    format_report,
    json_number,
)
from steval_link.analysis.summary import values_bad_report
from steval_link.emulation import broad
from steval_link.emulation.step_truth import score_euler
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.estimators.runner import row_decimation, run_estimator
from steval_link.estimators.st_mahony import MahonySettings
from steval_link.link.capture import capture_truth
from steval_link.link.load import read_recording
from steval_link.link.plausibility import held_back_sentence


def _trace(name: str, label: str, thx, thy, valid, fw_thx, fw_thy, note: str = "") -> TraceComparison:
    thx = np.asarray(thx, dtype=np.float64)
    thy = np.asarray(thy, dtype=np.float64)
    valid = np.asarray(valid, bool) & np.isfinite(thx) & np.isfinite(thy)
    dx = np.where(valid, angle_diff_rad(thx, fw_thx), np.nan)
    dy = np.where(valid, angle_diff_rad(thy, fw_thy), np.nan)
    return TraceComparison(name, label, True, AngleStats.of(dx), AngleStats.of(dy), int(np.count_nonzero(~valid)), note)


def _unavailable(name: str, note: str) -> TraceComparison:
    empty = AngleStats(0, math.nan, math.nan, math.nan)
    return TraceComparison(name, TRACE_LABELS.get(name, name), False, empty, empty, 0, note)


def compare_capture(
    tel,
    estimators: Sequence[str] = registry.COMPARE_DEFAULT,
    settings: MahonySettings | None = None,
    *,
    variant: str | None = None,
    variant_source: str = "variant setting",
) -> ComparisonReport:
    """Compare a capture's firmware angles with the seeded ST-Mahony replica and with ``estimators``.

    Args:
        tel: a :class:`steval_link.link.telemetry.Telemetry` with at least one attitude row.
        estimators: registry names run from power-up over the capture's inputs (``st-mahony`` here means the
            unseeded replica from power-up; the seeded replica is always compared). Names this installation lacks are
            reported as unavailable.
        settings: filter settings for the replica (default: those of the status frames, else the firmware's).
        variant: the ST release whose filter the replica runs (named by ``variant_source``); default: recognised
            from the data (the variant bit-exact on the most steps).

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

    replica, rep, prow = compare_replica(tel, settings, variant=variant, variant_source=variant_source)
    if replica is not None:
        thx = np.full(n, np.nan)
        thy = np.full(n, np.nan)
        thx[prow] = rep.thx_rad
        thy[prow] = rep.thy_rad
        valid = np.zeros(n, bool)
        valid[prow] = rep.seeded
        note = "bit-exact" if replica.all_exact else ("not seeded" if replica.seeded == 0 else "")
        traces.append(_trace(REPLICA_TRACE, "ST-Mahony port", thx, thy, valid, fw_thx, fw_thy, note))
    if (~exact).any():
        notes.append(
            f"{int((~exact).sum())} text-mode rows: their angles and inputs are rounded and carry no quaternion, so "
            "the port cannot be bit-exact there; firmware angles are compared with the other estimators only"
        )
        if replica is None:
            traces.append(_unavailable(REPLICA_TRACE, "text-mode capture: the bit-exact port needs binary frames"))

    estimates: dict[str, Any] = {}
    decimation = row_decimation(tel)
    for name in estimators:
        est, why = run_estimator(name, tel, decimation=decimation)
        if est is None:
            traces.append(_unavailable(name, why))
            continue
        estimates[name] = est
        label = TRACE_LABELS.get(name, name)
        traces.append(_trace(name, label, est.thx_rad, est.thy_rad, est.valid, fw_thx, fw_thy, why))

    if tel.source.get("symbols"):  # the emulator's reads by symbol: the attitude itself, or a check of the frames
        notes.append(tel.source["symbols"])
    notes.extend(link_notes(tel))
    nan_x = int(np.count_nonzero(~np.isfinite(fw_thx)))
    nan_y = int(np.count_nonzero(~np.isfinite(fw_thy)))
    values_bad = values_bad_report(tel)
    if nan_x or nan_y:
        why = (
            "its filter output is NaN or out of range, see above"
            if values_bad
            else "asin out of range at extreme rates"
        )
        notes.append(f"firmware NaN steps: {nan_x} pitch, {nan_y} roll ({why}); excluded from the statistics")
    src = tel.source or {}
    truth = truth_section(tel, rep, prow, estimates)
    return ComparisonReport(
        source={"path": src.get("path"), "kind": src.get("kind")},
        rows=n,
        binary_rows=int(exact.sum()),
        text_rows=int((~exact).sum()),
        firmware_nan_pitch=nan_x,
        firmware_nan_roll=nan_y,
        rates=rate_stats(tel),
        filter_settings=filter_settings_report(tel),
        replica=replica,
        traces=traces,
        notes=notes,
        values_bad=values_bad,
        held_back=held_back_sentence(tel.stats.implausible, tel.stats.held_values) if tel.stats.implausible else None,
        t_rel_s=relative_time_s(a.step, a.t_fw_s),
        replay=rep,
        replica_rows=prow,
        estimates=estimates,
        truth=truth,
    )


def truth_section(tel, rep, prow, estimates: dict[str, Any]) -> dict[str, Any] | None:
    """Inclination RMSE (deg, movement steps) of the firmware, the replica and each estimator against the ground truth
    a capture keeps (chunks T of an emulated BROAD run, matched to the frames by AHRS step), or None without one.
    The firmware and the replica are scored from their thx/thy (``quaternion_from_euler(thx, thy, 0)``) as
    ``steval evaluate --firmware`` scores them; the estimators from their quaternions as ``steval evaluate``."""
    src = tel.source or {}
    if src.get("kind") != "stv" or not src.get("path"):
        return None
    try:
        truth = capture_truth(read_recording(src["path"]).chunks)
    except (UserError, OSError):
        return None
    if truth is None:
        return None
    a = tel.attitude
    order = np.argsort(truth.step, kind="stable")
    t_step = truth.step[order]
    idx = np.clip(np.searchsorted(t_step, a.step), 0, max(len(t_step) - 1, 0))
    hit = (t_step[idx] == a.step) if len(t_step) else np.zeros(len(a.step), bool)
    q_true = np.full((len(a.step), 4), np.nan)
    q_true[hit] = truth.q_wxyz[order][idx[hit]]
    movement = np.zeros(len(a.step), bool)
    movement[hit] = truth.movement[order][idx[hit]]
    out: dict[str, float | None] = {}
    _, out["firmware"] = score_euler(a.thx_rad, a.thy_rad, q_true, movement)
    if rep is not None and prow is not None:
        thx = np.full(len(a.step), np.nan)
        thy = np.full(len(a.step), np.nan)
        thx[prow], thy[prow] = rep.thx_rad, rep.thy_rad
        _, out[REPLICA_TRACE] = score_euler(thx, thy, q_true, movement)
    for name, est in estimates.items():
        q = np.asarray(est.q_wxyz, dtype=np.float64)
        out[name] = broad.rmse_deg(broad.inclination_error_rad(q, q_true), movement)
    return {
        "source": "capture chunks T",
        "steps_matched": int(hit.sum()),
        "movement_steps": int(movement.sum()),
        "metric": "inclination RMSE over movement steps, degrees",
        "rmse_deg": {k: json_number(v) for k, v in out.items()},
    }

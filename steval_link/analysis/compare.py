"""``steval compare``: the firmware's own angles against the bit-exact replica (:mod:`~steval_link.analysis.diagnosis`;
not on text-mode rows), the EKFs and accelerometer tilt: RMS and max |Δ| of ``thx`` (pitch, about x) and ``thy`` (roll,
about y) in degrees, wrapped to ±180°, firmware NaN rows excluded; rate, drops, the step cost and the settings."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from steval_link.analysis.diagnosis import compare_replica, filter_settings_report
from steval_link.analysis.link_stats import link_notes, rate_stats, relative_time_s, step_cost
from steval_link.analysis.report import (
    REPLICA_TRACE,
    TRACE_LABELS,
    AngleStats,
    ComparisonReport,
    Coverage,
    TraceComparison,
    angle_diff_rad,
    coverage_of,
    format_report,  # noqa: F401 (the CLI imports it from here)
    json_number,
    on_rows,
    truth_on_steps,
)
from steval_link.analysis.summary import values_bad_report
from steval_link.emulation import broad
from steval_link.emulation.broad import score_euler
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.estimators.runner import row_decimation, run_estimator
from steval_link.estimators.st_mahony import MahonySettings
from steval_link.link.capture import capture_truth
from steval_link.link.load import read_recording
from steval_link.link.plausibility import held_back_sentence


def _trace(name: str, label: str, thx, thy, valid, fw_thx, fw_thy, note: str = "") -> TraceComparison:
    thx, thy = np.asarray(thx, dtype=np.float64), np.asarray(thy, dtype=np.float64)
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
    """Compare a capture's firmware angles with the seeded replica (``settings`` default: the status frames', else the
    firmware's; ``variant`` default: recognised) and with ``estimators`` run from power-up (missing: unavailable)."""
    a = tel.attitude
    n = len(a)
    if n == 0:
        raise ValueError("the capture has no attitude frames")
    fw = (np.asarray(a.thx_rad, dtype=np.float64), np.asarray(a.thy_rad, dtype=np.float64))
    exact = np.asarray(a.exact, bool)
    replica, rep, prow = compare_replica(tel, settings, variant=variant, variant_source=variant_source)
    traces, notes = _replica_trace(replica, rep, prow, n, fw, int((~exact).sum()))
    est_traces, estimates, est_notes = _estimator_traces(tel, estimators, fw)
    traces += est_traces
    notes += est_notes
    if tel.source.get("symbols"):  # the emulator's reads by symbol: the attitude itself, or a check of the frames
        notes.append(tel.source["symbols"])
    notes.extend(link_notes(tel))
    nan_x, nan_y = (int(np.count_nonzero(~np.isfinite(angle))) for angle in fw)
    values_bad = values_bad_report(tel)
    if nan_x or nan_y:
        why = (
            "the capture carries no firmware angles, only its inputs"
            if nan_x == n and nan_y == n and not exact.any()
            else "its filter output is NaN or out of range, see above"
            if values_bad
            else "asin out of range at extreme rates"
        )
        notes.append(f"firmware NaN steps: {nan_x} pitch, {nan_y} roll ({why}); excluded from the statistics")
    src = tel.source or {}
    cost = step_cost(tel)  # the one AHRS step cost (replay --json gives the same)
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
        truth=truth_section(tel, rep, prow, estimates),
        ahrs_step_cost=None if cost is None else cost.to_json(),
        ahrs_step_cost_text=None if cost is None else cost.sentence(),
    )


def _replica_trace(replica, rep, prow, n: int, fw, text_rows: int) -> tuple[list[TraceComparison], list[str]]:
    """The seeded replica's trace (or why it did not run) and the note on text-mode rows."""
    traces, notes = [], []
    if replica is not None:
        note = "bit-exact" if replica.all_exact else ("not seeded" if replica.seeded == 0 else "")
        thx, thy = on_rows(n, prow, rep.thx_rad), on_rows(n, prow, rep.thy_rad)
        traces.append(
            _trace(REPLICA_TRACE, "ST-Mahony replica", thx, thy, on_rows(n, prow, rep.seeded, False, bool), *fw, note)
        )
    if text_rows:
        notes.append(
            f"{text_rows} text-mode rows: their angles and inputs are rounded and carry no quaternion, so "
            "the replica cannot be bit-exact there; firmware angles are compared with the other estimators only"
        )
        if replica is None:
            traces.append(_unavailable(REPLICA_TRACE, "text-mode capture: the bit-exact replica needs binary frames"))
    return traces, notes


def _estimator_traces(tel, estimators: Sequence[str], fw) -> tuple[list[TraceComparison], dict[str, Any], list[str]]:
    """Each estimator run from power-up and compared with the firmware (unavailable without its inputs)."""
    a = tel.attitude
    traces, estimates, notes = [], {}, []
    decimation = row_decimation(tel)
    has_acc = bool(np.isfinite(a.acc_mg).all(axis=1).any())
    has_gyro = bool(np.isfinite(a.gyro_mdps).all(axis=1).any())
    if not (has_acc and has_gyro):
        notes.append(_inputs_absent_note(has_acc, has_gyro))
    for name in estimators:
        if not has_acc or (not has_gyro and name != "accel"):
            traces.append(_unavailable(name, f"needs {'acc' if name == 'accel' else 'acc and gyro'}: absent"))
            continue
        est, why = run_estimator(name, tel, decimation=decimation)
        if est is None:
            traces.append(_unavailable(name, why))
            continue
        estimates[name] = est
        traces.append(_trace(name, TRACE_LABELS.get(name, name), est.thx_rad, est.thy_rad, est.valid, *fw, why))
    return traces, estimates, notes


def _inputs_absent_note(has_acc: bool, has_gyro: bool) -> str:
    """What can be compared when the rows carry no accelerometer or gyro (a text log of angles)."""
    if has_acc:
        return (
            "no gyro in this capture: accel-only tilt is compared with the firmware's angles; the other estimators "
            "need gyro"
        )
    return (
        "no accelerometer or gyro in this capture (the firmware's angles only): the estimators need them "
        "(accel-only tilt needs acc; the EKFs and the replica need acc and gyro); print them too, or map them, "
        "to compare"
    )


def truth_section(tel, rep, prow, estimates: dict[str, Any]) -> dict[str, Any] | None:
    """Inclination RMSE (deg, movement steps) of the firmware, replica and estimators against kept truth, or None."""
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
    q_true, movement, hit = truth_on_steps(truth.step, truth.q_wxyz, truth.movement, a.step)
    out: dict[str, float | None] = {}
    cov: dict[str, Coverage] = {}
    scored = movement & np.isfinite(q_true).all(axis=1)
    t_fw = np.asarray(a.t_fw_s, np.float64)
    eulers = [("firmware", a.thx_rad, a.thy_rad)]
    if rep is not None and prow is not None:
        eulers.append((REPLICA_TRACE, on_rows(len(a.step), prow, rep.thx_rad), on_rows(len(a.step), prow, rep.thy_rad)))
    for name, thx, thy in eulers:
        _, out[name] = score_euler(thx, thy, q_true, movement)
        cov[name] = coverage_of(np.isfinite(thx) & np.isfinite(thy), scored, a.step, t_fw)
    for name, est in estimates.items():
        q = np.asarray(est.q_wxyz, dtype=np.float64)
        out[name] = broad.rmse_deg(broad.inclination_error_rad(q, q_true), movement)
        cov[name] = coverage_of(np.isfinite(q).all(axis=1), scored, a.step, t_fw)
    return {
        "source": "capture chunks T",
        "steps_matched": int(hit.sum()),
        "movement_steps": int(movement.sum()),
        "metric": "inclination RMSE over movement steps, degrees",
        "rmse_deg": {k: json_number(v) for k, v in out.items()},
        "scored_fraction": {k: c.to_json()["scored_fraction"] for k, c in cov.items()},
        "diverged_at_step": {k: c.diverged_at_step for k, c in cov.items()},
        "diverged_at_s": {k: c.to_json()["diverged_at_s"] for k, c in cov.items()},
        "coverage_notes": {k: c.sentence() for k, c in cov.items() if not c.complete},
    }

"""Accuracy against ground truth: every estimator on BROAD trials (through the STEVAL sensor pipeline model, or at
the trial's own rate) or on a capture with a ground-truth sidecar; inclination RMSE per trial and estimator.

Metric (BROAD): ``q_err = q_est ⊗ q_true⁻¹`` (earth frame), inclination error ``2·acos(√(w² + z²))``, RMSE in
degrees over the ``movement`` samples, ignoring NaN (occluded ground truth). See :mod:`steval_link.emulation.broad`.

Firmware (``--firmware ELF``): each ELF runs on the emulated board fed with the trial's motion and its own attitude
output is scored against the same truth, aligned per step the same way (:mod:`steval_link.analysis.firmware_eval`):
one more column of the table, and one line per firmware per trial with its instructions per AHRS step and the
bit-exact replica's score on the firmware's own inputs.

Ground truth for a capture (``.stv``, raw dump or text log): a sidecar ``<capture>.truth.npz`` next to it (or
given explicitly) with ``step`` (M,) int (the AHRS step counter of the frames, ``tel.attitude.step``), ``quat``
(M, 4) float wxyz body → earth (x right, y forward, z up body axes; z up earth), and optionally ``movement`` (M,)
bool (default: all True). Steps without a truth row are ignored.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from steval_link.analysis.firmware_eval import FirmwareResult
from steval_link.analysis.plots import require_matplotlib
from steval_link.analysis.report import json_number
from steval_link.constants import AHRS_RATE_HZ
from steval_link.emulation import broad
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.link.capture import capture_truth
from steval_link.link.load import read_recording, telemetry_of_recording

__all__ = [
    "EstimatorSpec",
    "TrialResult",
    "default_specs",
    "spec_labels",
    "evaluate_view",
    "evaluate_trial",
    "evaluate_capture",
    "truth_sidecar_path",
    "summary",
    "format_table",
    "plot_evaluation",
    "MEAN_TRIALS",
    "add_firmware",
    "firmware_lines",
]

#: the trials of the headline mean (BROAD 02, 07, 15, 24: slow/fast rotation, fast translation, tapping)
MEAN_TRIALS = ("02", "07", "15", "24")
#: throttle of the firmware's "flight mode" (kp 0.4) and "ground mode" (kp 10) runs
THR_FLIGHT = 450
THR_GROUND = 0


@dataclass(frozen=True)
class EstimatorSpec:
    """One evaluated estimator: a table label, a registry name, its options and the throttle it is fed."""

    label: str
    name: str
    options: dict = field(default_factory=dict)
    thr: int = 0


def spec_labels() -> tuple[str, ...]:
    """Every label :func:`default_specs` knows, in table order."""
    return ("st-mahony-flight", "st-mahony-ground", "accel", "ekf3", "mekf", "vqf")


def default_specs(rate_hz: float, *, own_rate: bool = False, only: Sequence[str] | None = None) -> list[EstimatorSpec]:
    """The estimators of ``steval evaluate`` for inputs at ``rate_hz``.

    ``st-mahony-flight``/``-ground``: the firmware's filter with thr 450 (kp 0.4) / thr 0 (kp 10); with ``own_rate``
    its dt is 1/rate (the firmware's 6.25 ms otherwise). ``accel``: accelerometer-only tilt. ``ekf3``, ``mekf``,
    ``vqf`` at ``rate_hz`` (mekf's pipeline-latency compensation is off with ``own_rate``). ``vqf`` is left out when
    the package is missing (unless asked for by name in ``only``, which then raises UserError). ``only`` selects
    labels; the registry name of an estimator (``st-mahony``) selects both Mahony runs.
    """
    specs = {
        "st-mahony-flight": EstimatorSpec(
            "st-mahony-flight", "st-mahony", {"dt_s": 1.0 / rate_hz} if own_rate else {}, THR_FLIGHT
        ),
        "st-mahony-ground": EstimatorSpec(
            "st-mahony-ground", "st-mahony", {"dt_s": 1.0 / rate_hz} if own_rate else {}, THR_GROUND
        ),
        "accel": EstimatorSpec("accel", "accel", {}),
        "ekf3": EstimatorSpec("ekf3", "ekf3", {"rate_hz": rate_hz}),
        "mekf": EstimatorSpec("mekf", "mekf", {"rate_hz": rate_hz, **({"latency_s": 0.0} if own_rate else {})}),
        "vqf": EstimatorSpec("vqf", "vqf", {"rate_hz": rate_hz}),
    }
    if only is None:
        return [s for k, s in specs.items() if k != "vqf" or registry.is_available("vqf")]
    out: list[EstimatorSpec] = []
    for item in only:
        item = item.strip()
        if not item:
            continue
        chosen = [s for k, s in specs.items() if k == item or s.name == item]
        if not chosen and registry.is_known(item):  # your own (FILE.py:CLASS, module:CLASS, a plug-in, options)
            sel = registry.resolve(item)
            taken = {s.label for s in out}
            label = registry.unique_name(sel, taken, repeated=str(sel) in taken)
            chosen = [EstimatorSpec(label, sel, {"rate_hz": rate_hz} if registry.accepts(sel, "rate_hz") else {})]
            try:
                registry.create(sel, **chosen[0].options)  # its options and constructor checked before the work
            except ValueError as exc:
                raise UserError(str(exc)) from None
        if not chosen:
            raise UserError(
                f"unknown estimator {item!r}; choose from: {', '.join(spec_labels())} (or st-mahony), "
                "FILE.py:CLASS, module:CLASS or an installed plug-in"
            )
        if item == "vqf" and not registry.is_available("vqf"):
            raise UserError('estimator vqf needs the vqf package: pip install "steval-link[vqf]"')
        out.extend(s for s in chosen if s not in out)
    if not out:
        raise UserError("--estimators selects no estimator")
    return out


@dataclass
class TrialResult:
    """The outcome of one trial (or capture).

    Attributes:
        name: trial name (file stem).
        rate_hz: step rate of the evaluated inputs, Hz.
        t_s: (M,) step times, s.
        movement: (M,) bool, steps that count.
        rmse_deg: label → inclination RMSE, degrees.
        err_rad: label → (M,) inclination error, rad.
        steps_per_s: label → estimator speed, steps/s.
        err_t_s: label → (K,) times of ``err_rad[label]`` when not ``t_s`` (a firmware's own steps), s.
        firmware: the firmware runs on this trial (``--firmware``).
    """

    name: str
    rate_hz: float
    t_s: np.ndarray
    movement: np.ndarray
    rmse_deg: dict[str, float] = field(default_factory=dict)
    err_rad: dict[str, np.ndarray] = field(default_factory=dict)
    steps_per_s: dict[str, float] = field(default_factory=dict)
    err_t_s: dict[str, np.ndarray] = field(default_factory=dict)
    firmware: list[FirmwareResult] = field(default_factory=list)


def add_firmware(res: TrialResult, fw: FirmwareResult) -> None:
    """Put a firmware run into a trial's result: its column (RMSE, error over its own steps) and its line."""
    res.rmse_deg[fw.label] = fw.rmse_deg
    res.err_rad[fw.label] = fw.err_rad
    res.err_t_s[fw.label] = fw.truth.t_trial_s
    res.steps_per_s[fw.label] = float("nan")  # emulated: its cost is the instructions per step
    res.firmware.append(fw)


def _firmware_dict(fw: FirmwareResult) -> dict:
    st = fw.settings
    return {
        "trial": fw.trial,
        "firmware": fw.label,
        "elf": fw.elf,
        "attitude_from": fw.source,
        "rmse_deg": _rounded(fw.rmse_deg),
        "steps": fw.steps,
        "movement_steps": int(np.count_nonzero(fw.truth.movement)),
        "instructions_per_step": fw.instructions_summary(),
        "port_rmse_deg": _rounded(fw.replica_rmse_deg),
        "port_bit_exact_steps": fw.replica_bit_exact,
        "port_steps": fw.replica_steps,
        "port_settings": None
        if st is None
        else {
            "kp_ground": st.kp_ground,
            "kp_flight": st.kp_flight,
            "ki": st.ki,
            "dt_s": st.dt_s,
            "min_thr": st.min_thr,
            "correction": st.correction,
        },
        "emulated_s": round(fw.emulated_s, 3),
        "wall_s": round(fw.wall_s, 2),
        "notes": list(fw.notes),
    }


def firmware_lines(results: Sequence[TrialResult]) -> list[str]:
    """One line per firmware per trial: RMSE, instructions per AHRS step, the replica's RMSE on its inputs."""
    fws = [fw for r in results for fw in r.firmware]
    if not fws:
        return []
    w0 = max(len(fw.trial) for fw in fws)
    w1 = max(len(fw.label) for fw in fws)
    out = [
        "firmware on the emulated board: inclination RMSE (deg) of its own thx/thy; instructions per AHRS step "
        "(emulator counts, interrupts excluded); the bit-exact ST-Mahony port on the firmware's own inputs"
    ]
    for fw in fws:
        ins = fw.instructions_summary()
        cost = "n/a" if ins["median"] is None else f"{ins['median']:.0f} instr/step ({ins['min']}-{ins['max']})"
        replica = (
            "port n/a"
            if fw.replica_rmse_deg is None
            else f"port {_fmt(fw.replica_rmse_deg)}, bit-exact {fw.replica_bit_exact}/{fw.replica_steps} steps"
        )
        note = f"  [{'; '.join(fw.notes)}]" if fw.notes else ""
        out.append(
            f"{fw.trial.ljust(w0)}  {fw.label.ljust(w1)}  {_fmt(fw.rmse_deg)}  {cost}  ({fw.source}; {replica}; "
            f"{fw.emulated_s:.0f} s emulated in {fw.wall_s:.1f} s wall){note}"
        )
    return out


def _fmt(x) -> str:
    v = json_number(x)
    return "—" if v is None else f"{v:.3f}"


Progress = Callable[[str, str], None]


def evaluate_view(
    view: broad.SteValView, specs: Sequence[EstimatorSpec], name: str, progress: Progress | None = None
) -> TrialResult:
    """Run every estimator of ``specs`` on ``view``'s inputs and score it against ``view``'s ground truth."""
    res = TrialResult(name, view.rate_hz, view.t_s, view.movement)
    for spec in specs:
        if progress:
            progress(name, spec.label)
        try:
            est = registry.create(spec.name, **spec.options)
        except (ImportError, ValueError) as exc:
            raise UserError(str(exc)) from None
        thr = np.full(view.acc_mg.shape[0], spec.thr, dtype=np.int64)
        t0 = time.perf_counter()
        out = est.run(view.acc_mg, view.gyro_mdps, thr)
        elapsed = time.perf_counter() - t0
        # the quaternion is scored wherever it is finite (``valid`` may also flag Euler-angle trouble, e.g. the
        # firmware's thy = NaN when |q| < 1 pushes asin's argument out of range; q itself is still the estimate)
        q = np.asarray(out.q_wxyz, dtype=np.float64)
        err = broad.inclination_error_rad(q, view.quat_true_wxyz)
        res.err_rad[spec.label] = err
        res.rmse_deg[spec.label] = broad.rmse_deg(err, view.movement)
        res.steps_per_s[spec.label] = view.acc_mg.shape[0] / elapsed if elapsed > 0 else float("inf")
    return res


def evaluate_trial(
    path,
    specs: Sequence[EstimatorSpec] | None = None,
    *,
    own_rate: bool = False,
    seed: int = 0,
    progress: Progress | None = None,
) -> TrialResult:
    """Load a BROAD trial and evaluate ``specs`` (default: :func:`default_specs`) on it.

    Without ``own_rate`` the trial goes through the STEVAL sensor pipeline model to 161.5 Hz AHRS steps
    (:func:`steval_link.emulation.broad.steval_view`, deterministic for a given ``seed``); with ``own_rate`` the
    estimators run on the trial's own samples at its own rate (285.7 Hz).
    """
    trial = path if isinstance(path, broad.BroadTrial) else broad.load_trial(path)
    view = broad.own_rate_view(trial) if own_rate else broad.steval_view(trial, seed=seed)
    if specs is None:
        specs = default_specs(view.rate_hz, own_rate=own_rate)
    return evaluate_view(view, specs, trial.name, progress)


def truth_sidecar_path(capture) -> Path:
    """``<capture>.truth.npz`` (e.g. ``flight.stv`` → ``flight.stv.truth.npz``)."""
    p = Path(capture)
    return p.with_name(p.name + ".truth.npz")


def _load_sidecar(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    try:
        with np.load(path, allow_pickle=False) as z:
            if "step" not in z.files or "quat" not in z.files:
                raise UserError(f"{path}: a ground-truth sidecar needs 'step' and 'quat' arrays")
            step = np.asarray(z["step"]).astype(np.int64).reshape(-1)
            quat = np.asarray(z["quat"], dtype=np.float64)
            mov = np.asarray(z["movement"]).astype(bool).reshape(-1) if "movement" in z.files else None
    except UserError:
        raise
    except Exception as exc:
        raise UserError(f"{path}: cannot read the ground-truth sidecar ({type(exc).__name__}: {exc})") from None
    if quat.shape != (step.shape[0], 4) or (mov is not None and mov.shape != step.shape):
        raise UserError(f"{path}: sidecar shapes do not match (step {step.shape}, quat {quat.shape})")
    return step, quat, np.ones(step.shape, bool) if mov is None else mov


def evaluate_capture(
    path, specs: Sequence[EstimatorSpec] | None = None, *, truth=None, progress: Progress | None = None
) -> TrialResult:
    """Evaluate estimators on a capture's own AHRS inputs against a ground-truth sidecar (see the module doc), or,
    without one, the truth the capture keeps (chunks T of ``steval emulate --broad``).

    The firmware's own estimate (``q`` of binary frames) is scored as ``firmware`` when present.
    """

    p = Path(path)
    src = read_recording(p)  # missing, unreadable, empty: its own sentence
    try:
        tel = telemetry_of_recording(src)
    except UserError:
        raise UserError(
            f"{p} is not a trial or capture: not a BROAD trial (.npz), and no steval frames in its "
            f"{len(src.data)} bytes"
        ) from None
    side = Path(truth) if truth is not None else truth_sidecar_path(p)
    kept = capture_truth(src.chunks) if truth is None and not side.is_file() else None
    if kept is None and not side.is_file():
        raise UserError(f"{p}: no ground truth; expected the sidecar {side} (step, quat[, movement])")
    att = tel.attitude
    if len(att.step) == 0:
        raise UserError(f"{p}: no attitude frames")
    if kept is not None:  # an emulated BROAD run keeps the truth it was fed (chunks T)
        step, quat, mov = kept.step, kept.q_wxyz, kept.movement
    else:
        step, quat, mov = _load_sidecar(side)
    order = np.argsort(step)
    step, quat, mov = step[order], quat[order], mov[order]
    idx = np.searchsorted(step, att.step)
    idx_c = np.clip(idx, 0, len(step) - 1)
    hit = (idx < len(step)) & (step[idx_c] == att.step)
    q_true = np.full((len(att.step), 4), np.nan)
    q_true[hit] = quat[idx_c[hit]]
    movement = np.zeros(len(att.step), bool)
    movement[hit] = mov[idx_c[hit]]
    t = np.asarray(att.t_fw_s, dtype=np.float64)
    dt = np.diff(t)
    rate = float(1.0 / np.median(dt)) if dt.size and np.median(dt) > 0 else AHRS_RATE_HZ
    view = broad.SteValView(
        np.asarray(att.acc_mg, np.float32), np.asarray(att.gyro_mdps, np.float32), t, q_true, movement, rate
    )
    if specs is None:
        specs = default_specs(AHRS_RATE_HZ)
    res = evaluate_view(view, specs, p.stem, progress)
    q_fw = np.asarray(att.q_wxyz, dtype=np.float64)
    if np.isfinite(q_fw).any():
        err = broad.inclination_error_rad(q_fw, q_true)
        res.err_rad["firmware"] = err
        res.rmse_deg["firmware"] = broad.rmse_deg(err, movement)
        res.steps_per_s["firmware"] = float("nan")
    return res


def _trial_key(name: str) -> str:
    return name.split("_", 1)[0]


def summary(results: Sequence[TrialResult], number: Callable[[float | None], float | None] | None = None) -> dict:
    """JSON-ready report: per-trial RMSE and speed, the mean over all trials, and over BROAD 02/07/15/24 if present.

    ``number``: how each figure is written (default: to 4 decimals, for JSON; the table rounds the raw values once).
    """
    rnd = number or _rounded
    labels: list[str] = []
    for r in results:
        labels.extend(k for k in r.rmse_deg if k not in labels)
    trials = [
        {
            "trial": r.name,
            "rate_hz": r.rate_hz,
            "steps": int(r.t_s.shape[0]),
            "rmse_deg": {k: rnd(r.rmse_deg.get(k)) for k in labels},
            "steps_per_s": {k: rnd(r.steps_per_s.get(k)) for k in labels},
        }
        for r in results
    ]
    out = {
        "metric": "inclination RMSE over movement samples, degrees",
        "estimators": labels,
        "trials": trials,
        "mean_rmse_deg": {k: rnd(_mean([r.rmse_deg.get(k) for r in results])) for k in labels},
    }
    fws = [_firmware_dict(fw) for r in results for fw in r.firmware]
    if fws:
        out["firmware"] = fws
        out["firmware_metric"] = (
            "inclination RMSE of quaternion_from_euler(thx, thy, 0) of the firmware's own "
            "output (the port's the same way), over movement steps, degrees"
        )
    sel = [r for r in results if _trial_key(r.name) in MEAN_TRIALS]
    if {_trial_key(r.name) for r in sel} == set(MEAN_TRIALS):
        out["mean_02_07_15_24_rmse_deg"] = {k: rnd(_mean([r.rmse_deg.get(k) for r in sel])) for k in labels}
    return out


def _mean(values) -> float:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.mean(v)) if v else float("nan")


def _rounded(x) -> float | None:
    """A JSON number to 4 decimals (None for NaN/inf)."""
    v = json_number(x)
    return None if v is None else round(v, 4)


def format_table(results: Sequence[TrialResult]) -> str:
    """A plain-text table: one row per trial, one column per estimator (inclination RMSE, °), mean rows."""
    s = summary(results, json_number)  # raw values: the table rounds once, as the firmware lines below
    labels = s["estimators"]
    w0 = max([len("trial")] + [len(r.name) for r in results] + [len("mean 02/07/15/24")])
    widths = [max(len(k), 7) for k in labels]
    lines = [
        "inclination RMSE (deg) over movement samples",
        "  ".join(["trial".ljust(w0)] + [k.rjust(w) for k, w in zip(labels, widths)]),
    ]

    def row(name, values):
        cells = ["—".rjust(w) if v is None else f"{v:.3f}".rjust(w) for v, w in zip(values, widths)]
        return "  ".join([name.ljust(w0)] + cells)

    for t in s["trials"]:
        lines.append(row(t["trial"], [t["rmse_deg"][k] for k in labels]))
    if len(results) > 1:
        lines.append(row("mean", [s["mean_rmse_deg"][k] for k in labels]))
    if "mean_02_07_15_24_rmse_deg" in s:
        lines.append(row("mean 02/07/15/24", [s["mean_02_07_15_24_rmse_deg"][k] for k in labels]))
    fw = firmware_lines(results)
    if fw:
        lines += [""] + fw
    return "\n".join(lines)


def plot_evaluation(results: Sequence[TrialResult], out_png, *, detail: int = 0) -> Path:
    """PNG: bars of RMSE per estimator per trial (top) and inclination error over time of trial ``detail``.

    Needs matplotlib (``pip install "steval-link[plot]"``; UserError otherwise).
    """

    plt = require_matplotlib()
    s = summary(results)
    labels = s["estimators"]
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(11, 8), constrained_layout=True)
    n = len(results)
    width = 0.8 / max(len(labels), 1)
    x = np.arange(n)
    for j, k in enumerate(labels):
        vals = [np.nan if t["rmse_deg"][k] is None else t["rmse_deg"][k] for t in s["trials"]]
        ax0.bar(x + (j - (len(labels) - 1) / 2) * width, vals, width, label=k)
    ax0.set_xticks(x, [r.name for r in results], rotation=15, ha="right", fontsize=8)
    ax0.set_ylabel("inclination RMSE (deg)")
    ax0.set_title("Inclination error against ground truth (movement samples)")
    ax0.legend(fontsize=8, ncol=3)
    ax0.grid(axis="y", alpha=0.3)
    r = results[min(max(detail, 0), n - 1)]
    for k in labels:
        e = np.degrees(r.err_rad[k])
        ax1.plot(r.err_t_s.get(k, r.t_s), e, lw=0.7, label=f"{k} ({r.rmse_deg[k]:.2f}°)")
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("inclination error (deg)")
    ax1.set_title(f"{r.name}: inclination error over time")
    ax1.legend(fontsize=8, ncol=3)
    ax1.grid(alpha=0.3)
    ax1.set_ylim(bottom=0)
    out = Path(out_png)
    try:
        fig.savefig(out, dpi=110)
    except OSError as exc:
        raise UserError(f"cannot write {out}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)
    return out

"""Accuracy against ground truth: every estimator (and a firmware ELF, :mod:`~steval_link.analysis.firmware_eval`) on
BROAD trials, through the STEVAL sensor pipeline model or at the trial's own rate, or on a capture with ground truth.

Metric: inclination error ``2·acos(√(w² + z²))`` of ``q_est ⊗ q_true⁻¹`` (earth frame), RMSE in degrees over the
``movement`` samples, NaN (occluded truth) ignored. A capture's sidecar ``<capture>.truth.npz``: ``step`` (M,) int,
``quat`` (M, 4) wxyz body → earth (x right, y forward, z up), optionally ``movement`` (M,) bool (default: all)."""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from steval_link.analysis.firmware_eval import FirmwareResult, cut_trial, firmware_labels, run_firmware
from steval_link.analysis.plots import require_matplotlib, save_figure
from steval_link.analysis.report import Coverage, coverage_of, json_number, percent, truth_on_steps
from steval_link.constants import AHRS_RATE_HZ
from steval_link.emulation import broad
from steval_link.emulation.elf import Elf
from steval_link.emulation.sensor_model import Lsm6dsl
from steval_link.errors import ParamError, UserError
from steval_link.estimators import registry
from steval_link.estimators.plugins import Selected, split_list
from steval_link.link.capture import capture_truth
from steval_link.link.load import read_recording, telemetry_of_recording

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


def default_specs(
    rate_hz: float, *, own_rate: bool = False, only: Sequence[str] | str | None = None
) -> list[EstimatorSpec]:
    """The estimators of ``steval evaluate`` at ``rate_hz``: ``st-mahony-flight``/``-ground`` (thr 450: kp 0.4 / thr 0:
    kp 10; with ``own_rate`` dt = 1/rate and mekf without latency compensation), ``accel``, ``ekf3``, ``mekf``, ``vqf``
    (when installed). ``only``: labels, references or selected objects, or one comma-separated text (``st-mahony``:
    both Mahony runs)."""
    mahony = {"dt_s": 1.0 / rate_hz} if own_rate else {}
    specs = {
        "st-mahony-flight": EstimatorSpec("st-mahony-flight", "st-mahony", mahony, THR_FLIGHT),
        "st-mahony-ground": EstimatorSpec("st-mahony-ground", "st-mahony", dict(mahony), THR_GROUND),
        "accel": EstimatorSpec("accel", "accel", {}),
        "ekf3": EstimatorSpec("ekf3", "ekf3", {"rate_hz": rate_hz}),
        "mekf": EstimatorSpec("mekf", "mekf", {"rate_hz": rate_hz, **({"latency_s": 0.0} if own_rate else {})}),
        "vqf": EstimatorSpec("vqf", "vqf", {"rate_hz": rate_hz}),
    }
    if only is None:
        return [s for k, s in specs.items() if k != "vqf" or registry.is_available("vqf")]
    out: list[EstimatorSpec] = []
    for item in split_list(only) if isinstance(only, str) else list(only):
        if not isinstance(item, str) or isinstance(item, Selected):  # an object chosen already: run as it is
            chosen = [EstimatorSpec(str(item), item, {})]
        elif not item.strip():
            continue
        else:
            item = item.strip()
            chosen = [s for k, s in specs.items() if k == item or s.name == item]
        if not chosen and registry.is_known(item):  # your own (FILE.py:CLASS, module:CLASS, a plug-in, options)
            sel = registry.resolve(item)
            chosen = [EstimatorSpec(str(sel), sel, {"rate_hz": rate_hz} if registry.accepts(sel, "rate_hz") else {})]
            try:
                registry.create(sel, **chosen[0].options)  # its options and constructor checked before the work
            except ValueError as exc:
                raise UserError(str(exc)) from None
        if not chosen:
            raise UserError(
                f"unknown estimator {item!r}; choose from: {', '.join(specs)} (or st-mahony), "
                "FILE.py:CLASS, module:CLASS or an installed plug-in"
            )
        if item == "vqf" and not registry.is_available("vqf"):
            raise UserError('estimator vqf needs the vqf package: pip install "steval-link[vqf]"')
        for s in chosen:
            registry.unique_name(s.label, {o.label for o in out})  # UserError for a label already taken
            out.append(s)
    if not out:
        raise ParamError("{estimators} selects no estimator", "estimators")
    return out


@dataclass
class TrialResult:
    """One trial (or capture): step rate (Hz), times ``t_s`` (M,), ``movement`` (M,); per label the inclination RMSE
    (deg), error (M,) rad, speed (steps/s), a firmware's own step times ``err_t_s`` and its coverage; firmware runs."""

    name: str
    rate_hz: float
    t_s: np.ndarray
    movement: np.ndarray
    rmse_deg: dict[str, float] = field(default_factory=dict)
    err_rad: dict[str, np.ndarray] = field(default_factory=dict)
    steps_per_s: dict[str, float] = field(default_factory=dict)
    err_t_s: dict[str, np.ndarray] = field(default_factory=dict)
    firmware: list[FirmwareResult] = field(default_factory=list)
    coverage: dict[str, Coverage] = field(default_factory=dict)

    def score(self, label: str, q_wxyz, view: broad.SteValView, steps, steps_per_s: float) -> None:
        """Score an estimate (N, 4) wxyz against ``view``'s truth under ``label`` (``steps``: each row's step)."""
        q = np.asarray(q_wxyz, dtype=np.float64)
        err = broad.inclination_error_rad(q, view.quat_true_wxyz)
        scored = np.asarray(view.movement, bool) & np.isfinite(view.quat_true_wxyz).all(axis=1)
        self.err_rad[label] = err
        self.rmse_deg[label] = broad.rmse_deg(err, view.movement)
        self.coverage[label] = coverage_of(np.isfinite(q).all(axis=1), scored, steps, view.t_s)
        self.steps_per_s[label] = steps_per_s


def add_firmware(res: TrialResult, fw: FirmwareResult) -> None:
    """Put a firmware run into a trial's result: its column (RMSE, error over its own steps) and its line."""
    res.rmse_deg[fw.label] = fw.rmse_deg
    res.err_rad[fw.label] = fw.err_rad
    res.err_t_s[fw.label] = fw.truth.t_trial_s
    res.steps_per_s[fw.label] = float("nan")  # emulated: its cost is the instructions per step
    res.coverage[fw.label] = fw.coverage
    res.firmware.append(fw)


def _firmware_dict(fw: FirmwareResult) -> dict:
    st = fw.settings
    return {
        "trial": fw.trial,
        "firmware": fw.label,
        "elf": fw.elf,
        "attitude_from": fw.source,
        "rmse_deg": rounded(fw.rmse_deg),
        **fw.coverage.to_json(),
        "gains": fw.gains,
        "steps": fw.steps,
        "movement_steps": int(np.count_nonzero(fw.truth.movement)),
        "instructions_per_step": fw.instructions_summary(),
        "replica_rmse_deg": rounded(fw.replica_rmse_deg),
        "replica_bit_exact_steps": fw.replica_bit_exact,
        "replica_steps": fw.replica_steps,
        "filter": None if st is None else st.variant,
        "replica_settings": None
        if st is None
        else {k: getattr(st, k) for k in ("kp_ground", "kp_flight", "ki", "dt_s", "min_thr", "correction")},
        "emulated_s": round(fw.emulated_s, 3),
        "wall_s": round(fw.wall_s, 2),
        "notes": list(fw.notes),
    }


def firmware_lines(results: Sequence[TrialResult]) -> list[str]:
    """One line per firmware per trial: RMSE, instructions per AHRS step, the replica's RMSE on its inputs."""
    fws = [fw for r in results for fw in r.firmware]
    if not fws:
        return []
    w0, w1 = max(len(fw.trial) for fw in fws), max(len(fw.label) for fw in fws)
    out = [
        "firmware on the emulated board: inclination RMSE (deg) of its own thx/thy; instructions per AHRS step "
        "(emulator counts, interrupts excluded); the bit-exact ST-Mahony replica on the firmware's own inputs"
    ]
    for fw in fws:
        ins = fw.instructions_summary()
        cost = "n/a" if ins["median"] is None else f"{ins['median']:.0f} instr/step ({ins['min']}-{ins['max']})"
        replica = (
            "replica n/a"
            if fw.replica_rmse_deg is None
            else f"replica {_fmt(fw.replica_rmse_deg)}, bit-exact {fw.replica_bit_exact}/{fw.replica_steps} steps"
            + ("" if fw.settings is None else f" with {fw.settings.variant}'s filter")
        )
        cov = fw.coverage
        notes = ([] if cov.complete else [cov.sentence()]) + list(fw.notes)
        note = f"  [{'; '.join(notes)}]" if notes else ""
        score = cov.cell(_fmt(fw.rmse_deg))
        out.append(
            f"{fw.trial.ljust(w0)}  {fw.label.ljust(w1)}  {score}  {cost}  ({fw.source}; {replica}; "
            f"{fw.emulated_s:.0f} s emulated in {fw.wall_s:.1f} s wall){note}"
        )
        if fw.gains:
            out.append(f"{''.ljust(w0)}  {''.ljust(w1)}  ran with {fw.gains}")
    return out


def _fmt(x) -> str:
    v = json_number(x)
    return "—" if v is None else f"{v:.3f}"


Progress = Callable[[str, str], None]


def evaluate_view(
    view: broad.SteValView,
    specs: Sequence[EstimatorSpec],
    name: str,
    progress: Progress | None = None,
    *,
    steps: np.ndarray | None = None,
) -> TrialResult:
    """Run ``specs`` on ``view``'s inputs and score them against its truth (``steps``: each row's step number)."""
    taken: set[str] = set()
    for spec in specs:  # two estimators under one label would share one column: never a silent merge
        taken.add(registry.unique_name(spec.label, taken))
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
        res.score(spec.label, out.q_wxyz, view, steps, view.acc_mg.shape[0] / elapsed if elapsed > 0 else float("inf"))
    return res


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
    """Score estimators on a capture against its sidecar or kept truth; binary frames' ``q`` as ``firmware``."""
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
    # an emulated BROAD run keeps the truth it was fed (chunks T)
    step, quat, mov = (kept.step, kept.q_wxyz, kept.movement) if kept is not None else _load_sidecar(side)
    q_true, movement, _ = truth_on_steps(step, quat, mov, att.step)
    t = np.asarray(att.t_fw_s, dtype=np.float64)
    dt = np.diff(t)
    rate = float(1.0 / np.median(dt)) if dt.size and np.median(dt) > 0 else AHRS_RATE_HZ
    view = broad.SteValView(
        np.asarray(att.acc_mg, np.float32), np.asarray(att.gyro_mdps, np.float32), t, q_true, movement, rate
    )
    specs = default_specs(AHRS_RATE_HZ) if specs is None else specs
    res = evaluate_view(view, specs, p.stem, progress, steps=np.asarray(att.step))
    if np.asarray(att.exact).any():  # binary frames carry the firmware's quaternion (text rows: NaN)
        res.score("firmware", att.q_wxyz, view, att.step, float("nan"))
    return res


def incomplete_labels(results: Sequence[TrialResult]) -> list[str]:
    """Labels whose score misses scored rows on some trial (their mean is not given, they are not ranked)."""
    return list(dict.fromkeys(k for r in results for k, c in r.coverage.items() if not c.complete))


def summary(results: Sequence[TrialResult], number: Callable[[float | None], float | None] | None = None) -> dict:
    """JSON-ready report: per-trial RMSE, coverage and speed, the means (all trials, BROAD 02/07/15/24); an incomplete
    estimator has no mean and is listed under ``incomplete``. ``number`` writes each figure (default: 4 decimals)."""
    rnd = number or rounded
    labels = list(dict.fromkeys(k for r in results for k in r.rmse_deg))
    incomplete = incomplete_labels(results)
    trials = []
    for r in results:
        cov = {k: r.coverage[k].to_json() for k in labels if k in r.coverage}
        trials.append(
            {
                "trial": r.name,
                "rate_hz": r.rate_hz,
                "steps": int(r.t_s.shape[0]),
                "rmse_deg": {k: rnd(r.rmse_deg.get(k)) for k in labels},
                "scored_fraction": {k: c["scored_fraction"] for k, c in cov.items()},
                "diverged_at_step": {k: c["diverged_at_step"] for k, c in cov.items()},
                "diverged_at_s": {k: c["diverged_at_s"] for k, c in cov.items()},
                "no_score_reason": {k: c["no_score_reason"] for k, c in cov.items() if c["no_score_reason"]},
                "steps_per_s": {k: rnd(r.steps_per_s.get(k)) for k in labels},
            }
        )

    def mean(rows: Sequence[TrialResult]) -> dict:
        return {k: None if k in incomplete else rnd(_mean([r.rmse_deg.get(k) for r in rows])) for k in labels}

    out = {
        "metric": "inclination RMSE over movement samples, degrees",
        "coverage": "scored_fraction: the share of the movement rows with truth the estimate covered (finite); "
        "an incomplete estimator has no mean and is not ranked",
        "estimators": labels,
        "incomplete": incomplete,
        "trials": trials,
        "mean_rmse_deg": mean(results),
    }
    fws = [_firmware_dict(fw) for r in results for fw in r.firmware]
    if fws:
        out["firmware"] = fws
        out["firmware_metric"] = (
            "inclination RMSE of quaternion_from_euler(thx, thy, 0) of the firmware's own output (the replica's the "
            "same way), over movement steps, degrees"
        )
    keys = {r.name: r.name.split("_", 1)[0] for r in results}  # "07" of "07_undisturbed_fast_rotation_B"
    sel = [r for r in results if keys[r.name] in MEAN_TRIALS]
    if {keys[r.name] for r in sel} == set(MEAN_TRIALS):
        out["mean_02_07_15_24_rmse_deg"] = mean(sel)
    return out


def _mean(values) -> float:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.mean(v)) if v else float("nan")


def rounded(x) -> float | None:
    """A JSON number to 4 decimals (None for NaN/inf)."""
    v = json_number(x)
    return None if v is None else round(v, 4)


def table_rows(results: Sequence[TrialResult]) -> tuple[list[str], list[list[str]]]:
    """The table as cells (header, a row per trial, the means), each RMSE marked with its coverage."""
    s = summary(results, json_number)  # raw values: the table rounds once, as the firmware lines below
    labels = s["estimators"]
    header = ["trial", *labels]
    rows: list[list[str]] = []
    for r, t in zip(results, s["trials"]):
        cells = [(_fmt(t["rmse_deg"][k]), r.coverage.get(k)) for k in labels]
        rows.append([t["trial"], *(text if cov is None else cov.cell(text) for text, cov in cells)])

    def mean_row(name: str, values: dict) -> list[str]:
        return [name] + ["incomplete" if k in s["incomplete"] else _fmt(values[k]) for k in labels]

    if len(results) > 1:
        rows.append(mean_row("mean", s["mean_rmse_deg"]))
    if "mean_02_07_15_24_rmse_deg" in s:
        rows.append(mean_row("mean 02/07/15/24", s["mean_02_07_15_24_rmse_deg"]))
    return header, rows


def coverage_lines(results: Sequence[TrialResult]) -> list[str]:
    """One line per incomplete score: the label, the trial and what it misses (where it diverged, or why none)."""
    return [f"{k} on {r.name}: {c.sentence()}" for r in results for k, c in r.coverage.items() if not c.complete]


def format_table(results: Sequence[TrialResult]) -> str:
    """A plain-text table of :func:`table_rows`, then what each incomplete score misses and the firmware lines."""
    header, rows = table_rows(results)
    w0 = max([len("trial")] + [len(row[0]) for row in rows])
    widths = [max([len(header[j]), 7] + [len(row[j]) for row in rows]) for j in range(1, len(header))]
    lines = ["inclination RMSE (deg) over movement samples"]
    lines += ["  ".join([row[0].ljust(w0)] + [c.rjust(w) for c, w in zip(row[1:], widths)]) for row in [header, *rows]]
    cov = coverage_lines(results)
    if cov:
        lines += ["", "incomplete scores (no mean, not ranked):"] + [f"  {c}" for c in cov]
    fw = firmware_lines(results)
    if fw:
        lines += [""] + fw
    return "\n".join(lines)


def write_csv(results: Sequence[TrialResult], path) -> Path:
    """The table as CSV (the cells of :func:`table_rows`, coverage marks included)."""
    header, rows = table_rows(results)
    out = Path(path)
    with out.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows([header, *rows])
    return out


def write_markdown(results: Sequence[TrialResult], path) -> Path:
    """The table as a Markdown table, with the coverage lines under it."""
    header, rows = table_rows(results)
    lines = ["inclination RMSE (deg) over movement samples", "", "| " + " | ".join(header) + " |"]
    lines.append("|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|")
    lines += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in rows]
    cov = coverage_lines(results)
    if cov:
        lines += ["", "Incomplete scores (no mean, not ranked):", ""] + [f"- {c}" for c in cov]
    out = Path(path)
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out


def plot_evaluation(results: Sequence[TrialResult], out_png, *, detail: int = 0) -> Path:
    """PNG of :func:`evaluation_figure` (UserError without matplotlib, or when it cannot be written)."""
    return save_figure(evaluation_figure(results, detail=detail), out_png, dpi=110)


def evaluation_figure(results: Sequence[TrialResult], *, detail: int = 0):
    """Bars of RMSE per estimator and trial (incomplete ones hatched) and trial ``detail``'s error over time."""
    plt = require_matplotlib()
    s = summary(results)
    labels = s["estimators"]
    incomplete = set(s["incomplete"])
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(11, 8), constrained_layout=True)
    n = len(results)
    width = 0.8 / max(len(labels), 1)
    x = np.arange(n)
    for j, k in enumerate(labels):
        vals = [np.nan if t["rmse_deg"][k] is None else t["rmse_deg"][k] for t in s["trials"]]
        xs = x + (j - (len(labels) - 1) / 2) * width
        if k not in incomplete:
            ax0.bar(xs, vals, width, label=k)
            continue
        # an incomplete score is drawn hollow and hatched, its coverage on it: not ranked with the complete ones
        bars = ax0.bar(xs, vals, width, label=f"{k} (incomplete: not ranked)", fill=False, hatch="//")
        for bar, t in zip(bars, s["trials"]):
            f = t["scored_fraction"].get(k)
            if f is not None and f < 1:
                h = bar.get_height() if np.isfinite(bar.get_height()) else 0.0
                ax0.annotate(percent(f), (bar.get_x() + bar.get_width() / 2, h), ha="center", va="bottom", fontsize=7)
    ax0.set_xticks(x, [r.name for r in results], rotation=15, ha="right", fontsize=8)
    ax0.set(ylabel="inclination RMSE (deg)", title="Inclination error against ground truth (movement samples)")
    ax0.legend(fontsize=8, ncol=3)
    ax0.grid(axis="y", alpha=0.3)
    r = results[min(max(detail, 0), n - 1)]
    for k in labels:
        e = np.degrees(r.err_rad[k])  # NaN stays NaN: a gap in the line, never 0
        cov = r.coverage.get(k)
        mark = "" if cov is None or cov.complete else f", {percent(cov.scored_fraction)} covered"
        (line,) = ax1.plot(r.err_t_s.get(k, r.t_s), e, lw=0.7, label=f"{k} ({_fmt(r.rmse_deg[k])}°{mark})")
        if cov is not None and cov.diverged_at_s is not None:
            ax1.axvline(cov.diverged_at_s, color=line.get_color(), ls="--", lw=0.8)
    ax1.set(xlabel="time (s)", ylabel="inclination error (deg)", ylim=(0, None))
    ax1.set_title(f"{r.name}: inclination error over time (dashed: where an estimate diverged)")
    ax1.legend(fontsize=8, ncol=3)
    ax1.grid(alpha=0.3)
    return fig


# ---- the flow of ``steval evaluate`` and ``steval_link.evaluate`` ------------------------------------------------

#: a firmware run counts this many estimator runs in the progress fraction (an emulation takes much longer)
FIRMWARE_WEIGHT = 20


def evaluate_data(
    paths,
    estimators=None,
    *,
    own_rate: bool = False,
    seed: int = 0,
    sensor_noise: bool = False,
    max_seconds: float | None = None,
    firmware: Sequence = (),
    variant: str | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> list[TrialResult]:
    """Score ``estimators`` on BROAD trials and captures with ground truth (``paths``: files and folders), and each
    ``firmware`` ELF on the emulated board with each trial. ``own_rate``: not through the STEVAL pipeline; ``variant``:
    the replica's release on a firmware's inputs. Every input is checked before the work."""
    items = broad.trial_paths(paths)
    n_specs = len(default_specs(100.0, only=estimators))  # the selection, checked before any work (any rate)
    if max_seconds is not None and not (max_seconds > 0 and math.isfinite(max_seconds)):
        raise ParamError(f"{{max_seconds}} must be a positive number of seconds, got {max_seconds}", "max_seconds")
    elfs = list(firmware)
    labels = firmware_labels(elfs)
    for elf in elfs:
        Elf(elf)  # missing or not an ARM ELF: one sentence before the long run
    n_trials = sum(p.suffix == ".npz" for p in items)
    if elfs and not n_trials:
        raise ParamError("{firmware} runs on BROAD trials (.npz): give at least one", "firmware")
    total = max(1, len(items) * n_specs + n_trials * len(elfs) * FIRMWARE_WEIGHT)
    done = 0

    def tick(name: str, stage: str, units: float = 1.0) -> None:
        nonlocal done
        if progress:
            progress(min(done / total, 1.0), f"{name[:32]}: {stage}")
        done += units

    results = []
    for p in items:
        tick(p.name, "loading", 0)
        if p.suffix != ".npz":
            results.append(evaluate_capture(p, default_specs(AHRS_RATE_HZ, only=estimators), progress=tick))
            continue
        trial = cut_trial(broad.load_trial(p), max_seconds)
        sensor = Lsm6dsl() if sensor_noise else None
        view = broad.own_rate_view(trial) if own_rate else broad.steval_view(trial, seed=seed, sensor=sensor)
        specs = default_specs(view.rate_hz, own_rate=own_rate, only=estimators)
        res = evaluate_view(view, specs, trial.name, tick)
        for elf, label in zip(elfs, labels):
            start = done

            def fw_progress(fraction: float, name=trial.name, label=label, start=start) -> None:
                if progress:
                    progress(min((start + fraction * FIRMWARE_WEIGHT) / total, 1.0), f"{name[:32]}: {label} (emulated)")

            run = run_firmware(elf, trial, label=label, seed=seed, progress=fw_progress, variant=variant)
            add_firmware(res, run)
            done += FIRMWARE_WEIGHT
        results.append(res)
    return results

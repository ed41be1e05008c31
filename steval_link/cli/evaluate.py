"""``steval evaluate``: inclination accuracy of every estimator against ground truth (BROAD trials or captures)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Optional

import typer

from steval_link.cli.app import app
from steval_link.cli.checks import VariantOption, check_variant
from steval_link.cli.data import default_broad_data
from steval_link.cli.outputs import ForceOption, JsonReportOption, atomic_output, check_output
from steval_link.cli.progress import progress_bar
from steval_link.constants import AHRS_RATE_HZ
from steval_link.emulation import broad
from steval_link.emulation.elf import Elf
from steval_link.emulation.sensor_model import Lsm6dsl
from steval_link.errors import UserError
from steval_link.estimators.plugins import split_list

__all__ = ["evaluate_command"]

#: a firmware run counts this many estimator runs on the progress bar
_FIRMWARE_WEIGHT = 20

_HELP = (
    "Inclination accuracy of the estimators against ground truth.\n\n"
    "DATA are BROAD trial .npz files (acc m/s², gyr rad/s, quat wxyz IMU→ENU, movement, fs), directories (their "
    "*.npz), or captures (.stv, raw dump, text log) with a ground-truth sidecar CAPTURE.truth.npz next to them "
    "(e.g. flight.stv.truth.npz) holding `step` (int, the frames' AHRS step counter), `quat` (wxyz, body→earth) "
    "and optionally `movement` (bool), or captures of steval emulate --broad, which keep their truth; the firmware's "
    "own estimate is then scored too.\n\n"
    "A BROAD trial runs through the STEVAL sensor pipeline model (807.7 Hz tick, LSM6DSL quantisation, 416 Hz gyro "
    "hold, the firmware's 2 s offset calibration, gyro IIR, 5-sample average → 161.5 Hz AHRS steps; "
    "deterministic); --native runs the estimators on the trial's own 285.7 Hz samples instead.\n\n"
    "Estimators: st-mahony-flight (firmware filter, thr 450, kp 0.4), st-mahony-ground (thr 0, kp 10), accel "
    "(accelerometer-only), ekf3, mekf, vqf (when installed).\n\n"
    "Firmware (--firmware ELF, repeatable): each ELF (a CubeIDE build of ST's release, patched or not, or the "
    "reference firmware) runs on the emulated board fed with each trial's motion (as steval emulate --broad), and its "
    "own attitude output (thx/thy of its attitude frames; for a build without them, its euler_ahrs global read by "
    "symbol each AHRS step) is scored against the same truth, one column each, labelled by the shortest path "
    "suffix that tells the ELFs apart. Each gets one line per trial: its RMSE, instructions per AHRS step (the "
    "emulator's counts) and the bit-exact ST-Mahony port's RMSE on the firmware's own inputs (equal for a stock "
    "build). Truth per step: the middle tick of the step's 5-tick input window (trial time 0 = the first TIM9 tick, "
    "≈ 1 s after power-up; the first 2 s are the firmware's calibration), as for the Python estimators. An "
    "emulated trial runs at a few times real time: --max-seconds cuts every trial short.\n\n"
    "Metric: q_err = q_est ⊗ q_true⁻¹, inclination error 2·acos(√(w²+z²)), RMSE (deg) over movement samples, NaN "
    "ignored. Coverage: an estimator (or firmware) whose estimate is not finite on every movement row with truth is "
    "marked with the share it covered (2.851 (63 %)) and the step it diverged at (JSON: scored_fraction, "
    "diverged_at_step, diverged_at_s); its mean reads 'incomplete' and it is not ranked with the complete ones "
    "(docs/explanation/scores.md). Exit code 2 for unreadable or malformed input."
)


@app.command("evaluate", help=_HELP)
def evaluate_command(
    data: Annotated[
        Optional[list[Path]],
        typer.Argument(
            help="BROAD .npz trials, directories of them, or captures with a .truth.npz sidecar. Default: the "
            "trials of steval data broad.",
            show_default=False,
        ),
    ] = None,
    estimators: Annotated[
        Optional[list[str]],
        typer.Option(
            "--estimators",
            "-e",
            help="Comma-separated or repeated labels: st-mahony-flight, st-mahony-ground (st-mahony: both), "
            "accel, ekf3, mekf, vqf, or your own (FILE.py:CLASS, "
            "module:CLASS, options in parentheses: docs/ESTIMATORS.md). Default: all "
            "available.",
        ),
    ] = None,
    as_json: JsonReportOption = False,
    native: Annotated[
        bool, typer.Option("--native", help="Run BROAD trials at their own rate, without the STEVAL pipeline.")
    ] = False,
    plot: Annotated[
        Optional[Path],
        typer.Option(
            "--plot",
            help="Write a PNG: RMSE bars per estimator and trial, "
            "and the first trial's error over time "
            "(needs matplotlib: pip install "
            '"steval-link\\[plot]").',
            show_default=False,
        ),
    ] = None,
    sensor_noise: Annotated[
        bool,
        typer.Option(
            "--sensor-noise",
            help="Add the LSM6DSL model's white noise (gyro "
            "75 mdps, acc 2 mg RMS) on top of the trial's "
            "own before quantisation.",
        ),
    ] = False,
    seed: Annotated[int, typer.Option("--seed", help="Seed of --sensor-noise (runs are deterministic).")] = 0,
    force: ForceOption = False,
    firmware: Annotated[
        Optional[list[Path]],
        typer.Option(
            "--firmware",
            help="A firmware ELF to run on the emulated board with each BROAD trial and score (repeatable).",
            show_default=False,
        ),
    ] = None,
    csv_out: Annotated[
        Optional[Path],
        typer.Option(
            "--csv", help="Also write the table (coverage marks included) to this CSV file.", show_default=False
        ),
    ] = None,
    markdown_out: Annotated[
        Optional[Path],
        typer.Option(
            "--markdown",
            help="Also write the table as Markdown (to paste in a report) to this file.",
            show_default=False,
        ),
    ] = None,
    max_seconds: Annotated[
        Optional[float],
        typer.Option(
            "--max-seconds",
            help="Use only the first S seconds of each BROAD trial (every estimator and firmware; "
            "the trials' movement starts after 26-46 s).",
            show_default=False,
        ),
    ] = None,
    variant: VariantOption = None,
) -> None:

    from steval_link.analysis import evaluate as ev  # reason: start-up time
    from steval_link.analysis import firmware_eval as fw  # reason: start-up time

    variant = check_variant(variant)  # the release's filter of the port on a --firmware's inputs
    items = broad.trial_paths(data or default_broad_data())  # the inputs first, then the output
    # repeatable, each value a comma-separated list (commas inside options stay)
    only = split_list(",".join(estimators)) if estimators else None
    # validate the selection once, before any work (rate does not matter for that)
    ev.default_specs(100.0, only=only)
    if max_seconds is not None and not (max_seconds > 0 and math.isfinite(max_seconds)):
        raise UserError(f"--max-seconds must be a positive number of seconds, got {max_seconds}")
    elfs = list(firmware or [])
    fw_labels = fw.firmware_labels(elfs)
    for elf in elfs:
        Elf(elf)  # missing or not an ARM ELF: one sentence before the long run
    if elfs and not any(p.suffix == ".npz" for p in items):
        raise UserError("--firmware runs on BROAD trials (.npz): give at least one")
    for out, option in ((csv_out, "--csv"), (markdown_out, "--markdown")):
        if out is not None:
            check_output(out, option=option, force=force, inputs=(*items, *elfs))
    if plot is not None:
        check_output(plot, option="--plot", force=force, inputs=(*items, *elfs))
        from steval_link.analysis.plots import require_matplotlib  # matplotlib loads only for --plot (start-up time)

        require_matplotlib()  # fail before the long run
    n_trials = sum(p.suffix == ".npz" for p in items)
    # the bar: one unit per estimator run, FIRMWARE_WEIGHT per firmware run (an emulation takes much longer)
    total = len(items) * len(ev.default_specs(100.0, only=only)) + n_trials * len(elfs) * _FIRMWARE_WEIGHT
    results = []
    with progress_bar("evaluate", quiet=as_json) as bar:
        done = 0

        def progress(trial: str, label: str) -> None:  # evaluate's per-estimator report → the bar
            nonlocal done
            bar(done / total, f"{trial[:32]}: {label}")
            done += 1

        for p in items:
            bar(done / total, f"{p.name[:32]}: loading")
            if p.suffix == ".npz":
                trial = fw.cut_trial(broad.load_trial(p), max_seconds)
                if native:
                    view = broad.own_rate_view(trial)
                else:
                    view = broad.steval_view(trial, seed=seed, sensor=Lsm6dsl() if sensor_noise else None)
                specs = ev.default_specs(view.rate_hz, own_rate=native, only=only)
                res = ev.evaluate_view(view, specs, trial.name, progress)
                for elf, label in zip(elfs, fw_labels):
                    start = done

                    def fw_progress(fraction: float, trial=trial.name, label=label, start=start) -> None:
                        bar((start + fraction * _FIRMWARE_WEIGHT) / total, f"{trial[:32]}: {label} (emulated)")

                    ev.add_firmware(
                        res, fw.run_firmware(elf, trial, label=label, seed=seed, progress=fw_progress, variant=variant)
                    )
                    done += _FIRMWARE_WEIGHT
                results.append(res)
            else:
                specs = ev.default_specs(AHRS_RATE_HZ, only=only)
                results.append(ev.evaluate_capture(p, specs, progress=progress))
        if plot is not None:
            bar(1.0, f"plotting {plot.name}")
            with atomic_output(plot, option="--plot", keep_suffix=True) as part:
                ev.plot_evaluation(results, part)
    for out, option, write in ((csv_out, "--csv", ev.write_csv), (markdown_out, "--markdown", ev.write_markdown)):
        if out is not None:
            with atomic_output(out, option=option, keep_suffix=True) as part:
                write(results, part)
    if as_json:
        report = ev.summary(results)
        report["mode"] = "native" if native else "steval-pipeline"
        report["sensor_noise"] = bool(sensor_noise and not native)
        report["seed"] = seed
        if max_seconds is not None:
            report["max_seconds"] = max_seconds
        if plot is not None:
            report["plot"] = str(plot)
        if csv_out is not None:
            report["csv"] = str(csv_out)
        if markdown_out is not None:
            report["markdown"] = str(markdown_out)
        typer.echo(json.dumps(report, allow_nan=False))
    else:
        typer.echo(ev.format_table(results))
        for out, what in ((plot, "plot"), (csv_out, "CSV table"), (markdown_out, "Markdown table")):
            if out is not None:
                typer.echo(f"{what} written to {out}")

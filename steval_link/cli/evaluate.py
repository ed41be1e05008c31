"""``steval evaluate``: inclination accuracy of every estimator against ground truth (BROAD trials or captures)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from steval_link.cli.app import app, argument, option
from steval_link.cli.checks import VariantOption, check_variant
from steval_link.cli.data import find_broad_data
from steval_link.cli.outputs import ForceOption, JsonReportOption, atomic_output, check_outputs
from steval_link.cli.progress import progress_bar
from steval_link.emulation import broad
from steval_link.errors import UserError
from steval_link.estimators.plugins import split_list

_HELP = (
    "Inclination accuracy of the estimators against ground truth.\n\n"
    "DATA are BROAD trial .npz files (acc m/s², gyr rad/s, quat wxyz IMU→ENU, movement, fs), directories (their "
    "*.npz), or captures (.stv, raw dump, text log) with a ground-truth sidecar CAPTURE.truth.npz next to them "
    "(e.g. flight.stv.truth.npz) holding `step` (int, the frames' AHRS step counter), `quat` (wxyz, body→earth) "
    "and optionally `movement` (bool), or captures of steval emulate --broad, which keep their truth; the firmware's "
    "own estimate is then scored too.\n\n"
    "A BROAD trial runs through the STEVAL sensor pipeline model (807.7 Hz tick, LSM6DSL quantisation, 416 Hz gyro "
    "hold, the firmware's 2 s offset calibration, gyro IIR, 5-sample average → 161.5 Hz AHRS steps; "
    "deterministic); --own-rate runs the estimators on the trial's own 285.7 Hz samples instead.\n\n"
    "Estimators: st-mahony-flight (firmware filter, thr 450, kp 0.4), st-mahony-ground (thr 0, kp 10), accel "
    "(accelerometer-only), ekf3, mekf, vqf (when installed).\n\n"
    "Firmware (--firmware ELF, repeatable): each ELF (a CubeIDE build of ST's release, patched or not, or the "
    "reference firmware) runs on the emulated board fed with each trial's motion (as steval emulate --broad), and its "
    "own attitude output (thx/thy of its attitude frames; for a build without them, its euler_ahrs global read by "
    "symbol each AHRS step) is scored against the same truth, one column each, labelled by the shortest path "
    "suffix that tells the ELFs apart. Each gets one line per trial: its RMSE, instructions per AHRS step (the "
    "emulator's counts) and the bit-exact ST-Mahony replica's RMSE on the firmware's own inputs (equal for a stock "
    "build). Truth per step: the middle tick of the step's 5-tick input window (trial time 0 = the first TIM9 tick, "
    "≈ 1 s after power-up; the first 2 s are the firmware's calibration), as for the Python estimators. An "
    "emulated trial runs at a few times real time: --max-seconds cuts every trial short.\n\n"
    "Metric: q_err = q_est ⊗ q_true⁻¹, inclination error 2·acos(√(w²+z²)), RMSE (deg) over movement samples, NaN "
    "ignored. Coverage: an estimator (or firmware) whose estimate is not finite on every movement row with truth is "
    "marked with the share it covered (2.851 (63 %)) and the step it diverged at (JSON: scored_fraction, "
    "diverged_at_step, diverged_at_s); its mean reads 'incomplete' and it is not ranked with the complete ones "
    "(docs/explanation/scores.md). Exit code 2 for unreadable or malformed input."
)


_OwnRate = option(bool, "--own-rate", help="Run BROAD trials at their own rate, without the STEVAL pipeline.")
_Csv = option(Path | None, "--csv", help="Also write the table (coverage marks included) to this CSV file.")


@app.command("evaluate", help=_HELP)
def evaluate_command(
    data: argument(
        list[Path] | None,
        help="BROAD .npz trials, directories of them, or captures with a .truth.npz sidecar. Default: the trials of "
        "steval data broad.",
    ) = None,
    estimators: option(
        list[str] | None,
        "--estimators",
        "-e",
        help="Comma-separated or repeated labels: st-mahony-flight, st-mahony-ground (st-mahony: both), accel, ekf3, "
        "mekf, vqf, or your own (FILE.py:CLASS, module:CLASS, options in parentheses: docs/ESTIMATORS.md). Default: "
        "all available.",
    ) = None,
    as_json: JsonReportOption = False,
    own_rate: _OwnRate = False,
    plot: option(
        Path | None,
        help="Write a PNG: RMSE bars per estimator and trial, and the first trial's error over time (needs matplotlib: "
        'pip install "steval-link\\[plot]").',
    ) = None,
    sensor_noise: option(
        bool,
        "--sensor-noise",
        help="Add the LSM6DSL model's white noise (gyro 75 mdps, acc 2 mg RMS) on top of the trial's own before "
        "quantisation.",
    ) = False,
    seed: option(int, help="Seed of --sensor-noise (runs are deterministic).") = 0,
    force: ForceOption = False,
    firmware: option(
        list[Path] | None,
        help="A firmware ELF to run on the emulated board with each BROAD trial and score (repeatable).",
    ) = None,
    csv_out: _Csv = None,
    markdown_out: option(
        Path | None, "--markdown", help="Also write the table as Markdown (to paste in a report) to this file."
    ) = None,
    max_seconds: option(
        float | None,
        help="Use only the first S seconds of each BROAD trial (every estimator and firmware; the trials' movement "
        "starts after 26-46 s).",
    ) = None,
    variant: VariantOption = None,
) -> None:
    from steval_link.analysis import evaluate as ev  # imported when run: a quick start for other commands

    variant = check_variant(variant)  # the release's filter of the replica on a --firmware's inputs
    if not data and (found := find_broad_data()) is None:
        raise UserError("no BROAD trials in the data cache: download them with `steval data broad`, or give DATA")
    data = data or [found]
    inputs = (*broad.trial_paths(data), *(firmware or []))
    outputs = {"--plot": plot, "--csv": csv_out, "--markdown": markdown_out}
    check_outputs(outputs, force=force, inputs=inputs)  # and matplotlib for --plot: before the long run
    with progress_bar("evaluate", quiet=as_json) as bar:
        results = ev.evaluate_data(
            data,
            split_list(",".join(estimators)) if estimators else None,  # repeatable, each a comma-separated list
            own_rate=own_rate,
            seed=seed,
            sensor_noise=sensor_noise,
            max_seconds=max_seconds,
            firmware=firmware or (),
            variant=variant,
            progress=bar,
        )
        writers = {"--plot": ev.plot_evaluation, "--csv": ev.write_csv, "--markdown": ev.write_markdown}
        for option, out in outputs.items():
            if out is not None:
                bar(1.0, f"writing {out.name}")
                with atomic_output(out, option=option, keep_suffix=True) as part:
                    writers[option](results, part)
    if not as_json:  # the table and the files written
        typer.echo(ev.format_table(results))
        for out, what in zip(outputs.values(), ("plot", "CSV table", "Markdown table")):
            if out is not None:
                typer.echo(f"{what} written to {out}")
        return
    report = ev.summary(results)
    report.update(mode="own-rate" if own_rate else "steval-pipeline", sensor_noise=bool(sensor_noise and not own_rate))
    report["seed"] = seed
    if max_seconds is not None:
        report["max_seconds"] = max_seconds
    report.update({flag[2:]: str(out) for flag, out in outputs.items() if out is not None})
    typer.echo(json.dumps(report, allow_nan=False))

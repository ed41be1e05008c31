"""``steval compare``: the firmware's angles against the bit-exact port, the EKFs and accelerometer-only tilt.

Exit codes: 0 when the report was produced — also when the port disagrees with the firmware (that is a finding,
shown with its first step and a diagnosis, and ``port.all_exact`` is false in ``--json``); 2 for user errors
(missing or unreadable capture, no attitude frames, unknown estimator, matplotlib missing for ``--plot``).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Optional

import typer

from steval_link.analysis.compare import compare_capture, format_report
from steval_link.cli.app import app
from steval_link.cli.checks import check_gain, check_throttle, require_attitude
from steval_link.cli.outputs import ForceOption, atomic_output, check_output
from steval_link.cli.progress import progress_bar, scaled
from steval_link.cli.replay import load_replay
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.estimators.st_mahony import MahonySettings
from steval_link.link.capture import demo_capture_path, read_source

__all__ = ["compare_command"]


def flight_plot_path(out_png: Path) -> Path:
    """Where ``--plot OUT.png`` puts the flight-control figure of a capture with flight-control frames:
    ``OUT-flight-control.png``."""
    return out_png.with_name(f"{out_png.stem}-flight-control{out_png.suffix or '.png'}")


def _settings(tel, ki, kp_ground, kp_flight, dt, min_thr, correction, fresh_squares):
    """Port settings: the status frames' (or the defaults) with the given fields replaced; None when none given."""

    changes = {
        k: v
        for k, v in dict(
            ki=ki,
            kp_ground=kp_ground,
            kp_flight=kp_flight,
            dt_s=dt,
            min_thr=min_thr,
            correction=correction,
            fresh_squares=fresh_squares,
        ).items()
        if v is not None
    }
    if not changes:
        return None
    for k, v in changes.items():
        if isinstance(v, float) and not math.isfinite(v):
            raise UserError(f"--{k.replace('_s', '').replace('_', '-')} must be a finite number, got {v}")
    if dt is not None and dt <= 0:
        raise UserError(f"--dt must be a period > 0 s, got {dt}")
    s = tel.status
    base = MahonySettings()
    ex = [j for j in range(len(s)) if s.exact[j]]
    if ex:
        j = ex[0]
        base = MahonySettings.of_status(s, j)
    return replace(base, **changes)


@app.command("compare")
def compare_command(
    capture: Annotated[
        Optional[Path],
        typer.Argument(
            help="Capture (.stv), raw serial dump or text-mode log. Default: the bundled demo recording.",
            show_default=False,
        ),
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the report as one JSON object (nothing else on stdout).")
    ] = False,
    plot: Annotated[
        Optional[Path],
        typer.Option(
            "--plot",
            metavar="OUT.png",
            help="Also write a figure (angles over time, firmware − port, "
            "differences per estimator) and, for a capture with flight-control frames, OUT-flight-control.png "
            "(targets vs angles, PID terms, motors); needs matplotlib: "
            'pip install "steval-link\\[plot]".',
        ),
    ] = None,
    estimator: Annotated[
        Optional[list[str]],
        typer.Option(
            "--estimator",
            "--estimators",
            "-e",
            help="Estimators to compare, comma-separated or repeated (default: ekf3, mekf, accel). "
            "The seeded ST-Mahony port is always compared.",
        ),
    ] = None,
    ki: Annotated[
        Optional[float],
        typer.Option(
            "--ki", help="Run the port with this AHRS_KI instead of the status frames' (diagnosis of a mismatch)."
        ),
    ] = None,
    kp_ground: Annotated[Optional[float], typer.Option("--kp-ground", help="Port kp below MIN_THR.")] = None,
    kp_flight: Annotated[Optional[float], typer.Option("--kp-flight", help="Port kp at or above MIN_THR.")] = None,
    dt: Annotated[Optional[float], typer.Option("--dt", help="Port integration period, s.")] = None,
    min_thr: Annotated[Optional[int], typer.Option("--min-thr", help="Port gain-switch throttle.")] = None,
    correction: Annotated[
        Optional[bool],
        typer.Option(
            "--correction/--no-correction", help="Port with/without accelerometer correction.", show_default=False
        ),
    ] = None,
    fresh_squares: Annotated[
        Optional[bool],
        typer.Option(
            "--fresh-squares/--stale-squares",
            help="Port normalisation variant (fresh: 2017 releases; stale: 170120).",
            show_default=False,
        ),
    ] = None,
    force: ForceOption = False,
) -> None:
    """Compare the firmware's pitch (thx) and roll (thy) with the bit-exact ST-Mahony port (bit-exact steps, first
    difference and why), the EKFs and accelerometer-only tilt: RMS and max differences in degrees, rate, jitter,
    drops and the filter settings. Exits 0 whenever the report is produced, even when the port disagrees."""

    # repeatable, and each value may be a comma-separated list like the other commands' --estimators
    names = registry.parse_names(
        ",".join(estimator) if estimator else None, registry.COMPARE_DEFAULT, require_installed=False
    )  # a missing optional package is a row of the report
    src = read_source(demo_capture_path() if capture is None else capture)  # the input first, then the outputs
    if plot is not None:
        check_output(plot, option="--plot", force=force, inputs=(src.path,))
        from steval_link.analysis.plots import require_matplotlib  # matplotlib loads only for --plot (start-up time)

        require_matplotlib()
    for option, gain in (("--ki", ki), ("--kp-ground", kp_ground), ("--kp-flight", kp_flight)):
        check_gain(option, gain)
    check_throttle("--min-thr", min_thr)
    with progress_bar("compare", quiet=as_json) as progress:
        tel, seen = load_replay(capture, scaled(progress, 0.0, 0.4), src=src)
        require_attitude(tel, "compare")
        if plot is not None and len(tel.fc):
            check_output(flight_plot_path(plot), option="--plot", force=force, inputs=(src.path,))
        for w in seen:  # the capture's damage: one line of our own on stderr (and a note in --json)
            print(f"steval: warning: {w}", file=sys.stderr)
        settings = _settings(tel, ki, kp_ground, kp_flight, dt, min_thr, correction, fresh_squares)
        progress(0.4, f"port and {', '.join(names)}")
        report = compare_capture(tel, estimators=names, settings=settings)
        if as_json:
            report.notes.extend(seen)
        if plot is not None:
            from steval_link.analysis.plots import plot_comparison  # matplotlib loads only for --plot (start-up time)

            progress(0.9, f"plotting {plot.name}")
            with atomic_output(plot, option="--plot", keep_suffix=True) as part:
                plot_comparison(tel, report, part)
                if len(tel.fc):
                    from steval_link.analysis.plots import plot_flight_control  # as above

                    fc_plot = flight_plot_path(plot)
                    with atomic_output(fc_plot, option="--plot", keep_suffix=True) as fc_part:
                        plot_flight_control(tel, fc_part)
    if as_json:
        d = report.as_dict()
        if plot is not None:
            d["plot"] = str(plot)
            if len(tel.fc):
                d["plot_flight_control"] = str(flight_plot_path(plot))
        json.dump(d, sys.stdout, indent=2, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print("\n".join(format_report(report)))
        if plot is not None:
            print(f"plot: {plot}")
            if len(tel.fc):
                print(f"flight-control plot: {flight_plot_path(plot)}")

"""``steval compare``: the firmware's angles against the bit-exact replica, the EKFs and accelerometer-only tilt."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

from steval_link.analysis import side_by_side as sbs
from steval_link.analysis.compare import compare_capture, format_report
from steval_link.analysis.flight_control import no_flight_figure_reason
from steval_link.cli import checks, outputs
from steval_link.cli.app import app, argument, option
from steval_link.cli.progress import progress_bar, scaled
from steval_link.cli.replay import MapOption, load_replay
from steval_link.cli.viewer_options import check_view_flags, view_sinks, with_rerun_options
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.estimators.runner import run_estimator
from steval_link.estimators.st_mahony import MahonySettings
from steval_link.link.capture import demo_capture_path
from steval_link.link.load import read_recording, telemetry_of_recording
from steval_viewer.sink_options import SinkOptions

#: ``-e`` of compare and report: the estimators compared with the firmware
CompareEstimatorsOption = option(
    list[str] | None,
    "--estimator",
    "--estimators",
    "-e",
    help="Estimators to compare, comma-separated or repeated (default: ekf3, mekf, accel); your own as FILE.py:CLASS "
    "or module:CLASS (docs/ESTIMATORS.md). The seeded ST-Mahony replica is always compared.",
)


@app.command("compare")
@with_rerun_options
@checks.with_filter_options("ki kp_ground kp_flight dt min_thr correction variant")
def compare_command(
    captures: argument(
        list[Path] | None,
        help="Capture (.stv), raw serial dump or text-mode log. Default: the bundled demo recording. Two or more: the "
        "flights side by side (see below).",
        metavar="CAPTURE",
    ) = None,
    as_json: outputs.JsonReportOption = False,
    plot: option(
        Path | None,
        metavar="OUT.png",
        help="Also write a figure (angles over time, firmware − replica, differences per estimator) and, for a capture "
        "whose drone was armed, OUT-flight-control.png (targets vs angles, PID terms, motors); with two or more "
        'captures one figure of the flights side by side; needs matplotlib: pip install "steval-link\\[plot]".',
    ) = None,
    estimator: CompareEstimatorsOption = None,
    filters: dict = None,
    align: option(
        str,
        metavar="time|motion",
        help="Two or more captures: align by firmware time from each first frame (time), or by cross-correlating the "
        "gyro with the first capture's (motion; the lag found is printed).",
    ) = "time",
    label: option(list[str] | None, help="Two or more captures: the name of each flight, in order (repeat it).") = None,
    force: outputs.ForceOption = False,
    text_map: MapOption = None,
    rerun: SinkOptions = None,
) -> None:
    """Compare the firmware's pitch (thx) and roll (thy) with the bit-exact ST-Mahony replica (bit-exact steps, first
    difference and why), the EKFs and accelerometer-only tilt: RMS and max differences in degrees, rate, jitter,
    drops and the filter settings. Exits 0 whenever the report is produced, even when the replica disagrees.

    Two or more captures: the flights side by side (e.g. stock against AHRS_KI=1.0f NO_CORRECTION=1), aligned by
    firmware time (or --align motion), labelled by what differs ("ki 0.1" vs "ki 1, correction off"; --label
    overrides), each against its accelerometer-only tilt in still phases (RMS, drift) and minus the first;
    mismatched inputs (durations, BLE against serial, lost frames, a truncated capture) are noted. --plot writes one
    figure, --json the settings and figures of each flight, --spawn/--serve/--connect/--rrd one Rerun recording
    with every flight in its own entity subtree, overlaid."""
    if captures and len(captures) > 1:
        given = [k for k, v in {"estimator": estimator, **filters}.items() if v is not None]
        if given:
            flags = [("--correction/--no-correction" if k == "correction" else checks.flag_of(k)) for k in given]
            verb = "applies" if len(flags) == 1 else "apply"
            raise UserError(
                f"{', '.join(flags)} {verb} to one capture; with two or more captures the flights are compared with "
                "each other (run steval compare CAPTURE on each for the replica)."
            )
        _side_by_side(captures, as_json=as_json, plot=plot, force=force, align=align, labels=label, viewer=rerun)
        return
    if align != "time" or label or rerun.any():
        raise UserError(
            "--align, --label, --rrd, --spawn, --serve and --connect are for two or more captures "
            "(one capture in Rerun: steval replay CAPTURE --spawn)."
        )
    _one_capture(captures, estimator, filters, as_json=as_json, plot=plot, force=force, text_map=text_map)


def _one_capture(captures, estimator, filters: dict, *, as_json: bool, plot, force: bool, text_map) -> None:
    """``steval compare [CAPTURE]``: the firmware against the replica and the estimators (text or JSON, figures)."""
    changes, variant = checks.filter_settings(filters)
    # a missing optional package is a row of the report
    names = checks.estimator_names(estimator, registry.COMPARE_DEFAULT, require_installed=False)
    src = read_recording(captures[0] if captures else demo_capture_path())  # the input first, then the outputs
    outputs.check_outputs({"--plot": plot}, force=force, inputs=(src.path,))
    with progress_bar("compare", quiet=as_json) as progress:
        tel, seen = load_replay(src, scaled(progress, 0.0, 0.4), text_map=text_map)
        checks.require_attitude(tel, "compare")
        no_fc_plot = no_flight_figure_reason(tel.fc)
        fc_plot = None  # the flight-control figure, where the drone was armed: OUT-flight-control.png
        if plot is not None and no_fc_plot is None:
            fc_plot = plot.with_name(f"{plot.stem}-flight-control{plot.suffix or '.png'}")
            outputs.check_output(fc_plot, option="--plot", force=force, inputs=(src.path,))
        outputs.print_warnings(seen)  # the capture's damage (and a note in --json)
        progress(0.4, f"replica and {', '.join(names)}")
        settings = None
        if changes:  # the status frames' settings (or the defaults) with the given ones replaced
            exact = [j for j in range(len(tel.status)) if tel.status.exact[j]]
            settings = replace(MahonySettings.of_status(tel.status, exact[0]) if exact else MahonySettings(), **changes)
        report = compare_capture(tel, estimators=names, settings=settings, variant=variant, variant_source="--variant")
        if as_json:
            report.notes.extend(seen)
        if plot is not None:
            from steval_link.analysis.plots import plot_comparison, plot_flight_control  # matplotlib: only for --plot

            progress(0.9, f"plotting {plot.name}")
            with outputs.atomic_output(plot, option="--plot", keep_suffix=True) as part:
                plot_comparison(tel, report, part)
                if fc_plot is not None:
                    with outputs.atomic_output(fc_plot, option="--plot", keep_suffix=True) as fc_part:
                        plot_flight_control(tel, fc_part)
    plots = [] if plot is None else [("plot", "plot", plot)]
    if fc_plot is not None:
        plots.append(("plot_flight_control", "flight-control plot", fc_plot))
    _print_report(as_json, report.as_dict, lambda: format_report(report) + _rerun_line(report, src.path), plots)
    if plot is not None and no_fc_plot is not None and len(tel.fc):
        print(f"no flight-control plot: {no_fc_plot}.", file=sys.stderr if as_json else sys.stdout)


def _print_report(as_json: bool, as_dict, format_lines, plots: list[tuple[str, str, Path]]) -> None:
    """The report as JSON or lines, with each figure written; ``plots``: (JSON key, label, path)."""
    if as_json:
        d = as_dict()
        d.update({key: str(path) for key, _, path in plots})
        outputs.print_json(d)
    else:
        print("\n".join(format_lines()))
        for _, label, path in plots:
            print(f"{label}: {path}")


def _load_flight(path: Path):
    """One capture as a side-by-side ``Flight`` (a BLE capture's: the ST-Mahony replica over its samples)."""
    src = read_recording(path)
    tel = telemetry_of_recording(src)
    if tel.link is not None:  # BLE: no firmware angles, the replica's on the samples
        replica = run_estimator("st-mahony", tel)[0] if tel.link.sensors else None
        return sbs.flight_of_ble(path, tel, replica, src.warnings)
    if len(tel.attitude) == 0:
        raise UserError(
            f"{path} has no attitude frames to compare ({len(tel.status)} status frames, {len(tel.text)} text lines)."
        )
    return sbs.flight_of_telemetry(path, tel, src.warnings)


def _side_by_side(captures: list[Path], *, as_json: bool, plot: Path | None, force: bool, align: str, labels, viewer):
    """``steval compare A B ...``: the flights side by side (text or JSON, the figure, the Rerun recording)."""
    if align not in sbs.ALIGN_MODES:
        raise UserError(f"--align must be time or motion, got {align!r}.")
    if labels and len(labels) != len(captures):
        raise UserError(f"{len(labels)} --label for {len(captures)} captures: give one per capture, in order.")
    check_view_flags(viewer)
    with progress_bar("compare", quiet=as_json or viewer.serve) as progress:
        flights = []
        for i, path in enumerate(captures):  # the inputs first, then the outputs
            progress(0.6 * i / len(captures), f"reading {path.name}")
            flights.append(_load_flight(path))
        inputs = tuple(captures)
        outputs.check_outputs({"--plot": plot}, force=force, inputs=inputs)
        options = view_sinks(viewer, force=force, inputs=inputs)  # before the work: a dead URL, a busy port
        progress(0.6, "aligning")
        result = sbs.side_by_side(flights, align=align, labels=labels)
        if plot is not None:
            progress(0.7, f"plotting {plot.name}")
            with outputs.atomic_output(plot, option="--plot", keep_suffix=True) as part:
                sbs.plot_side_by_side(result, part)
    _print_report(
        as_json, result.as_dict, lambda: sbs.format_side_by_side(result), [("plot", "plot", plot)] if plot else []
    )
    sys.stdout.flush()
    if options is not None:
        from steval_viewer.side_by_side_log import side_by_side_sink  # Rerun loads only for a viewer or an .rrd

        side_by_side_sink(options, result)


def _rerun_line(report, capture: Path) -> list[str]:
    """The command that runs the replica with the settings the diagnosis found (none: no line)."""
    found = dict(getattr(report.replica, "matching_variant", None) or {})
    if not found or "defaults" in found:
        return []
    if "kp" in found:
        found["kp_ground"], found["kp_flight"] = found.pop("kp")
    if "dt_s" in found:
        found["dt"] = found.pop("dt_s")
    if "variant" in found:
        found["variant"] = str(found["variant"]).removeprefix("ST ")
    return [f"to run the replica with them: {checks.command_line(['steval', 'compare', str(capture)], found)}"]

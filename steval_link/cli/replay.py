"""``steval replay``: decode a capture (or raw dump / text-mode log), run the estimators, print a summary, view it."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from steval_link.analysis.report import estimator_line, estimator_summary
from steval_link.analysis.summary import format_summary, summarize
from steval_link.cli.app import app, argument, option
from steval_link.cli.ble import BLE_LAYOUT_HELP, check_ble_layout
from steval_link.cli.checks import VariantOption, check_variant, estimator_names
from steval_link.cli.outputs import ForceOption, print_json, print_warnings
from steval_link.cli.progress import Progress, progress_bar, scaled
from steval_link.cli.viewer_options import view_sinks, with_rerun_options
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.estimators.runner import row_decimation, run_estimator
from steval_link.link.capture import demo_capture_path
from steval_link.link.load import read_recording, telemetry_of_recording
from steval_link.link.text_series import MAP_TARGETS, parse_map
from steval_viewer.sink_options import SinkOptions

#: ``--map``: which series of a text log are the attitude (the CLI's flag; ``parse_map`` reads it).
MapOption = option(
    list[str] | None,
    "--map",
    metavar="TARGET=SERIES[:UNIT]",
    help="Text logs: which printed series is the attitude or a sensor axis, comma-separated or repeated, "
    f"e.g. pitch=col2:deg (targets: {', '.join(MAP_TARGETS)}; units deg, rad, mg, g, m/s2, dps, rad/s). "
    "pitch/roll/yaw, thx/thy/thz, acc/gyro groups with a unit and ST's own output are mapped without it.",
)


def load_replay(src, progress: Progress, *, text_map: list[str] | None = None, ble_layout: str | None = None):
    """The Telemetry of a file ``read_recording`` read, and the warnings met reading it."""
    progress(0.2, "decoding")
    try:
        tel = telemetry_of_recording(src, text_map=parse_map(text_map) or None, ble_layout=ble_layout)
    except UserError as exc:
        raise _map_flag(exc) from None
    progress(1.0, "decoded")
    return tel, list(src.warnings)


def read_map_option(items: list[str] | None) -> dict | None:
    """The ``--map`` items read (UserError naming the flag when one does not read)."""
    try:
        return parse_map(items) or None
    except UserError as exc:
        raise _map_flag(exc) from None


def _map_flag(exc: UserError) -> UserError:
    """The library's sentence about its ``map`` parameter, naming the flag."""
    text = str(exc)
    return UserError("--" + text) if text.startswith("map ") else exc


def run_estimators(tel, names: Sequence[str], progress: Progress) -> dict[str, Any]:
    """Each named estimator run from power-up over the attitude rows' inputs: name → ``AttitudeEstimate``."""
    decimation = row_decimation(tel)
    out = {}
    # BLE rows of the drone's attitude, or a log of printed angles: no sensor values for an estimator to run on
    if (tel.link is not None and not tel.link.sensors) or not _has_sensor_rows(tel):
        return out
    for i, name in enumerate(names):
        progress(i / len(names), f"estimator {name}")
        estimate, why = run_estimator(name, tel, decimation=decimation)
        if estimate is None:
            raise UserError(f"estimator {name!r} is {why}")
        out[name] = estimate
    return out


def _has_sensor_rows(tel) -> bool:
    """Some attitude row has finite accelerometer and gyro values (the estimators' inputs)."""
    a = tel.attitude
    return bool(len(a)) and bool((np.isfinite(a.acc_mg).all(axis=1) & np.isfinite(a.gyro_mdps).all(axis=1)).any())


def print_summary(tel, estimates: dict, as_json: bool, warnings_seen: list[str], variant, names: Sequence[str]):
    """The summary (text or JSON) of the telemetry and the estimates; ``names``: the estimators asked for."""
    s = summarize(tel, variant=variant, variant_source="--variant")
    s["warnings"] += [w for w in warnings_seen if w not in s["warnings"]]
    s["estimators"] = [estimator_summary(name, est, tel) for name, est in estimates.items()]
    if names and not estimates and len(tel.attitude) and not _has_sensor_rows(tel):
        s["estimators_not_run"] = (
            f"estimators not run ({', '.join(names)}): the capture has no accelerometer and gyro values "
            "(print them, or name them with --map)"
        )
    if as_json:
        print_json(s)
        return
    print_warnings(s["warnings"])  # then the summary's lines and one per host estimator (``-e``)
    lines = format_summary(dict(s, warnings=[])) + [estimator_line(e) for e in s["estimators"]]
    print("\n".join(lines + ([s["estimators_not_run"]] if "estimators_not_run" in s else [])))


@app.command()
@with_rerun_options
def replay(
    capture: argument(
        Path | None,
        help="Capture (.stv), raw serial dump or text-mode log; detected by content. Default: the bundled demo "
        "recording.",
    ) = None,
    as_json: option(bool, "--json", help="Print the summary as JSON (for scripts).") = False,
    estimators: option(
        list[str] | None,
        "--estimators",
        "-e",
        help="Host estimators logged next to the firmware, comma-separated or repeated (st-mahony, accel, ekf3, "
        "mekf, vqf, your own FILE.py:CLASS or module:CLASS; "
        f"'none' for none). Default with a viewer or --rrd: {','.join(registry.REPLAY_DEFAULT)}.",
    ) = None,
    variant: VariantOption = None,
    force: ForceOption = False,
    text_map: MapOption = None,
    ble_layout: option(str | None, help=BLE_LAYOUT_HELP) = None,
    rerun: SinkOptions = None,
) -> None:
    """Decode a capture and print a summary: frames, duration, rate, drops, CRC failures, filter settings, the ST
    release whose filter the replica reproduces the firmware with.

    Any serial text works too: ST's own output, your own PRINTF, Arduino plotter, Teleplot and CSV lines are read
    as text telemetry (records, series, other lines); --map says which series is the attitude when the names do not.

    A BLE capture (steval live --ble, ST's unmodified firmware) gives its notifications, the motion cadence its
    ticks show (the sender's own rate, or drops: ST's congestion skips, gaps), battery, pressure, RSSI and arming,
    and the estimators run on its raw samples (dt from that cadence).

    With --spawn the desktop viewer opens with the replay and stays open when the command returns; --serve keeps a
    web viewer up until Ctrl-C; --rrd writes a complete file or, when interrupted, none (an existing one is
    replaced only with --force)."""
    viewer, rrd = rerun.any(), rerun.rrd
    variant = check_variant(variant)
    names = estimator_names(estimators, registry.REPLAY_DEFAULT if viewer else ())
    src = read_recording(demo_capture_path() if capture is None else capture)  # the input first, then the outputs
    # the sinks before the work: a bad --rrd, a dead --connect URL fails at once
    options = view_sinks(rerun, force=force, inputs=(src.path,))
    layout = check_ble_layout(ble_layout) if ble_layout else None
    try:
        with progress_bar("replay", quiet=as_json or rerun.serve) as progress:  # --serve waits for Ctrl-C: no bar
            tel, seen = load_replay(
                src, scaled(progress, 0.0, 0.3 if viewer else 1.0), text_map=text_map, ble_layout=layout
            )
            estimates = run_estimators(tel, names, scaled(progress, 0.3, 0.5))
            # the summary first: a --serve viewer keeps running until Ctrl-C
            print_summary(tel, estimates, as_json, seen, variant, names)
            sys.stdout.flush()
            if options is not None and tel.link is not None:  # BLE: the live pipeline and logger, as live
                from steval_viewer.live_adapter import recording_sink  # Rerun loads only for a viewer or an .rrd

                recording_sink(
                    options, list(names), src, layout=tel.link.layout.name, progress=scaled(progress, 0.5, 1.0)
                )
            elif options is not None:
                from steval_viewer.replay_log import replay_sink  # Rerun loads only for a viewer or an .rrd

                replay_sink(options, tel, estimates, progress=scaled(progress, 0.5, 1.0))
    except KeyboardInterrupt:
        if rrd is not None:  # the sink writes it whole or not at all (an earlier file there stays as it was)
            print(f"steval: {rrd} not written (interrupted before it was complete)", file=sys.stderr)
        raise

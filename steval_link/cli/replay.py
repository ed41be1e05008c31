"""``steval replay``: decode a capture (or raw dump / text-mode log) and summarise it.

Replay is a pipeline, one stage per step of the data flow::

    load_replay(path)             bytes → Telemetry            (capture.load_telemetry)
    run_estimators(tel, names)    Telemetry → {name: AttitudeEstimate}   (estimators.registry)
    sinks                         each ``sink(tel, estimates)``: summary printing, Rerun .rrd, ...

:func:`replay_pipeline` runs them; ``steval replay`` builds the sink list from its options.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from steval_link.capture import demo_capture_path, read_source, telemetry_of_source
from steval_link.cli.app import app
from steval_link.cli.progress import Progress, progress_bar, scaled
from steval_link.errors import UserError
from steval_link.summary import format_summary, summarize

__all__ = ["ReplayResult", "load_replay", "run_estimators", "replay_pipeline", "DEFAULT_ESTIMATORS"]

#: Estimators a sink that shows attitudes (Rerun) runs by default: the firmware's filter (the viewer shows it as the
#: bit-exact port seeded from status snapshots), accelerometer-only tilt and both EKFs.
DEFAULT_ESTIMATORS: tuple[str, ...] = ("st-mahony", "accel", "ekf3", "mekf")

#: A sink consumes the telemetry and the estimates (name → AttitudeEstimate) of one replay.
Sink = Callable[[Any, dict[str, Any]], None]


@dataclass
class ReplayResult:
    telemetry: Any
    estimates: dict[str, Any] = field(default_factory=dict)


def load_replay(path: Path | None, progress: Progress | None = None) -> tuple[Any, list[str]]:
    """Stage 1: the :class:`~steval_link.telemetry.Telemetry` of ``path`` (the demo recording when None), and the
    warnings met while reading it (e.g. a capture cut short)."""
    progress = scaled(progress, 0.0, 1.0)
    path = demo_capture_path() if path is None else Path(path)
    progress(0.0, f"reading {path.name}")
    src = read_source(path)
    progress(0.2, "decoding")
    tel = telemetry_of_source(src)
    progress(1.0, "decoded")
    return tel, list(src.warnings)


def run_estimators(tel, names: Sequence[str], progress: Progress | None = None) -> dict[str, Any]:
    """Stage 2: run each named estimator (``steval_link.estimators.registry``) from power-up over every attitude
    row's inputs (``acc_mg``, ``gyro_mdps``, ``thr``; decimated text-mode rows at their row rate); returns
    name → ``AttitudeEstimate``. Raises UserError for an unknown or uninstalled estimator."""
    from steval_link.estimators.runner import row_decimation, run_estimator

    progress = scaled(progress, 0.0, 1.0)
    decimation = row_decimation(tel)
    out = {}
    for i, name in enumerate(names):
        progress(i / len(names), f"estimator {name}")
        estimate, why = run_estimator(name, tel, decimation=decimation)
        if estimate is None:
            raise UserError(f"estimator {name!r} is {why}")
        out[name] = estimate
    return out


def replay_pipeline(
    path: Path | None, *, estimators: Sequence[str] = (), sinks: Sequence[Sink] = ()
) -> ReplayResult:
    """load → Telemetry → estimators → sinks."""
    tel, _ = load_replay(path)
    estimates = run_estimators(tel, estimators)
    for sink in sinks:
        sink(tel, estimates)
    return ReplayResult(tel, estimates)


def rrd_sink(out: Path) -> Sink:
    """Sink writing a Rerun recording to ``out``."""
    return viewer_sink(rrd=out)


def viewer_sink(*, rrd: Path | None = None, spawn: bool = False, serve: bool = False, connect: str | None = None,
                progress: Progress | None = None) -> Sink:
    """Sink logging the replay to Rerun (``steval_viewer``): an .rrd file and/or a viewer."""
    from steval_viewer.replay_log import replay_sink
    from steval_viewer.sinks import SinkOptions

    return replay_sink(SinkOptions(spawn=spawn, serve=serve, connect=connect, rrd=rrd), progress=progress)


def summary_sink(as_json: bool, warnings_seen: list[str]) -> Sink:
    """Sink printing the summary (text, or one JSON object) on stdout."""

    def sink(tel, estimates) -> None:
        s = summarize(tel)
        for w in warnings_seen:
            if w not in s["warnings"]:
                s["warnings"].append(w)
        if as_json:
            json.dump(s, sys.stdout, indent=2, allow_nan=False)
            sys.stdout.write("\n")
        else:
            for w in s["warnings"]:
                print(f"steval: warning: {w}", file=sys.stderr)
            s = dict(s, warnings=[])
            print("\n".join(format_summary(s)))

    return sink


@app.command()
def replay(
    capture: Annotated[
        Optional[Path],
        typer.Argument(
            help="Capture (.stv), raw serial dump or text-mode log; detected by content. Default: the bundled "
            "demo recording.",
            show_default=False,
        ),
    ] = None,
    rrd: Annotated[
        Optional[Path], typer.Option("--rrd", help="Also write a Rerun recording to this .rrd file.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON (for scripts).")] = False,
    spawn: Annotated[bool, typer.Option("--spawn", help="Show the replay in a native Rerun viewer.")] = False,
    serve: Annotated[
        bool, typer.Option("--serve", help="Show the replay in the Rerun web viewer on 127.0.0.1 (Ctrl-C to stop).")
    ] = False,
    connect: Annotated[
        Optional[str], typer.Option("--connect", help="Send the replay to a running Rerun viewer at this gRPC URL.")
    ] = None,
    estimators: Annotated[
        Optional[str],
        typer.Option(
            "--estimators",
            "-e",
            help="Host estimators logged next to the firmware, comma-separated (st-mahony, accel, ekf3, mekf, vqf; "
            f"'none' for none). Default with a viewer or --rrd: {','.join(DEFAULT_ESTIMATORS)}.",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Decode a capture and print a summary: frames, duration, rate, drops, CRC failures, filter settings."""
    from steval_link.live import resolve_estimators

    viewer = rrd is not None or spawn or serve or connect
    names = tuple(resolve_estimators(estimators)) if estimators is not None else (DEFAULT_ESTIMATORS if viewer else ())
    with progress_bar("replay", quiet=as_json or serve) as progress:  # --serve waits for Ctrl-C: no bar
        tel, seen = load_replay(capture, scaled(progress, 0.0, 0.3 if viewer else 1.0))
        # the summary first: a --serve viewer keeps running until Ctrl-C
        sinks: list[Sink] = [summary_sink(as_json, seen)]
        if viewer:
            sinks.append(viewer_sink(rrd=rrd, spawn=spawn, serve=serve, connect=connect,
                                     progress=scaled(progress, 0.5, 1.0)))
        estimates = run_estimators(tel, names, scaled(progress, 0.3, 0.5))
        for sink in sinks:
            sink(tel, estimates)

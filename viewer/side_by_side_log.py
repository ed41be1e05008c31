"""``steval compare A.stv B.stv ...`` in Rerun: each flight its own entity subtree (``flights/<k>/...``) on the
``aligned_time`` timeline, and a blueprint that overlays them. The entities are listed in ``viewer/README.md``."""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from steval_link.analysis.side_by_side import SideBySide, difference_series, format_side_by_side
from steval_viewer import drone_model
from steval_viewer.blueprint import window
from steval_viewer.columns import Times, send_scalars, send_transforms, series_style
from steval_viewer.sinks import log_whole

TIMELINE = "aligned_time"
ROOT = "flights"
NOTES = "notes"
#: Line colours of the flights, in order (then repeated).
COLOURS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14), (23, 190, 207)]
_ACCEL_GREY = (150, 150, 150)


def flight_key(i: int) -> str:
    """The entity segment of the ``i``-th flight: ``a``, ``b``, ..., then ``f27``, ..."""
    return chr(ord("a") + i) if i < 26 else f"f{i + 1}"


def flight_path(i: int, leaf: str) -> str:
    return f"{ROOT}/{flight_key(i)}/{leaf}"


def side_by_side_blueprint(labels: list[str]) -> rrb.Blueprint:
    """Pitch and roll of every flight overlaid (with accel-only tilt), differences from the first, 3D views, notes."""
    n = len(labels)

    def series(name: str, leaves: list[str]) -> rrb.TimeSeriesView:
        contents = [f"$origin/{flight_key(i)}/{leaf}" for i in range(n) for leaf in leaves]
        return rrb.TimeSeriesView(origin=ROOT, name=name, contents=contents, plot_legend=rrb.PlotLegend(visible=True))

    plots = rrb.Vertical(
        series("pitch thx (about x, nose up +), deg", ["pitch_thx_deg", "accel_pitch_thx_deg"]),
        series("roll thy (about y), deg", ["roll_thy_deg", "accel_roll_thy_deg"]),
        series("difference from the first flight, deg", ["diff_pitch_thx_deg", "diff_roll_thy_deg"]),
        series("gyro, deg/s", ["gyro_dps"]),
        row_shares=[3, 3, 2, 2],
    )
    drones = rrb.Vertical(
        *(rrb.Spatial3DView(origin=f"{ROOT}/{flight_key(i)}/world", name=labels[i]) for i in range(n)),
        rrb.TextDocumentView(origin=NOTES, name="Notes"),
    )
    return window(rrb.Horizontal(plots, drones, column_shares=[3, 1]), rrb.TimePanel(timeline=TIMELINE))


def log_side_by_side(rec: rr.RecordingStream, r: SideBySide) -> dict[str, int]:
    """Log every flight of ``r`` under its own subtree; returns the rows logged per entity path."""
    rec.send_blueprint(side_by_side_blueprint([f.label for f in r.flights]), make_active=True, make_default=True)
    counts: dict[str, int] = {}
    mesh = drone_model.quadcopter_mesh()
    ref = r.flights[0]
    for i, f in enumerate(r.flights):
        c = COLOURS[i % len(COLOURS)]
        light = tuple(int(0.55 * x + 0.45 * g) for x, g in zip(c, _ACCEL_GREY))
        grey = tuple(max(60, g - 35 * i) for g in _ACCEL_GREY)  # accel-only tilt: greys, the flights stand out
        gyro_names = [f"{f.label}: gyro {a}" for a in "xyz"]
        leaves = {
            "pitch_thx_deg": (f"{f.label}: pitch thx", c, 2.0, f.t_s, np.degrees(f.thx_rad)),
            "roll_thy_deg": (f"{f.label}: roll thy", c, 2.0, f.t_s, np.degrees(f.thy_rad)),
            "accel_pitch_thx_deg": (f"{f.label}: accel-only pitch", grey, 1.0, f.t_s, np.degrees(f.accel_thx_rad)),
            "accel_roll_thy_deg": (f"{f.label}: accel-only roll", grey, 1.0, f.t_s, np.degrees(f.accel_thy_rad)),
            "gyro_dps": (gyro_names, [c, light, _ACCEL_GREY], 1.0, f.t_s, np.asarray(f.gyro_mdps, np.float64) / 1000.0),
        }
        if i:
            t, dx, dy = difference_series(ref, f)
            leaves["diff_pitch_thx_deg"] = (f"{f.label} − {ref.label}: pitch", c, 2.0, t, dx)
            leaves["diff_roll_thy_deg"] = (f"{f.label} − {ref.label}: roll", light, 1.0, t, dy)
        for leaf, (name, colour, width, t, values) in leaves.items():
            path = flight_path(i, leaf)
            series_style(rec, path, name, colour, width)
            counts[path] = send_scalars(rec, path, Times(t, timeline=TIMELINE), values, gaps=False)
        world = flight_path(i, "world")
        rec.log(world, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        drone_model.log_mesh(rec, f"{world}/drone/model", mesh)
        counts[f"{world}/drone"] = send_transforms(rec, f"{world}/drone", Times(f.t_s, timeline=TIMELINE), f.q_wxyz)
    text = "```text\n" + "\n".join(format_side_by_side(r)) + "\n```"
    rec.log(NOTES, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
    counts[NOTES] = 1
    return counts


def side_by_side_sink(options: Any, r: SideBySide) -> dict[str, int]:
    """``steval compare`` of several flights to the sinks of ``options`` (:func:`~steval_viewer.sinks.log_whole`)."""
    return log_whole(options, "steval compare (side by side)", lambda rec: log_side_by_side(rec, r))

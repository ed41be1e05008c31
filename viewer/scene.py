"""Static part of every recording: world axes, view coordinates, drone models and the series styles (names,
colours) of every time series. Logged once per recording by the replay and the live path."""

from __future__ import annotations

from typing import Iterable

import rerun as rr

from steval_viewer import drone_model
from steval_viewer import entities as ent
from steval_viewer.columns import series_style

AXIS_LENGTH = 1.6
#: The world axes' names sit just beyond their arrow tips, clear of the rotors (Rerun labels an arrow's middle).
AXIS_LABEL_AT = 1.08 * AXIS_LENGTH
#: ... and the horizontal axes' names a little above the ground plane (above the front rotors from the default eye).
AXIS_LABEL_LIFT = 0.3


def log_static(rec: rr.RecordingStream, estimate_sources: Iterable[str], *, with_replica: bool) -> None:
    """Log the 3D scene and the styles of all series: of the host estimates ``estimate_sources`` (source
    segments) and, ``with_replica``, of firmware − replica."""
    sources = list(estimate_sources)
    rec.log(ent.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    axes = [(AXIS_LENGTH, 0, 0), (0, AXIS_LENGTH, 0), (0, 0, AXIS_LENGTH)]
    rec.log(ent.WORLD_AXES, rr.Arrows3D(vectors=axes, colors=ent.XYZ_COLORS, radii=0.015), static=True)
    at = [(AXIS_LABEL_AT, 0, AXIS_LABEL_LIFT), (0, AXIS_LABEL_AT, AXIS_LABEL_LIFT), (0, 0, AXIS_LABEL_AT)]
    labels = rr.Points3D(at, colors=ent.XYZ_COLORS, labels=["x right", "y forward", "z up"], radii=0.001)
    rec.log(ent.WORLD_AXIS_LABELS, labels, static=True)
    drone_model.log_models(rec, sources)
    gravity = rr.Arrows3D.from_fields(colors=[(255, 215, 0)], radii=[0.03])  # named in the 3D view's title
    rec.log(ent.ACC_GRAVITY, gravity, static=True)

    for source in [ent.SOURCE_FIRMWARE, *sources]:
        color = ent.source_color(source)
        width = 2.5 if source == ent.SOURCE_FIRMWARE else 1.5
        series_style(rec, ent.pitch_path(source), ent.source_label(source), color, width)
        series_style(rec, ent.roll_path(source), ent.source_label(source), color, width)
    series_style(rec, ent.yaw_path(ent.SOURCE_FIRMWARE), "thz yaw (firmware)", ent.source_color(ent.SOURCE_FIRMWARE))
    if with_replica:
        series_style(rec, ent.DIFF_THX, "thx pitch: firmware − replica", (230, 90, 90))
        series_style(rec, ent.DIFF_THY, "thy roll: firmware − replica", (90, 150, 230))
    # short names: the plot titles give the units, and a small legend hides less
    series_style(rec, ent.PLOT_ACC, ["acc x right", "acc y forward", "acc z up"], ent.XYZ_COLORS)
    series_style(rec, ent.PLOT_GYRO, ["gyro x (pitch rate)", "gyro y (roll rate)", "gyro z (yaw rate)"], ent.XYZ_COLORS)
    series_style(rec, ent.PLOT_THROTTLE, "throttle gTHR", (127, 127, 127))
    series_style(rec, ent.LINK_RATE, "attitude frames/s", (120, 200, 255))
    series_style(rec, ent.LINK_MISSING, "frames missing (sequence gaps)", (255, 160, 40))
    series_style(rec, ent.LINK_CRC, "CRC failures", (230, 60, 60))
    series_style(rec, ent.LINK_TX_DROPPED, "dropped by firmware (TX queue full)", (200, 120, 255))
    series_style(rec, ent.LINK_QUEUE, "TX queue peak (bytes)", (127, 127, 127))
    series_style(
        rec,
        ent.LINK_CYCLES,
        ["cycles min", "cycles mean", "cycles max"],
        [(44, 160, 44), (127, 127, 127), (214, 39, 40)],
        visible=[False, True, True],  # the plot's title names max and mean; min can be shown in the blueprint panel
    )

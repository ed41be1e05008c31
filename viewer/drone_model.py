"""The 3D scene of every recording: axes, the quadcopter (solid: firmware attitude; wireframe ghosts: host
estimates) and the series styles. Body frame: x right, y forward (nose), z up; 1 unit ≈ centre to motor. X
configuration: arms at ±45° from the nose, front propellers red, a red nose cone."""

from __future__ import annotations

import itertools
from typing import Iterable, NamedTuple

import numpy as np
import rerun as rr

from steval_link import constants as C
from steval_viewer import entities as ent
from steval_viewer.columns import series_style

ARM_LENGTH = 1.0  #: centre to motor axis
ARM_HALF_WIDTH = 0.045
ARM_HALF_HEIGHT = 0.03
BODY_HALF = (0.28, 0.36, 0.07)  #: central plate half sizes (x, y, z)
PROP_RADIUS = 0.42
PROP_Z = 0.11
MOTOR_RADIUS = 0.09
NOSE_LENGTH = 0.35

FRAME_COLOR = (60, 64, 72, 255)
ARM_COLOR = (90, 96, 108, 255)
MOTOR_COLOR = (30, 30, 30, 255)
PROP_FRONT_COLOR = (225, 60, 50, 255)
PROP_REAR_COLOR = (170, 175, 185, 255)
NOSE_COLOR = (235, 40, 40, 255)


def motor_positions() -> np.ndarray:
    """(4, 3) motor centres: front-right, front-left, rear-left, rear-right (body frame)."""
    angles = np.deg2rad([45.0, 135.0, 225.0, 315.0])  # from +x, counter-clockwise seen from above
    return np.stack([ARM_LENGTH * np.cos(angles), ARM_LENGTH * np.sin(angles), np.zeros(4)], axis=1)


def firmware_motor_positions() -> np.ndarray:
    """(4, 3) centres of the firmware's motors 1..4 (``motorN_pwm``, TIM4 channel N), placed by the signs of its
    mixer (:data:`steval_link.constants.MIXER`): motor 1 right rear, 2 right front, 3 left front, 4 left rear."""
    rows = np.asarray(C.MIXER, dtype=np.float64)
    d = ARM_LENGTH / np.sqrt(2.0)
    # a + pitch (x) term: front (+y); a + roll (y) term: left (-x)
    return np.stack([-np.sign(rows[:, 1]) * d, np.sign(rows[:, 0]) * d, np.zeros(4)], axis=1)


class Mesh(NamedTuple):
    """Triangle soup with per-vertex colours and normals (vertices not shared, so shading is flat)."""

    positions: np.ndarray  # (V, 3) float32
    normals: np.ndarray  # (V, 3) float32
    colors: np.ndarray  # (V, 4) uint8
    triangles: np.ndarray  # (T, 3) uint32


#: a box's faces (-x, +x, -y, +y, -z, +z) by corner index 4*ix + 2*iy + iz, outward winding
_BOX_QUADS = np.array([(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)])


def _box_triangles(center, half, angle_rad: float = 0.0) -> np.ndarray:
    """(12, 3, 3) triangles of a box turned by ``angle_rad`` about z, outward winding."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    turn = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])  # row vectors turned about z
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=3))) * half @ turn + np.asarray(center, dtype=float)
    return corners[np.stack([_BOX_QUADS[:, [0, 1, 2]], _BOX_QUADS[:, [0, 2, 3]]], axis=1).reshape(-1, 3)]


def _pairs(first: tuple, second: tuple) -> np.ndarray:
    """Triangles ``first[k]`` and ``second[k]`` in turn, each given by its corners ((n, 3) arrays or shared points)."""
    a, b = (np.stack(np.broadcast_arrays(*corners), axis=1) for corners in (first, second))
    return np.stack([a, b], axis=1).reshape(-1, 3, 3)


def _disc_triangles(center, radius, n=32, z_thickness=0.012) -> np.ndarray:
    """A thin two-sided disc (top and bottom fans), (2n, 3, 3)."""
    ang = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    c = np.asarray(center, dtype=float)
    p = c + np.stack([radius * np.cos(ang), radius * np.sin(ang), np.zeros(n)], axis=1)
    q = np.roll(p, -1, axis=0)
    top = np.array([0, 0, z_thickness / 2])
    return _pairs((c + top, p + top, q + top), (c - top, q - top, p - top))


def _nose_triangles(radius: float = 0.1, n: int = 20) -> np.ndarray:
    """The nose cone along +y from the plate's front edge, with its base cap."""
    base = np.array([0.0, BODY_HALF[1], 0.0])
    ang = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    p = base + radius * np.stack([np.cos(ang), np.zeros(n), -np.sin(ang)], axis=1)
    q = np.roll(p, -1, axis=0)
    return _pairs((p, q, base + (0.0, NOSE_LENGTH, 0.0)), (base, q, p))


def quadcopter_mesh() -> Mesh:
    """The solid quadcopter: plate, four arms, motors, props (front red), nose cone on +y."""
    parts = [(_box_triangles((0, 0, 0), BODY_HALF), FRAME_COLOR)]
    for m in motor_positions():
        arm = (ARM_LENGTH / 2, ARM_HALF_WIDTH, ARM_HALF_HEIGHT)
        parts.append((_box_triangles(m / 2, arm, np.arctan2(m[1], m[0])), ARM_COLOR))
        parts.append((_box_triangles(m + (0, 0, 0.04), (MOTOR_RADIUS, MOTOR_RADIUS, 0.06)), MOTOR_COLOR))
        color = PROP_FRONT_COLOR if m[1] > 0 else PROP_REAR_COLOR
        parts.append((_disc_triangles(m + (0, 0, PROP_Z), PROP_RADIUS), color))
    parts.append((_nose_triangles(), NOSE_COLOR))
    tris = np.concatenate([t for t, _ in parts])
    colors = np.concatenate([np.tile(np.array(c, dtype=np.uint8), (len(t) * 3, 1)) for t, c in parts])
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    positions = tris.reshape(-1, 3).astype(np.float32)
    normals = np.repeat(n, 3, axis=0).astype(np.float32)
    triangles = np.arange(len(positions), dtype=np.uint32).reshape(-1, 3)
    return Mesh(positions=positions, normals=normals, colors=colors, triangles=triangles)


def quadcopter_wireframe() -> list[np.ndarray]:
    """Line strips of the ghost: plate outline, arms, prop circles, nose arrow (body frame)."""
    hx, hy, _ = BODY_HALF
    strips = [np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0], [-hx, -hy, 0]], dtype=float)]
    ang = np.linspace(0.0, 2.0 * np.pi, 33)  # 32 segments, closed
    for m in motor_positions():
        strips.append(np.array([[0.0, 0.0, 0.0], m]))
        x, y = m[0] + PROP_RADIUS * np.cos(ang), m[1] + PROP_RADIUS * np.sin(ang)
        strips.append(np.stack([x, y, np.full_like(ang, PROP_Z)], axis=1))
    tip = hy + NOSE_LENGTH
    strips.append(np.array([[-0.12, hy, 0], [0, tip, 0], [0.12, hy, 0]]))
    strips.append(np.array([[0, 0, 0], [0, tip, 0]]))
    return [s.astype(np.float32) for s in strips]


def log_mesh(rec, path: str, m: Mesh) -> None:
    mesh3d = rr.Mesh3D(
        vertex_positions=m.positions, vertex_normals=m.normals, vertex_colors=m.colors, triangle_indices=m.triangles
    )
    rec.log(path, mesh3d, static=True)


AXIS_LENGTH = 1.6
#: The axes' names: beyond the arrow tips (Rerun labels an arrow's middle), x and y lifted above the front rotors.
AXIS_LABEL_AT = 1.08 * AXIS_LENGTH
AXIS_LABEL_LIFT = 0.3


def log_static(rec: rr.RecordingStream, estimate_sources: Iterable[str], *, with_replica: bool) -> None:
    """The static part of every recording: world axes, view coordinates, the quadcopter, a ghost per host estimate
    of ``estimate_sources`` (source segments), and the styles of all series (``with_replica``: firmware − replica)."""
    sources = list(estimate_sources)
    rec.log(ent.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    axes = [(AXIS_LENGTH, 0, 0), (0, AXIS_LENGTH, 0), (0, 0, AXIS_LENGTH)]
    rec.log(ent.WORLD_AXES, rr.Arrows3D(vectors=axes, colors=ent.XYZ_COLORS, radii=0.015), static=True)
    at = [(AXIS_LABEL_AT, 0, AXIS_LABEL_LIFT), (0, AXIS_LABEL_AT, AXIS_LABEL_LIFT), (0, 0, AXIS_LABEL_AT)]
    labels = rr.Points3D(at, colors=ent.XYZ_COLORS, labels=["x right", "y forward", "z up"], radii=0.001)
    rec.log(ent.WORLD_AXIS_LABELS, labels, static=True)
    log_mesh(rec, ent.DRONE_FIRMWARE_MODEL, quadcopter_mesh())
    strips = quadcopter_wireframe()
    for source in sources:
        ghost = rr.LineStrips3D(strips, colors=[(*ent.source_color(source), 200)], radii=0.012)
        rec.log(ent.estimate_model_path(source), ghost, static=True)
    gravity = rr.Arrows3D.from_fields(colors=[(255, 215, 0)], radii=[0.03])  # named in the 3D view's title
    rec.log(ent.ACC_GRAVITY, gravity, static=True)

    for source in [ent.SOURCE_FIRMWARE, *sources]:
        width = 2.5 if source == ent.SOURCE_FIRMWARE else 1.5
        for path in (ent.pitch_path(source), ent.roll_path(source)):
            series_style(rec, path, ent.source_label(source), ent.source_color(source), width)
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
    # the plot's title names max and mean; min can be shown in the blueprint panel
    colors = [(44, 160, 44), (127, 127, 127), (214, 39, 40)]
    series_style(rec, ent.LINK_CYCLES, ["cycles min", "cycles mean", "cycles max"], colors, visible=[False, True, True])

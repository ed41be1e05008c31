"""A BLE capture (ST's stock firmware over Bluetooth) in Rerun: raw sensors, battery, pressure, temperature, RSSI,
arming, the notification rate, the host estimators' attitude with the 3D drone, and a visible note that the firmware
port cannot be bit-exact on BLE data (:data:`steval_link.analysis.ble.NOT_BIT_EXACT`).

Layout (entity paths in :mod:`steval_viewer.entities`): the solid drone follows the first estimator (ST-Mahony by
default), the others are ghosts; pitch/roll plots per estimator as in a serial replay. Timelines: ``fw_time`` (the
drone's tick clock, motion rows on the estimators' uniform grid) and ``host_time`` (arrival) for the notifications.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from steval_link.analysis.ble import NOT_BIT_EXACT, BleReplay
from steval_link.link.ble_telemetry import BleTelemetry
from steval_viewer import blueprint as bp
from steval_viewer import drone_model
from steval_viewer import entities as ent
from steval_viewer.columns import Times, send_arrows, send_scalars, send_texts, send_transforms
from steval_viewer.sinks import log_whole, open_session

__all__ = [
    "ble_blueprint",
    "log_ble_static",
    "log_ble_replay",
    "ble_replay_sink",
    "BleLiveLogger",
    "log_ble_notifications",
    "log_ble_estimates",
]

Progress = Callable[[float, str], None] | None
_XYZ = [(230, 60, 60), (60, 200, 60), (70, 110, 240)]
#: the drone and link series: (path, the plot's name, the series' name)
_ENV = (
    (ent.BLE_BATTERY, "battery (%)", "battery %"),
    (ent.BLE_PRESSURE, "pressure (hPa)", "pressure hPa"),
    (ent.BLE_RSSI, "RSSI (dBm)", "RSSI dBm"),
    (ent.BLE_ARMED, "armed (0/1)", "armed"),
    (ent.BLE_TEMPERATURE, "temperature (°C)", "temperature °C"),
    (ent.BLE_RATE, "motion notifications/s", "motion notifications/s"),
)


def ble_blueprint(sources: list[str], *, live: bool = False) -> rrb.Blueprint:
    """3D view (solid: first estimate; ghosts: the others) and the note above the environment plots; right: pitch,
    roll, raw acc/gyro/mag."""
    timeline = ent.TIMELINE_HOST if live else ent.TIMELINE_FW
    solid = sources[0] if sources else None
    overrides = {ent.estimate_path(s): rrb.EntityBehavior(visible=False) for s in sources[1:]}
    if solid is not None:
        overrides[ent.estimate_path(solid)] = rrb.EntityBehavior(visible=False)  # shown solid instead
    label = ent.source_label(solid) if solid else "no estimator"
    view3d = rrb.Spatial3DView(
        origin=ent.WORLD,
        name=f"Attitude over BLE (solid: {label} on the BLE samples, yellow: gravity from the accelerometer)",
        overrides=overrides or None,
        eye_controls=rrb.EyeControls3D(position=(2.1, -2.6, 1.6), look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 0.0, 1.0)),
        line_grid=rrb.LineGrid3D(visible=True, spacing=0.5),
    )

    def series(origin: str, name: str, legend: bool = False, bottom: bool = False) -> rrb.TimeSeriesView:
        return bp._series(origin, name, live, timeline, legend=legend, legend_bottom=bottom)

    env = rrb.Tabs(
        rrb.Grid(*(series(path, name) for path, name, _ in _ENV), grid_columns=3, name="Drone and link"),
        rrb.TextLogView(origin=ent.LOG_BLE_CONSOLE, name="BLE console"),
        name="Environment",
    )
    left = rrb.Vertical(view3d, rrb.TextDocumentView(origin=ent.BLE_NOTE, name="Note"), env, row_shares=[6, 1, 3])
    right = rrb.Vertical(
        rrb.Horizontal(
            series(ent.PLOT_PITCH, "thx pitch, about x (deg, nose up +)", legend=True),
            series(ent.PLOT_ROLL, "thy roll, about y (deg)", legend=True),
        ),
        rrb.Horizontal(
            series(ent.BLE_ACC, "accelerometer (mg), one ISR sample", legend=True, bottom=True),
            series(ent.BLE_GYRO, "gyro (deg/s), before the IIR", legend=True, bottom=True),
            series(ent.BLE_MAG, "magnetometer (mgauss)", legend=True, bottom=True),
        ),
        row_shares=[3, 2],
    )
    return bp.two_columns(left, right, live, timeline)


def _line(rec: rr.RecordingStream, path: str, names: list[str], colors: list) -> None:
    rec.log(path, rr.SeriesLines(names=names, colors=colors, widths=[1.5] * len(names)), static=True)


def log_ble_static(rec: rr.RecordingStream, sources: list[str]) -> None:
    """The scene, the drone models, the series styles and the note."""
    rec.log(ent.WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(
        ent.WORLD_AXES,
        rr.Arrows3D(vectors=[(0.6, 0, 0), (0, 0.6, 0), (0, 0, 0.6)], colors=_XYZ, radii=0.015),
        static=True,
    )
    drone_model.log_mesh(rec, ent.BLE_DRONE_MODEL)
    drone_model.log_ghosts(rec, sources[1:])
    rec.log(ent.BLE_GRAVITY, rr.Arrows3D.from_fields(colors=[(255, 215, 0)], radii=[0.03]), static=True)
    for s in sources:
        c = ent.source_color(s)
        _line(rec, ent.pitch_path(s), [ent.pitch_label(s)], [c])
        _line(rec, ent.roll_path(s), [ent.roll_label(s)], [c])
    _line(rec, ent.BLE_ACC, ["acc x right", "acc y forward", "acc z up"], _XYZ)
    _line(rec, ent.BLE_GYRO, ["gyro x (pitch rate)", "gyro y (roll rate)", "gyro z (yaw rate)"], _XYZ)
    _line(rec, ent.BLE_MAG, ["mag x", "mag y", "mag z"], _XYZ)
    for path, _, name in _ENV:
        _line(rec, path, [name], [(120, 200, 255)])
    rec.log(ent.BLE_NOTE, rr.TextDocument(NOT_BIT_EXACT), static=True)


def _rate_bins(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(last row of each 1 s bin, notifications/s in it)."""
    if len(t_s) < 2:
        return np.zeros(0, np.int64), np.zeros(0)
    k = np.floor(t_s - t_s[0]).astype(np.int64)
    ends = np.flatnonzero(np.diff(k, append=k[-1] + 1))
    counts = np.diff(np.concatenate(([-1], ends)))
    return ends, counts.astype(np.float64)


def log_ble_notifications(
    rec: rr.RecordingStream, ble: BleTelemetry, t_motion: np.ndarray, counts: dict[str, int]
) -> None:
    """The notifications' values: raw sensors and gravity arrow (motion rows at ``t_motion``, drone s), environment,
    arming, console."""
    n = len(ble)
    mt = Times(t_motion, ble.motion_t_host_s)
    acc = np.asarray(ble.acc_mg, np.float64)
    if n:
        for path, v in (
            (ent.BLE_ACC, acc),
            (ent.BLE_GYRO, np.asarray(ble.gyro_mdps, np.float64) / 1000.0),
            (ent.BLE_MAG, np.asarray(ble.mag_mgauss, np.float64)),
        ):
            send_scalars(rec, path, mt, v)
            counts[path] = counts.get(path, 0) + n
        with np.errstate(invalid="ignore"):
            send_arrows(rec, ent.BLE_GRAVITY, mt, -acc / 1000.0)
    et = Times(ble.env_t_fw_s, ble.env_t_host_s)
    for path, v in (
        (ent.BLE_PRESSURE, ble.pressure_hpa),
        (ent.BLE_BATTERY, ble.battery_pct),
        (ent.BLE_TEMPERATURE, ble.temperature_c),
        (ent.BLE_RSSI, ble.rssi_dbm),
    ):
        if len(v):
            send_scalars(rec, path, et, np.asarray(v, np.float64))
            counts[path] = counts.get(path, 0) + len(v)
    if len(ble.armed):
        send_scalars(rec, ent.BLE_ARMED, Times(ble.arming_t_fw_s, ble.arming_t_host_s), ble.armed.astype(np.float64))
        counts[ent.BLE_ARMED] = counts.get(ent.BLE_ARMED, 0) + len(ble.armed)
    if ble.console:
        th = np.array([c[0] for c in ble.console], np.float64)
        tf = np.interp(th, ble.motion_t_host_s, t_motion) if n > 1 else th
        texts = [f"[{c[1]}] {c[2]}" for c in ble.console]
        levels = ["WARN" if c[1] == "stderr" else "INFO" for c in ble.console]
        send_texts(rec, ent.LOG_BLE_CONSOLE, Times(tf, th), texts, levels)
        counts[ent.LOG_BLE_CONSOLE] = counts.get(ent.LOG_BLE_CONSOLE, 0) + len(texts)


def log_ble_estimates(
    rec: rr.RecordingStream, times: Times, estimates: dict[str, tuple], counts: dict[str, int]
) -> None:
    """Estimates on the estimators' grid: name → (q_wxyz (N,4), thx_rad, thy_rad, valid or None); the first one
    moves the solid drone, the others their ghosts."""
    for i, (name, (q, thx, thy, valid)) in enumerate(estimates.items()):
        s = ent.source_name(name)
        valid = np.ones(len(times), bool) if valid is None else np.asarray(valid, bool)
        send_transforms(rec, ent.BLE_DRONE if i == 0 else ent.estimate_path(s), times, np.asarray(q, np.float64), valid)
        for path, v in (
            (ent.pitch_path(s), np.degrees(np.asarray(thx, np.float64))),
            (ent.roll_path(s), np.degrees(np.asarray(thy, np.float64))),
        ):
            send_scalars(rec, path, times, v, valid)
            counts[path] = counts.get(path, 0) + int(valid.sum())


def _host_of(t_s: np.ndarray, ble: BleTelemetry, t_motion: np.ndarray) -> np.ndarray | None:
    """Host times of grid rows, interpolated from the motion notifications' (drone, host) pairs."""
    if len(ble) < 2:
        return None
    return np.interp(t_s, t_motion, ble.motion_t_host_s)


def log_ble_replay(
    rec: rr.RecordingStream, replay: BleReplay, *, blueprint: bool = True, progress: Progress = None
) -> dict[str, int]:
    """Log a whole BLE replay; returns samples logged per entity path."""
    ble, inp = replay.ble, replay.inputs
    sources = [ent.source_name(n) for n in replay.estimates]
    if blueprint:
        rec.send_blueprint(ble_blueprint(sources), make_active=True, make_default=True)
    log_ble_static(rec, sources)
    counts: dict[str, int] = {}
    n = len(ble)
    # each motion notification at its row of the estimators' grid (its sample number)
    first = np.flatnonzero(~inp.filled) if len(inp.filled) else np.zeros(0, np.int64)
    t_motion = inp.t_s[first] if len(first) == n else ble.motion_t_fw_s
    log_ble_notifications(rec, ble, t_motion, counts)
    ends, rate = _rate_bins(t_motion)
    if len(ends):
        send_scalars(rec, ent.BLE_RATE, Times(t_motion, ble.motion_t_host_s).take(ends), rate)
        counts[ent.BLE_RATE] = len(ends)
    if progress is not None:
        progress(0.5, "logging the estimators")
    gt = Times(inp.t_s, _host_of(inp.t_s, ble, t_motion))
    ests = {name: (e.q_wxyz, e.thx_rad, e.thy_rad, getattr(e, "valid", None)) for name, e in replay.estimates.items()}
    log_ble_estimates(rec, gt, ests, counts)
    return counts


class BleLiveLogger:
    """The Rerun side of ``steval live --ble`` (``steval_link.live.ble_source.BleViewer``): the live blueprint
    (host time, scrolling), then each round's rows."""

    def __init__(self, options: Any, recording_name: str | None = None) -> None:
        self.session = open_session(options.sinks, recording_name=recording_name, checked=True)  # checked by the CLI
        self.rec = self.session.rec
        sources = [ent.source_name(n) for n in options.estimators]
        self.rec.send_blueprint(ble_blueprint(sources, live=True), make_active=True, make_default=True)
        log_ble_static(self.rec, sources)
        self.counts: dict[str, int] = {}

    def log_rows(self, rows) -> None:
        ble = rows.ble
        t_motion = np.asarray(ble.motion_t_fw_s, np.float64)
        log_ble_notifications(self.rec, ble, t_motion, self.counts)
        if len(rows.t_s):
            times = Times(rows.t_s, _host_of(rows.t_s, ble, t_motion))
            log_ble_estimates(
                self.rec, times, {k: (q, x, y, None) for k, (q, x, y) in rows.estimates.items()}, self.counts
            )

    def close(self) -> None:
        self.session.close()


def ble_replay_sink(options: Any, *, progress: Progress = None) -> Callable[[BleReplay], dict[str, int]]:
    """The Rerun sink of ``steval replay`` for a BLE capture (``.rrd`` written whole or not at all, as
    ``replay_log.replay_sink``)."""

    def sink(replay: BleReplay) -> dict[str, int]:
        path = replay.source.get("path")
        name = f"steval replay {Path(path).name}" if path else "steval replay (BLE)"

        def log(rec):
            counts = log_ble_replay(
                rec, replay, progress=None if progress is None else (lambda f, s="": progress(0.6 * f, s))
            )
            if progress is not None:
                progress(0.6, "writing to Rerun")
            return counts

        return log_whole(options, name, log)

    return sink

"""The default Rerun blueprint of steval-link, sent with every recording: the 3D view above the link tabs on the
left, the attitude plots on the right; live recordings scroll the last :data:`LIVE_WINDOW_S` s."""

from __future__ import annotations

import math
from typing import Callable, Iterable, Mapping

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from steval_link import constants as C
from steval_viewer import entities as ent
from steval_viewer.columns import TEXT_ROOT

#: a legend's height over its plot's at the default window (1600×1000), by plot and series count (5, 3, 3)
LEGEND_SHARE = {"angles": 0.32, "sensors": 0.42, "link": 0.62}
#: Width of the scrolling window of the live blueprint, seconds.
LIVE_WINDOW_S = 10.0


def _plotter(live: bool, timeline: str) -> Callable[..., rrb.TimeSeriesView]:
    """Time-series views of one layout: ``live`` scrolls the last :data:`LIVE_WINDOW_S` of ``timeline``."""
    start = rrb.TimeRangeBoundary.cursor_relative(seconds=-LIVE_WINDOW_S)
    scroll = rrb.VisibleTimeRange(timeline, start=start, end=rrb.TimeRangeBoundary.cursor_relative()) if live else None

    def plot(origin, name, contents="$origin/**", y_range=None, *, legend=True, bottom=False, left=False):
        """A time-series view; ``legend``: False for one-series plots. The legend sits right in a replay (a flight's
        calm end), left live (the newest data is on the right) or with ``left``; ``bottom`` for data at the top."""
        corner = ("Left" if live or left else "Right") + ("Bottom" if bottom else "Top")
        key = rrb.PlotLegend(corner=getattr(rrb.Corner2D, corner), visible=legend)
        axis = None if y_range is None else rrb.ScalarAxis(range=y_range)
        return rrb.TimeSeriesView(
            origin=origin, contents=contents, name=name, time_ranges=scroll, plot_legend=key, axis_y=axis
        )

    return plot


def axis_limit(max_abs: float) -> float | None:
    """A symmetric y range ±limit holding ``max_abs`` whose ends are labelled ticks (1, 2 or 5 × 10^k: Rerun labels
    only powers of ten), with room for the legend; None for no finite data."""
    if not 0 < max_abs < math.inf:
        return None
    need = 1.6 * max_abs
    k = math.floor(math.log10(need))
    return next(m * 10.0**k for m in (1.0, 2.0, 5.0, 10.0) if m * 10.0**k >= need)


def make_blueprint(
    *,
    live: bool = False,
    ghost_sources: Iterable[str] = (),
    gyro_max_dps: float | None = None,
    flight_control: bool = False,
    never_armed: bool = False,
    replica_verdict: str | None = None,
    y_ranges: Mapping[str, tuple[float, float]] | None = None,
    ble: bool = False,
    absent: Iterable[str] = (),
    text: bool = False,
) -> rrb.Blueprint:
    """The default blueprint. ``live``: the last 10 s on ``host_time`` (else the whole flight on ``fw_time``).
    ``ghost_sources``: those with a ghost drone (one shown, by ``GHOST_PREFERENCE``). ``gyro_max_dps``: the gyro
    plot's ± range. ``y_ranges``: by plot entity. ``absent``: plots left out. ``text``: the text tab in front."""
    yr = dict(y_ranges or {})
    sources = list(ghost_sources)
    ghost = next((s for s in ent.GHOST_PREFERENCE if s in sources), sources[0] if sources else None)
    timeline = ent.TIMELINE_HOST if live else ent.TIMELINE_FW
    plot = _plotter(live, timeline)
    overrides = {ent.estimate_path(s): rrb.EntityBehavior(visible=False) for s in sources if s != ghost}
    view3d = rrb.Spatial3DView(
        origin=ent.WORLD,
        name="Attitude: firmware (solid, red props = front), estimate (ghost), gravity (yellow)",
        overrides=overrides or None,
        eye_controls=rrb.EyeControls3D(position=(2.1, -2.6, 1.6), look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 0.0, 1.0)),
        line_grid=rrb.LineGrid3D(visible=True, spacing=0.5),
    )
    left = rrb.Vertical(view3d, link_view(plot, yr, ble, text), row_shares=[3, 2])
    limit = None if gyro_max_dps is None else axis_limit(gyro_max_dps)
    right = attitude_view(plot, yr, replica_verdict, None if limit is None else (-limit, limit), frozenset(absent))
    if flight_control:
        right = rrb.Tabs(right, flight_view(plot, never_armed), name="Attitude / flight control")
    time_panel = rrb.TimePanel(timeline=timeline, state="collapsed", play_state="following" if live else None)
    return window(rrb.Horizontal(left, right, column_shares=[2, 3]), time_panel)


def window(content, time_panel: rrb.TimePanel) -> rrb.Blueprint:
    """A layout's window: ``content``, ``time_panel``, the side panels closed."""
    closed = (rrb.BlueprintPanel(expanded=False), rrb.SelectionPanel(expanded=False))
    return rrb.Blueprint(content, time_panel, *closed, collapse_panels=False)


def link_view(plot: Callable, yr: Mapping[str, tuple[float, float]], ble: bool, text: bool) -> rrb.Tabs:
    """The link tabs under the 3D view: link health, firmware log, text telemetry (in front when ``text``), BLE."""
    losses = [f"+ {ent.LINK_MISSING}", f"+ {ent.LINK_CRC}", f"+ {ent.LINK_TX_DROPPED}"]
    health = [
        plot(ent.LINK_RATE, "Frame rate (frames/s)", y_range=(0.0, 200.0), legend=False),
        plot(ent.LINK, "Link losses (count, cumulative)", losses, yr.get(ent.LINK), left=True),
        plot(ent.LINK_CYCLES, "AHRS cycles/step (max, mean)", legend=False),
        plot(ent.LINK_QUEUE, "TX queue peak (bytes)", legend=False),
    ]
    tabs = [rrb.Grid(*health, grid_columns=2, name="Link health"), rrb.TextLogView(origin="log", name="Firmware log")]
    tabs += [plot(TEXT_ROOT, "Text telemetry (your printed series)", bottom=True), *([ble_view(plot)] if ble else [])]
    return rrb.Tabs(*tabs, active_tab=2 if text else None, name="Link")


def attitude_view(plot: Callable, yr, replica_verdict: str | None, gyro_range, absent: frozenset[str]) -> rrb.Vertical:
    """The plots on the right, but ``absent`` ones; the replica only in the difference plot (it hides the firmware)."""
    diff = "firmware − replica (deg)" + (f": {replica_verdict}" if replica_verdict else "")
    titles = {
        ent.PLOT_PITCH: "thx pitch, about x (deg, nose up +)",
        ent.PLOT_ROLL: "thy roll, about y (deg, right side down +)",
    }
    angles = [plot(p, title, ["$origin/**", f"- {p}/{ent.SOURCE_REPLICA}"], yr.get(p)) for p, title in titles.items()]
    yaw = plot(ent.PLOT_YAW, f"thz yaw (deg): integrated at gTHR ≥ {C.MIN_THR}, else 0", legend=False)
    sensors = [
        plot(ent.PLOT_ACC, "accelerometer (mg)", y_range=yr.get(ent.PLOT_ACC), bottom=True),
        plot(ent.PLOT_GYRO, "gyro (deg/s)", y_range=gyro_range, bottom=True),
        plot(ent.PLOT_THROTTLE, "gTHR", legend=False),
    ]
    rows = (angles, [yaw, plot(ent.PLOT_DIFF, diff, y_range=yr.get(ent.PLOT_DIFF))], sensors)
    kept, shares = [], []
    for row, share, columns in zip(rows, (3, 2, 2), (None, None, [2, 2, 1])):
        views = [v for v in row if str(v.origin) not in absent]
        if views:
            kept.append(rrb.Horizontal(*views, column_shares=columns if len(views) == len(row) else None))
            shares.append(share)
    return rrb.Vertical(*kept, row_shares=shares, name="Attitude")


def ble_view(plot: Callable) -> rrb.Vertical:
    """A BLE link's own values: what its rows are, the drone's battery, pressure, temperature, RSSI and arming."""
    paths = (ent.BLE_BATTERY, ent.BLE_PRESSURE, ent.BLE_RSSI, ent.BLE_ARMED, ent.BLE_TEMPERATURE, ent.BLE_MAG)
    titles = ("battery (%)", "pressure (hPa)", "RSSI (dBm)", "armed (0/1)", "temperature (°C)", "magnetometer (mgauss)")
    plots = [plot(path, title, legend=False) for path, title in zip(paths, titles)]
    note = rrb.TextDocumentView(origin=ent.BLE_NOTE, name="Note")
    return rrb.Vertical(note, rrb.Grid(*plots, grid_columns=3), row_shares=[1, 3], name="BLE")


def flight_view(plot: Callable, never_armed: bool = False) -> rrb.Vertical:
    """The flight-control view: per axis the remote's target against the firmware's angle, then the loops' outputs."""
    fw = ent.SOURCE_FIRMWARE
    angles = (ent.pitch_path(fw), ent.roll_path(fw), ent.yaw_path(fw))
    targets = [
        plot("/", f"{name} vs target (deg)", [f"+ {target}", f"+ {angle}"])
        for name, target, angle in zip(("pitch thx", "roll thy", "yaw thz"), ent.FC_TARGETS, angles)
    ]
    axes = ("pitch (x)", "roll (y)", "yaw (z)")
    outer = [plot(path, f"outer {axis}: s1, P, I (rad/s)") for path, axis in zip(ent.FC_OUTER, axes)]
    out = rrb.Horizontal(
        plot(ent.FC_INNER, "inner loop s2 (PWM)", bottom=True),
        plot(ent.FC_MOTORS, "motors (of 2000)", bottom=True),
        plot(ent.FC_STICKS, "remote sticks", bottom=True),
        plot(ent.FC_VBAT, "Vbat", legend=False),
        column_shares=[2, 2, 2, 1],
    )
    name = "Flight control (never armed: targets at rest, motors off)" if never_armed else "Flight control"
    return rrb.Vertical(rrb.Horizontal(*targets), rrb.Horizontal(*outer), out, row_shares=[3, 2, 2], name=name)


def send_blueprint(rec: rr.RecordingStream, **kwargs) -> None:
    """Build the blueprint (arguments of :func:`make_blueprint`) and send it as the recording's default."""
    rec.send_blueprint(make_blueprint(**kwargs), make_active=True, make_default=True)


def replica_verdict(step, bit_exact, seeded) -> str | None:
    """The replica against the firmware in words (a panel title); None when no row was seeded."""
    seeded = np.asarray(seeded, bool)
    n, differ = int(seeded.sum()), np.flatnonzero(seeded & ~np.asarray(bit_exact, bool))
    if n == 0:
        return None
    if not differ.size:
        return f"bit-exact on {n} of {n} steps"
    return f"first difference at step {int(np.asarray(step)[differ[0]])}"  # short: a title at the default window size


def legend_room(values, *, share: float, bottom: bool, floor: float | None = None) -> tuple[float, float] | None:
    """A y range that leaves the top (or ``bottom``) ``share`` of a plot's height free for its legend; ``floor``: a
    value the range always shows (0 for counts). None for no finite data."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    lo, hi = float(v.min()), float(v.max())
    if floor is not None:
        lo = min(lo, floor)
    span = hi - lo if hi > lo else max(abs(hi) * 0.1, 1.0)
    pad = 0.04 * span
    total = (span + 2 * pad) / (1.0 - share)
    if bottom:
        return (hi + pad - total, hi + pad)
    return (lo - pad, lo - pad + total)

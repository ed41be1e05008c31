"""The default layout as a user sees it after ``steval replay recordings/demo.stv --rrd X``: legends out of the
data, a gyro axis with labelled ticks, the 3D axis names clear of the rotor discs (read back from the .rrd)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.link.load import load_telemetry
from steval_viewer import blueprint as bp
from steval_viewer import drone_model
from steval_viewer import entities as ent
from steval_viewer.blueprint import axis_limit
from steval_viewer.rrd_check import active_tabs, blueprint_views, read_rrd, static_values

DEMO = Path(__file__).resolve().parents[1] / "recordings" / "demo.stv"
LEFT_BOTTOM, RIGHT_TOP = 3, 2


@pytest.fixture(scope="module")
def demo_rrd(tmp_path_factory):
    out = tmp_path_factory.mktemp("layout") / "demo.rrd"
    with pytest.MonkeyPatch.context() as mp:
        code, _, err = run_cli(mp, _Capsys(), "replay", DEMO, "--rrd", out)
    assert code == 0, err
    return out


class _Capsys:
    """capsys for a module-scoped fixture: the CLI's output is not needed here."""

    def readouterr(self):
        return "", ""


def test_angle_legends_sit_where_the_demo_has_no_data(demo_rrd):
    views = blueprint_views(demo_rrd)
    pitch = next(v for v in views.values() if v.get("ViewBlueprint:space_origin") == ent.PLOT_PITCH)
    roll = next(v for v in views.values() if v.get("ViewBlueprint:space_origin") == ent.PLOT_ROLL)
    for view in (pitch, roll):
        assert view["PlotLegend:visible"] is True and view["PlotLegend:corner"] == RIGHT_TOP
    # the demo's pitch dip near 17 s (the lower left, where the legend used to be) and, in the top right corner
    # the legend now takes (last ~45 % of the flight, upper ~40 % of the axis), no data at all (t from the first
    # frame, which comes at 2.985 s since the demo is the real firmware under emulation: the dip 1 s earlier)
    tel = load_telemetry(DEMO)
    t = tel.attitude.t_fw_s - tel.attitude.t_fw_s[0]
    pitch_deg = np.degrees(tel.attitude.thx_rad)
    assert pitch_deg[(t > 9) & (t < 19)].min() < -25
    late = t > 0.55 * t[-1]
    assert pitch_deg[late].max() < 0.6 * pitch_deg.max()
    # one-series plots need no legend (their title names the series; the cycles plot lists max, mean, min top down)
    for origin in (ent.PLOT_YAW, ent.PLOT_THROTTLE, ent.LINK_RATE, ent.LINK_QUEUE, ent.LINK_CYCLES):
        view = next(v for v in views.values() if v.get("ViewBlueprint:space_origin") == origin)
        assert view["PlotLegend:visible"] is False, origin


def test_gyro_axis_has_labelled_ticks_around_the_data(demo_rrd):
    views = blueprint_views(demo_rrd)
    gyro = next(v for v in views.values() if v.get("ViewBlueprint:space_origin") == ent.PLOT_GYRO)
    lo, hi = gyro["ScalarAxis:range"]
    g_dps = np.abs(load_telemetry(DEMO).attitude.gyro_mdps).max() / 1000.0
    assert lo == -hi and hi >= 1.5 * g_dps  # room for the legend at the bottom
    assert gyro["PlotLegend:corner"] != LEFT_BOTTOM
    # Rerun labels powers of ten: the ends ±1, 2 or 5 × 10^k show at least three labelled ticks
    k = np.floor(np.log10(hi))
    assert hi / 10**k in (1.0, 2.0, 5.0)
    assert axis_limit(66.3) == 200.0 and axis_limit(5.0) == 10.0 and axis_limit(float("nan")) is None


def test_3d_labels_are_off_the_rotor_discs(demo_rrd):
    axes = static_values(demo_rrd, ent.WORLD_AXES)
    assert "Arrows3D:labels" not in axes  # Rerun draws an arrow's label at its middle: on the rotors
    gravity = static_values(demo_rrd, ent.ACC_GRAVITY)
    assert "Arrows3D:labels" not in gravity
    names = static_values(demo_rrd, ent.WORLD_AXIS_LABELS)
    assert names["Points3D:labels"] == ["x right", "y forward", "z up"]
    motors = drone_model.motor_positions()
    for p in np.asarray(names["Points3D:positions"]):
        # far from every rotor disc (and beyond the arrow tip)
        assert np.linalg.norm(motors - p, axis=1).min() > drone_model.PROP_RADIUS + 0.3
        assert np.linalg.norm(p) > np.linalg.norm(axes["Arrows3D:vectors"], axis=1).max()


def _view(views, origin):
    return next(v for v in views.values() if v.get("ViewBlueprint:space_origin") == origin)


def test_the_replica_is_only_in_the_difference_panel_which_states_its_verdict(demo_rrd):
    """Bit-exact, the replica's line would hide the firmware's: the angle plots leave it out, and the difference
    panel says in words how many steps are bit-exact."""
    views = blueprint_views(demo_rrd)
    for origin, path in (
        (ent.PLOT_PITCH, ent.pitch_path(ent.SOURCE_REPLICA)),
        (ent.PLOT_ROLL, ent.roll_path(ent.SOURCE_REPLICA)),
    ):
        query = str(_view(views, origin)["ViewContents:query"])
        assert f"- {path}" in query
    titles = [name for name, v in views.items() if v.get("ViewBlueprint:space_origin") == ent.PLOT_DIFF]
    assert titles == ["firmware − replica (deg): bit-exact on 9210 of 9210 steps"]
    yaw = [name for name, v in views.items() if v.get("ViewBlueprint:space_origin") == ent.PLOT_YAW][0]
    assert "gTHR ≥ 200" in yaw  # the yaw's reset to 0 below the gain-switch throttle, explained


def test_legends_of_the_accelerometer_and_link_losses_leave_the_data_free(demo_rrd):
    views = blueprint_views(demo_rrd)
    a = load_telemetry(DEMO).attitude
    acc = np.asarray(a.acc_mg, float)
    lo, hi = _view(views, ent.PLOT_ACC)["ScalarAxis:range"]
    assert _view(views, ent.PLOT_ACC)["PlotLegend:corner"] in (LEFT_BOTTOM, 4)
    # the legend takes the bottom band of the plot: no sample there
    assert acc.min() > lo + bp.LEGEND_SHARE["sensors"] * (hi - lo) and acc.max() <= hi
    lo, hi = _view(views, ent.LINK)["ScalarAxis:range"]
    assert lo < 0 < hi  # zero losses at the bottom, the legend (top left) above them


def test_port_verdict_and_legend_room():
    assert bp.replica_verdict([5, 6, 7], [True, True, True], [True, True, True]) == "bit-exact on 3 of 3 steps"
    v = bp.replica_verdict([5, 6, 7, 8], [True, False, True, True], [True, True, True, False])
    assert v == "first difference at step 6"
    assert bp.replica_verdict([1], [False], [False]) is None
    lo, hi = bp.legend_room([-10.0, 30.0], share=0.4, bottom=False)
    assert lo < -10 and 30 < lo + 0.6 * (hi - lo)  # the data in the lower 60 %
    assert bp.legend_room([np.nan], share=0.4, bottom=True) is None


def test_flight_control_tab_says_when_the_drone_was_never_armed():
    for never_armed in (True, False):
        right = bp.make_blueprint(flight_control=True, never_armed=never_armed).root_container.contents[1]
        names = [str(t.name) for t in right.contents]
        assert names[0] == "Attitude" and names[1].startswith("Flight control")
        assert ("never armed" in names[1]) == never_armed


def test_a_log_of_printed_angles_shows_only_the_plots_it_has_values_for(demo_rrd, tmp_path, monkeypatch, capsys):
    """A student's PRINTF log of pitch and roll: no yaw, no sensors, no replica. Its replay leaves those panels out
    (they would stay empty); the demo's replay has them all."""
    a = load_telemetry(DEMO).attitude
    log = tmp_path / "exercise2.log"
    pitch, roll = np.degrees(a.thx_rad[:600].astype(float)), np.degrees(a.thy_rad[:600].astype(float))
    log.write_text("".join(f"Drone_Pitch = {p:f}\tDrone_Roll = {r:f}\n\n" for p, r in zip(pitch, roll)))
    out = tmp_path / "log.rrd"
    code, _, err = run_cli(monkeypatch, capsys, "replay", log, "--rrd", out)
    assert code == 0, err
    plots = (ent.PLOT_PITCH, ent.PLOT_ROLL, ent.PLOT_YAW, ent.PLOT_DIFF, ent.PLOT_ACC, ent.PLOT_GYRO, ent.PLOT_THROTTLE)
    shown = {v.get("ViewBlueprint:space_origin") for v in blueprint_views(out).values()}
    assert [p in shown for p in plots] == [True, True, False, False, False, False, False]
    demo = {v.get("ViewBlueprint:space_origin") for v in blueprint_views(demo_rrd).values()}
    assert all(p in demo for p in plots)
    # the printed series in front, replayed and live; the demo's tabs as they were
    live = tmp_path / "live.rrd"
    code, _, err = run_cli(
        monkeypatch, capsys, "live", "--port", f"replay://{log}?rate=400", "--no-view", "--rrd", live,
        "--duration", "1", "--out", tmp_path / "live.stv",
    )  # fmt: skip
    assert code == 0, err
    for path in (out, live):
        assert [t for t in active_tabs(path) if t.startswith("Text telemetry")], (path, active_tabs(path))
    assert not [t for t in active_tabs(demo_rrd) if t.startswith("Text telemetry")]
    # no accelerometer printed: no gravity arrow sent live (an all-null column is an error in the viewer)
    assert ent.ACC_GRAVITY not in read_rrd(live).samples and ent.ACC_GRAVITY in read_rrd(demo_rrd).samples
    # nor motor arrows: they come with flight-control frames (an arrow without vectors is a viewer error)
    assert not [p for p in read_rrd(live).static if p.startswith(ent.motor_path(1).rsplit("/", 1)[0])]

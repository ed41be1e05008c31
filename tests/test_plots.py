"""Figures of ``steval compare --plot`` and ``steval simulate --plot`` (skipped without matplotlib), and the
one-line error when matplotlib is missing."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from test_compare import capture_bytes, run_cli, telemetry, text_mode_bytes  # noqa: E402

from steval_link.analysis import plots
from steval_link.analysis.compare import compare_capture
from steval_link.errors import UserError
from steval_link.estimators.st_mahony import MahonySettings

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


@pytest.fixture
def mpl():
    return pytest.importorskip("matplotlib")


def lines_by_label(ax) -> dict:
    return {ln.get_label(): ln for ln in ax.get_lines()}


def test_comparison_figure_draws_every_trace_in_degrees(mpl):
    tel = telemetry(n=800)
    r = compare_capture(tel, estimators=("accel",))
    fig = plots.comparison_figure(tel, r)
    ax_p, ax_r, ax_d = fig.axes[0], fig.axes[1], fig.axes[2]
    assert "pitch (thx, about x)" in ax_p.get_title(loc="left") and "roll (thy, about y)" in ax_r.get_title(loc="left")
    assert "[deg]" in ax_p.get_ylabel()
    lp = lines_by_label(ax_p)
    assert {"firmware (drone)", "ST-Mahony replica (seeded)", "accel-only tilt"} <= set(lp)
    assert np.allclose(lp["firmware (drone)"].get_ydata(), np.degrees(tel.attitude.thx_rad.astype(float)))
    assert np.allclose(
        lines_by_label(ax_r)["firmware (drone)"].get_ydata(), np.degrees(tel.attitude.thy_rad.astype(float))
    )
    # the replica is bit-exact: the difference panel says so and its lines are zero
    texts = [t.get_text() for t in ax_d.texts]
    assert any("bit-exact on all 800" in t for t in texts)
    assert np.all(lines_by_label(ax_d)["pitch: firmware − replica"].get_ydata() == 0)
    # the bar panel has one group per available estimator
    ax_b = fig.axes[3]
    assert [t.get_text() for t in ax_b.get_yticklabels()] == ["ST-Mahony replica", "accel-only tilt"]
    import matplotlib.pyplot as plt

    plt.close(fig)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_comparison_png_of_a_mismatch_with_drops_and_nan(mpl, tmp_path):
    tel = telemetry(
        n=1200,
        drop=range(300, 320),
        burst=(700, 760),
        fw_settings=MahonySettings(ki=1.0),
        status_settings=MahonySettings(),
    )
    r = compare_capture(tel, estimators=("accel", "st-mahony"))
    fig = plots.comparison_figure(tel, r)
    ax_d = fig.axes[2]
    assert "first difference: step 0" in lines_by_label(ax_d)
    assert any("firmware NaN" in str(p.get_label()) for p in fig.axes[1].patches)  # a shaded gap, not a mark at 0°
    import matplotlib.pyplot as plt

    plt.close(fig)
    out = plots.plot_comparison(tel, r, tmp_path / "mismatch.png")
    w, h = png_size(out)
    assert w > 1000 and h > 600


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_text_mode_comparison_png(mpl, tmp_path):
    from steval_link.link.decoder import decode_bytes

    tel = decode_bytes(text_mode_bytes(), source={"path": "log.txt", "kind": "text"})
    r = compare_capture(tel, estimators=("accel",))
    out = plots.plot_comparison(tel, r, tmp_path / "text.png")
    assert png_size(out)[0] > 1000


def test_decimation_keeps_peaks():
    t = np.arange(100_000, dtype=float)
    y = np.zeros_like(t)
    y[54_321] = 7.0
    y[10_000:10_010] = np.nan
    tt, yy = plots._decimate(t, y, 2000)
    assert tt.size <= 4000 and np.nanmax(yy) == 7.0 and np.isnan(yy).any()
    assert np.all(np.diff(tt[np.isfinite(yy)]) >= 0)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_simulation_figure_and_png(mpl, tmp_path):
    from steval_link.emulation.lab5 import run_simulation

    res = run_simulation(gyro_mdps=(1000, 2000, 4000), acc_mg=(0, 0, 0), iterations=100)
    fig = plots.simulation_figure(res)
    titles = [ax.get_title(loc="left") for ax in fig.axes[:3]]
    assert titles == ["eax = thx: pitch (about x)", "eay = thy: roll (about y)", "eaz = thz: yaw (about z)"]
    y = fig.axes[0].get_lines()[0].get_ydata()
    assert np.allclose(y, np.degrees(res.eax_rad.astype(float)))
    assert "final" in fig.axes[2].get_title(loc="right")
    import matplotlib.pyplot as plt

    plt.close(fig)
    out = plots.plot_simulation(res, tmp_path / "sim.png")
    assert png_size(out)[1] > 500


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_cli_compare_plot(mpl, tmp_path, capsys):
    cap = tmp_path / "c.bin"
    cap.write_bytes(capture_bytes(n=600))
    out = tmp_path / "c.png"
    code, stdout, err = run_cli(["compare", str(cap), "--plot", str(out), "--json"], capsys)
    assert code == 0, err
    import json

    assert json.loads(stdout)["plot"] == str(out)
    assert png_size(out)[0] > 1000


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_cli_simulate_plot(mpl, tmp_path, capsys):
    out = tmp_path / "s.png"
    code, stdout, err = run_cli(["simulate", "--plot", str(out)], capsys)
    assert code == 0, err
    assert f"plot: {out}" in stdout and png_size(out)[0] > 800


def test_cli_plot_unwritable_exits_2(mpl, tmp_path, capsys):
    cap = tmp_path / "c.bin"
    cap.write_bytes(capture_bytes(n=300))
    code, _, err = run_cli(["compare", str(cap), "--plot", str(tmp_path / "no" / "dir" / "c.png")], capsys)
    assert code == 2 and err.count("\n") == 1 and "cannot write" in err and "--plot" in err


def test_missing_matplotlib_is_one_line_with_the_install_command(monkeypatch, tmp_path, capsys):
    for name in list(sys.modules):
        if name == "matplotlib" or name.startswith("matplotlib."):
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    with pytest.raises(UserError, match=r'pip install "steval-link\[plot\]"'):
        plots.require_matplotlib()
    cap = tmp_path / "c.bin"
    cap.write_bytes(capture_bytes(n=300))
    for args in (
        ["compare", str(cap), "--plot", str(tmp_path / "x.png")],
        ["simulate", "--plot", str(tmp_path / "y.png")],
    ):
        code, out, err = run_cli(args, capsys)
        assert code == 2 and err.count("\n") == 1 and 'pip install "steval-link[plot]"' in err
        assert out == ""
    assert not (tmp_path / "x.png").exists()


@pytest.mark.slow  # compare with figures on the bundled recordings: ≈ 15 s of CPU each
@pytest.mark.parametrize("name, armed", [("demo", False), ("flight", True)])
def test_cli_compare_flight_control_figure_only_when_armed(mpl, tmp_path, capsys, name, armed):
    """demo.stv was never armed: no flight-control figure, and one line says why; flight.stv gets one."""
    from pathlib import Path

    cap = Path(__file__).resolve().parents[1] / "recordings" / f"{name}.stv"
    out = tmp_path / "x.png"
    code, stdout, err = run_cli(["compare", str(cap), "--plot", str(out), "-e", "accel"], capsys)
    assert code == 0, err
    fc = tmp_path / "x-flight-control.png"
    assert png_size(out)[0] > 1000
    if armed:
        assert png_size(fc)[0] > 1000 and f"flight-control plot: {fc}" in stdout
    else:
        assert not fc.exists()
        why = [ln for ln in stdout.splitlines() if ln.startswith("no flight-control plot")]
        assert len(why) == 1 and "never armed" in why[0]


def test_simulation_figure_overlays_compare_runs(mpl):
    from steval_link.emulation.lab5 import run_simulation

    base = run_simulation(acc_mg=(0, 0, 1000), iterations=50)
    other = run_simulation(acc_mg=(0, 0, 1000), iterations=50, estimator_options={"correction": False})
    fig = plots.simulation_figure(base, compare=[("correction=off", other)])
    lines = lines_by_label(fig.axes[0])
    assert set(lines) == {"st-mahony as given", "with correction=off"}
    assert np.allclose(lines["with correction=off"].get_ydata(), np.degrees(other.eax_rad.astype(float)))
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["st-mahony as given", "with correction=off"]
    import matplotlib.pyplot as plt

    plt.close(fig)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_cli_simulate_compare_with(mpl, tmp_path, capsys):
    out = tmp_path / "s.png"
    args = ["simulate", "--acc", "0", "0", "1000", "--noise", "--seed", "3", "--plot", str(out)]
    code, stdout, err = run_cli([*args, "--compare-with", "ki=1", "--compare-with", "correction=off,kp=2"], capsys)
    assert code == 0, err
    assert png_size(out)[0] > 800
    with_lines = [ln for ln in stdout.splitlines() if ln.startswith("with ")]
    assert [ln.split(":")[0] for ln in with_lines] == ["with ki=1", "with correction=off,kp=2"]
    # the same inputs and noise: the compare run is the run with that setting given directly
    code, alone, _ = run_cli(["simulate", "--acc", "0", "0", "1000", "--noise", "--seed", "3", "--ki", "1"], capsys)
    eax = [ln for ln in alone.splitlines() if "eax" in ln][0].split(":")[1].split()[0]
    assert f"eax {eax}°" in with_lines[0]
    code, _, err = run_cli([*args, "--force", "--compare-with", "gain=3"], capsys)
    assert code == 2 and err.count("\n") == 1 and "--compare-with" in err


def test_differences_figure_draws_each_estimator_minus_the_firmware(mpl):
    tel = telemetry(n=500)
    r = compare_capture(tel, estimators=("accel",))
    fig = plots.differences_figure(tel, r)
    (line,) = [ln for ln in fig.axes[0].get_lines() if ln.get_label().startswith("accel-only tilt")]
    est = r.estimates["accel"]
    want = np.degrees(est.thx_rad.astype(float) - tel.attitude.thx_rad.astype(float))
    assert np.allclose(line.get_ydata(), want, atol=1e-9)
    assert f"RMS {r.trace('accel').pitch.rms_deg:.2f}°" in line.get_label()
    import matplotlib.pyplot as plt

    plt.close(fig)

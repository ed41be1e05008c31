"""The compare figure says what it shows (issue #31): its title names the estimators -e chose; the firmware's NaN
steps are a gap in its line (shaded), never drawn along 0°; an unavailable RMS is no bar."""

from __future__ import annotations

import numpy as np
import pytest

from steval_link.analysis.compare import compare_capture
from steval_link.link.capture import demo_capture_path
from steval_link.link.load import load_telemetry

pytest.importorskip("matplotlib")


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_title_names_the_chosen_estimators_and_nan_is_a_gap():
    from steval_link.analysis.plots import comparison_figure

    tel = load_telemetry(demo_capture_path())
    a = tel.attitude
    a.thx_rad = np.array(a.thx_rad, copy=True)
    a.thx_rad[3000:4000] = np.nan  # the firmware's filter gave up for a while
    report = compare_capture(tel, estimators=["ekf3"])
    fig = comparison_figure(tel, report)
    title = fig._suptitle.get_text()
    assert "EKF (3-state)" in title and "accel" not in title and "ST-Mahony replica" in title
    ax_p = fig.axes[0]
    fw_line = next(ln for ln in ax_p.get_lines() if ln.get_label() == "firmware (drone)")
    x, y = np.asarray(fw_line.get_xdata(), float), np.asarray(fw_line.get_ydata(), float)
    t = np.asarray(report.t_rel_s)
    inside = (x > t[3000]) & (x < t[3999])
    assert inside.any() and np.isnan(y[inside]).all()
    for ln in ax_p.get_lines():  # nothing drawn at 0° for the NaN rows
        yd = np.asarray(ln.get_ydata(), float)
        assert not (yd.size > 10 and np.all(yd == 0)), ln.get_label()
    fig2 = comparison_figure(tel, compare_capture(tel, estimators=["accel", "mekf"]))
    assert "accel-only tilt" in fig2._suptitle.get_text() and "3-state" not in fig2._suptitle.get_text()

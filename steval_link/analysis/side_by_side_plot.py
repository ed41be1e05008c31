"""The figure of ``steval compare A.stv B.stv ... --plot OUT.png``: pitch (thx, about x, nose up +) and roll (thy,
about y) of every flight overlaid with the first flight's accelerometer-only tilt as the reference and its still
phases shaded, each later flight minus the first, and a table of RMS against accel-only tilt in still phases and
of drift (the error in the last still phase). matplotlib is optional
(:func:`steval_link.analysis.plots.require_matplotlib`)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from steval_link.analysis.plots import _decimate, _spans, require_matplotlib, save_figure
from steval_link.analysis.report import fmt_number
from steval_link.analysis.side_by_side import SideBySide, difference_series

#: Flight colours, in order (the viewer uses the same).
COLOURS = ["tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange", "tab:cyan"]


def plot_side_by_side(r: SideBySide, out_png) -> Path:
    """Write :func:`side_by_side_figure` as a PNG to ``out_png`` (UserError when it cannot be written)."""
    return save_figure(side_by_side_figure(r), out_png)


def side_by_side_figure(r: SideBySide):
    """Pitch and roll of every flight over the first's accel-only tilt, the differences, and the still-phase table."""
    plt = require_matplotlib()
    fig = plt.figure(figsize=(13, 11))
    grid = fig.add_gridspec(4, 1, height_ratios=[3, 3, 2, 1.0], hspace=0.38)
    fig.subplots_adjust(top=0.93, bottom=0.02, left=0.07, right=0.98)
    ax_p = fig.add_subplot(grid[0])
    ax_r = fig.add_subplot(grid[1], sharex=ax_p)
    ax_d = fig.add_subplot(grid[2], sharex=ax_p)
    ax_t = fig.add_subplot(grid[3])
    _angle_panel(ax_p, r, "thx_rad", "accel_thx_rad", "pitch = thx (rotation about x, nose up +)")
    _angle_panel(ax_r, r, "thy_rad", "accel_thy_rad", "roll = thy (rotation about y, right side down +)")
    _differences_panel(ax_d, r)
    _still_table(ax_t, r)
    fig.suptitle(textwrap.fill(" vs ".join(f.label for f in r.flights), 150), fontsize=12)
    return fig


def _angle_panel(ax, r: SideBySide, attr: str, acc_attr: str, title: str) -> None:
    """One angle of every flight over the first flight's accel-only tilt, its still phases shaded."""
    ref = r.flights[0]
    _spans(ax, ref.t_s, ref.still, f"still phases ({ref.label})")
    t, y = _decimate(ref.t_s, np.degrees(getattr(ref, acc_attr)))
    ax.plot(t, y, color="0.55", lw=0.8, label=f"accel-only tilt ({ref.label}): reference", zorder=1)
    for i, f in enumerate(r.flights):
        t, y = _decimate(f.t_s, np.degrees(getattr(f, attr)))
        ax.plot(t, y, color=COLOURS[i % len(COLOURS)], lw=1.6 if i == 0 else 1.2, label=f.label, zorder=3 + i)
    ax.set_ylabel(f"{title.split(' ')[0]} {attr[:3]} (deg)")
    ax.set_title(title, fontsize=10, loc="left")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")


def _differences_panel(ax, r: SideBySide) -> None:
    """Each later flight minus the first, pitch solid and roll dashed."""
    ref = r.flights[0]
    for i, f in enumerate(r.flights[1:], start=1):
        t, dx, dy = difference_series(ref, f)
        c = COLOURS[i % len(COLOURS)]
        ax.plot(*_decimate(t, dx), color=c, lw=1.2, label=f"pitch thx: {f.label} − {ref.label}")
        ax.plot(*_decimate(t, dy), color=c, lw=1.0, ls="--", label=f"roll thy: {f.label} − {ref.label}")
    ax.axhline(0, color="0.3", lw=0.6)
    ax.set_ylabel("difference (deg)")
    ax.set_title("each flight minus the first", fontsize=10, loc="left")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    how = "firmware time from each first frame" if r.align == "time" else "motion (gyro cross-correlation)"
    ax.set_xlabel(f"time (s), aligned by {how}")


def _still_table(ax, r: SideBySide) -> None:
    """Per flight: still time, RMS against accel-only tilt in still phases, drift and drift rate."""
    ax.axis("off")
    head = ["flight", "still (s)", "RMS pitch thx (deg)", "RMS roll thy (deg)", "drift pitch (deg)",
            "drift roll (deg)", "drift rate p / r (deg/min)"]  # fmt: skip
    rows = []
    for f in r.flights:
        g = f.figures
        px, ry = g["pitch_thx"], g["roll_thy"]
        rows.append([
            textwrap.shorten(f.label, 46, placeholder=" …"),  # the legend above has the whole label
            f"{g['still_s']:.1f}",
            fmt_number(px["rms_still_deg"], ".3f"),
            fmt_number(ry["rms_still_deg"], ".3f"),
            fmt_number(px["drift_deg"], "+.3f"),
            fmt_number(ry["drift_deg"], "+.3f"),
            f"{fmt_number(px['drift_rate_deg_per_min'], '+.2f')} / {fmt_number(ry['drift_rate_deg_per_min'], '+.2f')}",
        ])  # fmt: skip
    widths = [0.26] + [0.74 / (len(head) - 1)] * (len(head) - 1)
    table = ax.table(cellText=rows, colLabels=head, loc="center", cellLoc="center", colWidths=widths)
    table.auto_set_font_size(False)
    table.set_fontsize(8.5)
    table.scale(1, 1.4)
    for i in range(len(rows)):
        table[i + 1, 0].get_text().set_color(COLOURS[i % len(COLOURS)])
    ax.set_title(
        "against accel-only tilt, still phases only (drift: the mean error in the last still phase)",
        fontsize=10,
        loc="left",
    )

"""Figures for lab reports (PNG): ``steval compare --plot`` and ``steval simulate --plot``; matplotlib is optional
(:func:`require_matplotlib`), on the Agg backend. Angles in degrees; thx is pitch (about x), thy roll (about y)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.analysis.flight_control import MOTORS, outer_p
from steval_link.analysis.report import angle_diff_rad, on_rows, setting_text, true_runs
from steval_link.errors import ParamError, UserError

INSTALL_HINT = 'pip install "steval-link[plot]"'

#: Line styles per trace: (colour, width, linestyle, z-order).
_STYLE = {
    "firmware": ("black", 2.2, "-", 3),
    "replica": ("tab:orange", 1.1, "--", 4),
    "st-mahony": ("tab:purple", 1.0, ":", 5),
    "accel": ("tab:gray", 0.6, "-", 2),
    "ekf3": ("tab:blue", 1.0, "-", 5),
    "mekf": ("tab:green", 1.0, "-.", 5),
    "vqf": ("tab:pink", 1.0, "-", 5),
}
#: Legend order: firmware and replica first, then the estimators in this order.
_ORDER = ["firmware (drone)", "ST-Mahony replica (seeded)"]
_EXTRA_COLOURS = ["tab:red", "tab:brown", "tab:olive", "tab:cyan"]
#: Lines longer than this are reduced (min/max per bucket, so peaks stay visible).
MAX_LINE_POINTS = 8000


def require_matplotlib():
    """``matplotlib.pyplot`` on the Agg backend; raises :class:`UserError` (exit 2) naming the install command."""
    try:
        import matplotlib

        matplotlib.use("Agg", force=True)
        import matplotlib.pyplot as plt
    except ImportError:
        raise ParamError(f"{{plot}} needs matplotlib, which is not installed: {INSTALL_HINT}", "plot") from None
    return plt


def _decimate(t: np.ndarray, y: np.ndarray, max_points: int = MAX_LINE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Min/max decimation of a line for drawing: peaks survive, NaN gaps stay gaps."""
    n = t.shape[0]
    if n <= max_points:
        return t, y
    buckets = max_points // 2
    edges = np.linspace(0, n, buckets + 1).astype(np.int64)
    tt, yy = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        seg = y[a:b]
        fin = np.isfinite(seg)
        picks = sorted((a + int(np.nanargmin(seg)), a + int(np.nanargmax(seg)))) if fin.any() else []
        tt += [t[i] for i in picks]
        yy += [y[i] for i in picks]
        if not fin.all():  # a NaN gap stays a gap
            tt.append(t[b - 1] if picks else t[a])
            yy.append(np.nan)
    return np.asarray(tt), np.asarray(yy)


def save_figure(fig, out_png, *, dpi: int = 130) -> Path:
    """Write ``fig`` to ``out_png`` (format by extension) and close it; UserError when it cannot be written."""
    out = Path(out_png)
    try:
        fig.savefig(out, dpi=dpi)
    except OSError as exc:
        raise UserError(f"cannot write the plot {out}: {exc.strerror or exc}") from None
    except ValueError as exc:  # unknown file extension
        raise UserError(f"cannot write the plot {out}: {exc}") from None
    finally:
        import matplotlib.pyplot as plt

        fig.clf()
        plt.close(fig)
    return out


def _label_panel(ax, ylabel: str, title: str) -> None:
    """A panel's y label, its title on the left and a light grid."""
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10, loc="left")
    ax.grid(True, alpha=0.3)


def _spans(ax, t: np.ndarray, mask: np.ndarray, label: str | None, color: str = "gold", alpha: float = 0.18) -> None:
    """Shade every run of rows where ``mask`` is True (one legend entry)."""
    for k, (a, b) in enumerate(true_runs(mask)):
        ax.axvspan(t[a], t[b - 1], color=color, alpha=alpha, lw=0, zorder=0, label=label if k == 0 else None)


def plot_comparison(tel, report, out_png, *, title: str | None = None) -> Path:
    """Write :func:`comparison_figure` as a PNG to ``out_png`` (returns the path; UserError when not writable)."""
    return save_figure(comparison_figure(tel, report, title=title), out_png)


def comparison_figure(tel, report, *, title: str | None = None):
    """Pitch (thx, about x) and roll (thy, about y) of the firmware, replica and estimators over firmware time; below,
    firmware − replica with the throttle; right, RMS and max |Δ| against the firmware per estimator."""
    plt = require_matplotlib()
    from matplotlib.gridspec import GridSpec

    a = tel.attitude
    t = np.asarray(report.t_rel_s, dtype=np.float64)
    fw = _degrees(a.thx_rad, a.thy_rad)
    fs = report.filter_settings or {}
    min_thr = fs["min_thr"] if isinstance(fs.get("min_thr"), int) else C.MIN_THR
    replica = _replica_degrees(report, t.shape[0])
    traces = _estimate_traces(report)

    fig = plt.figure(figsize=(13, 8.2))
    gs = GridSpec(3, 2, figure=fig, width_ratios=[3.2, 1], height_ratios=[1, 1, 0.8], hspace=0.4, wspace=0.22)
    ax_p = fig.add_subplot(gs[0, 0])
    ax_r = fig.add_subplot(gs[1, 0], sharex=ax_p)
    ax_d = fig.add_subplot(gs[2, 0], sharex=ax_p)
    ax_b = fig.add_subplot(gs[0:2, 1])
    ax_txt = fig.add_subplot(gs[2, 1])
    ax_txt.axis("off")

    thr = np.asarray(a.thr)
    for ax, key, what in ((ax_p, "pitch", "pitch (thx, about x)"), (ax_r, "roll", "roll (thy, about y)")):
        flight = f"throttle ≥ {min_thr}: kp_flight" if key == "pitch" else None
        _angle_panel(
            ax, t, key, what, fw[key], traces, None if replica is None else replica[key], report, thr >= min_thr, flight
        )
    _restart_lines((ax_p, ax_r, ax_d), t, a.step)
    _comparison_legend(fig, ax_p)
    plt.setp([*ax_p.get_xticklabels(), *ax_r.get_xticklabels()], visible=False)
    _replica_panel(ax_d, t, fw, replica, report)
    _throttle_twin(ax_d, t, thr, min_thr)
    _difference_bars(ax_b, ax_txt, report)
    lines = _summary_lines(report, fs)
    wrapped = [w for line in lines for w in textwrap.wrap(line, 44, subsequent_indent="  ")]
    ax_txt.text(
        0.0, 0.72, "\n".join(wrapped), va="top", ha="left", fontsize=8, family="monospace", transform=ax_txt.transAxes
    )
    src = Path(str(report.source.get("path") or "capture")).name
    shown = ", ".join((["ST-Mahony replica"] if replica is not None else []) + [label for _, label, _, _ in traces])
    default = f"steval compare: {src} — firmware vs {shown or 'no estimator'} (axes: x right, y forward, z up)"
    fig.suptitle(title or default, fontsize=11)
    fig.subplots_adjust(left=0.07, right=0.97, top=0.9, bottom=0.07)
    return fig


def _degrees(thx_rad, thy_rad) -> dict[str, np.ndarray]:
    """Pitch (thx, about x) and roll (thy, about y) in degrees, float64."""
    return {"pitch": np.degrees(np.asarray(thx_rad, np.float64)), "roll": np.degrees(np.asarray(thy_rad, np.float64))}


def _replica_degrees(report, n: int) -> dict[str, np.ndarray] | None:
    """The seeded replica's pitch and roll in degrees on the capture's rows (NaN where it did not run)."""
    if report.replay is None:
        return None
    rows, rep = report.replica_rows, report.replay
    return _degrees(on_rows(n, rows, rep.thx_rad), on_rows(n, rows, rep.thy_rad))


def _estimate_traces(report) -> list[tuple[str, str, dict[str, np.ndarray], tuple]]:
    """Per estimator: name, label, pitch and roll in degrees (NaN where not valid) and line style."""
    extra = iter(_EXTRA_COLOURS)
    traces = []
    for name, est in report.estimates.items():
        label = next((tr.label for tr in report.traces if tr.name == name), name)
        valid = np.asarray(est.valid, bool)
        degrees = {k: np.where(valid, v, np.nan) for k, v in _degrees(est.thx_rad, est.thy_rad).items()}
        traces.append((name, label, degrees, _STYLE.get(name) or (next(extra, "tab:red"), 1.0, "-", 4)))
    return traces


def _styled_line(ax, t, y, style, label) -> None:
    c, lw, ls, z = style
    ax.plot(*_decimate(t, y), color=c, lw=lw, ls=ls, zorder=z, label=label)


def _angle_panel(ax, t, key, what, fw_deg, traces, replica_deg, report, at_flight, flight_label) -> None:
    """One angle over time: flight-throttle spans, the estimators, the firmware, the replica, firmware NaN gaps."""
    _spans(ax, t, at_flight, flight_label)
    for _name, label, vals, style in traces:
        _styled_line(ax, t, vals[key], style, label)
    _styled_line(ax, t, fw_deg, _STYLE["firmware"], "firmware (drone)")
    if replica_deg is not None:
        _styled_line(ax, t, replica_deg, _STYLE["replica"], "ST-Mahony replica (seeded)")
    nan_rows = ~np.isfinite(fw_deg)
    if nan_rows.any():  # a gap in the firmware's line, shaded: never drawn as 0°
        why = "its filter diverged" if getattr(report, "values_bad", None) else "asin out of range"
        _spans(ax, t, nan_rows, f"firmware NaN ({why})", color="crimson", alpha=0.15)
    _label_panel(ax, f"{what} [deg]", what)


def _restart_lines(axes, t, step) -> None:
    """A vertical line where the firmware's step counter goes back (a restart); the first axes carry the label."""
    restarts = np.flatnonzero(np.diff(np.asarray(step, dtype=np.int64)) <= 0) + 1
    for ax in axes:
        for k, r in enumerate(restarts):
            label = "firmware restart" if (k == 0 and ax is axes[0]) else None
            ax.axvline(t[r], color="dimgray", lw=1.0, ls="-.", zorder=1, label=label)


def _comparison_legend(fig, ax) -> None:
    """The figure's legend from ``ax``: firmware and replica first."""
    h, lab = ax.get_legend_handles_labels()
    rank = {name: i for i, name in enumerate(_ORDER)}
    order = sorted(range(len(lab)), key=lambda i: (rank.get(lab[i], len(rank)), i))
    h, lab = [h[i] for i in order], [lab[i] for i in order]
    fig.legend(h, lab, loc="upper left", bbox_to_anchor=(0.07, 0.955), ncol=min(len(h), 7), fontsize=8,
               frameon=False, columnspacing=1.2, handlelength=2.0)  # fmt: skip


def _centre_text(ax, text: str, **kw) -> None:
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", **kw)


def _replica_panel(ax, t, fw, replica, report) -> None:
    """Firmware − replica in degrees: unseeded rows greyed, bit-exact said in words, the first difference marked."""
    ax.set_title("firmware − ST-Mahony replica", fontsize=10, loc="left")
    if replica is None:
        _centre_text(ax, "text-mode capture: the bit-exact replica needs binary frames", fontsize=10)
        return
    p = report.replica
    for key, colour in (("pitch", "tab:blue"), ("roll", "tab:red")):
        d = _wrap_deg(fw[key] - replica[key])
        ax.plot(*_decimate(t, d), color=colour, lw=0.9, label=f"{key}: firmware − replica")
    covered, exact = np.zeros(t.shape[0], bool), np.zeros(t.shape[0], bool)
    covered[report.replica_rows] = report.replay.seeded
    exact[report.replica_rows] = report.replay.bit_exact
    _spans(ax, t, ~covered, "replica not seeded", color="lightgray", alpha=0.6)
    if p.all_exact:
        ax.set_ylim(-1, 1)
        _centre_text(ax, f"replica bit-exact on all {p.bit_exact} seeded steps", fontsize=11, color="darkgreen",
                     bbox=dict(boxstyle="round", fc="honeydew", ec="darkgreen"))  # fmt: skip
    else:
        fm = p.first_mismatch
        if fm is not None:
            ax.axvline(fm["t_rel_s"], color="crimson", lw=1.2, ls=":", label=f"first difference: step {fm['step']}")
        _spans(ax, t, covered & ~exact, "not bit-exact", color="crimson", alpha=0.08)
    ax.set_ylabel("firmware − replica [deg]")


def _throttle_twin(ax, t, thr, min_thr) -> None:
    """The throttle (gTHR) shaded on a twin axis behind ``ax``; one legend for both, above ``ax``."""
    ax_thr = ax.twinx()
    ax_thr.fill_between(t, thr, step="mid", color="gold", alpha=0.25, lw=0, label="throttle (gTHR)")
    ax_thr.set_ylabel("throttle", fontsize=8, color="darkgoldenrod")
    ax_thr.tick_params(labelsize=7, colors="darkgoldenrod")
    ax_thr.set_ylim(0, max(float(np.max(thr)) * 1.1 if thr.size else 1.0, float(min_thr) * 1.5))
    ax.set_zorder(ax_thr.get_zorder() + 1)
    ax.patch.set_visible(False)
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax_thr.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=3, fontsize=7, frameon=False,
              borderaxespad=0.1, columnspacing=1.0)  # fmt: skip
    ax.set_xlabel("firmware time since the first frame [s]")
    ax.grid(True, alpha=0.3)


def _difference_bars(ax, ax_legend, report) -> None:
    """RMS and max |Δ| from the firmware per available estimator (NaN: no bar, "n/a"); the legend in ``ax_legend``."""
    avail = [tr for tr in report.traces if tr.available and tr.pitch.n]
    y = np.arange(len(avail))
    h = 0.2
    series = [
        ("pitch RMS", [tr.pitch.rms_deg for tr in avail], "tab:blue", 1.0),
        ("pitch max |Δ|", [tr.pitch.max_abs_deg for tr in avail], "tab:blue", 0.35),
        ("roll RMS", [tr.roll.rms_deg for tr in avail], "tab:red", 1.0),
        ("roll max |Δ|", [tr.roll.max_abs_deg for tr in avail], "tab:red", 0.35),
    ]
    vmax = max([v for _, vals, _, _ in series for v in vals if math.isfinite(v)] + [0.0])
    for k, (lab, vals, c, alpha) in enumerate(series):
        vals = np.asarray(vals, float)
        pos = y + (k - 1.5) * h
        ax.barh(pos, np.where(np.isfinite(vals), vals, 0.0), height=h, color=c, alpha=alpha, label=lab)
        for yy, v, tr in zip(pos, vals, avail):
            if not math.isfinite(v):
                ax.text(vmax * 0.01, yy, "n/a", va="center", fontsize=6.5)
                continue
            txt = "0 (bit-exact)" if v == 0 and tr.note == "bit-exact" else f"{v:.3g}"
            ax.text(v + vmax * 0.01, yy, txt, va="center", fontsize=6.5)
    ax.set_yticks(y, [tr.label for tr in avail], fontsize=8)
    ax.invert_yaxis()
    ax.set(xlim=(0, vmax * 1.25 if vmax > 0 else 1.0), xlabel="difference from the firmware [deg]")
    ax.set_title("vs firmware: RMS and max |Δ|", fontsize=10, loc="left")
    hb, lb = ax.get_legend_handles_labels()
    ax_legend.legend(hb, lb, loc="upper left", bbox_to_anchor=(0.0, 1.0), ncol=2, fontsize=7.5, frameon=False,
                     borderaxespad=0.0)  # fmt: skip
    ax.grid(True, axis="x", alpha=0.3)


def _summary_lines(report, fs: dict) -> list[str]:
    """The figure's summary: replica agreement, rate, drops, filter settings, firmware NaN, divergence."""
    p, rt = report.replica, report.rates
    lines = []
    if p is not None:
        lines.append(f"replica bit-exact: {p.bit_exact} / {p.seeded} seeded steps")
        if p.first_mismatch:
            lines.append(f"first difference: step {p.first_mismatch['step']} (t = {p.first_mismatch['t_rel_s']:.2f} s)")
            if p.matching_variant:
                lines.append("matches: " + _variant_text(p.matching_variant))
    if rt.rate_hz:
        lines.append(f"rate {rt.rate_hz:.1f} Hz, period σ {rt.period_std_ms or 0:.3f} ms")
    lines.append(f"dropped {rt.frames_missing} frames in {rt.seq_gaps} gaps, {rt.crc_failures} CRC failures")
    if fs.get("from") == "status frames":
        lines.append(f"kp {fs['kp_ground']:g}/{fs['kp_flight']:g}, ki {fs['ki']:g}, dt {fs['dt_s']:g} s")
    if report.firmware_nan_pitch or report.firmware_nan_roll:
        lines.append(f"firmware NaN: {report.firmware_nan_pitch} pitch, {report.firmware_nan_roll} roll steps")
    div = p.divergence if p is not None else None
    if div is not None:
        lines.append(f"firmware filter left |q| ≈ 1 at step {div['step']}; replica {div['replica']}")
    return lines


def differences_figure(tel, report, *, title: str | None = None):
    """Each estimator minus the firmware over time, degrees: pitch (thx, about x) above roll (thy, about y)."""
    plt = require_matplotlib()
    a = tel.attitude
    t = np.asarray(report.t_rel_s, dtype=np.float64)
    fw = _degrees(a.thx_rad, a.thy_rad)
    fig, axes = plt.subplots(2, 1, figsize=(13, 6.5), sharex=True)
    for ax, what, key in ((axes[0], "pitch (thx, about x)", "pitch"), (axes[1], "roll (thy, about y)", "roll")):
        for name, label, vals, (c, lw, ls, z) in _estimate_traces(report):
            tr = report.trace(name)
            rms = getattr(tr, key).rms_deg if tr is not None else math.nan
            if name == "accel":
                c, lw, z = "0.6", 0.6, 2
            d = _wrap_deg(vals[key] - fw[key])
            ax.plot(*_decimate(t, d), color=c, lw=lw, ls=ls, zorder=z, label=f"{label} (RMS {rms:.2f}°)")
        ax.axhline(0.0, color="black", lw=0.8)
        _label_panel(ax, "estimator − firmware [deg]", f"{what}: each estimator minus the firmware")
        ax.legend(fontsize=9, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    axes[-1].set_xlabel("firmware time since the first frame [s]")
    src = report.source.get("path") or "capture"
    fig.suptitle(title or f"{Path(str(src)).name}: the estimators against the firmware's angles", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    return fig


def plot_flight_control(tel, out_png, *, title: str | None = None) -> Path:
    """Write :func:`flight_control_figure` as a PNG to ``out_png`` (returns the path)."""
    return save_figure(flight_control_figure(tel, title=title), out_png)


def flight_control_figure(tel, *, title: str | None = None):
    """The flight-control frames as Betaflight's Blackbox shows them: per axis the remote's target against the
    firmware's angle (pitch = thx about x, roll = thy about y), the outer loop's s1, P and I, the motors and s2."""
    plt = require_matplotlib()
    a, fc = tel.attitude, tel.fc
    t0 = float(a.t_fw_s[0]) if len(a) else 0.0
    t = np.asarray(a.t_fw_s, np.float64) - t0
    tf = np.asarray(fc.t_fw_s, np.float64) - t0
    steps = np.asarray(a.step, np.int64)
    order = np.argsort(steps, kind="stable")
    j = np.clip(np.searchsorted(steps[order], fc.step), 0, max(len(steps) - 1, 0))
    found = steps[order][j] == np.asarray(fc.step, np.int64)
    ang = np.stack([a.thx_rad, a.thy_rad, a.thz_rad], axis=1)[order[j]].astype(np.float32)
    ang[~found] = np.nan
    p = outer_p(fc.euler_rc_rad, ang)
    s1 = np.asarray(fc.outer_s1_radps, np.float32)
    fw_ang = np.degrees(np.stack([a.thx_rad, a.thy_rad, a.thz_rad], axis=1).astype(np.float64))
    rc = np.degrees(np.asarray(fc.euler_rc_rad, np.float64))

    fig, axes = plt.subplots(4, 2, figsize=(13, 10), sharex=True)
    names = ("pitch (thx, about x, nose up +)", "roll (thy, about y, right side down +)", "yaw (thz)")
    for i, name in enumerate(names):
        ax = axes[i, 0]
        ax.plot(*_decimate(t, fw_ang[:, i]), color="black", lw=1.2, label="firmware angle")
        ax.step(tf, rc[:, i], where="post", color="tab:red", lw=1.4, label="target (remote, euler_rc)")
        _label_panel(ax, f"{name.split(' ')[0]} [deg]", f"{name}: target vs firmware")
        ax = axes[i, 1]
        ax.plot(tf, s1[:, i], ".-", color="tab:red", lw=1.0, ms=3, label=f"{'xyz'[i]}_s1 (firmware)")
        ax.plot(tf, p[:, i], "--", color="tab:blue", lw=1.0, label="P = kp1·(target − angle)")
        if i < 2:
            ax.plot(tf, s1[:, i] - p[:, i], color="tab:green", lw=1.0, label="I = s1 − P (ki1 = 0)")
        _label_panel(ax, "rate setpoint [rad/s]", f"outer loop {name.split(' ')[0]} ({'xyz'[i]}): s1, P, I")
        ax.legend(fontsize=7, loc="upper right")
    axes[0, 0].legend(fontsize=8, loc="upper right")
    for ax, values, labels, unit, what in (
        (axes[3, 0], fc.motor_pwm, [m.label for m in MOTORS], "PWM [counts of 2000]", "motors (motor_pwm)"),
        (axes[3, 1], fc.inner_s2_pwm, ("x_s2 pitch", "y_s2 roll", "z_s2 yaw"), "PWM counts", "inner loop outputs s2"),
    ):
        for k, lab in enumerate(labels):
            ax.plot(tf, np.asarray(values, np.float64)[:, k], lw=1.0, label=lab)
        _label_panel(ax, unit, what)
        ax.legend(fontsize=7, ncol=len(labels) // 2, loc="upper right")
        ax.set_xlabel("firmware time since the first frame [s]")
    every = int(np.max(fc.fc_every)) if len(fc) else 0
    src = Path(str((getattr(tel, "source", None) or {}).get("path") or "capture")).name
    default = f"steval compare: {src} — flight control ({len(fc)} frames, one every {every} AHRS steps)"
    fig.suptitle(title or default, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return fig


def _variant_text(variant: dict) -> str:
    """``{"ki": 1.0, "kp": [10, 10]}`` → ``ki=1, kp_ground=10, kp_flight=10``."""
    out = []
    for k, v in variant.items():
        if k == "kp":
            out.append(f"kp_ground={v[0]:g}, kp_flight={v[1]:g}")
        elif k == "defaults":
            out.append("the firmware defaults")
        else:  # on/off, a release's name, a float to 7 digits
            out.append(f"{k}={v:.7g}" if isinstance(v, float) else f"{k}={setting_text(v)}")
    return ", ".join(out)


def _wrap_deg(d_deg: np.ndarray) -> np.ndarray:
    """A difference in degrees wrapped to [-180, 180)."""
    return np.degrees(angle_diff_rad(np.radians(d_deg), 0.0))


def plot_simulation(result, out_png, *, title: str | None = None, compare=()) -> Path:
    """Write :func:`simulation_figure` as a PNG to ``out_png`` (returns the path; UserError when not writable)."""
    return save_figure(simulation_figure(result, title=title, compare=compare), out_png)


#: colours of overlaid ``simulate`` runs: the run as given first
_RUN_COLOURS = ["black", "tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange", "tab:brown", "tab:cyan"]


def _run_name(res) -> str:
    """The run in a few words: its estimator and options (``ekf3 (r_acc=0.001)``)."""
    opts = ", ".join(f"{k}={v}" for k, v in (res.options or {}).items())
    return f"{res.estimator}" + (f" ({opts})" if opts else "")


def simulation_figure(result, *, title: str | None = None, compare=()):
    """eax (pitch, about x), eay (roll), eaz (yaw) in degrees over a ``simulate`` run; ``compare``: runs overlaid."""
    plt = require_matplotlib()
    res = result
    k = np.asarray(res.step, dtype=np.int64)
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.2), sharex=True)
    names = (
        ("eax_rad", "eax = thx: pitch (about x)", "tab:blue"),
        ("eay_rad", "eay = thy: roll (about y)", "tab:red"),
        ("eaz_rad", "eaz = thz: yaw (about z)", "tab:green"),
    )
    runs = [(f"{_run_name(res)} as given", res)] + [(f"with {label}", r) for label, r in compare]
    valid = np.asarray(res.valid, bool)
    for ax, (attr, label, c) in zip(axes, names):
        for i, (run_label, r) in enumerate(runs):
            colour = c if not compare else _RUN_COLOURS[i % len(_RUN_COLOURS)]
            kr = np.asarray(r.step, dtype=np.int64)
            v = np.degrees(np.asarray(getattr(r, attr), dtype=np.float64))
            ls = "-" if i == 0 else ("--", "-.", ":")[(i - 1) % 3]
            ax.plot(kr, v, color=colour, lw=1.2, ls=ls, marker="." if kr.size <= 200 and not compare else None,
                    ms=3, label=run_label if compare else label)  # fmt: skip
        v = np.degrees(np.asarray(getattr(res, attr), dtype=np.float64))
        bad = ~valid | ~np.isfinite(v)
        if bad.any():
            ax.plot(k[bad], np.zeros(int(bad.sum())), "x", color="crimson", ms=4, label="invalid / NaN")
        if k.size and not compare:
            final = f"final {v[-1]:+.6f}°" if np.isfinite(v[-1]) else "final: NaN"
            ax.set_title(final, fontsize=9, loc="right", color=c)
        _label_panel(ax, f"{label.split(':')[0]} [deg]", label)
        if bad.any() and not compare:
            ax.legend(fontsize=7, loc="upper left")
    if compare:
        h, lab = axes[0].get_legend_handles_labels()
        fig.legend(h, lab, loc="upper center", bbox_to_anchor=(0.5, 0.925), ncol=min(len(h), 3), fontsize=9)
    axes[-1].set_xlabel(f"iteration (dt = {res.dt_s * 1e3:g} ms)")
    dt = float(res.dt_s)
    if dt > 0:
        top = axes[0].secondary_xaxis("top", functions=(lambda x: (x + 1) * dt, lambda s: s / dt - 1))
        top.set_xlabel("simulated time [s]", fontsize=8)
        top.tick_params(labelsize=7)

    def vec(x) -> str:
        x = np.asarray(x, dtype=np.float64)
        return "[" + ", ".join(f"{float(v):g}" for v in (x if x.ndim == 1 else x[0])) + "]"

    noise = ""
    if res.seed is not None:
        noise = f", noise σ gyro {res.gyro_noise_mdps:g} mdps, acc {res.acc_noise_mg:g} mg (seed {res.seed})"
    inputs = f"gyro {vec(res.gyro_mdps)} mdps, acc {vec(res.acc_mg)} mg" if res.iterations else "no iterations"
    if res.iterations and res.seed is not None:
        mg = np.mean(np.asarray(res.gyro_mdps, np.float64), axis=0)
        ma = np.mean(np.asarray(res.acc_mg, np.float64), axis=0)
        inputs = f"mean gyro {vec(np.round(mg, 1))} mdps, acc {vec(np.round(ma, 1))} mg"
    default = f"steval simulate: {_run_name(res)}, {res.iterations} iterations\n{inputs}{noise}"
    fig.suptitle(title or default, fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.96 - 0.035 * ((len(runs) + 2) // 3) if compare else 0.96))
    return fig

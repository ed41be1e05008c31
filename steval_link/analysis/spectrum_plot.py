"""The ``steval spectrum --plot`` figure: the Welch PSD of the gyro and the accelerometer per axis (the Nyquist, the
marks, the peaks, a register image named), the spectrograms and the gyro's frequency-vs-throttle map (else a panel
saying what the lines are); nine panels at most, fonts of 9 pt or more."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.analysis.plots import require_matplotlib, save_figure
from steval_link.analysis.spectrum import REGISTER_BEAT_HZ, SIGNALS, UNITS, Peak, Spectra, alias_lines

_AXIS_NAMES = {"x": "x (right)", "y": "y (forward)", "z": "z (up)"}
_MARK_COLOURS = ["tab:purple", "tab:green", "tab:brown", "tab:olive", "tab:cyan"]
#: matplotlib settings of the figure: every text 9 pt or more at the saved size
_RC = {"font.size": 10, "axes.titlesize": 11, "axes.labelsize": 10, "xtick.labelsize": 9, "ytick.labelsize": 9,
       "legend.fontsize": 9}  # fmt: skip

#: what the lines of a spectrum are, in a student's words (the footer, and the panel when the throttle is constant)
EXPLANATION = (
    f"What the rows sample: the TIM9 ISR reads the sensors at {C.ISR_RATE_HZ:.1f} Hz; the main loop averages 5 "
    f"reads (a boxcar) and runs the AHRS at {C.AHRS_RATE_HZ:.2f} Hz, so the spectra end at its Nyquist, "
    f"{C.AHRS_RATE_HZ / 2:.2f} Hz (red). A vibration above it is aliased to |f − k·{C.AHRS_RATE_HZ:.2f}| Hz, "
    f"weakened by the average (zero at multiples of {C.AHRS_RATE_HZ:.2f} Hz) and, for the gyro, by its IIR "
    f"(−3 dB near 101 Hz). The gyro's output register refreshes at 416 Hz and is read at {C.ISR_RATE_HZ:.1f} Hz: "
    f"the two beat at {REGISTER_BEAT_HZ:.1f} Hz, so every gyro line at f also shows, about 1 % as strong, at "
    f"|f ± {REGISTER_BEAT_HZ:.1f}| and |f ± {2 * REGISTER_BEAT_HZ:.1f}| Hz (a 12 Hz motion: 36.3 and 60.6 Hz)."
)


def _db(psd: np.ndarray) -> np.ndarray:
    p = np.asarray(psd, dtype=np.float64)
    tiny = np.nanmax(p) * 1e-12 if np.isfinite(p).any() and np.nanmax(p) > 0 else 1e-30
    with np.errstate(invalid="ignore"):
        return 10 * np.log10(np.maximum(p, tiny))


def _levels(values: np.ndarray) -> tuple[float, float]:
    """Colour range of a heat map: the 2nd to the top percentile of its finite dB values (noise floor to peak)."""
    v = values[np.isfinite(values)]
    if v.size == 0:
        return 0.0, 1.0
    lo, hi = float(np.percentile(v, 2)), float(v.max())
    return lo, hi if hi > lo else lo + 1.0


def throttle_varied(sp: Spectra) -> bool:
    """True when the windows fall in two throttle bins or more (a frequency-vs-throttle map shows something)."""
    return int(np.count_nonzero(sp.thr_windows)) >= 2


def image_of(peak: Peak, stronger: list[Peak], sensor: str, rate_hz: float, tolerance_hz: float) -> Peak | None:
    """The stronger peak whose 416 Hz-register image (:func:`alias_lines`) lands on ``peak`` (within
    ``tolerance_hz``) with about the predicted amplitude (a third to three times its gain), or None."""
    if sensor != "gyro":
        return None
    for s in stronger:
        main, *images = alias_lines(s.freq_hz, sensor, rate_hz)
        for line in images:
            ratio = peak.amplitude / max(s.amplitude, 1e-30) * main.gain / line.gain
            if abs(line.seen_hz - peak.freq_hz) <= tolerance_hz and 1 / 3 <= ratio <= 3:
                return s
    return None


def _psd_panel(ax, sp: Spectra, k: int, marks_hz, found: list[Peak], legend: bool) -> None:
    """One PSD panel: the line, the Nyquist, the marks' lines, the peaks (an image of a stronger one named)."""
    name, sensor, axis_i = SIGNALS[k]
    f, nyq = sp.freq_hz, sp.nyquist_hz
    ax.semilogy(f, np.maximum(sp.psd[:, k], 1e-30), color="black", lw=1.0)
    ax.axvline(nyq, color="red", lw=1.2, label=f"Nyquist {nyq:.2f} Hz")
    for m, fm in enumerate(marks_hz):
        colour = _MARK_COLOURS[m % len(_MARK_COLOURS)]
        for j, line in enumerate(alias_lines(fm, sensor, sp.rate_hz)):
            image = line.what == "416 Hz ODR image"
            ax.axvline(
                line.seen_hz,
                color=colour,
                lw=1.0,
                ls=":" if image else "--",
                label=(f"{fm:g} Hz input" if not image else f"{fm:g} Hz: register images") if j < 2 else None,
            )
    for i, p in enumerate(found):
        src = image_of(p, found[:i], sensor, sp.rate_hz, 1.5 * sp.resolution_hz)
        text = f"{p.freq_hz:.1f} Hz" + (f"\nimage of {src.freq_hz:.1f} Hz" if src else "")
        ax.plot([p.freq_hz], [p.psd], "o", color="tab:orange", ms=4)
        left = p.freq_hz > 0.7 * nyq  # near the right edge: the label to the left of the peak
        ax.annotate(
            text,
            (p.freq_hz, p.psd),
            textcoords="offset points",
            xytext=(-4 if left else 4, 2),
            ha="right" if left else "left",
            fontsize=9,
            color="darkorange",
        )
    ax.set_xlim(0, nyq * 1.02)
    ax.set_title(f"{sensor} {_AXIS_NAMES['xyz'[axis_i]]}: PSD")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"{UNITS[sensor]}²/Hz")
    ax.grid(True, which="major", alpha=0.3)
    if legend:
        ax.legend(loc="upper right", framealpha=0.85)


def _spectrogram_panel(fig, ax, sp: Spectra, sensor: str) -> None:
    """The sensor's spectrogram, power summed over x, y, z, in dB."""
    cols = [k for k, (_, s, _) in enumerate(SIGNALS) if s == sensor]
    z = _db(sp.spectrogram[:, :, cols].sum(axis=2)).T
    lo, hi = _levels(z)
    mesh = ax.pcolormesh(sp.window_t_fw_s, sp.freq_hz, z, shading="nearest", cmap="inferno", vmin=lo, vmax=hi)
    fig.colorbar(mesh, ax=ax, label=f"dB re 1 {UNITS[sensor]}²/Hz")
    ax.set_ylim(0, sp.nyquist_hz)
    ax.set_title(f"{sensor} spectrogram (x + y + z)")
    ax.set_xlabel("firmware time [s since boot]")
    ax.set_ylabel("frequency [Hz]")


def _throttle_panel(fig, ax, sp: Spectra, marks_hz) -> None:
    """The gyro's frequency-vs-throttle map over the throttle bins that hold windows (empty bins left out)."""
    occupied = np.flatnonzero(sp.thr_windows)
    cols = [k for k, (_, s, _) in enumerate(SIGNALS) if s == "gyro"]
    z = _db(sp.thr_psd[occupied][:, :, cols].sum(axis=2)).T
    lo, hi = _levels(z)
    f = sp.freq_hz
    f_edges = np.concatenate(([0.0], 0.5 * (f[1:] + f[:-1]), [f[-1]]))
    mesh = ax.pcolormesh(np.arange(len(occupied) + 1), f_edges, z, shading="flat", cmap="inferno", vmin=lo, vmax=hi)
    fig.colorbar(mesh, ax=ax, label="dB re 1 mdps²/Hz")
    for m, fm in enumerate(marks_hz):
        seen = alias_lines(fm, "gyro", sp.rate_hz)[0].seen_hz
        ax.axhline(seen, color=_MARK_COLOURS[m % len(_MARK_COLOURS)], lw=1.0, ls="--")
    e = sp.thr_edges
    labels = [f"{e[b]:.0f}–{e[b + 1]:.0f}" for b in occupied]
    step = max(1, len(labels) // 5)
    ax.set_xticks(np.arange(len(occupied))[::step] + 0.5, labels[::step])
    ax.set_ylim(0, sp.nyquist_hz)
    ax.set_title("gyro (x + y + z) vs throttle")
    ax.set_xlabel(f"throttle gTHR (bins with data; motors from {C.MIN_THR})")
    ax.set_ylabel("frequency [Hz]")


def spectra_figure(sp: Spectra, *, marks_hz=(), peaks: dict[str, list[Peak]] | None = None, title: str = ""):
    """The figure (a matplotlib ``Figure``) described in the module docstring."""
    plt = require_matplotlib()
    with plt.rc_context(_RC):
        fig, axes = plt.subplots(3, 3, figsize=(16, 14), squeeze=False)
        for k, (name, sensor, axis_i) in enumerate(SIGNALS):
            row = 0 if sensor == "gyro" else 1
            _psd_panel(axes[row, axis_i], sp, k, marks_hz, (peaks or {}).get(name, []), legend=axis_i == 0)
        _spectrogram_panel(fig, axes[2, 0], sp, "gyro")
        _spectrogram_panel(fig, axes[2, 1], sp, "acc")
        footer = EXPLANATION
        if throttle_varied(sp):
            _throttle_panel(fig, axes[2, 2], sp, marks_hz)
        else:
            ax = axes[2, 2]
            ax.axis("off")
            ax.set_title("what the lines are", loc="left")
            thr = f"The throttle stayed at {sp.window_thr.mean():.0f}: no frequency-vs-throttle map."
            ax.text(0, 1, textwrap.fill(EXPLANATION, 52) + "\n\n" + textwrap.fill(thr, 52), va="top", fontsize=9.5,
                    transform=ax.transAxes)  # fmt: skip
            footer = ""
        head = (title + ": " if title else "") + (
            f"{len(sp.window_t_fw_s)} Hann windows of {sp.nperseg} rows ({sp.resolution_hz:.2f} Hz resolution) over "
            f"{sp.seconds_used:.1f} s in {len(sp.runs)} run(s) of consecutive steps; rows at {sp.rate_hz:.2f} Hz"
        )
        fig.suptitle(head, fontsize=12)
        bottom = 0.0
        if footer:
            fig.text(0.01, 0.01, textwrap.fill(footer, 200), va="bottom", ha="left", fontsize=9.5)
            bottom = 0.075
        fig.tight_layout(rect=(0, bottom, 1, 0.97))
    return fig


def plot_spectra(sp: Spectra, out_png, *, marks_hz=(), peaks=None, title: str = "") -> Path:
    """Write :func:`spectra_figure` to ``out_png`` (returns the path; UserError when it cannot be written)."""
    return save_figure(spectra_figure(sp, marks_hz=marks_hz, peaks=peaks, title=title), out_png, dpi=100)

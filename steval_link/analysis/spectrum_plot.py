"""The ``steval spectrum --plot`` figure: per axis (columns x, y, z) and sensor (gyro, then acc), the Welch PSD, the
spectrogram over firmware time and the frequency-vs-throttle map (Blackbox's heat map), with the AHRS Nyquist and
the aliases of ``--mark-hz`` frequencies marked. matplotlib is optional (:func:`~steval_link.analysis.plots.
require_matplotlib`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.analysis.plots import require_matplotlib, save_figure
from steval_link.analysis.spectrum import SIGNALS, UNITS, Peak, Spectra, alias_lines

__all__ = ["spectra_figure", "plot_spectra"]

_AXIS_NAMES = {"x": "x (right)", "y": "y (forward)", "z": "z (up)"}
_MARK_COLOURS = ["tab:purple", "tab:green", "tab:brown", "tab:olive", "tab:cyan"]


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


def spectra_figure(sp: Spectra, *, marks_hz=(), peaks: dict[str, list[Peak]] | None = None, title: str = ""):
    """The figure (a matplotlib ``Figure``) described in the module docstring."""
    plt = require_matplotlib()
    fig, axes = plt.subplots(6, 3, figsize=(16, 24), squeeze=False)
    nyq = sp.nyquist_hz
    f = sp.freq_hz
    t = sp.window_t_fw_s
    edges = sp.thr_edges
    for k, (name, sensor, axis_i) in enumerate(SIGNALS):
        row0 = 0 if sensor == "gyro" else 3
        col = axis_i
        unit = UNITS[sensor]
        label = f"{sensor} {_AXIS_NAMES['xyz'[axis_i]]}"
        # PSD
        ax = axes[row0, col]
        ax.semilogy(f, np.maximum(sp.psd[:, k], 1e-30), color="black", lw=1.0)
        ax.axvline(nyq, color="red", lw=1.2, label=f"Nyquist {nyq:.2f} Hz")
        for m, fm in enumerate(marks_hz):
            colour = _MARK_COLOURS[m % len(_MARK_COLOURS)]
            for line in alias_lines(fm, sensor, sp.rate_hz):
                ax.axvline(
                    line.seen_hz,
                    color=colour,
                    lw=1.0,
                    ls="--" if line.what != "416 Hz ODR image" else ":",
                    label=f"{line.source_hz:g} Hz → {line.seen_hz:.1f} Hz (×{line.gain:.2g})",
                )
        for p in (peaks or {}).get(name, []):
            ax.plot([p.freq_hz], [p.psd], "o", color="tab:orange", ms=4)
            ax.annotate(
                f"{p.freq_hz:.1f} Hz",
                (p.freq_hz, p.psd),
                textcoords="offset points",
                xytext=(3, 3),
                fontsize=7,
                color="tab:orange",
            )
        ax.set_xlim(0, nyq * 1.02)
        ax.set_title(f"{label}: PSD")
        ax.set_xlabel("frequency, Hz")
        ax.set_ylabel(f"{unit}²/Hz")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, loc="upper right")
        # spectrogram
        ax = axes[row0 + 1, col]
        z = _db(sp.spectrogram[:, :, k]).T
        lo, hi = _levels(z)
        mesh = ax.pcolormesh(t, f, z, shading="nearest", cmap="inferno", vmin=lo, vmax=hi)
        fig.colorbar(mesh, ax=ax, label=f"dB re 1 {unit}²/Hz")
        ax.axhline(nyq, color="red", lw=1.2)
        ax.set_ylim(0, nyq)
        ax.set_title(f"{label}: spectrogram")
        ax.set_xlabel("firmware time, s since boot")
        ax.set_ylabel("frequency, Hz")
        # frequency vs throttle
        ax = axes[row0 + 2, col]
        z = _db(sp.thr_psd[:, :, k]).T
        lo, hi = _levels(z)
        f_edges = np.concatenate(([0.0], 0.5 * (f[1:] + f[:-1]), [f[-1]]))
        mesh = ax.pcolormesh(edges, f_edges, np.ma.masked_invalid(z), shading="flat", cmap="inferno", vmin=lo, vmax=hi)
        fig.colorbar(mesh, ax=ax, label=f"dB re 1 {unit}²/Hz")
        for m, fm in enumerate(marks_hz):
            ax.axhline(
                alias_lines(fm, sensor, sp.rate_hz)[0].seen_hz,
                color=_MARK_COLOURS[m % len(_MARK_COLOURS)],
                lw=1.0,
                ls="--",
            )
        ax.set_ylim(0, nyq)
        ax.set_title(f"{label}: frequency vs throttle")
        ax.set_xlabel(f"throttle gTHR (window mean; motors run from {C.MIN_THR})")
        ax.set_ylabel("frequency, Hz")
    fig.suptitle(
        (title + "\n" if title else "")
        + f"sensors read at {C.ISR_RATE_HZ:.1f} Hz (TIM9 ISR), averaged 5:1 → rows at {sp.rate_hz:.2f} Hz: Nyquist "
        f"{nyq:.2f} Hz (red); vibration above it shows at |f − k·{sp.rate_hz:.2f} Hz| (dashed: --mark-hz aliases; "
        f"dotted: the gyro's 416 Hz-register images)\n"
        f"{len(t)} Hann windows of {sp.nperseg} rows ({sp.resolution_hz:.2f} Hz resolution) over "
        f"{sp.seconds_used:.1f} s in {len(sp.runs)} run(s) of consecutive steps",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    return fig


def plot_spectra(sp: Spectra, out_png, *, marks_hz=(), peaks=None, title: str = "") -> Path:
    """Write :func:`spectra_figure` to ``out_png`` (returns the path; UserError when it cannot be written)."""
    return save_figure(spectra_figure(sp, marks_hz=marks_hz, peaks=peaks, title=title), out_png, dpi=100)

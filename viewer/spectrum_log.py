"""``steval spectrum`` in Rerun: the spectra of a capture (:class:`steval_link.analysis.spectrum.Spectra`) under
``spectrum/...`` (PSD in dB, frequency from 0 to the AHRS Nyquist; listed in ``viewer/README.md``), their blueprint."""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from steval_link.analysis.spectrum import SIGNALS, UNITS, Spectra, format_summary
from steval_viewer import entities as ent
from steval_viewer.blueprint import window
from steval_viewer.columns import Times, send_scalars
from steval_viewer.sinks import log_whole

ROOT = "spectrum"
NOTES = f"{ROOT}/notes"
_COLOURS = {"x": (220, 60, 60), "y": (60, 170, 60), "z": (60, 100, 230)}
_NO_LEGEND = rrb.PlotLegend(visible=False)


def _path(kind: str, name: str) -> str:
    return f"{ROOT}/{kind}/{name}"


def _db(psd: np.ndarray) -> np.ndarray:
    p = np.asarray(psd, dtype=np.float64)
    finite = p[np.isfinite(p)]
    tiny = finite.max() * 1e-12 if finite.size and finite.max() > 0 else 1e-30
    with np.errstate(invalid="ignore"):
        return (10 * np.log10(np.maximum(p, tiny))).astype(np.float32)


def _label(name: str) -> str:
    sensor, axis = name.split("_")
    return f"{sensor} {axis} (dB re 1 {UNITS[sensor]}²/Hz)"


def _grid(kind: str, view, title: str) -> rrb.Grid:
    return rrb.Grid(
        *(view(_path(kind, name), f"{title}: {_label(name)}") for name, _, _ in SIGNALS), grid_columns=3, name=title
    )


def _bars(origin: str, name: str) -> rrb.BarChartView:
    return rrb.BarChartView(origin=origin, name=name, plot_legend=_NO_LEGEND)


def _heat(origin: str, name: str) -> rrb.TensorView:
    dim = rr.encodings.TensorDimensionSelection
    axes = rrb.TensorSliceSelection(width=dim(dimension=1, invert=False), height=dim(dimension=0, invert=True))
    mapping = rrb.TensorScalarMapping(colormap="Inferno")
    return rrb.TensorView(origin=origin, name=name, slice_selection=axes, scalar_mapping=mapping, view_fit="Fill")


def spectrum_blueprint(nyquist_hz: float) -> rrb.Blueprint:
    """Tabs: the capture's PSD, the spectrum at the time cursor (with the signals), spectrograms, frequency vs throttle;
    the notes on the right. ``nyquist_hz``: named in the bar charts' titles (Rerun labels few ticks)."""
    span = f"0–{nyquist_hz:.2f} Hz →"
    signals = rrb.Horizontal(
        rrb.TimeSeriesView(origin=f"{ROOT}/signal/gyro", name="gyro (mdps)"),
        rrb.TimeSeriesView(origin=f"{ROOT}/signal/acc", name="accelerometer (mg)"),
        rrb.TimeSeriesView(origin=f"{ROOT}/signal/thr", name="throttle gTHR", plot_legend=_NO_LEGEND),
    )
    window_plots = _grid("window", _bars, f"at the cursor, {span}")
    cursor = rrb.Vertical(window_plots, signals, row_shares=[3, 1], name="Spectrum at the cursor")
    tabs = rrb.Tabs(
        _grid("psd", _bars, f"PSD, {span}"),
        cursor,
        _grid("spectrogram", _heat, "spectrogram (time →, frequency ↑)"),
        _grid("throttle", _heat, "frequency ↑ vs throttle →"),
        name="Spectra",
        active_tab=0,
    )
    notes = rrb.TextDocumentView(origin=NOTES, name="Notes")
    panel = rrb.TimePanel(timeline=ent.TIMELINE_FW, state="collapsed")
    return window(rrb.Horizontal(tabs, notes, column_shares=[4, 1]), panel)


def log_spectra(rec: rr.RecordingStream, tel: Any, sp: Spectra, notes: list[str]) -> dict[str, int]:
    """Log ``sp`` and the rows of ``tel`` it came from; returns the values logged per entity path."""
    rec.send_blueprint(spectrum_blueprint(sp.nyquist_hz), make_active=True, make_default=True)
    counts: dict[str, int] = {}
    f = np.asarray(sp.freq_hz, dtype=np.float64)
    colours = [_COLOURS["xyz"[axis]] for _, _, axis in SIGNALS]
    occupied = np.flatnonzero(sp.thr_windows)
    for k, (name, _, _) in enumerate(SIGNALS):
        spec = _db(sp.spectrogram[:, :, k]).T  # (F, W)
        thr = _db(sp.thr_psd[occupied, :, k]).T if occupied.size else np.zeros((len(f), 0), np.float32)
        for kind, values, size in (
            ("psd", rr.BarChart(_db(sp.psd[:, k]), abscissa=f, color=colours[k]), len(f)),
            ("spectrogram", rr.Tensor(spec, dim_names=("frequency", "window")), spec.size),
            ("throttle", rr.Tensor(thr, dim_names=("frequency", "throttle bin")), thr.size),
        ):
            rec.log(_path(kind, name), values, static=True)
            counts[_path(kind, name)] = int(size)
        counts[_path("window", name)] = len(sp.window_t_fw_s)
    for w, t in enumerate(sp.window_t_fw_s):
        rec.set_time(ent.TIMELINE_FW, duration=float(t))
        for k, (name, _, _) in enumerate(SIGNALS):
            rec.log(_path("window", name), rr.BarChart(_db(sp.spectrogram[w, :, k]), abscissa=f, color=colours[k]))
    rec.reset_time()
    att = tel.attitude
    times = Times(att.t_fw_s, getattr(att, "t_host_s", None), getattr(att, "step", None))
    for sensor, values in (("gyro", att.gyro_mdps), ("acc", att.acc_mg)):
        path = f"{ROOT}/signal/{sensor}"
        names = [f"{sensor} {a} ({UNITS[sensor]})" for a in "xyz"]
        rec.log(path, rr.SeriesLines(names=names, colors=[_COLOURS[a] for a in "xyz"]), static=True)
        send_scalars(rec, path, times, np.asarray(values, dtype=np.float64))
        counts[path] = len(times)
    send_scalars(rec, f"{ROOT}/signal/thr", times, np.asarray(att.thr, dtype=np.float64))
    text = "\n".join(f"- {line}" if i else f"**{line}**" for i, line in enumerate(notes))
    edges = sp.thr_edges
    bins = ", ".join(f"{edges[b]:.0f}–{edges[b + 1]:.0f} ({int(sp.thr_windows[b])})" for b in occupied)
    text += (
        f"\n\nBar charts: frequency 0 … {sp.nyquist_hz:.2f} Hz (the AHRS Nyquist) along x, PSD in dB. Heat maps: "
        f"frequency up (bin {sp.resolution_hz:.2f} Hz), windows of {sp.nperseg} rows or throttle bins to the "
        f"right. Throttle bins holding windows (gTHR range (windows)): {bins or 'none'}."
    )
    rec.log(NOTES, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
    counts[NOTES] = len(notes)
    return counts


def spectrum_sink(options: Any, recording_name: str, tel: Any, sp: Spectra, marks_hz, peaks) -> None:
    """``steval spectrum`` to the sinks of ``options`` (``log_whole``)."""
    log_whole(options, recording_name, lambda rec: log_spectra(rec, tel, sp, format_summary(sp, peaks, marks_hz)))

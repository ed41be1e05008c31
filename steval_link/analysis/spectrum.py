"""Sensor spectra of a capture (``steval spectrum``): Welch PSD, spectrogram and frequency-vs-throttle map of the
gyro (mdps) and accelerometer (mg) per axis, as Betaflight's Blackbox viewer shows them.

The rows hold the main loop's 5-sample averages of the 807.7 Hz ISR reads, at 161.54 Hz: the spectra end at
80.77 Hz; a vibration above it is aliased (:func:`alias_lines`). numpy only (scipy is an optional extra): runs of
consecutive steps cut into half-overlapping Hann windows, the one-sided PSD (unit²/Hz, scipy's ``welch`` density
convention) averaged; the rate measured on the firmware's clock."""

from __future__ import annotations

import csv
import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.analysis.plots import require_matplotlib, save_figure
from steval_link.emulation.sensor_model import GYRO_ODR_HZ, iir_frequency_response
from steval_link.errors import ParamError, UserError

#: the beat of the gyro's 416 Hz output register read at the ISR rate (2·416 − 807.7 ≈ 24.3 Hz): a gyro line at f
#: also shows, weakly, at |f ± 24.3| and |f ± 48.6| Hz
REGISTER_BEAT_HZ = 2 * GYRO_ODR_HZ - C.ISR_RATE_HZ
#: the six signals, in column order: (name, sensor, axis index)
SIGNALS: tuple[tuple[str, str, int], ...] = tuple(
    (f"{sensor}_{axis}", sensor, i) for sensor in ("gyro", "acc") for i, axis in enumerate("xyz")
)
#: unit of each sensor's samples
UNITS = {"gyro": "mdps", "acc": "mg"}
#: rows per FFT window by default (1.58 s at 161.54 Hz: 0.63 Hz resolution)
DEFAULT_NPERSEG = 256
#: fewest rows per window (a shorter capture is too short for a spectrum)
MIN_NPERSEG = 32
#: a window's step rate may differ from the nominal AHRS rate by this fraction before a run is cut there
_TIME_TOLERANCE = 0.5


def alias_hz(f_hz: float, rate_hz: float = C.AHRS_RATE_HZ) -> float:
    """Where a sinusoid at ``f_hz`` appears when sampled at ``rate_hz``: folded into [0, rate/2]."""
    r = math.fmod(abs(float(f_hz)), rate_hz)
    return min(r, rate_hz - r)


def _boxcar_gain(f_hz: float) -> float:
    """|gain| of the main loop's 5-sample average at the ISR rate (1 at 0 Hz, 0 at multiples of the AHRS rate)."""
    x = math.pi * f_hz / C.ISR_RATE_HZ
    s = math.sin(x)
    return 1.0 if abs(s) < 1e-12 else abs(math.sin(C.FIFO_ORDER * x) / (C.FIFO_ORDER * s))


def chain_gain(f_hz: float, sensor: str) -> float:
    """|gain| from a sinusoid at ``f_hz`` at the sensor to what the AHRS rows hold (at its alias): the boxcar for
    the accelerometer; the 416 Hz register hold, the gyro IIR and the boxcar for the gyro."""
    g = _boxcar_gain(f_hz)
    if sensor == "gyro":
        x = math.pi * f_hz / GYRO_ODR_HZ
        hold = 1.0 if x == 0 else abs(math.sin(x) / x)  # the 416 Hz register's sample-and-hold: |sinc(f / 416 Hz)|
        g *= abs(complex(iir_frequency_response([f_hz])[0][0])) * hold
    return g


@dataclass(frozen=True)
class AliasLine:
    """Where a vibration at ``source_hz`` shows in one sensor's rows: ``seen_hz`` (0 … 80.77 Hz), ``gain`` (amplitude
    seen / at the sensor) and ``what`` ("direct", "alias", "416 Hz ODR image")."""

    sensor: str
    source_hz: float
    seen_hz: float
    gain: float
    what: str


def alias_lines(f_hz: float, sensor: str, rate_hz: float = C.AHRS_RATE_HZ, min_gain: float = 0.005) -> list[AliasLine]:
    """The lines a sinusoid at ``f_hz`` makes in ``sensor``'s rows: the main line, then for the gyro the images of its
    416 Hz register at ``|k·416 ± f|`` (k = 1 … 4) at least ``min_gain`` strong (12 Hz: 36.3 and 60.6 Hz)."""
    f = abs(float(f_hz))
    direct = f <= rate_hz / 2
    lines = [AliasLine(sensor, f, alias_hz(f, rate_hz), chain_gain(f, sensor), "direct" if direct else "alias")]
    if sensor == "gyro":
        for k in (1, 2, 3, 4):
            for image in (k * GYRO_ODR_HZ - f, k * GYRO_ODR_HZ + f):
                image = abs(image)
                g = chain_gain(image, "gyro")
                if abs(image - f) >= 1e-9 and g >= min_gain:
                    lines.append(AliasLine(sensor, image, alias_hz(image, rate_hz), g, "416 Hz ODR image"))
    return lines


def contiguous_runs(
    step, t_fw_s, values, decimation: int = 1, rate_hz: float = C.AHRS_RATE_HZ
) -> list[tuple[int, int]]:
    """Runs ``(start, stop)`` of consecutive rows: each ``decimation`` AHRS steps and periods (± half) after the one
    before, every value finite; a dropped frame, a restart, a time jump or a NaN ends a run."""
    step = np.asarray(step, dtype=np.int64)
    t = np.asarray(t_fw_s, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    n = len(step)
    if n == 0:
        return []
    good = np.isfinite(v).reshape(n, -1).all(axis=1) & np.isfinite(t)
    period = decimation / rate_hz
    dt = np.diff(t)
    link = (np.diff(step) == decimation) & (np.abs(dt - period) <= _TIME_TOLERANCE * period) & good[1:] & good[:-1]
    ends = np.append(np.flatnonzero(~link) + 1, n)
    starts = np.concatenate([[0], ends[:-1]])
    return [(int(a), int(b)) for a, b in zip(starts, ends) if good[a]]


def welch_windows(x, fs_hz: float, nperseg: int, hop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-sided PSD of each Hann window of ``x`` (N,) or (N, K): ``(freq_hz (F,), starts (W,), psd (W, F, K))``.
    Windows start every ``hop`` rows, their mean removed; their mean is ``scipy.signal.welch``'s."""
    a = np.asarray(x, dtype=np.float64).reshape(len(x), -1)
    n = a.shape[0]
    freq = np.fft.rfftfreq(nperseg, 1.0 / fs_hz)
    if n < nperseg:
        return freq, np.zeros(0, np.int64), np.zeros((0, len(freq), a.shape[1]))
    starts = np.arange(0, n - nperseg + 1, hop, dtype=np.int64)
    idx = starts[:, None] + np.arange(nperseg)[None, :]
    frames = a[idx]  # (W, nperseg, K)
    frames -= frames.mean(axis=1, keepdims=True)
    w = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(nperseg) / nperseg)  # periodic Hann: scipy's Welch default
    spec = np.fft.rfft(frames * w[None, :, None], axis=1)
    psd = (spec.real**2 + spec.imag**2) / (fs_hz * float(np.sum(w * w)))
    psd[:, 1 : len(freq) - 1 + nperseg % 2] *= 2.0  # one-sided: all but 0 Hz and an even window's Nyquist bin
    return freq, starts, psd


@dataclass
class Spectra:
    """Spectra of one capture; column k of every PSD is ``SIGNALS[k]`` (gyro x, y, z in mdps²/Hz, then acc x, y, z
    in mg²/Hz) over F bins 0 … Nyquist, W windows (centre ``window_t_fw_s`` s since boot) and B throttle bins (gTHR;
    NaN when empty). ``rate_hz``: rows per second on the firmware clock (≈ 161.54 Hz)."""

    freq_hz: np.ndarray
    psd: np.ndarray
    window_t_fw_s: np.ndarray
    window_thr: np.ndarray
    spectrogram: np.ndarray
    thr_edges: np.ndarray
    thr_psd: np.ndarray
    thr_windows: np.ndarray
    rate_hz: float
    decimation: int
    nperseg: int
    hop: int
    runs: list[tuple[int, int]]
    rows: int
    rows_used: int
    notes: list[str] = field(default_factory=list)

    @property
    def nyquist_hz(self) -> float:
        return self.rate_hz / 2

    @property
    def resolution_hz(self) -> float:
        return self.rate_hz / self.nperseg

    @property
    def seconds_used(self) -> float:
        return self.rows_used / self.rate_hz


def compute_spectra(tel, *, nperseg: int | None = None, overlap: float = 0.5, throttle_bins: int = 10) -> Spectra:
    """The spectra of a telemetry; ``nperseg`` default 256 (or the longest run's power of two, at least 32)."""
    if not 0 <= overlap < 1:
        raise ParamError(f"{{overlap}} must be a fraction in [0, 1), got {overlap}", "overlap")
    if throttle_bins < 1:
        raise ParamError(f"{{throttle_bins}} must be at least 1, got {throttle_bins}", "throttle_bins")
    if nperseg is not None and nperseg < MIN_NPERSEG:
        raise ParamError(f"{{nperseg}} must be at least {MIN_NPERSEG} rows, got {nperseg}", "nperseg")
    att = tel.attitude
    n = len(att.step)
    if n == 0:
        raise UserError("the capture has no attitude frames, so there is nothing to take a spectrum of.")
    step = np.asarray(att.step, dtype=np.int64)
    t = np.asarray(att.t_fw_s, dtype=np.float64)
    values = np.concatenate([att.gyro_mdps, att.acc_mg], axis=1).astype(np.float64)
    d = np.diff(step)
    decimation = int(np.median(d[d > 0])) if (d > 0).any() else 1
    runs = contiguous_runs(step, t, values, decimation)
    notes: list[str] = []
    nperseg = _window_rows(nperseg, max((b - a for a, b in runs), default=0), decimation, notes)
    hop = max(1, int(round(nperseg * (1 - overlap))))
    used = [(a, b) for a, b in runs if b - a >= nperseg]
    nominal = C.AHRS_RATE_HZ / decimation
    steps = sum(int(step[b - 1] - step[a]) for a, b in used)  # the rate measured on the firmware clock
    secs = sum(float(t[b - 1] - t[a]) for a, b in used)
    rate = steps / secs / decimation if steps > 0 and secs > 0 else nominal
    if abs(rate / nominal - 1) > 0.02:
        notes.append(
            f"the firmware clock gives {rate:.2f} rows/s, not the nominal {nominal:.2f}; the spectra use the "
            f"measured rate"
        )
    if decimation > 1:
        notes.append(f"decimated rows (one per {decimation} AHRS steps, text mode): Nyquist {rate / 2:.2f} Hz")
    freq, spectrogram, window_t, window_thr = _windows(
        values, t, np.asarray(att.thr, np.float64), used, rate, nperseg, hop
    )
    edges, thr_psd, counts = _by_throttle(spectrogram, window_thr, throttle_bins)
    if len(runs) > 1:
        notes.append(
            f"{len(runs)} runs of consecutive rows (gaps from dropped frames, restarts or time jumps); "
            f"{len(used)} long enough for a window"
            + (f", {len(runs) - len(used)} shorter ones left out" if len(runs) > len(used) else "")
        )
    return Spectra(
        freq_hz=freq,
        psd=spectrogram.mean(axis=0),
        window_t_fw_s=window_t,
        window_thr=window_thr,
        spectrogram=spectrogram,
        thr_edges=edges,
        thr_psd=thr_psd,
        thr_windows=counts,
        rate_hz=rate,
        decimation=decimation,
        nperseg=nperseg,
        hop=hop,
        runs=used,
        rows=n,
        rows_used=sum(b - a for a, b in used),
        notes=notes,
    )


def _window_rows(nperseg: int | None, longest: int, decimation: int, notes: list[str]) -> int:
    """Rows per window: ``nperseg``, else the default or the longest run's power of two; UserError when too short."""
    if nperseg is None:
        nperseg = DEFAULT_NPERSEG
        if longest < nperseg:
            nperseg = 1 << max(int(math.floor(math.log2(max(longest, 1)))), 0)
            if nperseg >= MIN_NPERSEG:
                notes.append(
                    f"short capture: windows of {nperseg} rows instead of {DEFAULT_NPERSEG} (coarser "
                    f"frequency resolution)"
                )
    need = max(nperseg, MIN_NPERSEG)
    if longest < need:
        rate = C.AHRS_RATE_HZ / decimation
        raise UserError(
            f"the capture is too short for a spectrum: its longest run of consecutive attitude frames is "
            f"{longest} rows ({longest / rate:.2f} s), and a window needs {need} ({need / rate:.2f} s)."
        )
    return nperseg


def _windows(values, t, thr, runs, rate: float, nperseg: int, hop: int):
    """Every window of every run: (freq_hz, PSD per window, centre time per window, mean throttle per window)."""
    specs, centres, thr_w = [], [], []
    for a, b in runs:  # at least one: compute_spectra checked it
        freq, starts, psd = welch_windows(values[a:b], rate, nperseg, hop)
        specs.append(psd)
        centres.append(0.5 * (t[a + starts] + t[a + starts + nperseg - 1]))
        csum = np.concatenate(([0.0], np.cumsum(thr[a:b])))
        thr_w.append((csum[starts + nperseg] - csum[starts]) / nperseg)
    return freq, np.concatenate(specs, axis=0), np.concatenate(centres), np.concatenate(thr_w)


def _by_throttle(spectrogram: np.ndarray, window_thr: np.ndarray, bins: int):
    """The windows' mean PSD per throttle bin: (edges, PSD per bin (NaN: empty), windows per bin)."""
    lo, hi = (math.floor(float(window_thr.min())), math.ceil(float(window_thr.max()))) if window_thr.size else (0, 1)
    edges = np.linspace(lo, max(hi, lo + 1), bins + 1)  # one gTHR unit wide at least
    which = np.clip(np.searchsorted(edges, window_thr, side="right") - 1, 0, len(edges) - 2)
    thr_psd = np.full((len(edges) - 1, *spectrogram.shape[1:]), np.nan)
    counts = np.bincount(which, minlength=len(edges) - 1)
    for k in np.flatnonzero(counts):
        thr_psd[k] = spectrogram[which == k].mean(axis=0)
    return edges, thr_psd, counts


@dataclass(frozen=True)
class Peak:
    """A PSD peak: ``freq_hz`` (Gaussian fit of three bins), ``psd`` (unit²/Hz), ``amplitude`` (unit, of the sinusoid
    making the power over ±3 bins above the floor) and ``above_floor_db`` (over the median PSD)."""

    freq_hz: float
    psd: float
    amplitude: float
    above_floor_db: float


def find_peaks(freq_hz, psd, count: int = 3, min_hz: float = 1.0, min_db: float = 6.0) -> list[Peak]:
    """Up to ``count`` strongest local maxima of ``psd`` (F,) at or above ``min_hz``, at least ``min_db`` over the
    median PSD there, each at least 4 bins from a stronger one (a Hann window's main lobe is ±2 bins wide)."""
    f = np.asarray(freq_hz, dtype=np.float64)
    p = np.asarray(psd, dtype=np.float64)
    band = f >= min_hz
    if f.size < 3 or not band.any():
        return []
    df = f[1] - f[0]
    floor = float(np.median(p[band]))
    k = np.arange(1, len(p) - 1)
    is_max = (p[k] > p[k - 1]) & (p[k] >= p[k + 1]) & band[k]
    if band[-1] and len(p) > 1 and p[-1] > p[-2]:  # a peak on the Nyquist bin
        k = np.append(k, len(p) - 1)
        is_max = np.append(is_max, True)
    cand = k[is_max]
    cand = cand[np.argsort(-p[cand], kind="stable")]
    out: list[Peak] = []
    taken: list[int] = []
    for i in cand:
        ratio = p[i] / floor if floor > 0 else np.inf
        if len(out) >= count or ratio < 10 ** (min_db / 10):
            break
        if any(abs(int(i) - j) < 4 for j in taken):
            continue
        taken.append(int(i))
        centre = float(f[i])
        if 0 < i < len(p) - 1 and np.all(p[i - 1 : i + 2] > 0):
            a, b, c = np.log(p[i - 1 : i + 2])
            den = a - 2 * b + c
            if den < 0:
                centre += float(np.clip(0.5 * (a - c) / den, -0.5, 0.5)) * df
        lo, hi = max(int(i) - 3, 0), min(int(i) + 4, len(p))
        power = max(float(np.sum(p[lo:hi]) - floor * (hi - lo)), 0.0) * df
        db = float(10 * math.log10(ratio)) if np.isfinite(ratio) else math.inf
        out.append(Peak(centre, float(p[i]), math.sqrt(2 * power), db))
    return out


#: CSV columns of :func:`write_csv`; the PSD columns carry their unit (mdps²/Hz, mg²/Hz)
CSV_COLUMNS = (
    *"section t_fw_s thr thr_lo thr_hi windows freq_hz".split(),
    *(f"{name}_psd_{UNITS[sensor]}2_per_hz" for name, sensor, _ in SIGNALS),
)


def _num(v) -> str:
    v = float(v)
    return "" if not math.isfinite(v) else repr(v)


def write_csv(sp: Spectra, stream) -> int:
    """The spectra as one CSV table; ``section`` ``psd`` (Welch average), ``spectrogram`` (per window: ``t_fw_s``,
    mean ``thr``) or ``throttle`` (per non-empty bin ``thr_lo`` … ``thr_hi``). Returns the rows written."""
    w = csv.writer(stream, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    # (the row's first cells, its PSD (F, 6)) per section
    blocks = [(["psd", "", "", "", "", len(sp.window_t_fw_s)], sp.psd)]
    blocks += [
        (["spectrogram", _num(t), _num(thr), "", "", 1], sp.spectrogram[k])
        for k, (t, thr) in enumerate(zip(sp.window_t_fw_s, sp.window_thr))
    ]
    blocks += [
        (["throttle", "", "", _num(sp.thr_edges[b]), _num(sp.thr_edges[b + 1]), int(sp.thr_windows[b])], sp.thr_psd[b])
        for b in np.flatnonzero(sp.thr_windows)
    ]
    for head, psd in blocks:
        for f, row in zip(sp.freq_hz, psd):
            w.writerow([*head, _num(f), *map(_num, row)])
    return len(blocks) * len(sp.freq_hz)


def format_summary(
    sp: Spectra, peaks: dict[str, list[Peak]], marks_hz=(), *, min_hz: float = 1.0, source: str = ""
) -> list[str]:
    """The printed summary: what was analysed, the rates and Nyquist, the top peaks per axis, the marks' aliases."""
    secs = sp.seconds_used
    lines = [
        f"steval spectrum{' ' + source if source else ''}: {sp.rows} attitude rows, {sp.rows_used} in "
        f"{len(sp.runs)} run{'s' if len(sp.runs) != 1 else ''} of consecutive steps ({secs:.1f} s); "
        f"{len(sp.window_t_fw_s)} Hann windows of {sp.nperseg} rows ({sp.nperseg / sp.rate_hz:.2f} s, "
        f"{100 * (1 - sp.hop / sp.nperseg):.0f} % overlap)",
        f"rows at {sp.rate_hz:.2f} Hz (firmware clock): Nyquist {sp.nyquist_hz:.2f} Hz, resolution "
        f"{sp.resolution_hz:.2f} Hz. The sensors are read at {C.ISR_RATE_HZ:.1f} Hz (ISR) and averaged 5 to 1, so "
        f"vibration above {sp.nyquist_hz:.2f} Hz shows at its alias |f - k*{sp.rate_hz:.2f} Hz|.",
    ]
    lines += [f"note: {n}" for n in sp.notes]
    lines.append(
        f"top peaks per axis (>= {min_hz:g} Hz, >= 6 dB over the median; amplitude of the sinusoid that would make it):"
    )
    for name, sensor, i in SIGNALS:
        found = peaks.get(name, [])
        text = "   ".join(
            f"{p.freq_hz:6.2f} Hz {p.amplitude:8.1f} {UNITS[sensor]} (+{p.above_floor_db:.0f} dB)" for p in found
        )
        label = f"{sensor} {'xyz'[i]} ({UNITS[sensor]})"
        lines.append(f"  {label:<16} {text or 'no clear peak'}")
    if len(sp.thr_edges) > 2 or sp.thr_windows.sum():
        occupied = np.flatnonzero(sp.thr_windows)
        lines.append(
            f"throttle: windows' mean gTHR {sp.window_thr.min():.0f}..{sp.window_thr.max():.0f}, "
            f"{len(occupied)} of {len(sp.thr_edges) - 1} throttle bins hold windows"
        )
    for f in marks_hz:
        parts = []
        for sensor in ("gyro", "acc"):
            main, *images = alias_lines(f, sensor, sp.rate_hz)
            s = f"{sensor} at {main.seen_hz:.2f} Hz (x{main.gain:.3g})"
            s += "".join(
                f", and at {im.seen_hz:.2f} Hz (x{im.gain:.3g}) through the gyro register's 416 Hz image at "
                f"{im.source_hz:.1f} Hz"
                for im in images
            )
            parts.append(s)
        where = "below the Nyquist, seen directly" if f <= sp.nyquist_hz else "above the Nyquist, aliased"
        lines.append(f"mark {f:g} Hz ({where}): " + "; ".join(parts))
    return lines


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
    lo, hi = (float(np.percentile(v, 2)), float(v.max())) if v.size else (0.0, 1.0)
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
            label = (f"{fm:g} Hz: register images" if image else f"{fm:g} Hz input") if j < 2 else None
            ax.axvline(line.seen_hz, color=colour, lw=1.0, ls=":" if image else "--", label=label)
    for i, p in enumerate(found):
        src = image_of(p, found[:i], sensor, sp.rate_hz, 1.5 * sp.resolution_hz)
        text = f"{p.freq_hz:.1f} Hz" + (f"\nimage of {src.freq_hz:.1f} Hz" if src else "")
        ax.plot([p.freq_hz], [p.psd], "o", color="tab:orange", ms=4)
        left = p.freq_hz > 0.7 * nyq  # near the right edge: the label to the left of the peak
        style = dict(textcoords="offset points", fontsize=9, color="darkorange", ha="right" if left else "left")
        ax.annotate(text, (p.freq_hz, p.psd), xytext=(-4 if left else 4, 2), **style)
    ax.set(xlim=(0, nyq * 1.02), title=f"{sensor} {_AXIS_NAMES['xyz'[axis_i]]}: PSD", xlabel="frequency [Hz]")
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
    ax.set(ylim=(0, sp.nyquist_hz), title=f"{sensor} spectrogram (x + y + z)", ylabel="frequency [Hz]")
    ax.set_xlabel("firmware time [s since boot]")


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
    ax.set(ylim=(0, sp.nyquist_hz), title="gyro (x + y + z) vs throttle", ylabel="frequency [Hz]")
    ax.set_xlabel(f"throttle gTHR (bins with data; motors from {C.MIN_THR})")


def spectra_figure(sp: Spectra, *, marks_hz=(), peaks: dict[str, list[Peak]] | None = None, title: str = ""):
    """The ``--plot`` figure: PSD per axis, spectrograms, the frequency-vs-throttle map (else what the lines are)."""
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

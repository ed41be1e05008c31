"""``steval spectrum``: PSD, spectrogram and frequency-vs-throttle map of a capture's gyro and accelerometer."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from steval_link.analysis import spectrum as S
from steval_link.cli.app import app, argument, option
from steval_link.cli.checks import require_attitude
from steval_link.cli.outputs import ForceOption, atomic_output, check_outputs, print_warnings, write_atomic
from steval_link.cli.progress import progress_bar, scaled
from steval_link.cli.replay import load_replay
from steval_link.cli.viewer_options import view_sinks, with_rerun_options
from steval_link.errors import UserError
from steval_link.link.load import read_recording
from steval_viewer.sink_options import SinkOptions

#: largest --nperseg (a window of 2^16 rows is 6.8 minutes at 161.54 Hz)
MAX_NPERSEG = 65536
MAX_THROTTLE_BINS = 100


_Csv = option(
    Path | None,
    "--csv",
    help="Write the numbers to this CSV: sections psd, spectrogram and throttle, PSD columns in mdps²/Hz and mg²/Hz.",
)
_MinHz = option(float, "--min-hz", metavar="HZ", help="Peaks below this are not printed (slow motion, not vibration).")


@app.command("spectrum")
@with_rerun_options
def spectrum_cmd(
    capture: argument(Path, help="Capture (.stv), raw serial dump or text-mode log; detected by content."),
    plot: option(
        Path | None,
        help="Write the figure (PSD, spectrogram and frequency-vs-throttle map per axis) to this image (.png, .svg, "
        '.pdf, ...); needs matplotlib: pip install "steval-link\\[plot]".',
    ) = None,
    csv_out: _Csv = None,
    mark_hz: option(
        list[float] | None,
        metavar="HZ",
        help="Mark where a vibration at HZ shows: at HZ below the 80.77 Hz Nyquist, at its alias above it (the gyro "
        "also at its 416 Hz-register images), with the gain of the firmware's averaging and gyro filter; repeatable.",
    ) = None,
    nperseg: option(
        int | None,
        metavar="ROWS",
        help=f"Rows per FFT window (default {S.DEFAULT_NPERSEG}: 1.58 s, 0.63 Hz "
        f"resolution; less for a shorter capture; at least {S.MIN_NPERSEG}).",
    ) = None,
    overlap: option(float, help="Fraction of a window the next one overlaps.") = 0.5,
    throttle_bins: option(
        int, metavar="N", help="Throttle bins of the frequency-vs-throttle map, over the capture's range of gTHR."
    ) = 10,
    peaks: option(int, metavar="N", help="Peaks printed per axis.") = 3,
    min_hz: _MinHz = 1.0,
    force: ForceOption = False,
    rerun: SinkOptions = None,
) -> None:
    """Gyro and accelerometer spectra per axis, like Blackbox's: Welch PSD, spectrogram over firmware time and
    frequency vs throttle, over runs of consecutive AHRS steps (dropped frames split them).

    The rows come at the AHRS rate (161.54 Hz: Nyquist 80.77 Hz); the sensors are read at 807.7 Hz and averaged 5 to
    1, so motor vibration above the Nyquist shows at an alias: --mark-hz computes where. Prints the top peaks per
    axis; --plot, --csv and the Rerun options (--spawn, --rrd, ...) add the figure, the numbers and the viewer."""
    marks = list(mark_hz or [])
    _check_numbers(marks, nperseg, overlap, throttle_bins, peaks, min_hz)
    src = read_recording(capture)  # the input first, then the outputs, then the work
    check_outputs({"--plot": plot, "--csv": csv_out}, force=force, inputs=(capture,))
    options = view_sinks(rerun, force=force, inputs=(capture,))  # a bad --rrd or a dead --connect URL: before the work
    if plot is not None:
        _check_plot_format(plot)
    with progress_bar("spectrum", quiet=rerun.serve) as progress:
        tel, warnings_seen = load_replay(src, scaled(progress, 0.0, 0.3))
        require_attitude(tel, "take a spectrum of")
        progress(0.3, "spectra")
        sp = S.compute_spectra(tel, nperseg=nperseg, overlap=overlap, throttle_bins=throttle_bins)
        found = {
            name: S.find_peaks(sp.freq_hz, sp.psd[:, k], peaks, min_hz) for k, (name, _, _) in enumerate(S.SIGNALS)
        }
        lines = S.format_summary(sp, found, marks, min_hz=min_hz, source=capture.name)
        if csv_out is not None:
            progress(0.4, f"writing {csv_out.name}")
            write_atomic(csv_out, "--csv", lambda fh: S.write_csv(sp, fh), text=True)
        if plot is not None:
            from steval_link.analysis.spectrum import plot_spectra  # matplotlib loads only for --plot

            progress(0.5, f"plotting {plot.name}")
            with atomic_output(plot, option="--plot", keep_suffix=True) as part:
                plot_spectra(sp, part, marks_hz=marks, peaks=found, title=f"steval spectrum {capture.name}")
    print_warnings(warnings_seen)
    print("\n".join(lines))
    for what, path in (("csv", csv_out), ("plot", plot)):
        if path is not None:
            print(f"{what}: {path}")
    if options is not None:
        from steval_viewer.spectrum_log import spectrum_sink  # Rerun loads only for a viewer or an .rrd

        try:
            spectrum_sink(options, f"steval spectrum {capture.name}", tel, sp, marks, found)
        except KeyboardInterrupt:
            if rerun.rrd is not None:  # the sink writes it whole or not at all
                print(f"steval: {rerun.rrd} not written (interrupted before it was complete)", file=sys.stderr)
            raise


def _check_numbers(marks: list[float], nperseg, overlap: float, throttle_bins: int, peaks: int, min_hz: float) -> None:
    """The numeric options in range, before any work."""
    for f in marks:
        if not (math.isfinite(f) and f > 0):
            raise UserError(f"--mark-hz must be a frequency > 0 Hz, got {f:g}")
    if nperseg is not None and not S.MIN_NPERSEG <= nperseg <= MAX_NPERSEG:
        raise UserError(f"--nperseg must be between {S.MIN_NPERSEG} and {MAX_NPERSEG} rows, got {nperseg}")
    if not (math.isfinite(overlap) and 0 <= overlap < 1):
        raise UserError(f"--overlap must be a fraction in [0, 1), got {overlap:g}")
    if not 1 <= throttle_bins <= MAX_THROTTLE_BINS:
        raise UserError(f"--throttle-bins must be between 1 and {MAX_THROTTLE_BINS}, got {throttle_bins}")
    if not 0 <= peaks <= 20:
        raise UserError(f"--peaks must be between 0 and 20, got {peaks}")
    if not (math.isfinite(min_hz) and min_hz >= 0):
        raise UserError(f"--min-hz must be ≥ 0 Hz, got {min_hz:g}")


def _check_plot_format(plot: Path) -> None:
    """matplotlib is there and writes the format ``plot``'s extension names."""
    from steval_link.analysis.plots import require_matplotlib  # matplotlib loads only for --plot (start-up time)

    plt = require_matplotlib()
    fig = plt.figure()
    formats = fig.canvas.get_supported_filetypes()
    plt.close(fig)
    if plot.suffix.lower().lstrip(".") not in formats:
        raise UserError(f"--plot {plot}: give a file name ending in one of .{', '.join(sorted(formats))}")

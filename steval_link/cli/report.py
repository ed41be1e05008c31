"""``steval report``: one or more captures as a lab report (HTML and/or Markdown)."""

from __future__ import annotations

import sys
from pathlib import Path

from steval_link.analysis import html_report as H
from steval_link.analysis import spectrum as S
from steval_link.analysis.compare import compare_capture
from steval_link.analysis.side_by_side import flight_of_telemetry, side_by_side
from steval_link.cli.app import app, argument, option
from steval_link.cli.checks import estimator_names, require_attitude
from steval_link.cli.compare import CompareEstimatorsOption
from steval_link.cli.outputs import ForceOption, atomic_output, check_outputs
from steval_link.cli.progress import progress_bar, scaled
from steval_link.cli.replay import load_replay
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.link.ble_payloads import is_ble_source
from steval_link.link.load import read_recording


def _spectrum(tel):
    """The spectra and peaks of ``tel``, or (None, {}, the sentence why there are none)."""
    try:
        sp = S.compute_spectra(tel)
    except UserError as exc:
        return None, {}, str(exc)
    return sp, {name: S.find_peaks(sp.freq_hz, sp.psd[:, k]) for k, (name, _, _) in enumerate(S.SIGNALS)}, None


@app.command("report")
def report_command(
    captures: argument(list[Path], help="Captures (.stv), raw serial dumps or text-mode logs.", metavar="CAPTURE"),
    out: option(
        Path | None, "--out", "-o", metavar="REPORT.html", help="Write the report as one self-contained HTML page."
    ) = None,
    markdown: option(
        Path | None,
        metavar="REPORT.md",
        help="Write the report as Markdown; its figures go to REPORT_images/ beside it.",
    ) = None,
    estimator: CompareEstimatorsOption = None,
    title: option(str | None, help="The report's title.") = None,
    force: ForceOption = False,
) -> None:
    """A lab report in one command: per capture its summary and filter settings, the attitude figure with
    accelerometer-only tilt, the firmware-vs-replica verdict, the estimators' table (with the RMSE against the
    ground truth when the capture keeps one), the AHRS step cost (exercise 6), the sensor spectrum and, for an armed
    drone, the flight control; with several captures also the flights side by side. The HTML page embeds every
    figure and loads nothing from the network: open it in any browser, hand it in or paste from it."""
    if out is None and markdown is None:
        raise UserError("give --out REPORT.html and/or --markdown REPORT.md: where the report goes.")
    names = estimator_names(estimator, registry.COMPARE_DEFAULT, require_installed=False)
    sources = [read_recording(c) for c in captures]  # the inputs first, then the outputs
    for src in sources:
        if is_ble_source(src):
            raise UserError(
                f"{src.path} is a BLE capture: steval report takes serial captures (steval compare "
                "takes BLE captures side by side)."
            )
    check_outputs({"--out": out, "--markdown": markdown}, force=force, inputs=tuple(s.path for s in sources))
    from steval_link.analysis.plots import require_matplotlib  # matplotlib loads only here (start-up time)

    require_matplotlib()
    per, flights = [], []
    with progress_bar("report") as progress:
        for i, (path, src) in enumerate(zip(captures, sources)):
            part = scaled(progress, i / len(captures), (i + 0.9) / len(captures))
            tel, warnings = load_replay(src, scaled(part, 0.0, 0.2))
            require_attitude(tel, "report on")
            part(0.2, f"{path.name}: replica and {', '.join(names)}")
            report = compare_capture(tel, estimators=names)
            part(0.6, f"{path.name}: spectrum and figures")
            sp, peaks, why = _spectrum(tel)
            per.append((path.name, H.capture_sections(tel, report, sp, peaks, warnings=warnings, spectrum_note=why)))
            if len(captures) > 1:
                flights.append(flight_of_telemetry(path, tel, warnings))
        side = H.side_by_side_section(side_by_side(flights)) if len(flights) > 1 else None
        rep = H.report_of(title or "steval report: " + ", ".join(c.name for c in captures), per, side)
        progress(0.95, "writing")  # the HTML page and/or the Markdown with its images, each whole or not at all
        if out is not None:
            with atomic_output(out, option="--out", keep_suffix=True) as part:
                part.write_text(H.render_html(rep), encoding="utf-8")
        if markdown is not None:
            images = markdown.with_name(f"{markdown.stem}_images")
            with atomic_output(markdown, option="--markdown", keep_suffix=True) as part:
                part.write_text(H.render_markdown(rep, images, images.name), encoding="utf-8")
    for label, path in (("report", out), ("markdown", markdown)):
        if path is not None:
            print(f"{label}: {path}")
    sys.stdout.flush()

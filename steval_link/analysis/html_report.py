"""``steval report``: captures as a lab report, built as :class:`Section` s of sentences, lines, tables and figures: a
self-contained HTML page (inline CSS and figures, no script, nothing from the network) or Markdown with PNG files.
Written with the standard library's ``html.escape``: a template engine would be one more dependency for a dozen tags."""

from __future__ import annotations

import base64
import html
import io
from dataclasses import dataclass, field
from pathlib import Path

from steval_link import constants as C
from steval_link.analysis.flight_control import no_flight_figure_reason
from steval_link.analysis.report import ComparisonReport, fmt_number, setting_text
from steval_link.analysis.side_by_side import format_side_by_side
from steval_link.analysis.spectrum import SIGNALS, UNITS, Peak, Spectra
from steval_link.analysis.summary import format_summary, summarize


@dataclass(frozen=True)
class Figure:
    """One figure: ``key`` (a file-name stem), a caption, the PNG bytes."""

    key: str
    caption: str
    png: bytes


@dataclass(frozen=True)
class Table:
    """One table: its caption, the column heads, rows of cells (text)."""

    caption: str
    head: list[str]
    rows: list[list[str]]


@dataclass
class Section:
    """One heading and what stands under it, in order: sentences, monospace lines, tables, figures."""

    heading: str
    sentences: list[str] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)
    tables: list[Table] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)


@dataclass
class LabReport:
    """The whole report: a title and its sections; ``level`` per section (1: a capture's name, 2: under it)."""

    title: str
    sections: list[tuple[int, Section]] = field(default_factory=list)


def figure_png(fig, *, dpi: int = 100) -> bytes:
    """A matplotlib figure as PNG bytes (the figure is closed)."""
    import matplotlib.pyplot as plt  # the caller checked matplotlib (require_matplotlib)

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return buf.getvalue()


def _settings_table(report: ComparisonReport) -> Table | None:
    """The filter settings the status frames report, each with the 170120 default when it differs."""
    fs = report.filter_settings
    if not fs or fs.get("from") != "status frames":
        return None
    diff = fs.get("differs_from_defaults", {})
    rows = []
    for key, what in (
        ("kp_ground", "kp below min_thr (on the ground)"),
        ("kp_flight", "kp at or above min_thr (flying)"),
        ("ki", "ki"),
        ("dt_s", "dt, s"),
        ("min_thr", "min_thr (gTHR)"),
        ("correction", "accelerometer correction"),
        ("variant", "the ST release whose filter it runs"),
    ):
        if key in fs:
            default = diff.get(key, [None, None])[1]
            rows.append([what, setting_text(fs[key]), "same" if default is None else setting_text(default)])
    return Table(f"filter settings (from {fs['status_frames']} status frames)", ["setting", "value", "default"], rows)


def verdict_sentences(report: ComparisonReport) -> list[str]:
    """The firmware against the bit-exact replica, in words: bit-exact on N of N steps, or the first difference."""
    p = report.replica
    if p is None:
        return [
            "Text-mode capture: the angles are rounded and carry no quaternion, so the replica cannot be compared "
            "bit for bit; the estimators below are compared with the firmware instead."
        ]
    if p.seeded == 0:
        return [f"The replica could not be started: {p.unseeded_reason or 'no status snapshot'}."]
    if p.all_exact:
        out = [
            f"Bit-exact on {p.bit_exact} of {p.seeded} steps: the Python replica of ahrs_fusion_ag reproduces "
            "every quaternion and angle the firmware sent, bit for bit."
        ]
    else:
        fm = p.first_mismatch
        out = [
            f"NOT bit-exact: {p.bit_exact} of {p.seeded} steps agree; the first difference is at step {fm['step']} "
            f"(t = {fm['t_rel_s']:.3f} s into the capture).",
            *p.diagnosis,
        ]
    if p.seeded < p.rows:
        out.append(f"{p.rows - p.seeded} of {p.rows} rows were not covered (before a snapshot, or after lost frames).")
    return out


def _estimator_table(report: ComparisonReport) -> Table:
    """Each estimator against the firmware (RMS, max |Δ| in degrees), with the RMSE against truth when kept."""
    truth = (report.truth or {}).get("rmse_deg")
    head = ["estimator", "steps", "pitch RMS", "pitch max |Δ|", "roll RMS", "roll max |Δ|"]
    head += ["RMSE vs truth", "note"] if truth else ["note"]
    fw = fmt_number(truth.get("firmware"), ".3f") if truth else ""
    rows = [["firmware (drone)", str(report.rows), "0", "0", "0", "0", fw, ""]] if truth else []
    for t in report.traces:
        stats = (t.pitch.rms_deg, t.pitch.max_abs_deg, t.roll.rms_deg, t.roll.max_abs_deg)
        cells = [str(min(t.pitch.n, t.roll.n)), *map(fmt_number, stats)] if t.available else ["—", "", "", "", ""]
        vs_truth = [fmt_number(truth.get(t.name), ".3f") if t.available else ""] if truth else []
        rows.append([t.label, *cells, *vs_truth, t.note])
    cap = "angles against the firmware, degrees (Δ = estimator − firmware; pitch = thx about x, roll = thy about y)"
    if truth:
        cap += (
            f"; RMSE vs truth: inclination error over {report.truth['movement_steps']} movement steps of the "
            "ground truth the capture keeps"
        )
    return Table(cap, head, rows)


def _step_cost(report: ComparisonReport) -> Section:
    """Exercise 6: what one AHRS step costs on the drone, and the share of its period."""
    rt = report.rates
    sec = Section("AHRS step cost (exercise 6)")
    if rt.ahrs_cycles_mean is None:
        sec.sentences.append("No status frames with cycle counts: the cost of a step is not known for this capture.")
        return sec
    unit = "emulated instructions" if rt.cycles_emulated else "CPU cycles"
    period = C.AHRS_PERIOD_US
    rows = []
    for what in ("min", "mean", "max"):
        us = rt.ahrs_us(what)
        share = fmt_number(100 * us / period if us is not None else None, ".1f")
        rows.append([what, fmt_number(us, ".1f"), fmt_number(getattr(rt, f"ahrs_cycles_{what}"), ".0f"), share])
    caption = f"ahrs_fusion_ag per step at {(rt.cpu_hz or 0) / 1e6:g} MHz ({unit}); the AHRS period is {period:.0f} µs"
    sec.tables.append(Table(caption, ["", "µs", unit, "% of the period"], rows))
    if rt.cycles_emulated:
        sec.sentences.append(
            "This capture comes from the emulated board: the counts are instructions, not Cortex-M4 cycles (a real "
            "drone's DWT counter gives cycles, usually more)."
        )
    return sec


def _peak_table(peaks: dict[str, list[Peak]]) -> Table:
    rows = []
    for name, sensor, _ in SIGNALS:
        text = ", ".join(f"{p.freq_hz:.1f} Hz ({p.amplitude:.1f} {UNITS[sensor]})" for p in peaks.get(name, []))
        rows.append([name.replace("_", " "), text or "no clear peak"])
    return Table("strongest peaks per axis (frequency, amplitude of the sinusoid)", ["signal", "peaks"], rows)


def capture_sections(
    tel,
    report: ComparisonReport,
    spectra: Spectra | None,
    peaks: dict[str, list[Peak]],
    *,
    warnings: list[str] = (),
    spectrum_note: str | None = None,
) -> list[Section]:
    """The sections of one capture, from its summary to its flight control (the spectrum else ``spectrum_note``)."""
    from steval_link.analysis.plots import (  # matplotlib (checked by the caller)
        comparison_figure,
        differences_figure,
        flight_control_figure,
    )

    summary = Section("summary and settings", lines=format_summary(summarize(tel)))
    summary.sentences += [f"Warning: {w}" for w in warnings]
    settings = _settings_table(report)
    if settings is not None:
        summary.tables.append(settings)
    attitude = Section("attitude")
    attitude.sentences.append(
        "Pitch is thx (rotation about x, the right axis, nose up +) and roll is thy (rotation about y, the forward "
        "axis): the firmware's names. The lab handouts' textbook formulas call them the other way round."
    )
    what = (
        "the firmware's angles with the replica, the estimators and accelerometer-only tilt; below, firmware − replica"
    )
    what += "; right, each estimator's difference from the firmware"
    attitude.figures.append(Figure("attitude", what, figure_png(comparison_figure(tel, report))))
    verdict = Section("firmware against the replica", sentences=verdict_sentences(report))
    estimators = Section("estimators", tables=[_estimator_table(report)], sentences=list(report.notes))
    if report.estimates:
        what = "each estimator minus the firmware over time, degrees (accelerometer-only tilt in grey)"
        estimators.figures.append(Figure("estimators", what, figure_png(differences_figure(tel, report))))
    spectrum = Section("sensor spectrum")
    if spectra is None:
        spectrum.sentences.append(spectrum_note or "no spectrum")
    else:
        from steval_link.analysis.spectrum import spectra_figure  # matplotlib (checked)

        spectrum.figures.append(
            Figure("spectrum", "gyro and accelerometer spectra", figure_png(spectra_figure(spectra, peaks=peaks)))
        )
        spectrum.tables.append(_peak_table(peaks))
    flight = Section("flight control")
    why = no_flight_figure_reason(tel.fc)
    if why is None:
        what = "targets against angles, PID terms, motors"
        flight.figures.append(Figure("flight-control", what, figure_png(flight_control_figure(tel))))
    else:
        flight.sentences.append(f"No flight-control figure: {why}.")
    return [summary, attitude, verdict, estimators, _step_cost(report), spectrum, flight]


def side_by_side_section(result) -> Section:
    """The flights side by side (:class:`~steval_link.analysis.side_by_side.SideBySide`): its lines and figure."""
    from steval_link.analysis.side_by_side import side_by_side_figure  # matplotlib (checked)

    what = "every flight on one time axis against the first one's accelerometer-only tilt"
    figure = Figure("side-by-side", what, figure_png(side_by_side_figure(result)))
    return Section("the captures side by side", lines=format_side_by_side(result), figures=[figure])


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;max-width:1320px;margin:1.5em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em;border-bottom:2px solid #444}h2{font-size:1.3em;margin-top:1.8em;border-bottom:1px solid #bbb}
table{border-collapse:collapse;margin:.6em 0 1em;font-size:.92em}caption{text-align:left;font-style:italic;
padding:.2em 0}th,td{border:1px solid #ccc;padding:.25em .6em;text-align:left}th{background:#f0f0f0}
td.n{text-align:right;font-variant-numeric:tabular-nums}pre{background:#f7f7f7;padding:.6em;overflow-x:auto;
font-size:.85em}figure{margin:1em 0}img{max-width:100%;height:auto;border:1px solid #ddd}
figcaption{font-size:.9em;color:#555}
"""


def _cell_class(text: str) -> str:
    try:
        float(text.replace(",", ""))
        return ' class="n"'
    except ValueError:
        return ""


def _html_table(t: Table) -> str:
    e = html.escape
    head = "".join(f"<th>{e(h)}</th>" for h in t.head)
    body = "".join("<tr>" + "".join(f"<td{_cell_class(c)}>{e(c)}</td>" for c in row) + "</tr>" for row in t.rows)
    return f"<table><caption>{e(t.caption)}</caption><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def render_html(report: LabReport) -> str:
    """The report as one HTML page: inline CSS, figures as ``data:image/png;base64`` URIs, no script, no link out."""
    e = html.escape
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{e(report.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(report.title)}</h1>",
    ]
    for level, sec in report.sections:
        out.append(f"<h{level + 1}>{e(sec.heading)}</h{level + 1}>")
        out += [f"<p>{e(s)}</p>" for s in sec.sentences]
        if sec.lines:
            out.append("<pre>" + e("\n".join(sec.lines)) + "</pre>")
        out += [_html_table(t) for t in sec.tables]
        for fig in sec.figures:
            data = base64.b64encode(fig.png).decode("ascii")
            out.append(
                f'<figure><img alt="{e(fig.caption)}" src="data:image/png;base64,{data}">'
                f"<figcaption>{e(fig.caption)}</figcaption></figure>"
            )
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def render_markdown(report: LabReport, images_dir: Path, images_link: str) -> str:
    """The report as Markdown, each figure written to ``images_dir`` as ``NN-KEY.png``, linked under ``images_link``."""
    images_dir.mkdir(parents=True, exist_ok=True)
    out = [f"# {report.title}", ""]
    n = 0
    for level, sec in report.sections:
        out += [f"{'#' * (level + 1)} {sec.heading}", ""]
        for s in sec.sentences:
            out += [s, ""]
        if sec.lines:
            out += ["```text", *sec.lines, "```", ""]
        for t in sec.tables:
            out += [f"*{t.caption}*", "", "| " + " | ".join(_md_cell(h) for h in t.head) + " |"]
            out.append("|" + "|".join("---" for _ in t.head) + "|")
            out += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in t.rows]
            out.append("")
        for fig in sec.figures:
            n += 1
            name = f"{n:02d}-{fig.key}.png"
            (images_dir / name).write_bytes(fig.png)
            out += [f"![{fig.caption}]({images_link}/{name})", "", f"*{fig.caption}*", ""]
    return "\n".join(out)


def report_of(title: str, captures: list[tuple[str, list[Section]]], side: Section | None) -> LabReport:
    """A :class:`LabReport`: the side-by-side first (several captures), then each capture under its name."""
    rep = LabReport(title)
    if side is not None:
        rep.sections.append((1, side))
    for name, secs in captures:
        rep.sections.append((1, Section(name)))
        rep.sections += [(2, s) for s in secs]
    return rep

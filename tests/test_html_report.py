"""``steval report``: the self-contained HTML page (every figure embedded, nothing from the network; rendered in
headless Chromium, where every image must load), the Markdown with its images, the side-by-side of several
captures, and the one-line errors."""

from __future__ import annotations

import base64
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from support.cli import run_cli

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "recordings" / "demo.stv"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or "/usr/bin/chromium"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

#: appended to a copy of the page: after load, the images that decoded, written into the DOM for --dump-dom
PROBE = """<script>
window.addEventListener("load", () => {
  const imgs = [...document.images];
  const ok = imgs.filter((i) => i.complete && i.naturalWidth > 0 && i.naturalHeight > 0);
  document.body.setAttribute("data-images", imgs.length + "/" + ok.length);
  document.body.setAttribute("data-sizes", ok.map((i) => i.naturalWidth + "x" + i.naturalHeight).join(","));
});
</script>"""


@pytest.fixture(scope="module")
def demo_report(tmp_path_factory):
    pytest.importorskip("matplotlib")
    mp = pytest.MonkeyPatch()
    out = tmp_path_factory.mktemp("report")
    html, md = out / "r.html", out / "r.md"

    class _Cap:  # run_cli reads capsys only through readouterr
        def readouterr(self):
            return "", ""

    code, stdout, err = run_cli(mp, _Cap(), "report", DEMO, "--out", html, "--markdown", md, "-e", "accel")
    mp.undo()
    assert code == 0, err
    return html, md


@pytest.mark.slow  # steval report on the bundled recordings: ≈ 30 s of CPU
def test_html_embeds_every_figure_and_loads_nothing(demo_report):
    html, _ = demo_report
    page = html.read_text(encoding="utf-8")
    srcs = re.findall(r'<img[^>]*src="([^"]+)"', page)
    # the attitude, the estimators against the firmware, the spectrum (demo.stv was never armed: no flight control)
    assert len(srcs) == 3
    for src in srcs:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == PNG_MAGIC
    assert not re.search(r'(src|href)="(https?:)?//', page) and "<link" not in page and "<script" not in page
    # the sections a student hands in: verdict, estimators' table, step cost, the flight-control sentence
    assert "Bit-exact on 9210 of 9210 steps" in page
    assert page.count("<table>") >= 3 and "accel-only tilt" in page and "ST-Mahony replica" in page
    assert "AHRS step cost" in page and "% of the period" in page
    assert "No flight-control figure: the drone was never armed" in page


@pytest.mark.slow  # steval report, then headless Chromium
@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason="needs chromium")
def test_chromium_shows_every_figure(demo_report, tmp_path):
    html, _ = demo_report
    probe = tmp_path / "probe.html"
    probe.write_text(html.read_text(encoding="utf-8").replace("</body>", PROBE + "</body>"), encoding="utf-8")
    args = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=5000"]
    dom = subprocess.run(
        [*args, "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=120, check=True
    ).stdout
    m = re.search(r'data-images="(\d+)/(\d+)"', dom)
    assert m, dom[:500]
    total, ok = int(m.group(1)), int(m.group(2))
    assert total == 3 and ok == total
    sizes = re.search(r'data-sizes="([^"]*)"', dom).group(1).split(",")
    assert all(int(s.split("x")[0]) >= 800 for s in sizes)
    # the page itself (without the probe) renders: a screenshot wider than the figures, mostly not blank
    shot = tmp_path / "shot.png"
    subprocess.run(
        [*args, "--hide-scrollbars", "--window-size=1400,3000", f"--screenshot={shot}", html.as_uri()],
        capture_output=True,
        timeout=120,
        check=True,
    )
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)
    assert img.shape[1] == 1400 and img.shape[0] == 3000
    non_white = (img[..., :3] < 0.9).any(axis=2).mean()
    assert non_white > 0.05


@pytest.mark.slow  # steval report on the bundled recordings: ≈ 30 s of CPU
def test_markdown_links_its_images(demo_report):
    _, md = demo_report
    text = md.read_text(encoding="utf-8")
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert len(links) == 3
    for link in links:
        assert (md.parent / link).read_bytes()[:8] == PNG_MAGIC
    assert re.search(r"^\| estimator \| steps \|", text, re.M) and "Bit-exact on 9210 of 9210 steps" in text


@pytest.mark.slow  # steval report on the bundled recordings: ≈ 30 s of CPU
def test_several_captures_side_by_side(monkeypatch, capsys, tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "two.html"
    broad = ROOT / "recordings" / "broad_07.stv"
    code, stdout, err = run_cli(
        monkeypatch, capsys, "report", broad, ROOT / "recordings" / "flight.stv", "--out", out, "-e", "accel"
    )
    assert code == 0, err
    page = out.read_text(encoding="utf-8")
    assert "the captures side by side" in page and "flight.stv" in page and "broad_07.stv" in page
    # side-by-side; per capture the attitude, the estimators, the spectrum; flight.stv's flight control
    assert len(re.findall(r'<img[^>]*src="data:image/png;base64,', page)) == 8


@pytest.mark.parametrize(
    "args, words",
    [
        ([str(DEMO)], "--out REPORT.html"),
        (["missing.stv", "--out", "x.html"], "missing.stv"),
    ],
)
def test_errors_are_one_line(monkeypatch, capsys, tmp_path, args, words):
    monkeypatch.chdir(tmp_path)
    code, stdout, err = run_cli(monkeypatch, capsys, "report", *args)
    assert code == 2 and err.count("\n") == 1 and words in err
    assert not (tmp_path / "x.html").exists()


def test_estimator_table_has_the_truth_column_when_the_capture_keeps_truth():
    from test_compare import telemetry

    from steval_link.analysis import html_report as H
    from steval_link.analysis.compare import compare_capture

    r = compare_capture(telemetry(n=400), estimators=("accel",))
    assert "RMSE vs truth" not in H._estimator_table(r).head
    r.truth = {"movement_steps": 321, "rmse_deg": {"firmware": 1.25, "st-mahony-replica": 1.25, "accel": 2.5}}
    t = H._estimator_table(r)
    col = t.head.index("RMSE vs truth")
    by_name = {row[0]: row[col] for row in t.rows}
    assert by_name == {"firmware (drone)": "1.250", "ST-Mahony replica": "1.250", "accel-only tilt": "2.500"}
    assert "321 movement steps" in t.caption

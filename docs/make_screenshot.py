"""Make every picture of the docs from today's code: the default viewer's tabs on ``recordings/demo.stv`` and every
figure the README's and the how-tos' commands write, into ``docs/images/`` (and ``docs/screenshot.png``, the
README's picture).

The viewer: ``steval replay recordings/demo.stv --spawn`` on a virtual display (Xvfb, Mesa's llvmpipe through
Vulkan), each tab made active through Rerun's gRPC control API and the screenshot taken by the viewer itself (as
tests/test_viewer_display.py does). The figures: the ``steval`` commands themselves, as a student runs them; the
lab report's page photographed by headless Chromium.

Usage (Linux, with Xvfb, mesa-vulkan-drivers and chromium; the project's venv active)::

    python docs/make_screenshot.py            # everything
    python docs/make_screenshot.py figures    # only the figures (no display needed)
    python docs/make_screenshot.py viewer     # only the viewer's tabs
    python docs/make_screenshot.py viewer DIR # the viewer's tabs into DIR (docs/ untouched: a test's check)

Prints each PNG it wrote and its size.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "docs" / "images"
#: the recordings as a student names them (the commands run in the project's folder)
REC = Path("recordings")

#: recordings/demo.stv: AHRS steps 0..9209
DEMO_LAST_STEP = 9209
#: time the viewer gets to lay out and draw every view once the data is in
SETTLE_S = 8.0
#: the viewer's screenshots: file name → (the right side's tab, the left side's tab), by their names
VIEWER_SHOTS = {
    "viewer-attitude.png": ("Attitude", "Link health"),
    "viewer-flight-control.png": ("Flight control", "Link health"),
    "viewer-firmware-log.png": ("Attitude", "Firmware log"),
}
#: a student's PRINTF log (ETH exercise 2) of demo.stv's angles, replayed: the text telemetry tab
TEXT_SHOT = ("viewer-text-telemetry.png", "Text telemetry", "Link health")
#: the figures: file name → the steval arguments that write it ({out}: the file, {tmp}: a scratch folder)
FIGURES = {
    "compare-demo.png": ["compare", REC / "demo.stv", "--plot", "{out}"],
    "compare-flight.png": ["compare", REC / "flight.stv", "--plot", "{out}"],
    "compare-side-by-side.png": ["compare", REC / "demo.stv", REC / "flight.stv", "--plot", "{out}"],
    "spectrum-demo.png": ["spectrum", REC / "demo.stv", "--plot", "{out}"],
    "spectrum-12hz.png": ["spectrum", "{tmp}/vib12.stv", "--mark-hz", "12", "--plot", "{out}"],
    "simulate-compare.png": [
        "simulate",
        *("--acc", "0", "0", "1000", "-n", "400"),
        *("--compare-with", "ki=1", "--compare-with", "correction=off", "--compare-with", "estimator=ekf3"),
        *("--plot", "{out}"),
    ],
}
#: written beside another figure by the same command
SIDE_FIGURES = {"compare-flight-flight-control.png": "compare-flight.png"}
#: the lab report's page (``steval report``), photographed by Chromium
REPORT = "report.png"
#: every image the docs use (tests/test_docs_images.py checks each exists and is a non-empty PNG)
ALL_IMAGES = (*VIEWER_SHOTS, TEXT_SHOT[0], *FIGURES, *SIDE_FIGURES, REPORT)


def steval(*args, cwd: Path = ROOT, env=None) -> subprocess.CompletedProcess:
    """``steval ARGS`` as a student runs it; exits this script with its error when it fails."""
    cmd = [sys.executable, "-c", "from steval_link.cli import main; main()", *map(str, args)]
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    if r.returncode != 0:
        sys.exit(f"make_screenshot: steval {' '.join(map(str, args))} failed:\n{r.stderr}")
    return r


def _written(path: Path) -> None:
    shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    print(f"{shown}: {path.stat().st_size} bytes")


def make_figures(tmp: Path) -> None:
    """Every figure of :data:`FIGURES` and the report's page."""
    steval("synth", "--scenario", "bench", "--duration", "30", "--seed", "5", "--vibration", "gyro-x:12:3000",
           "--out", tmp / "vib12.stv")  # fmt: skip
    for name, args in FIGURES.items():
        out = IMAGES / name
        steval(*[str(a).format(out=out, tmp=tmp) for a in args], "--force")
        _written(out)
    for name in SIDE_FIGURES:
        _written(IMAGES / name)
    page = tmp / "report.html"
    steval("report", REC / "demo.stv", "--out", page, "--force")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        sys.exit("make_screenshot: the report's picture needs chromium")
    subprocess.run(
        [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1300,2600",
         f"--screenshot={IMAGES / REPORT}", page.as_uri()],
        capture_output=True, timeout=120, check=True,
    )  # fmt: skip
    _written(IMAGES / REPORT)


def _set_tabs(client, right: str, left: str) -> None:
    """Make the tabs whose names start with ``right`` and ``left`` active in the viewer's blueprint."""
    bp = client.get_blueprint()
    d = bp.blueprint
    names = {
        path: next(iter(parts.values())).get("display_name")
        for path, parts in d.items()
        if isinstance(parts, dict) and parts
    }
    for parts in d.values():
        c = parts.get("ContainerBlueprint") if isinstance(parts, dict) else None
        if c and c.get("container_kind") == "Tabs":
            for child in c["contents"]:
                if any((names.get(child) or "").startswith(tab) for tab in (right, left)):
                    c["active_tab"] = child
    client.set_blueprint(d, store_id=bp.store_id)


def write_printf_log(path: Path) -> None:
    """demo.stv's angles as ETH exercise 2 prints them (``Drone_Pitch = %f\\tDrone_Roll = %f\\n\\n``, after a
    banner line): pitch is thx, roll thy, in degrees."""
    import numpy as np

    from steval_link.link.load import load_telemetry

    a = load_telemetry(ROOT / REC / "demo.stv").attitude
    pitch, roll = np.degrees(a.thx_rad.astype(np.float64)), np.degrees(a.thy_rad.astype(np.float64))
    lines = ["STEVAL-FCU001V1 exercise 2\r\n"] + [
        f"Drone_Pitch = {p:f}\tDrone_Roll = {r:f}\n\n" for p, r in zip(pitch, roll)
    ]
    path.write_text("".join(lines))


def make_viewer_shots(images: Path = IMAGES) -> None:
    """The default viewer on demo.stv, one screenshot per tab (:data:`VIEWER_SHOTS`) into ``images``, and (into
    docs/images) docs/screenshot.png; then a PRINTF log's text telemetry (:data:`TEXT_SHOT`)."""
    with tempfile.TemporaryDirectory(prefix="steval-printf-") as tmp:
        log = Path(tmp) / "exercise2.log"
        write_printf_log(log)
        _viewer_shots(REC / "demo.stv", VIEWER_SHOTS, images)
        _viewer_shots(log, {TEXT_SHOT[0]: TEXT_SHOT[1:]}, images)
    if images == IMAGES:
        shutil.copyfile(IMAGES / "viewer-attitude.png", ROOT / "docs" / "screenshot.png")
        _written(ROOT / "docs" / "screenshot.png")


def _viewer_shots(capture: Path, shots: dict, images: Path) -> None:
    """``steval replay CAPTURE --spawn`` on a virtual display, a screenshot per ``shots`` entry (file → tabs)."""
    sys.path.insert(0, str(ROOT / "tests"))  # the display helpers the viewer tests use
    from rerun.experimental import ViewerClient
    from support.xdisplay import (
        VirtualDisplay,
        display_tools_missing,
        kill_processes,
        rerun_processes,
        viewer_recording,
    )

    from steval_viewer.sink_options import free_port

    why = display_tools_missing()
    if why:
        sys.exit(f"make_screenshot: {why}")
    display = VirtualDisplay(width=1600, height=1000)
    port = free_port()
    # a viewer with no remembered state (window size, panels): the picture depends on the display alone
    state = tempfile.TemporaryDirectory(prefix="steval-screenshot-")
    env = dict(display.env, XDG_DATA_HOME=state.name, XDG_CONFIG_HOME=state.name, XDG_CACHE_HOME=state.name)
    try:
        steval("replay", capture, "--spawn", "--grpc-port", port, env=env)
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        viewer_recording(url, timeline="ahrs_step", end=DEMO_LAST_STEP, timeout_s=120)
        if shutil.which("xdotool"):  # the pointer off the plots (no hover tooltip): over the 3D view's empty grid
            subprocess.run(["xdotool", "mousemove", "60", "420"], env=env, check=False)
        time.sleep(SETTLE_S)
        client = ViewerClient.connect(url)
        for name, (right, left) in shots.items():
            _set_tabs(client, right, left)
            time.sleep(2.0)
            out = images / name
            out.write_bytes(client.take_screenshot())
            _written(out)
    finally:
        kill_processes(rerun_processes(port))
        display.close()
        state.cleanup()


def main(what: str, out: str | None = None) -> None:
    IMAGES.mkdir(parents=True, exist_ok=True)
    if what not in ("all", "figures", "viewer") or (out is not None and what != "viewer"):
        sys.exit("usage: python docs/make_screenshot.py [all|figures|viewer [DIR]]")
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        make_viewer_shots(Path(out))
        return
    if what in ("all", "figures"):
        with tempfile.TemporaryDirectory(prefix="steval-figures-") as tmp:
            make_figures(Path(tmp))
    if what in ("all", "viewer"):
        make_viewer_shots()


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "all", sys.argv[2] if len(sys.argv) > 2 else None)

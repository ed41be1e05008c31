"""Make docs/screenshot.png, the README's picture, from today's viewer: ``steval replay recordings/demo.stv --spawn``
on a virtual display (Xvfb, Mesa's llvmpipe through Vulkan), the screenshot taken by the viewer itself (Rerun's
gRPC control API, as tests/test_viewer_display.py does).

Usage (Linux, with Xvfb and mesa-vulkan-drivers; the project's venv active)::

    python docs/make_screenshot.py [OUT.png]        # default: docs/screenshot.png

Prints where it wrote the PNG and its size.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the display helpers the viewer tests use

from support.xdisplay import (  # noqa: E402
    VirtualDisplay,
    display_tools_missing,
    kill_processes,
    rerun_processes,
    screenshot,
    viewer_recording,
)

from steval_viewer.sink_options import free_port  # noqa: E402

#: recordings/demo.stv: AHRS steps 0..9209
DEMO_LAST_STEP = 9209
#: time the viewer gets to lay out and draw every view once the data is in
SETTLE_S = 8.0


def main(out: Path) -> None:
    why = display_tools_missing()
    if why:
        sys.exit(f"make_screenshot: {why}")
    display = VirtualDisplay(width=1600, height=1000)
    port = free_port()
    # a viewer with no remembered state (window size, panels): the picture depends on the display alone
    state = tempfile.TemporaryDirectory(prefix="steval-screenshot-")
    env = dict(display.env, XDG_DATA_HOME=state.name, XDG_CONFIG_HOME=state.name, XDG_CACHE_HOME=state.name)
    try:
        cmd = [
            sys.executable,
            "-c",
            "from steval_link.cli import main; main()",
            "replay",
            str(ROOT / "recordings" / "demo.stv"),
            "--spawn",
            "--grpc-port",
            str(port),
        ]
        r = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True, timeout=300)
        if r.returncode != 0:
            sys.exit(f"make_screenshot: steval replay failed:\n{r.stderr}")
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        viewer_recording(url, timeline="ahrs_step", end=DEMO_LAST_STEP, timeout_s=120)
        time.sleep(SETTLE_S)
        png = screenshot(url, out)
        print(f"{out}: {len(png)} bytes")
    finally:
        kill_processes(rerun_processes(port))
        display.close()
        state.cleanup()


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "screenshot.png")

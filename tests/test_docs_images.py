"""The docs' pictures: every image ``docs/make_screenshot.py`` makes exists in ``docs/images`` as a non-empty PNG
(the viewer's tabs at the default window size), and every image the how-tos link exists."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _script():
    spec = importlib.util.spec_from_file_location("make_screenshot", ROOT / "docs" / "make_screenshot.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == PNG_MAGIC
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


@pytest.mark.parametrize("name", _script().ALL_IMAGES)
def test_every_image_the_script_makes_is_in_the_docs(name):
    data = (ROOT / "docs" / "images" / name).read_bytes()
    w, h = png_size(data)
    assert len(data) > 20_000 and w >= 800 and h >= 600, (name, len(data), w, h)
    if name in _script().VIEWER_SHOTS:
        assert (w, h) == (1600, 1000)


def test_the_viewer_shots_cover_every_tab():
    shots = _script().VIEWER_SHOTS
    rights = {r for r, _ in shots.values()}
    lefts = {left for _, left in shots.values()}
    assert rights == {"Attitude", "Flight control"} and lefts == {"Link health", "Firmware log"}


@pytest.mark.parametrize("page", sorted((ROOT / "docs" / "howto").glob("*.md")), ids=lambda p: p.name)
def test_howto_images_exist(page):
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", page.read_text(encoding="utf-8")):
        assert (page.parent / link).is_file(), link

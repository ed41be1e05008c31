"""``steval estimator check`` scores the bundled captures only, never the user's own recordings in the same folder
(issue #31)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from steval_link.analysis import estimator_check
from steval_link.link.capture import demo_capture_path

ROOT = Path(__file__).resolve().parents[1]


def test_the_bundled_list_is_what_make_recordings_makes():
    script = (ROOT / "recordings" / "make_recordings.sh").read_text()
    made = set(re.findall(r"([A-Za-z0-9_]+\.stv)", script))
    assert set(estimator_check.BUNDLED_CAPTURES) == made
    assert [p.name for p in estimator_check.bundled_captures()] == [
        n for n in estimator_check.BUNDLED_CAPTURES if (ROOT / "recordings" / n).is_file()
    ]


def test_a_users_own_recording_is_not_bundled(tmp_path, monkeypatch):
    shutil.copy(demo_capture_path(), tmp_path / "demo.stv")
    shutil.copy(demo_capture_path(), tmp_path / "steval-20261126T051500Z.stv")  # what steval live writes there
    monkeypatch.setattr(estimator_check, "demo_capture_path", lambda: tmp_path / "demo.stv")
    assert [p.name for p in estimator_check.bundled_captures()] == ["demo.stv"]

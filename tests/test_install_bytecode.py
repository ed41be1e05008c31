"""An in-place build (what ``pip install -e .`` runs) byte-compiles every source of the packages, so that a Python
that writes no bytecode (``PYTHONDONTWRITEBYTECODE``) starts ``steval`` without compiling them."""

from __future__ import annotations

import importlib.util
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _stale_or_missing(source: Path) -> bool:
    """True unless the cached bytecode of ``source`` is the one Python would load (same mtime and size)."""
    cached = Path(importlib.util.cache_from_source(str(source)))
    if not cached.is_file():
        return True
    head = cached.read_bytes()[:16]
    if head[:4] != importlib.util.MAGIC_NUMBER:
        return True
    flags, mtime, size = struct.unpack("<III", head[4:16])
    st = source.stat()
    return flags != 0 or mtime != int(st.st_mtime) & 0xFFFFFFFF or size != st.st_size & 0xFFFFFFFF


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_an_in_place_build_byte_compiles_the_packages(tmp_path):
    # a copy of the project without bytecode (the build also rebuilds the C extensions there, not under other tests)
    skip = shutil.ignore_patterns("__pycache__", "*.so", "*.pyd", "*.stv")
    for folder in ("steval_link", "viewer", "recordings"):
        shutil.copytree(ROOT / folder, tmp_path / folder, ignore=skip)
    for name in ("setup.py", "pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, tmp_path / name)
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "SOURCE_DATE_EPOCH": "1700000000"}  # (still timestamps)
    r = subprocess.run(
        [sys.executable, "setup.py", "-q", "build_ext", "--inplace"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    sources = [p for folder in ("steval_link", "viewer") for p in sorted((tmp_path / folder).rglob("*.py"))]
    assert len(sources) > 50
    assert [str(p.relative_to(tmp_path)) for p in sources if _stale_or_missing(p)] == []

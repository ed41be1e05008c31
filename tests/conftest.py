"""Shared fixtures: the ``../shared`` data directory and stream builders (helpers live in ``tests/support``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support.streams import StreamBuilder

SHARED_DIR = Path(__file__).resolve().parents[1] / ".." / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` next to the project (lab docs, conformance vectors, datasets); skips the test when absent."""
    if not SHARED_DIR.is_dir():
        pytest.skip("../shared is not available (fresh clone without the shared data)")
    return SHARED_DIR.resolve()




@pytest.fixture(scope="session")
def reference_elf(tmp_path_factory) -> Path:
    """The reference firmware's default build (``make -C firmware_patch reference``), once per test session; skips
    when it cannot be built here (in CI the build fails instead: tests/support/firmware.py)."""
    from support import firmware as S

    why = S.missing()
    if why:
        pytest.skip(why)
    return S.build_reference(tmp_path_factory.mktemp("reference"))


@pytest.fixture
def stream() -> StreamBuilder:
    """A fresh :class:`StreamBuilder` (deterministic values)."""
    return StreamBuilder(seed=1)


@pytest.fixture
def make_stream():
    """Factory of :class:`StreamBuilder` with a given seed."""
    return StreamBuilder







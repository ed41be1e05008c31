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




@pytest.fixture
def stream() -> StreamBuilder:
    """A fresh :class:`StreamBuilder` (deterministic values)."""
    return StreamBuilder(seed=1)


@pytest.fixture
def make_stream():
    """Factory of :class:`StreamBuilder` with a given seed."""
    return StreamBuilder







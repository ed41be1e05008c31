"""Shared fixtures: the ``../shared`` data directory and stream builders (helpers live in ``tests/support``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support.streams import StreamBuilder

SHARED_DIR = Path(__file__).resolve().parents[1] / ".." / "shared"


def pytest_addoption(parser):
    parser.addoption(
        "--runslow",
        action="store_true",
        default=False,
        help="also run the tests marked slow (real viewers, emulated firmware, pseudo-terminals); CI does",
    )


def pytest_collection_modifyitems(config, items):
    """Without ``--runslow`` the tests marked ``slow`` are deselected: ``python -m pytest`` is the quick suite."""
    if config.getoption("--runslow"):
        return
    slow = [item for item in items if item.get_closest_marker("slow") is not None]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if item.get_closest_marker("slow") is None]


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` next to the project (lab docs, conformance vectors, datasets); skips the test when absent."""
    if not SHARED_DIR.is_dir():
        pytest.skip("../shared is not available (fresh clone without the shared data)")
    return SHARED_DIR.resolve()


@pytest.fixture(scope="session", autouse=True)
def _click_tree_built_once():
    """In-process ``steval`` runs (``main()``) build the CLI's click command tree once per session, not once per run."""
    import typer.main
    from support.cli import cached_get_command

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(typer.main, "get_command", cached_get_command(typer.main.get_command))
        yield


@pytest.fixture(scope="session")
def host_build(tmp_path_factory) -> Path:
    """Our host C programs (``stv_encode``, ``test_stv``) built once per test session; their folder."""
    import shutil
    import subprocess

    if shutil.which("make") is None or shutil.which("gcc") is None:
        pytest.skip("needs make and gcc for the host build")
    build = tmp_path_factory.mktemp("fw-host")
    subprocess.run(
        [
            "make",
            "-s",
            "-C",
            str(Path(__file__).resolve().parents[1] / "firmware_patch"),
            f"BUILD_DIR={build}",
            f"{build}/host/stv_encode",
            f"{build}/host/test_stv",
        ],
        check=True,
        capture_output=True,
    )
    return build / "host"


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

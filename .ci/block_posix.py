"""pytest plugin for CI (``-p block_posix`` with ``.ci`` on PYTHONPATH): the test suite as Windows sees it.

``import pty`` (and ``tty``, ``termios``, ``fcntl``, ``resource``) raises ImportError when the importing module is
one of the suite's own (a test module, ``conftest``, ``tests/support``), directly or through
``pytest.importorskip``; libraries keep theirs (pyserial imports ``termios`` on POSIX and ``serialwin32`` on
Windows, so blocking it for them would test nothing real). ``.ci/run`` collects the suite this way: every module
must collect, the POSIX-only ones skipping with a reason.
"""

from __future__ import annotations

import builtins
import importlib
import sys
from pathlib import Path

#: the modules Windows does not have
BLOCKED = frozenset({"pty", "tty", "termios", "fcntl", "resource"})
TESTS = Path(__file__).resolve().parents[1] / "tests"

_import = builtins.__import__


def _ours(globals_) -> bool:
    """Whether a module's globals are those of a module under tests/."""
    file = (globals_ or {}).get("__file__")
    try:
        return bool(file) and Path(file).resolve().is_relative_to(TESTS)
    except (OSError, ValueError):
        return False


def _missing(name: str) -> ModuleNotFoundError:
    return ModuleNotFoundError(f"No module named {name!r} (blocked by .ci/block_posix.py, as on Windows)", name=name)


def _blocked_import(name, globals=None, locals=None, fromlist=(), level=0):
    if level == 0 and name.split(".")[0] in BLOCKED:
        importer = globals or {}
        if _ours(importer):
            raise _missing(name)
    return _import(name, globals, locals, fromlist, level)


_import_module = importlib.import_module


def _blocked_import_module(name, package=None):
    """``importlib.import_module``, which ``pytest.importorskip`` uses: blocked when a module of ours asked."""
    if name.split(".")[0] in BLOCKED:
        caller = sys._getframe(1).f_globals
        if caller.get("__name__") == "_pytest.outcomes":
            caller = sys._getframe(2).f_globals
        if _ours(caller):
            raise _missing(name)
    return _import_module(name, package)


builtins.__import__ = _blocked_import
importlib.import_module = _blocked_import_module

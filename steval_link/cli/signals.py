"""SIGTERM and SIGHUP end a command the way Ctrl-C does, so its cleanup runs (a ``--serve`` web viewer stopped,
no half-written ``.rrd`` left behind) instead of the process dying mid-write."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

#: the signals turned into KeyboardInterrupt (those that exist on this platform)
SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


def _interrupt(signum, _frame) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


@contextlib.contextmanager
def signals_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise KeyboardInterrupt in the main thread; the old handlers come back
    afterwards. A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {}
    for sig in SIGNALS:
        try:
            old[sig] = signal.signal(sig, _interrupt)
        except (ValueError, OSError):  # pragma: no cover - a signal this platform will not hand over
            pass
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)

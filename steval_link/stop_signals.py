"""The stop signals (Ctrl-C, SIGTERM, SIGHUP) in one place: a command ends the way Ctrl-C ends it, so its cleanup
runs (a ``--serve`` viewer stopped, no half-written ``.rrd``), and a live session stops at its next round."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator

#: the stop signals, by name (those this platform has are used)
STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


def interrupt(signum: int) -> None:
    """A handler for :func:`on_stop_signals`: the signal raises KeyboardInterrupt, as Ctrl-C does."""
    raise KeyboardInterrupt(signal.Signals(signum).name)


@contextlib.contextmanager
def on_stop_signals(handler: Callable[[int], None], *, sigint: bool = True) -> Iterator[None]:
    """Within the block, each stop signal calls ``handler(signum)`` (``sigint`` False: Ctrl-C keeps its own
    handler). The old handlers come back afterwards. A no-op outside the main thread, where signals cannot be set."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    names = STOP_SIGNALS if sigint else STOP_SIGNALS[1:]
    old = {}
    for sig in (getattr(signal, name) for name in names if hasattr(signal, name)):
        with contextlib.suppress(ValueError, OSError):  # a signal this platform will not hand over
            old[sig] = signal.signal(sig, lambda signum, _frame: handler(signum))
    try:
        yield
    finally:
        for sig, previous in old.items():
            with contextlib.suppress(ValueError, OSError):
                signal.signal(sig, previous)

"""The one progress bar of the ``steval`` commands: rich, on stderr, only when stderr is a terminal. Library
functions take a callback ``progress(fraction 0..1, stage)`` and never print; :func:`progress_bar` draws it."""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

#: progress(fraction done 0..1, stage) — what library functions call; the stage is a few words
Progress = Callable[[float, str], None]

#: A job that ends earlier shows no bar at all (no flicker on short captures).
SHOW_AFTER_S = 0.5


def scaled(progress: Progress, start: float, end: float) -> Progress:
    """``progress`` for one part of a job: its 0..1 maps to ``start``..``end`` of the whole."""
    return lambda fraction, stage="": progress(start + (end - start) * min(max(fraction, 0.0), 1.0), stage)


@contextmanager
def progress_bar(description: str, *, quiet: bool = False) -> Iterator[Progress]:
    """A progress callback drawing a bar on stderr while the block runs (a no-op when ``quiet`` or not a tty)."""
    stream = sys.stderr
    if quiet or not getattr(stream, "isatty", lambda: False)():
        yield lambda fraction, stage="": None
        return
    from rich.console import Console
    from rich.progress import BarColumn, SpinnerColumn, TaskProgressColumn, TextColumn, TimeElapsedColumn
    from rich.progress import Progress as RichProgress

    bar = RichProgress(
        SpinnerColumn(),
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[stage]}"),
        console=Console(file=stream),
        transient=True,
        # what the command prints meanwhile goes above the bar (stdout only when it is this terminal too)
        redirect_stdout=sys.stdout.isatty(),
        redirect_stderr=True,
    )
    task = bar.add_task(description, total=1.0, stage="")
    lock, done = threading.Lock(), threading.Event()

    def show() -> None:  # after SHOW_AFTER_S, whether or not the job reported meanwhile
        with lock:
            if not done.is_set():
                bar.start()

    def update(fraction: float, stage: str = "") -> None:
        bar.update(task, completed=min(max(float(fraction), 0.0), 1.0), stage=stage)

    timer = threading.Timer(SHOW_AFTER_S, show)
    timer.daemon = True
    timer.start()
    try:
        yield update
    finally:
        timer.cancel()
        with lock:
            done.set()
            bar.stop()  # nothing when it never started

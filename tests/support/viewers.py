"""A live viewer that drops everything (the interface :class:`steval_link.live.pipeline.LiveViewer`): a test
subclasses it and keeps only what it checks."""

from __future__ import annotations


class NullViewer:
    def log_batch(self, batch) -> None:
        pass

    def log_status(self, frame, at) -> None:
        pass

    def log_text(self, frame, at) -> None:
        pass

    def log_link(self, stats, t_unix_s) -> None:
        pass

    def log_event(self, text, at, level) -> None:
        pass

    def close(self) -> None:
        pass

"""The Rerun side of a live session (:class:`ViewerLogger`): the sinks a session chose and the loggers that write
to them; the session knows it only through the :class:`steval_link.live.pipeline.LiveViewer` protocol."""

from __future__ import annotations

import contextlib
import functools
from pathlib import Path

from steval_link.link.ble_payloads import ble_items, layout_named
from steval_link.live.pipeline import RRD_ONLY_INTERVAL_S, LivePipeline
from steval_link.live.session import LiveOptions


class ViewerLogger:
    """The sinks of ``options`` and a LiveLogger on the main stream (the viewer's, else the ``.rrd``'s). With a
    viewer *and* an ``.rrd`` the file has its own stream and logger, ``file``, fed merged batches."""

    def __init__(self, options: LiveOptions, recording_name: str | None = None) -> None:
        from steval_viewer import live_log, sinks  # Rerun loads only when a session uses it (start-up time)

        self.session = sinks.open_session(options.sinks, recording_name=recording_name, split_file=True, checked=True)
        #: whether a viewer gets the stream (else only the ``.rrd``: merged batches, few chunks)
        self.has_viewer = self.session.viewer_url is not None
        ble = getattr(options, "link_kind", None) == "ble"  # a BLE link: its layout from the start
        logger = functools.partial(live_log.LiveLogger, estimator_names=options.estimators, ble=ble)
        self.logger = logger(self.session.rec)
        self.file = None if self.session.file_rec is None else logger(self.session.file_rec)

    @property
    def output_failure(self) -> str | None:
        """Why the ``.rrd`` stopped being written, one sentence (the session says it: closing does not raise it)."""
        failure = self.session.rrd_failure
        self.session.rrd_failure_said |= failure is not None
        return failure

    def __getattr__(self, name: str):
        """``log_batch``, ``log_status``, ``log_text``, ``log_flight``, ``log_event``: the main stream's logger's."""
        if name == "logger":  # not made yet (a failure in __init__)
            raise AttributeError(name)
        return getattr(self.logger, name)

    def log_link(self, stats, t_unix_s: float) -> None:
        self.logger.log_link(stats, t_unix_s)
        if self.file is not None:
            self.file.log_link(stats, t_unix_s)

    def close(self) -> None:
        with contextlib.ExitStack() as stack:  # each closes even when the one before raised
            stack.callback(self.session.close)
            if self.file is not None:
                stack.callback(self.file.close)
            self.logger.close()


#: notifications fed to the pipeline at a time by :func:`recording_sink`
REPLAY_BATCH = 4096


def recording_sink(options, estimators: list[str], src, *, layout: str = "stock", progress=None) -> int:
    """``steval replay`` of a BLE capture ``src`` in Rerun, through the one pipeline and logger; the rows logged."""
    from steval_viewer import live_log, sinks  # Rerun loads only for a viewer or an .rrd (start-up time)

    items = ble_items(src.chunks or {}, getattr(src, "events", None) or [])

    def log(rec) -> int:
        logger = live_log.LiveLogger(rec, estimator_names=estimators, live=False, ble=True)
        timing = dict(view_interval_s=RRD_ONLY_INTERVAL_S, t0_unix_s=0.0, baud=0)
        pipe = LivePipeline(estimators, logger, **timing, ble_layout=layout_named(layout))
        for i in range(0, len(items), REPLAY_BATCH):
            pipe.feed_ble(items[i : i + REPLAY_BATCH], final=i + REPLAY_BATCH >= len(items))
            if progress is not None:
                progress(min(1.0, (i + REPLAY_BATCH) / max(len(items), 1)), "logging to Rerun")
        pipe.flush_view()
        logger.close()
        return logger.frames

    return sinks.log_whole(options, f"steval replay {Path(str(src.path)).name}", log)

"""The Rerun side of a live session (:class:`ViewerLogger`): the sinks a session chose and the loggers that write
to them; the session knows it only through the :class:`steval_link.live.pipeline.LiveViewer` protocol.
"""

from __future__ import annotations

from steval_link.live.session import LiveOptions


class ViewerLogger:
    """The Rerun side of a live session: the sinks of ``options`` and a :class:`steval_viewer.live_log.LiveLogger`.

    ``log_batch``/``log_status``/``log_text`` go to the session's main stream (the viewer's; the ``.rrd``'s when
    there is no viewer). With a viewer *and* ``--rrd`` the file has its own stream of the same recording and its
    own logger, ``file`` (else None), which the pipeline feeds merged batches every RRD_ONLY_INTERVAL_S (written as
    they come: ``steval_viewer.rrd_writer``); ``log_link`` goes to both; ``close`` flushes and closes both.
    ``output_failure``: one sentence once the ``.rrd`` could not be written (the session says it and exits non-zero).

    Imported only when a viewer or an ``.rrd`` is asked for (``--no-view`` without ``--rrd``: no Rerun at all).
    """

    def __init__(self, options: LiveOptions, recording_name: str | None = None) -> None:
        """``options.sinks``: the sinks the CLI built and checked (``steval_viewer.sink_options.session_sinks``)."""
        from steval_viewer import live_log, sinks  # Rerun loads only when a session uses it (start-up time)

        self.session = sinks.open_session(options.sinks, recording_name=recording_name, split_file=True, checked=True)
        self.logger = live_log.LiveLogger(self.session.rec, estimator_names=options.estimators)
        self.file: live_log.LiveLogger | None = None
        if self.session.file_rec is not None:
            self.file = live_log.LiveLogger(self.session.file_rec, estimator_names=options.estimators)

    @property
    def has_viewer(self) -> bool:
        """Whether a viewer gets the stream (else only the ``.rrd``: merged batches, few chunks)."""
        return self.session.has_viewer

    @property
    def output_failure(self) -> str | None:
        """Why the ``.rrd`` stopped being written (disk full, deleted), one sentence; None while it is fine (read by
        the session, which says it: closing does not raise it again)."""
        failure = self.session.rrd_failure
        if failure is not None:
            self.session.rrd_failure_said = True
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
        """Send what the loggers hold and finish both streams (the ``.rrd`` is complete afterwards)."""
        try:
            try:
                self.logger.close()
            finally:
                if self.file is not None:
                    self.file.close()
        finally:
            self.session.close()


def make_viewer_logger(options: LiveOptions, recording_name: str | None = None) -> ViewerLogger:
    """The Rerun side of a live session (see :class:`ViewerLogger`)."""
    return ViewerLogger(options, recording_name)

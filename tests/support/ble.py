"""A live BLE session over the fake backend, run until the fake has played every notification."""

from __future__ import annotations

import threading
import time


def run_until_played(session, fake):
    """``session.run()`` of a ``LiveSession`` over a BLE source and ``fake`` (a ``FakeBleBackend``), stopped
    ("test") once the fake has sent its last notification; returns the session's summary."""

    def stopper():
        while fake.finished is None or not fake.finished.is_set():
            time.sleep(0.01)
        session.request_stop("test")

    threading.Thread(target=stopper, daemon=True).start()
    return session.run()


class RecordingViewer:
    """A live session's logger (the ``LiveViewer`` protocol, whatever the link) that keeps what it is given: the
    row batches (``LiveRows``), the BLE environment and arming frames with their times, the notes, and whether it
    was closed."""

    has_viewer = True

    def __init__(self) -> None:
        self.batches, self.env, self.arming, self.notes, self.texts = [], [], [], [], []
        self.closed = False

    def log_batch(self, batch) -> None:
        self.batches.append(batch)

    def log_environment(self, frame, at) -> None:
        self.env.append((frame, at))

    def log_arming(self, frame, at) -> None:
        self.arming.append((frame, at))

    def log_note(self, text, at) -> None:
        self.notes.append(text)

    def log_text(self, frame, at) -> None:
        self.texts.append(frame)

    def log_status(self, frame, at) -> None:
        pass

    def log_event(self, text, at, level="INFO") -> None:
        pass

    def log_link(self, stats, t_unix_s) -> None:
        pass

    def close(self) -> None:
        self.closed = True


def telemetry_of_records(records, events=()):
    """The one model (``Telemetry``, its ``link`` the BLE facts) of notifications ``(t_host_s, char id, payload)``,
    as a capture holding them loads (``events``: the capture's, e.g. ``reconnect``)."""
    from pathlib import Path

    import numpy as np

    from steval_link.link.ble_payloads import ble_chunk
    from steval_link.link.capture import CHUNK_BLE
    from steval_link.link.load import Recording, telemetry_of_recording

    none = np.zeros(0, np.int64)
    chunks = {CHUNK_BLE: [(t, ble_chunk(c, p)) for t, c, p in records]}
    src = Recording(Path("notifications.stv"), {"extra": {"link": "ble"}}, b"", none, none.astype(float), list(events))
    src.chunks = chunks
    return telemetry_of_recording(src)


def held_rows(tel):
    """(N,) bool over the rows: True for a row that holds the last sample over a notification sent and lost."""
    import numpy as np

    held = np.ones(len(tel.attitude), bool)
    held[tel.link.samples["row"]] = False
    return held

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

"""A live BLE session over the fake backend, run until the fake has played every notification."""

from __future__ import annotations

import asyncio


def run_until_played(session, fake):
    """``session.run()`` of a ``BleLiveSession`` over ``fake`` (a ``FakeBleBackend``), stopped ("test") once the fake
    has sent its last notification; returns the session's summary."""

    async def stopper():
        while fake.finished is None or not fake.finished.is_set():
            await asyncio.sleep(0.01)
        session.request_stop("test")

    orig_main = session._main

    async def main_with_stop(*a):
        await asyncio.gather(orig_main(*a), stopper())

    session._main = main_with_stop
    return session.run()

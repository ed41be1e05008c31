"""``steval live --ble``: an unmodified drone over Bluetooth: scan, connect, record, estimate, view, reconnect.

The same order as the serial session: every notification goes to the capture first (a ``B`` chunk with its arrival
time), then to a bounded inbox; the session's loop (10 Hz) decodes the inbox, runs the live estimators on the motion
samples (one row per sender sample at the firmware's AHRS step period, a dropped notification's row holding the
last sample: dt from the ticks, as :func:`steval_link.link.ble_payloads.uniform_inputs` does for a replay), hands
the rows to the viewer (:class:`BleViewer`) and shows a health line. The link (:class:`~steval_link.link.
ble_transport.BleLink`) reconnects on loss; each loss and reconnection is a capture event. Ctrl-C / SIGTERM /
SIGHUP / ``--duration`` stop it; the capture is closed whole.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TextIO

import numpy as np

from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.link.ble_payloads import (
    CHAR_ARMING,
    CHAR_ENV,
    CHAR_MOTION,
    DEVICE_NAME_PREFIX,
    STEP_PERIOD_S,
    TICK_S,
    BleTelemetry,
    TickUnwrapper,
    ble_chunk,
    decode_notifications,
)
from steval_link.link.ble_transport import BleBackend, BleLink
from steval_link.link.capture import CHUNK_BLE, CaptureWriter, default_capture_path
from steval_link.live.estimators import failure_sentence
from steval_link.live.health import HealthDisplay
from steval_link.live.session import LiveOptions, install_stop_signals, restore_signals
from steval_link.quat import euler_from_quaternion

__all__ = ["BleViewer", "BleRows", "BleLiveSummary", "BleLiveSession", "INBOX_MAX"]

#: notifications held between two rounds at most (10 s of the three characteristics); older ones are dropped from
#: the live view only (the capture has them all)
INBOX_MAX = 5000
ROUND_S = 0.1


@dataclass
class BleRows:
    """One round of decoded notifications for the viewer: ``ble`` (ticks unwrapped over the session, ``t_host_s`` s
    since the capture started) and the estimators' rows (``t_s`` drone time, name → (N, 4) q_wxyz, thx, thy)."""

    ble: BleTelemetry
    t_s: np.ndarray
    estimates: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]


class BleViewer(Protocol):
    def log_rows(self, rows: BleRows) -> None: ...

    def close(self) -> None: ...


@dataclass
class BleLiveSummary:
    capture_path: Path
    seconds: float
    counts: dict[str, int]
    rows_held: int
    connections: int
    losses: int
    stopped_by: str
    capture_discarded: bool = False

    def line(self) -> str:
        c = self.counts
        where = "no capture (nothing received)" if self.capture_discarded else f"capture {self.capture_path}"
        return (f"steval: {self.seconds:.1f} s over BLE: {c.get('motion', 0)} motion, {c.get('environment', 0)} "
                f"environment, {c.get('arming', 0)} arming notifications; {self.rows_held} motion samples missing "
                f"(held); {self.connections} connection(s), {self.losses} lost; stopped: {self.stopped_by}; {where}")


class BleLiveSession:
    """See the module docstring. ``backend``: a ``link.ble_transport.BleBackend`` (bleak, or a fake in tests)."""

    def __init__(self, options: LiveOptions, *, target: str | None, backend: BleBackend,
                 viewer_factory: Callable[[LiveOptions, str], BleViewer] | None = None,
                 clock: Callable[[], float] = time.time, stream: TextIO | None = None,
                 scan_timeout_s: float = 5.0) -> None:
        self.options = options
        self.target = target
        self.backend = backend
        self.viewer_factory = viewer_factory
        self.clock = clock
        self.display = HealthDisplay(stream if stream is not None else sys.stderr)
        self.scan_timeout_s = scan_timeout_s
        self._stop_reason: str | None = None
        self._inbox: deque[tuple[int, bytes, float]] = deque(maxlen=INBOX_MAX)
        self._unwrap = TickUnwrapper()
        self._last_k: int | None = None  # the last sender sample number given to the estimators
        self._last_sample: tuple[np.ndarray, np.ndarray] | None = None
        self._t0_tick_s: float | None = None
        self.rows_held = 0
        self.counts: dict[str, int] = {}

    # -- stop requests (signals, --duration)
    @property
    def stop_requested(self) -> bool:
        return self._stop_reason is not None

    def request_stop(self, reason: str) -> None:
        if self._stop_reason is None:
            self._stop_reason = reason

    def run(self) -> BleLiveSummary:
        path = self.options.out or default_capture_path(self.options.recordings_dir)
        if not path.parent.is_dir():
            path.parent.mkdir(parents=True, exist_ok=True)
        what = self.target or f"{DEVICE_NAME_PREFIX}*"
        capture = CaptureWriter(path, port=f"ble:{what}", baud=0, extra={"link": "ble", "target": self.target},
                                discard_empty=True)
        self._start_unix = self.clock() - capture.now()
        self._capture = capture
        viewer = None
        old = install_stop_signals(self)
        started = time.monotonic()
        link = BleLink(self.backend, self.target, self._on_notification, on_event=self._event(capture),
                       clock=self.clock, scan_timeout_s=self.scan_timeout_s)
        try:
            if self.viewer_factory is not None and self.options.uses_rerun:
                viewer = self.viewer_factory(self.options, f"steval live --ble {what}")
            self.estimators = {n: registry.create(n, dt_s=STEP_PERIOD_S) if n in ("st-mahony", "st_mahony")
                               else registry.create(n, rate_hz=1.0 / STEP_PERIOD_S)
                               if n != "accel" and registry.accepts(n, "rate_hz")
                               else registry.create(n) for n in self.options.estimators}
            asyncio.run(self._main(link, viewer, started))
        finally:
            restore_signals(old)
            try:
                capture.mark_event("stop", self._stop_reason or "end")
            except Exception:  # noqa: BLE001 - the notifications are written already
                pass
            capture.close()
            if viewer is not None:
                try:
                    viewer.close()
                except UserError as exc:
                    self.display.note(f"viewer: {exc}")
            self.display.close()
        return BleLiveSummary(path, time.monotonic() - started, dict(self.counts), self.rows_held,
                              link.connections, link.losses, self._stop_reason or "end", capture.discarded)

    # -- the link's callbacks (the event loop's thread)
    def _on_notification(self, cid: int, data: bytes, t_unix: float) -> None:
        t = t_unix - self._start_unix
        self._capture.write_chunk(CHUNK_BLE, ble_chunk(cid, data), t)
        self._inbox.append((cid, data, t))

    def _event(self, capture: CaptureWriter):
        def on_event(kind: str, text: str) -> None:
            capture.mark_event(kind, text)
            if kind == "connect":
                self.display.note(f"connected to {text} over BLE")
            elif kind == "disconnect":
                self.display.note("BLE link lost; reconnecting (Ctrl-C stops)")
            elif kind == "reconnect":
                self.display.note(f"reconnected to {text}")
            else:
                self.display.note(f"{kind}: {text}")
        return on_event

    async def _main(self, link: BleLink, viewer: BleViewer | None, started: float) -> None:
        stop = asyncio.Event()
        task = asyncio.ensure_future(link.run(stop))
        try:
            while not task.done():
                await asyncio.wait({task}, timeout=ROUND_S)
                d = self.options.duration_s
                if d is not None and time.monotonic() - started >= d:
                    self.request_stop("duration")
                if self.stop_requested:
                    stop.set()
                self._round(viewer)
            task.result()  # a UserError of the link (no adapter, drone not found...) ends the session here
            self._round(viewer)
        finally:
            if not task.done():
                task.cancel()

    def _round(self, viewer: BleViewer | None) -> None:
        if not self._inbox:
            if self.counts:
                self.display.show(self._health(), time.monotonic())
            return
        items = list(self._inbox)
        self._inbox.clear()
        ble = decode_notifications([(t, cid, data) for cid, data, t in items])
        for k, v in ble.counts.items():
            self.counts[k] = self.counts.get(k, 0) + v
        # one clock over the session: every tick of this round unwrapped in arrival order by the session's unwrapper
        sizes = {CHAR_MOTION: 20, CHAR_ENV: 12, CHAR_ARMING: 3}
        ticks: dict[int, list[int]] = {c: [] for c in sizes}
        for cid, data, _ in items:
            if sizes.get(cid) == len(data):
                ticks[cid].append(self._unwrap(data[0] | data[1] << 8))
        ble.motion_tick = np.asarray(ticks[CHAR_MOTION], dtype=np.int64)
        ble.motion_t_fw_s = ble.motion_tick * TICK_S
        ble.env_t_fw_s = np.asarray(ticks[CHAR_ENV], dtype=np.float64) * TICK_S
        ble.arming_t_fw_s = np.asarray(ticks[CHAR_ARMING], dtype=np.float64) * TICK_S
        t_s, acc, gyro = self._grid(ble)
        estimates = {}
        thr = 0
        for name, est in list(self.estimators.items()):
            try:
                q = np.array([est.step(a, g, thr) for a, g in zip(acc, gyro)], dtype=np.float64).reshape(-1, 4)
            except Exception as exc:  # noqa: BLE001 - a failing estimator is switched off; the session goes on
                self.display.note(f"{failure_sentence(name, exc)}; {name} disabled, recording and viewing go on")
                del self.estimators[name]
                continue
            thx, thy, _ = euler_from_quaternion(q) if len(q) else (np.zeros(0), np.zeros(0), None)
            estimates[name] = (q, thx, thy)
        if viewer is not None:
            viewer.log_rows(BleRows(ble, t_s, estimates))
        self.display.show(self._health(), time.monotonic())

    def _grid(self, ble: BleTelemetry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The estimators' rows of this round: one per sender sample since the last round's (rows of dropped
        notifications hold the last sample)."""
        if self._t0_tick_s is None and len(ble):
            self._t0_tick_s = float(ble.motion_t_fw_s[0])
        t_rows, acc_rows, gyro_rows = [], [], []
        for t, a, g in zip(ble.motion_t_fw_s, ble.acc_mg, ble.gyro_mdps):
            k = int(round((t + TICK_S / 2 - self._t0_tick_s) / STEP_PERIOD_S))
            if self._last_k is None:
                self._last_k = k - 1
            missing = k - self._last_k - 1
            if missing >= 2 and self._last_sample is not None:  # beyond the tick's blur: samples were dropped
                la, lg = self._last_sample
                for _ in range(missing):
                    self._last_k += 1
                    t_rows.append(self._t0_tick_s + self._last_k * STEP_PERIOD_S)
                    acc_rows.append(la)
                    gyro_rows.append(lg)
                self.rows_held += missing
            self._last_k += 1
            t_rows.append(self._t0_tick_s + self._last_k * STEP_PERIOD_S)
            acc_rows.append(a)
            gyro_rows.append(g)
            self._last_sample = (a, g)
        return (np.asarray(t_rows, np.float64), np.asarray(acc_rows, np.float32).reshape(-1, 3),
                np.asarray(gyro_rows, np.float32).reshape(-1, 3))

    def _health(self) -> str:
        c = self.counts
        return (f"BLE {c.get('motion', 0)} motion / {c.get('environment', 0)} env / {c.get('arming', 0)} arming "
                f"notifications, {self.rows_held} motion samples missing")

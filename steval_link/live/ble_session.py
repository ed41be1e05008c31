"""``steval live --ble``: an unmodified drone over Bluetooth: scan, connect, record, estimate, view, reconnect.

The same order as the serial session: every notification goes to the capture first (a ``B`` chunk with its arrival
time), then to a bounded inbox; the session's loop (10 Hz) decodes the inbox, runs the live estimators on the motion
samples, hands the rows to the viewer (:class:`BleViewer`) and shows a health line. The motion stream's cadence is
found from the ticks of its first :data:`LOCK_SAMPLES` samples (:func:`steval_link.link.ble_payloads.
motion_cadence`; until then the rounds are held back, not shown), which fixes the estimators' dt: one row per sender
sample, a row held over a notification only when the ticks show it was sent and lost (a gap of that cadence, or ST's
congestion skips), as :func:`steval_link.link.ble_payloads.uniform_inputs` does for a replay; a sample read twice
(a poller) is one sample. The health line says which case it is. The link (:class:`~steval_link.link.
ble_transport.BleLink`) reconnects on loss; each loss and reconnection is a capture event. Ctrl-C / SIGTERM /
SIGHUP / ``--duration`` stop it; the capture is closed whole.
"""

from __future__ import annotations

import asyncio
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol, TextIO

import numpy as np

from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.link.ble_cadence import (
    CONGESTION,
    GAPS,
    POLLED,
    STEADY,
    STEP_PERIOD_S,
    Cadence,
    RunNumberer,
    gap_mask,
    motion_cadence,
)
from steval_link.link.ble_cadence import sender_phase as _phase
from steval_link.link.ble_payloads import (
    CHAR_ARMING,
    CHAR_ENV,
    CHAR_MOTION,
    CHAR_NAMES,
    DEVICE_NAME_PREFIX,
    TICK_S,
    TickUnwrapper,
    ble_chunk,
)
from steval_link.link.ble_telemetry import BleTelemetry, decode_notifications
from steval_link.link.ble_transport import BleBackend, BleLink
from steval_link.link.capture import CHUNK_BLE, CaptureWriter, default_capture_path
from steval_link.live.estimators import failure_sentence
from steval_link.live.health import HealthDisplay
from steval_link.live.session import LiveOptions, install_stop_signals, restore_signals
from steval_link.quat import euler_from_quaternion

__all__ = ["BleViewer", "BleRows", "BleLiveSummary", "BleLiveSession", "INBOX_MAX", "LOCK_SAMPLES"]

#: notifications held between two rounds at most (10 s of the three characteristics); older ones are dropped from
#: the live view only (the capture has them all)
INBOX_MAX = 5000
ROUND_S = 0.1
#: motion samples that fix the cadence (and the estimators' dt); fewer when 3 s of drone time pass or at the end
LOCK_SAMPLES = 64
LOCK_SPAN_S = 3.0
#: the inbox's marker of a reconnection (not a characteristic id)
RECONNECTED = -1
#: motion ticks kept for the health line's interval (its precision grows with the span)
TICKS_KEPT = 20_000


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
    cadence: Cadence | None = None  #: as the health line last said it (dropped = rows_held)

    def line(self) -> str:
        c = self.counts
        where = "no capture (nothing received)" if self.capture_discarded else f"capture {self.capture_path}"
        what = self.cadence.describe() if self.cadence is not None else "no motion cadence (too few samples)"
        return (
            f"steval: {self.seconds:.1f} s over BLE: {c.get('motion', 0)} motion, {c.get('environment', 0)} "
            f"environment, {c.get('arming', 0)} arming notifications; {what}; {self.connections} "
            f"connection(s), {self.losses} lost; stopped: {self.stopped_by}; {where}"
        )


class BleLiveSession:
    """See the module docstring. ``backend``: a ``link.ble_transport.BleBackend`` (bleak, or a fake in tests)."""

    def __init__(
        self,
        options: LiveOptions,
        *,
        target: str | None,
        backend: BleBackend,
        viewer_factory: Callable[[LiveOptions, str], BleViewer] | None = None,
        clock: Callable[[], float] = time.time,
        stream: TextIO | None = None,
        scan_timeout_s: float = 5.0,
    ) -> None:
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
        self._pending: list[tuple[int, bytes, float]] = []  # notifications before the cadence is found
        self._last_motion: bytes | None = None  # the last motion payload (a repeat of it is the same sample)
        self._cadence: Cadence | None = None  # found from the first samples: fixes dt and the numbering
        self._t0_s = 0.0  # the sender's phase (drone time of sample 0), s
        self._last_k: int | None = None  # the last sender sample number given to the estimators
        self._numberer: RunNumberer | None = None
        self._last_tick = 0
        self._last_sample: tuple[np.ndarray, np.ndarray] | None = None
        self._ticks: deque[int] = deque(maxlen=TICKS_KEPT)
        self._numbers: deque[int] = deque(maxlen=TICKS_KEPT)  # the sender's number of each tick kept
        self.estimators: dict = {}
        self.rows_held = 0
        self.gaps = 0
        self.repeats = 0
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
        capture = CaptureWriter(
            path, port=f"ble:{what}", baud=0, extra={"link": "ble", "target": self.target}, discard_empty=True
        )
        self._start_unix = self.clock() - capture.now()
        self._capture = capture
        viewer = None
        old = install_stop_signals(self)
        started = time.monotonic()
        link = BleLink(
            self.backend,
            self.target,
            self._on_notification,
            on_event=self._event(capture),
            clock=self.clock,
            scan_timeout_s=self.scan_timeout_s,
        )
        try:
            if self.viewer_factory is not None and self.options.uses_rerun:
                viewer = self.viewer_factory(self.options, f"steval live --ble {what}")
            self._make_estimators(STEP_PERIOD_S)  # the names checked now; made again with the cadence's dt
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
        return BleLiveSummary(
            path,
            time.monotonic() - started,
            dict(self.counts),
            self.rows_held,
            link.connections,
            link.losses,
            self._stop_reason or "end",
            capture.discarded,
            self.cadence(),
        )

    def _make_estimators(self, dt_s: float) -> None:
        self.estimators = {
            n: registry.create(n, dt_s=dt_s)
            if n in ("st-mahony", "st_mahony")
            else registry.create(n, rate_hz=1.0 / dt_s)
            if n != "accel" and registry.accepts(n, "rate_hz")
            else registry.create(n)
            for n in self.options.estimators
        }

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
                self._inbox.append((RECONNECTED, b"", 0.0))  # the next motion sample follows a lost link
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
            self._round(viewer, final=True)
        finally:
            if not task.done():
                task.cancel()

    def _round(self, viewer: BleViewer | None, final: bool = False) -> None:
        items = list(self._inbox)
        self._inbox.clear()
        for cid, data, t in items:
            if cid == RECONNECTED:
                self._pending.append((cid, data, t))
                continue
            name = CHAR_NAMES.get(cid)
            if name is not None:
                self.counts[name] = self.counts.get(name, 0) + 1
            if cid == CHAR_MOTION and len(data) == 20:
                if data == self._last_motion:  # the same sample read again: one sample
                    self.repeats += 1
                    continue
                self._last_motion = data
            self._pending.append((cid, data, t))
        if self._cadence is None and not self._ready(final):
            if self.counts:
                self.display.show(self._health(), time.monotonic())
            return
        items, self._pending = self._pending, []
        if items:
            self._process(items, viewer)
        if self.counts:
            self.display.show(self._health(), time.monotonic())

    def _ready(self, final: bool) -> bool:
        """Enough motion samples pending to find the cadence (or the session ends)."""
        ticks = [d[0] | d[1] << 8 for c, d, _ in self._pending if c == CHAR_MOTION and len(d) == 20]
        if final or len(ticks) >= LOCK_SAMPLES or len(self._pending) >= INBOX_MAX:  # (no motion: shown anyway)
            return True
        span = (ticks[-1] - ticks[0]) % (1 << 16) if len(ticks) > 1 else 0
        return len(ticks) >= 8 and span * TICK_S >= LOCK_SPAN_S

    def _process(self, items: list[tuple[int, bytes, float]], viewer: BleViewer | None) -> None:
        breaks, n_motion = [], 0
        for cid, data, _ in items:
            if cid == RECONNECTED:
                breaks.append(n_motion)
            elif cid == CHAR_MOTION and len(data) == 20:
                n_motion += 1
        items = [it for it in items if it[0] != RECONNECTED]
        ble = decode_notifications([(t, cid, data) for cid, data, t in items])
        ble.motion_breaks = np.unique(np.asarray(breaks, dtype=np.int64))
        # one clock over the session: every tick unwrapped in arrival order by the session's unwrapper
        sizes = {CHAR_MOTION: 20, CHAR_ENV: 12, CHAR_ARMING: 3}
        ticks: dict[int, list[int]] = {c: [] for c in sizes}
        for cid, data, _ in items:
            if sizes.get(cid) == len(data):
                ticks[cid].append(self._unwrap(data[0] | data[1] << 8))
        ble.motion_tick = np.asarray(ticks[CHAR_MOTION], dtype=np.int64)
        ble.motion_t_fw_s = ble.motion_tick * TICK_S
        ble.env_t_fw_s = np.asarray(ticks[CHAR_ENV], dtype=np.float64) * TICK_S
        ble.arming_t_fw_s = np.asarray(ticks[CHAR_ARMING], dtype=np.float64) * TICK_S
        if self._cadence is None and len(ble):
            self._lock(ble)
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

    def _lock(self, ble: BleTelemetry) -> None:
        """The cadence of the first samples fixes the estimators' dt and how samples are numbered."""
        c = motion_cadence(ble.motion_tick, self.repeats, ble.motion_breaks)
        if c is None:  # a single sample (or one tick) before the end: ST's step, as the stock firmware sends
            c = Cadence(STEADY, STEP_PERIOD_S, 0, 0, self.repeats, 0.0, True)
        self._cadence = c
        self._t0_s = _phase(ble.motion_t_fw_s, c.interval_s) if c.kind != POLLED else 0.0
        self._numberer = RunNumberer(c.interval_s / TICK_S)
        self._make_estimators(c.interval_s)

    def _grid(self, ble: BleTelemetry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The estimators' rows of this round: one per sender sample since the last round's; the rows of
        notifications the ticks show as sent and lost hold the last sample. The numbering is a replay's
        (:func:`steval_link.link.ble_payloads.cadence_numbers`), a round at a time: consecutive for reads, the
        ticks' phase at ST's step, the runs' phases for any other period (a run after a gap known as far as this
        round goes)."""
        c = self._cadence
        n = len(ble)
        if c is None or n == 0:
            return np.zeros(0), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
        dt = c.interval_s
        if not c.exact and c.kind != POLLED:  # the period measured so far (dt's precision grows with the span)
            dt = self._period_s()
            self._numberer.p = dt / TICK_S
        first = self._last_k is None
        if c.kind == POLLED:
            k = np.arange(n, dtype=np.int64) + (0 if first else self._last_k + 1)
        elif c.exact:  # ST's step, known exactly: the smallest numbering the ticks' phase allows
            lo = np.ceil((ble.motion_t_fw_s - self._t0_s) / dt - 1e-9).astype(np.int64)
            if first:
                lo[0] = 0
            prev = -1 if first else self._last_k
            j = np.arange(n)
            k = np.maximum.accumulate(np.maximum(lo, prev + 1 + j) - j) + j
        else:
            k = self._numberer.numbers(ble.motion_tick)
        self._ticks.extend(ble.motion_tick.tolist())
        self._numbers.extend(k.tolist())
        prev = k[0] - 1 if first else self._last_k
        grid = np.arange(prev + 1, k[-1] + 1)
        before = np.concatenate([[prev], k[:-1]])
        for b in ble.motion_breaks[ble.motion_breaks < n].tolist():
            grid = grid[(grid <= before[b]) | (grid >= k[b])]  # never sent: the link was down
        src = np.searchsorted(k, grid, side="right") - 1  # the last sample received at or before each row
        acc, gyro = np.asarray(ble.acc_mg, np.float32), np.asarray(ble.gyro_mdps, np.float32)
        acc_rows, gyro_rows = acc[np.maximum(src, 0)], gyro[np.maximum(src, 0)]
        if (src < 0).any():  # rows before this round's first sample: held from the last round's
            la, lg = self._last_sample
            acc_rows[src < 0], gyro_rows[src < 0] = la, lg
        self.rows_held += len(grid) - n
        if c.kind != POLLED:
            d = np.diff(ble.motion_tick, prepend=ble.motion_tick[0] if first else self._last_tick)
            gap = gap_mask(np.maximum(d, 0), dt / TICK_S)
            gap[ble.motion_breaks[ble.motion_breaks < n]] = False
            self.gaps += int(np.count_nonzero(gap))
        if c.kind == POLLED:
            t_rows = ble.motion_t_fw_s + TICK_S / 2
        else:
            t_rows = self._t0_s + grid * dt
        self._last_k, self._last_tick = int(k[-1]), int(ble.motion_tick[-1])
        self._last_sample = (acc[-1], gyro[-1])
        return np.asarray(t_rows, np.float64), acc_rows, gyro_rows

    def _period_s(self) -> float:
        """The sender's interval measured so far, s: the least-squares slope of the ticks kept against their sample
        numbers (as a replay refines it) once they span more than the samples that found the cadence; until then
        the cadence's own."""
        if len(self._numbers) > LOCK_SAMPLES and self._numbers[-1] - self._numbers[0] > 1:
            k = np.asarray(self._numbers, dtype=np.float64)
            return float(np.polyfit(k, np.asarray(self._ticks, dtype=np.float64), 1)[0]) * TICK_S
        return self._cadence.interval_s

    def cadence(self) -> Cadence | None:
        """The cadence as found so far: the kind from the first samples and the rows held since, the interval
        measured over the motion ticks kept (ST's step exactly when the stream runs at it; a poller's mean)."""
        c = self._cadence
        if c is None:
            return None
        ticks = self._ticks
        span_s = (ticks[-1] - ticks[0]) * TICK_S if len(ticks) > 1 else c.span_s
        if c.exact:
            interval = c.interval_s
        elif c.kind == POLLED:
            interval = span_s / (len(ticks) - 1) if len(ticks) > 1 and span_s > 0 else c.interval_s
        else:
            interval = self._period_s()
        kind = POLLED if c.kind == POLLED else STEADY if not self.rows_held else CONGESTION if c.exact else GAPS
        return replace(
            c,
            kind=kind,
            interval_s=interval,
            dropped=self.rows_held,
            gaps=self.gaps if self.rows_held else 0,
            repeats=self.repeats,
            span_s=span_s,
        )

    def _health(self) -> str:
        c = self.counts
        cad = self.cadence()
        what = cad.describe() if cad is not None else "finding the motion cadence"
        return (
            f"BLE {c.get('motion', 0)} motion / {c.get('environment', 0)} env / {c.get('arming', 0)} arming "
            f"notifications; {what}"
        )

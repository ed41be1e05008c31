"""The BLE source of a live session (``steval live --ble``): an unmodified drone over Bluetooth: scan, connect,
record, estimate, view, reconnect.

The same order as a serial port: the link runs its event loop in its own thread, where every notification goes to
the capture first (a ``B`` chunk with its arrival time), then to a bounded inbox; each round of the session (10 Hz)
decodes the inbox, runs the live estimators on the motion
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
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

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
from steval_link.link.ble_transport import BleBackend, BleDevice, BleLink
from steval_link.link.capture import CHUNK_BLE
from steval_link.live.estimators import failure_sentence
from steval_link.live.sources import CaptureFields, Source
from steval_link.quat import euler_from_quaternion

__all__ = ["BleViewer", "BleRows", "BleSource", "INBOX_MAX", "LOCK_SAMPLES"]

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


class BleSource(Source):
    """See the module docstring. ``target``: a drone's name or address (None: the strongest ``DRN1…``);
    ``backend``: a ``link.ble_transport.BleBackend`` (bleak, or a fake in tests)."""

    kind = "ble"
    takes_commands = False  # ST's stock firmware takes no commands over BLE

    def __init__(
        self,
        target: str | None,
        *,
        backend: BleBackend,
        clock: Callable[[], float] = time.time,
        scan_timeout_s: float = 5.0,
    ) -> None:
        self.target = target
        self.backend = backend
        self.clock = clock
        self.scan_timeout_s = scan_timeout_s
        self._inbox: deque[tuple[int, bytes, float]] = deque(maxlen=INBOX_MAX)
        self._notes: deque[str] = deque(maxlen=64)  # the link's events, said by the session's thread
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
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self.link: BleLink | None = None
        self._device: BleDevice | None = None  # the drone found by open()
        self.estimators: dict = {}
        self.rows_held = 0
        self.gaps = 0
        self.repeats = 0
        self.counts: dict[str, int] = {}

    # -- the session's calls
    @property
    def what(self) -> str:
        """The drone asked for: its name or address, or any ``DRN1…``."""
        return self.target or f"{DEVICE_NAME_PREFIX}*"

    def capture_fields(self) -> CaptureFields:
        return CaptureFields(f"ble:{self.what}", 0, {"link": "ble", "target": self.target})

    def recording_name(self, session) -> str:
        return f"steval live --ble {self.what}"

    def open(self, session) -> None:
        """The input first: the drone is found (or the adapter's failure said) before any file or viewer."""
        super().open(session)
        self.link = BleLink(
            self.backend,
            self.target,
            self._on_notification,
            on_event=self._on_event,
            clock=self.clock,
            scan_timeout_s=self.scan_timeout_s,
        )
        self._device = asyncio.run(self.link.find_first())

    def start(self, session) -> None:
        """The link runs its event loop in its own thread: notifications go to the capture there, first."""
        self._start_unix = self.clock() - session.capture.now()
        self._make_estimators(STEP_PERIOD_S)  # the names checked now; made again with the cadence's dt
        self._thread = threading.Thread(target=self._run_link, name="steval-ble-link", daemon=True)
        self._thread.start()

    def _run_link(self) -> None:
        async def main() -> None:
            self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
            await self.link.run(self._stop, self._device)

        try:
            asyncio.run(main())
        except BaseException as exc:  # noqa: BLE001 - a UserError of the link (no adapter, drone not found...)
            self._error = exc

    def round(self) -> bool:
        self._thread.join(ROUND_S)
        for _ in range(len(self._notes)):
            self.session.display.note(self._notes.popleft())
        if self._thread.is_alive():
            self._round(self.session.viewer)
            return True
        if self._error is not None:
            raise self._error
        self._round(self.session.viewer, final=True)
        return False

    def finish(self, error: BaseException | None) -> None:
        if self._thread is None:
            return
        loop, stop = getattr(self, "_loop", None), getattr(self, "_stop", None)
        if loop is not None and stop is not None and self._thread.is_alive():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:  # the loop closed meanwhile
                pass
        self._thread.join()
        for _ in range(len(self._notes)):
            self.session.display.note(self._notes.popleft())
        if error is None and self._error is None:
            self._round(self.session.viewer, final=True)

    def health(self, now_mono_s: float) -> str:
        c = self.counts
        if not c:
            return ""  # nothing received yet: no line
        cad = self.cadence()
        what = cad.describe() if cad is not None else "finding the motion cadence"
        return (
            f"BLE {c.get('motion', 0)} motion / {c.get('environment', 0)} env / {c.get('arming', 0)} arming "
            f"notifications; {what}"
        )

    def summary_fields(self) -> dict[str, Any]:
        link = self.link
        return {
            "counts": dict(self.counts),
            "rows_held": self.rows_held,
            "connections": link.connections if link is not None else 0,
            "disconnects": link.losses if link is not None else 0,
            "cadence": self.cadence(),
        }

    def _make_estimators(self, dt_s: float) -> None:
        self.estimators = {
            n: registry.create(n, dt_s=dt_s)
            if n in ("st-mahony", "st_mahony")
            else registry.create(n, rate_hz=1.0 / dt_s)
            if n != "accel" and registry.accepts(n, "rate_hz")
            else registry.create(n)
            for n in self.session.options.estimators
        }

    # -- the link's callbacks (the event loop's thread)
    def _on_notification(self, cid: int, data: bytes, t_unix: float) -> None:
        t = t_unix - self._start_unix
        self.session.capture.write_chunk(CHUNK_BLE, ble_chunk(cid, data), t)
        self._inbox.append((cid, data, t))

    def _on_event(self, kind: str, text: str) -> None:
        self.session.capture.mark_event(kind, text)
        if kind == "connect":
            self._notes.append(f"connected to {text} over BLE")
        elif kind == "disconnect":
            self._notes.append("BLE link lost; reconnecting (Ctrl-C stops)")
        elif kind == "reconnect":
            self._inbox.append((RECONNECTED, b"", 0.0))  # the next motion sample follows a lost link
            self._notes.append(f"reconnected to {text}")
        else:
            self._notes.append(f"{kind}: {text}")

    def _round(self, viewer: BleViewer | None, final: bool = False) -> None:
        items = []
        while self._inbox:  # appended by the link's thread meanwhile: taken one by one, none lost
            items.append(self._inbox.popleft())
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
            return
        items, self._pending = self._pending, []
        if items:
            self._process(items, viewer)

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
                why = failure_sentence(name, exc)
                self.session.display.note(f"{why}; {name} disabled, recording and viewing go on")
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

"""The estimators of a live session, run per :class:`LiveRows`: the ST Mahony filter followed bit for bit from
status snapshots (:class:`LiveMahony`), the registry's and your own (:class:`LiveEstimators`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from steval_link import constants as C
from steval_link.estimators import firmware_replay, registry, st_mahony
from steval_link.estimators.runner import created_at
from steval_link.link.telemetry import AttitudeArrays


@dataclass
class LiveRows:
    """The attitude rows of one processing round (times on the capture's base) with every live estimate:
    ``estimates`` maps a source name (``st-mahony``, ``accel``...) to (N, 4) q_wxyz, NaN where undefined."""

    attitude: AttitudeArrays
    estimates: dict[str, np.ndarray] = field(default_factory=dict)
    #: (N, 3) float32 magnetometer of each row, mgauss, where the link sends it (BLE); None: not sent
    mag_mgauss: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.attitude)

    @property
    def finite(self) -> np.ndarray:
        """(N,) bool: the filter inputs (acc, gyro) are finite, so estimators may take the row."""
        a = self.attitude
        return np.isfinite(a.acc_mg).all(axis=1) & np.isfinite(a.gyro_mdps).all(axis=1)

    @classmethod
    def concat(cls, parts: list[LiveRows]) -> LiveRows:
        """One set of the rows of ``parts``, in order (estimate names must agree)."""
        if len(parts) == 1:
            return parts[0]
        estimates = {name: np.concatenate([p.estimates[name] for p in parts]) for name in parts[0].estimates}
        mags = [p.mag_mgauss for p in parts]
        mag = np.concatenate(mags) if all(m is not None for m in mags) else None
        return cls(AttitudeArrays.concat([p.attitude for p in parts]), estimates, mag)


class LiveMahony(firmware_replay.ReplicaFollower):
    """The bit-exact ST Mahony filter run live (``replay_firmware``'s follower), (re)seeded from the firmware's status
    snapshots: NaN until one unless the stream starts at step 0; a snapshot that disagrees re-seeds it."""

    def __init__(self) -> None:
        super().__init__(euler=False)
        self.rows_exact = 0
        self.rows_mismatch = 0
        self.last_rows_mismatch = 0  # mismatching rows of the latest call

    def attitude(self, step: np.ndarray, acc_mg, gyro_mdps, thr, fw_q_wxyz, finite: np.ndarray) -> np.ndarray:
        """Step the filter over these frames (in order); returns (N, 4) float32 q, NaN where unseeded."""
        q, _, _, seeded = self.rows_recognising(step, acc_mg, gyro_mdps, thr, finite, fw_q_wxyz)
        k = int(np.count_nonzero(seeded & st_mahony.bits_equal(q, fw_q_wxyz).all(axis=1)))
        self.rows_exact += k
        self.last_rows_mismatch = int(np.count_nonzero(seeded)) - k
        self.rows_mismatch += self.last_rows_mismatch
        return q

    def status(self, frame) -> None:
        if not frame.exact:  # a text-mode $STA row has no q, integral or gains: nothing to seed from
            return
        snap = st_mahony.MahonyState(q_wxyz=frame.q_wxyz, int_xyz=frame.int_xyz)
        self.snapshot(int(frame.step), snap, st_mahony.MahonySettings.of_status(frame))

    def describe(self) -> str:
        """The filter's state in a few words for the health line."""
        if not self.seeded:
            return "replica resyncing" if self.seed_count else "replica waiting for a status snapshot"
        if self.last_rows_mismatch:
            return f"replica DIFFERS from firmware ({self.rows_mismatch} frames)"
        return "replica bit-exact" if self.rows_exact else "replica seeded"


#: A live estimator is disabled when it gives NaN on NAN_FLOOD_S of finite input in a row, needs more than SLOW_SHARE
#: of the stream time it is fed over SLOW_WINDOW_S of wall time, or stalls the view in one call over STALL_S, s.
NAN_FLOOD_S = 3.0
SLOW_SHARE = 0.5
SLOW_WINDOW_S = 5.0
STALL_S = 2.0


@dataclass
class _Watch:
    """One estimator's NaN rows in a row and its processing and stream time in the current window."""

    window_start_s: float
    nan_rows: int = 0
    busy_s: float = 0.0
    stream_s: float = 0.0


class LiveEstimators:
    """Every host estimator on each attitude row. A row with a non-finite input is fed to none (one NaN would poison
    its state). An estimator that raises, floods NaN or cannot keep up is disabled: one line in :attr:`notes`, NaN
    estimates from then on, and the session goes on."""

    def __init__(self, names: list[str], *, clock=time.perf_counter) -> None:
        self.mahony = LiveMahony() if "st-mahony" in names else None
        self.others = {name: registry.create(name) for name in names if name != "st-mahony"}
        self.names = list(names)
        self.clock = clock
        self.disabled: dict[str, str] = {}  # name → why it was disabled (one sentence)
        self.notes: list[str] = []  # sentences not shown yet (the pipeline hands them on)
        now = clock()
        self._watch = {name: _Watch(now) for name in self.others}

    def use_dt(self, dt_s: float) -> None:
        """Run every estimator at ``dt_s`` on rows no firmware filter produced (BLE): the replica as a plain filter
        at that dt (nothing to follow), the others at 1/dt where they take a rate."""
        self.mahony = None
        self.others = {name: created_at(name, dt_s) for name in self.names}
        self._watch = {name: _Watch(self.clock()) for name in self.others}

    def process(self, rows: LiveRows) -> None:
        a = rows.attitude
        finite = rows.finite
        if self.mahony is not None:
            rows.estimates["st-mahony"] = self.mahony.attitude(
                a.step, a.acc_mg, a.gyro_mdps, a.thr, a.q_wxyz, finite & a.exact
            )
        rows_in = np.flatnonzero(finite)
        for name, est in self.others.items():
            q = np.full((len(rows), 4), np.nan, dtype=np.float64)
            if rows_in.size and name not in self.disabled:
                t0 = self.clock()
                try:
                    res = est.run(a.acc_mg[rows_in], a.gyro_mdps[rows_in], a.thr[rows_in].astype(np.int64))
                    valid = np.asarray(res.valid, dtype=bool)
                    q[rows_in] = np.where(valid[:, None], res.q_wxyz, np.nan)
                except registry.PluginError as exc:  # a user's estimator: names their file and line
                    why = str(exc)
                except Exception as exc:  # noqa: BLE001 - any failure of an estimator costs it, never the session
                    text = str(exc).strip().splitlines()
                    why = f"estimator {name} failed: {type(exc).__name__}" + (f": {text[0]}" if text else "")
                else:
                    why = self._verdict(name, est, rows_in.size, valid, self.clock() - t0)
                if why is not None:
                    self.disabled[name] = why
                    self.notes.append(f"{why}; {name} disabled, recording and viewing go on")
            rows.estimates[name] = q

    def _verdict(self, name: str, est, n: int, valid: np.ndarray, elapsed_s: float) -> str | None:
        """Why ``name`` is disabled after a call of ``n`` rows (None: it keeps up)."""
        w = self._watch[name]
        last_valid = np.flatnonzero(valid)
        w.nan_rows = n - 1 - int(last_valid[-1]) if last_valid.size else w.nan_rows + n
        if w.nan_rows >= NAN_FLOOD_S * C.AHRS_RATE_HZ:
            where = est.origin("step") if hasattr(est, "origin") else name
            return (
                f"estimator {name} gave no estimate (NaN) for {w.nan_rows} frames of valid input in "
                f"a row ({w.nan_rows / C.AHRS_RATE_HZ:.1f} s); look at {where}"
            )
        if elapsed_s > STALL_S:
            return (
                f"estimator {name} took {elapsed_s:.1f} s for {n} frames ({n / C.AHRS_RATE_HZ:.2f} s "
                "of stream): too slow to run live (steval compare runs it offline)"
            )
        w.busy_s += elapsed_s
        w.stream_s += n / C.AHRS_RATE_HZ
        now = self.clock()
        if now - w.window_start_s < SLOW_WINDOW_S:
            return None
        if w.stream_s > 0 and w.busy_s > SLOW_SHARE * w.stream_s:
            return (
                f"estimator {name} needed {1000 * w.busy_s / max(w.stream_s, 1e-9):.0f} ms per "
                f"second of stream for {now - w.window_start_s:.0f} s (at most "
                f"{1000 * SLOW_SHARE:.0f} ms to keep up live; steval compare runs it offline)"
            )
        w.busy_s = w.stream_s = 0.0
        w.window_start_s = now
        return None

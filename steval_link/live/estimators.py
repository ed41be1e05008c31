"""The estimators of a live session: the ST port followed bit for bit from status snapshots (:class:`LivePort`) and
the registry estimators (:class:`LiveEstimators`), run per :class:`AttitudeBatch` of frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from steval_link.estimators import registry, st_mahony


@dataclass
class AttitudeBatch:
    """The attitude frames of one processing round as arrays, with every estimate (units in the names).

    ``estimates`` maps a source name (``st-mahony``, ``accel``, ``ekf3``...) to (N, 4) q_wxyz, NaN where the
    estimate is undefined (port not seeded yet, non-finite input): such rows must not be plotted.
    """

    step: np.ndarray  # (N,) int64
    t_us: np.ndarray  # (N,) int64 (firmware µs, as sent)
    t_unix_s: np.ndarray  # (N,) float64, Unix epoch
    acc_mg: np.ndarray  # (N, 3) float32
    gyro_mdps: np.ndarray  # (N, 3) float32
    q_wxyz: np.ndarray  # (N, 4) float32, firmware
    thz_rad: np.ndarray  # (N,) float32
    thr: np.ndarray  # (N,) int16
    finite: np.ndarray  # (N,) bool, every value of the frame is finite
    exact: np.ndarray  # (N,) bool, binary frame (bit-exact); False: rounded text-mode row without q
    thx_rad: np.ndarray  # (N,) float32, text-mode pitch (about x); NaN for binary frames (derive from q)
    thy_rad: np.ndarray  # (N,) float32, text-mode roll (about y); NaN for binary frames
    estimates: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.step.shape[0])

    @classmethod
    def concat(cls, batches: list["AttitudeBatch"]) -> "AttitudeBatch":
        """One batch of the frames of ``batches``, in order (estimate names must agree)."""
        if len(batches) == 1:
            return batches[0]
        arrays = {
            name: np.concatenate([getattr(b, name) for b in batches])
            for name in cls.__dataclass_fields__
            if name != "estimates"
        }
        estimates = {name: np.concatenate([b.estimates[name] for b in batches]) for name in batches[0].estimates}
        return cls(**arrays, estimates=estimates)


class LivePort:
    """The bit-exact ST Mahony port run live, (re)seeded from the firmware's status snapshots.

    Semantics as :func:`steval_link.estimators.st_mahony.replay_firmware`: the port starts from the power-up state
    when the stream starts at step 0; otherwise (joined mid-flight, frames lost, non-finite input) it is unseeded
    (NaN) until the next status snapshot, and bit-exact from the step after it.
    """

    def __init__(self) -> None:

        self._sm = st_mahony
        self.state = None  # MahonyState, or None when unseeded
        self.settings = st_mahony.MahonySettings()
        self.next_step: int | None = None
        self.seeds = 0
        self.snapshots_confirmed = 0  # status snapshots that matched the port's own state bit for bit
        self.rows_exact = 0
        self.rows_mismatch = 0
        self.rows_unseeded = 0
        self.last_rows_mismatch = 0  # mismatching rows of the latest call

    @property
    def seeded(self) -> bool:
        return self.state is not None

    def attitude(self, step: np.ndarray, acc_mg, gyro_mdps, thr, fw_q_wxyz, finite: np.ndarray) -> np.ndarray:
        """Step the port over these frames (in order); returns (N, 4) float32 q, NaN where unseeded."""
        n = step.shape[0]
        out = np.full((n, 4), np.nan, dtype=np.float32)
        mismatch_before = self.rows_mismatch
        a = 0
        while a < n:
            # a run of consecutive steps with finite inputs
            if not finite[a]:
                self.state = None
                self.next_step = None
                a += 1
                continue
            b = a + 1
            while b < n and finite[b] and step[b] == step[b - 1] + 1:
                b += 1
            s0 = int(step[a])
            if self.state is not None and self.next_step != s0:
                self.state = None  # frames lost: out of sync until the next snapshot
            if self.state is None and s0 == 0:
                self.state = self._sm.MahonyState()  # the stream starts at power-up
                self.seeds += 1
            if self.state is not None:
                q, _, _, self.state = self._sm.run(
                    acc_mg[a:b], gyro_mdps[a:b], thr[a:b], settings=self.settings, state=self.state, euler=False
                )
                out[a:b] = q
                exact = self._sm.bits_equal(q, fw_q_wxyz[a:b]).all(axis=1)
                k = int(np.count_nonzero(exact))
                self.rows_exact += k
                self.rows_mismatch += (b - a) - k
                self.next_step = int(step[b - 1]) + 1
            else:
                self.rows_unseeded += b - a
                self.next_step = int(step[b - 1]) + 1
            a = b
        self.last_rows_mismatch = self.rows_mismatch - mismatch_before
        return out

    def status(self, frame) -> None:
        """A status frame: seed the port from its snapshot when unseeded or out of sync (else confirm it)."""
        st = self._sm
        snap = st.MahonyState(q_wxyz=frame.q_wxyz, int_xyz=frame.int_xyz)
        settings = st.MahonySettings.of_status(frame)
        step = int(frame.step)
        if (
            self.state is not None
            and self.next_step == step + 1
            and settings == self.settings
            and self.state.bits_equal(snap)
        ):
            self.snapshots_confirmed += 1
            return
        if not np.all(np.isfinite(snap.as_array())):
            self.state = None  # the firmware's own filter holds NaN: nothing to follow
            return
        self.state = snap
        self.settings = settings
        self.next_step = step + 1
        self.seeds += 1

    def describe(self) -> str:
        """The port's state in a few words for the health line."""
        if self.state is None:
            return "port resyncing" if self.seeds else "port waiting for a status snapshot"
        if self.last_rows_mismatch:
            return f"port DIFFERS from firmware ({self.rows_mismatch} frames)"
        return "port bit-exact" if self.rows_exact else "port seeded"


class LiveEstimators:
    """Every host estimator run on each attitude frame: the seeded ST port plus any registry estimator.

    Rows with a non-finite input are never fed to an estimator (one NaN would poison a filter's state for good);
    their estimates are NaN.
    """

    def __init__(self, names: list[str]) -> None:

        self.port = LivePort() if "st-mahony" in names else None
        self.others = {name: registry.create(name) for name in names if name != "st-mahony"}
        self.names = list(names)

    def process(self, batch: AttitudeBatch) -> None:
        if self.port is not None:
            batch.estimates["st-mahony"] = self.port.attitude(
                batch.step, batch.acc_mg, batch.gyro_mdps, batch.thr, batch.q_wxyz, batch.finite & batch.exact
            )
        rows = np.flatnonzero(batch.finite)
        for name, est in self.others.items():
            q = np.full((len(batch), 4), np.nan, dtype=np.float64)
            if rows.size:
                res = est.run(batch.acc_mg[rows], batch.gyro_mdps[rows], batch.thr[rows].astype(np.int64))
                qq = np.asarray(res.q_wxyz, dtype=np.float64)
                qq[~np.asarray(res.valid, dtype=bool)] = np.nan
                q[rows] = qq
            batch.estimates[name] = q

    def status(self, frame) -> None:
        if self.port is not None:
            self.port.status(frame)


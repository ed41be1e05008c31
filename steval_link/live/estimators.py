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
    finite: np.ndarray  # (N,) bool, the filter inputs (acc, gyro) are finite: estimators may take the row
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

    The same follower as :func:`steval_link.estimators.st_mahony.replay_firmware`
    (:class:`~steval_link.estimators.st_mahony.PortFollower`): it starts from the power-up state when the stream
    starts at step 0; otherwise (joined mid-flight, frames lost, non-finite input) it is unseeded (NaN) until the
    next status snapshot, and bit-exact from the step after it. Live, a snapshot that disagrees with the port
    (a settings change, a difference) re-seeds it.
    """

    def __init__(self) -> None:
        self.follower = st_mahony.PortFollower(follow_snapshots=True, euler=False)
        self.rows_exact = 0
        self.rows_mismatch = 0
        self.rows_unseeded = 0
        self.last_rows_mismatch = 0  # mismatching rows of the latest call

    @property
    def seeded(self) -> bool:
        return self.follower.seeded

    @property
    def settings(self) -> st_mahony.MahonySettings:
        """The filter settings the port runs with (the latest snapshot's)."""
        return self.follower.settings

    @property
    def seeds(self) -> int:
        return self.follower.seed_count

    @property
    def snapshots_confirmed(self) -> int:
        """Status snapshots that matched the port's own state bit for bit."""
        return self.follower.confirmed

    def attitude(self, step: np.ndarray, acc_mg, gyro_mdps, thr, fw_q_wxyz, finite: np.ndarray) -> np.ndarray:
        """Step the port over these frames (in order); returns (N, 4) float32 q, NaN where unseeded."""
        q, _, _, seeded = self.follower.rows(step, acc_mg, gyro_mdps, thr, np.asarray(finite, dtype=bool))
        exact = seeded & st_mahony.bits_equal(q, fw_q_wxyz).all(axis=1)
        k = int(np.count_nonzero(exact))
        n_seeded = int(np.count_nonzero(seeded))
        self.rows_exact += k
        self.last_rows_mismatch = n_seeded - k
        self.rows_mismatch += n_seeded - k
        self.rows_unseeded += int(np.count_nonzero(np.asarray(finite, dtype=bool) & ~seeded))
        return q

    def status(self, frame) -> None:
        """A status frame: seed the port from its snapshot when unseeded or out of sync (else confirm it)."""
        if not frame.exact:  # a text-mode $STA row has no q, integral or gains: nothing to seed from
            return
        snap = st_mahony.MahonyState(q_wxyz=frame.q_wxyz, int_xyz=frame.int_xyz)
        self.follower.snapshot(int(frame.step), snap, st_mahony.MahonySettings.of_status(frame))

    def describe(self) -> str:
        """The port's state in a few words for the health line."""
        if not self.seeded:
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


"""BROAD trials (Laidig et al. 2021, CC BY 4.0): loading, firmware units, the STEVAL view of a trial, the error
metrics, and the truth each AHRS step of an emulated run saw (:class:`StepTruth`).

A trial ``.npz`` holds ``acc`` (N, 3) m/s², ``gyr`` (N, 3) rad/s, ``quat`` (N, 4) wxyz IMU → ENU (NaN where the
markers were occluded), ``movement`` (N,) bool and ``fs`` (Hz); the IMU axes are the firmware's.

Metric (BROAD paper): ``q_err = q_est ⊗ q_true⁻¹`` (earth frame); RMSE over ``movement`` samples ignoring NaN.
Estimates are body → earth quaternions, like the firmware's and BROAD's IMU → ENU. A constant heading offset
leaves the inclination error unchanged, so 6-axis estimators are compared on inclination only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.emulation import sensor_model as sm
from steval_link.errors import UserError
from steval_link.quat import interpolate_quat, quat_conjugate, quat_multiply, quat_normalize, quaternion_from_euler
from steval_link.units import RAD_TO_MDPS

#: m/s² per g for the conversion to mg. The trials' resting |acc| is 9.81–9.87 m/s² (IMU-dependent calibration;
#: local gravity in Berlin is 9.813), so 9.81 is the right scale to within the sensors' own 0.6 % spread.
G_MPS2 = 9.81
_KEYS = ("acc", "gyr", "quat", "movement", "fs")


@dataclass(frozen=True)
class BroadTrial:
    """One BROAD trial in SI units (float64), as stored."""

    name: str  #: file stem, e.g. ``02_undisturbed_slow_rotation_B``
    fs_hz: float  #: sampling rate, Hz (285.714)
    acc_mps2: np.ndarray  #: (N, 3) m/s²
    gyr_radps: np.ndarray  #: (N, 3) rad/s
    quat_wxyz: np.ndarray  #: (N, 4) ground truth IMU → ENU (NaN where occluded)
    movement: np.ndarray  #: (N,) bool, samples that count for the metrics

    @property
    def t_s(self) -> np.ndarray:
        """(N,) sample times, s from the first sample."""
        return np.arange(self.acc_mps2.shape[0]) / self.fs_hz

    @property
    def acc_mg(self) -> np.ndarray:
        """(N, 3) accelerometer in mg (÷ :data:`G_MPS2`)."""
        return self.acc_mps2 / G_MPS2 * 1000.0

    @property
    def gyro_mdps(self) -> np.ndarray:
        """(N, 3) gyro in mdps."""
        return self.gyr_radps * RAD_TO_MDPS


def load_trial(path) -> BroadTrial:
    """Read a BROAD trial ``.npz``; a missing or malformed file raises :class:`UserError` (one sentence)."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: no such file")
    try:
        with np.load(p, allow_pickle=False) as z:
            missing = [k for k in _KEYS if k not in z.files]
            if missing:
                raise UserError(f"{p}: not a BROAD trial (.npz without {', '.join(missing)})")
            acc, gyr, quat = (np.asarray(z[k], dtype=np.float64) for k in ("acc", "gyr", "quat"))
            mov = np.asarray(z["movement"]).astype(bool)
            fs = float(np.asarray(z["fs"]).reshape(()))
    except UserError:
        raise
    except Exception as exc:  # zip/pickle/format errors from numpy
        raise UserError(f"{p}: cannot read as a BROAD .npz ({type(exc).__name__}: {exc})") from None
    n = acc.shape[0]
    if acc.ndim != 2 or acc.shape[1] != 3 or gyr.shape != acc.shape or quat.shape != (n, 4) or mov.shape != (n,):
        raise UserError(
            f"{p}: malformed BROAD trial (acc {acc.shape}, gyr {gyr.shape}, quat {quat.shape}, "
            f"movement {mov.shape}; expected (N,3), (N,3), (N,4), (N,))"
        )
    if not np.isfinite(fs) or fs <= 0 or n < 2:
        raise UserError(f"{p}: malformed BROAD trial (fs = {fs}, {n} samples)")
    return BroadTrial(p.stem, fs, acc, gyr, quat, mov)


def trial_paths(items) -> list[Path]:
    """DATA arguments expanded: a directory's ``*.npz`` (sorted, no ``*.truth.npz`` sidecars); files stay."""
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(q for q in p.glob("*.npz") if not q.name.endswith(".truth.npz"))
            if not found:
                raise UserError(f"{p}: directory holds no .npz trial")
            out.extend(found)
        elif p.exists():
            out.append(p)
        else:
            raise UserError(f"{p}: no such file or directory")
    return out


def _error_quat(q_est, q_true) -> np.ndarray:
    return quat_multiply(quat_normalize(q_est), quat_conjugate(quat_normalize(q_true)))


def inclination_error_rad(q_est_wxyz, q_true_wxyz) -> np.ndarray:
    """Inclination error, rad: ``2·acos(√(w² + z²))`` of ``q_est ⊗ q_true⁻¹`` (both body → earth, any norm)."""
    e = _error_quat(q_est_wxyz, q_true_wxyz)
    return 2.0 * np.arccos(np.clip(np.sqrt(e[..., 0] ** 2 + e[..., 3] ** 2), 0.0, 1.0))


def heading_error_rad(q_est_wxyz, q_true_wxyz) -> np.ndarray:
    """Heading error, rad: ``2·atan(|z / w|)`` of ``q_est ⊗ q_true⁻¹``."""
    e = _error_quat(q_est_wxyz, q_true_wxyz)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 2.0 * np.arctan(np.abs(e[..., 3] / e[..., 0]))


def rmse_deg(err_rad, mask=None) -> float:
    """RMSE in degrees over ``mask`` (all when None), ignoring NaN; NaN when nothing is left."""
    e = np.asarray(err_rad, dtype=np.float64)
    if mask is not None:
        e = e[np.asarray(mask, dtype=bool)]
    e = e[np.isfinite(e)]
    return float(np.degrees(np.sqrt(np.mean(e * e)))) if e.size else float("nan")


@dataclass(frozen=True)
class SteValView:
    """Estimator inputs and ground truth on a common step grid."""

    acc_mg: np.ndarray  #: (M, 3) float32 accelerometer input per step, mg
    gyro_mdps: np.ndarray  #: (M, 3) float32 gyro input per step, mdps
    t_s: np.ndarray  #: (M,) time each step represents in trial time, s (see :func:`steval_view`)
    quat_true_wxyz: np.ndarray  #: (M, 4) float64 ground truth at ``t_s`` (NaN where occluded)
    movement: np.ndarray  #: (M,) bool, the trial's movement mask at ``t_s``
    rate_hz: float  #: step rate, Hz


def truth_at_trial_time(trial: BroadTrial, t_trial_s) -> tuple[np.ndarray, np.ndarray]:
    """(q_wxyz (M, 4), movement (M,)) at trial times ``t_trial_s``: q interpolated; NaN / False outside the trial."""
    t = np.asarray(t_trial_s, dtype=np.float64).reshape(-1)
    t_end = float(trial.t_s[-1])
    inside = (t >= 0.0) & (t <= t_end)
    q = np.full((t.shape[0], 4), np.nan)
    mov = np.zeros(t.shape[0], dtype=bool)
    if inside.any():
        q[inside] = interpolate_quat(trial.t_s, trial.quat_wxyz, t[inside])
        idx = np.clip(np.rint(t[inside] * trial.fs_hz).astype(np.int64), 0, len(trial.t_s) - 1)
        mov[inside] = trial.movement[idx]
    return q, mov


def steval_view(trial: BroadTrial, *, seed: int | None = None, sensor: sm.Lsm6dsl | None = None) -> SteValView:
    """The trial as the STEVAL sees it at 161.5 Hz: resampled to the ISR tick (the gyro held at 416 Hz), quantised
    like the ST driver (with ``sensor``'s noise, seeded by ``seed``, when given), through the ISR pipeline. A step's
    ``t_s`` is the middle of the 5 ticks it averages; the gyro's ≈ 3.3 ms delay stays in every estimator's error."""
    t = trial.t_s
    t_tick, acc = sm.resample_to_tick(t, trial.acc_mg)
    _, gyro = sm.resample_to_tick(t, trial.gyro_mdps, hold_hz=sm.GYRO_ODR_HZ)
    if sensor is not None:
        acc_r, gyro_r = sensor.read(acc, gyro, rng=0 if seed is None else seed, t_tick_s=t_tick)
    else:
        acc_r, gyro_r = sm.quantise(acc, sm.ACC_SENSITIVITY_MG), sm.quantise(gyro, sm.GYRO_SENSITIVITY_MDPS)
    try:
        out = sm.run_isr(acc_r, gyro_r)
    except ValueError as exc:
        raise UserError(f"trial {trial.name}: too short for the STEVAL pipeline ({exc})") from None
    t_step = t_tick[out.step_tick - (C.FIFO_ORDER // 2)]
    return SteValView(out.acc_ahrs_mg, out.gyro_ahrs_mdps, t_step, *truth_at_trial_time(trial, t_step), C.AHRS_RATE_HZ)


def own_rate_view(trial: BroadTrial) -> SteValView:
    """The trial at its own rate (285.7 Hz) in firmware units, without the STEVAL pipeline (float32 mg / mdps)."""
    acc, gyro = trial.acc_mg.astype(np.float32), trial.gyro_mdps.astype(np.float32)
    return SteValView(acc, gyro, trial.t_s, trial.quat_wxyz, trial.movement, trial.fs_hz)


@dataclass(frozen=True)
class TruthRows:
    """Ground truth per AHRS step."""

    step: np.ndarray  #: (M,) int64 AHRS step counter (0 = the first step after power-up)
    t_s: np.ndarray  #: (M,) emulated time of the step's middle input tick, s since power-up
    t_trial_s: np.ndarray  #: (M,) trial time of that tick, s (outside [0, trial end]: no truth)
    q_wxyz: np.ndarray  #: (M, 4) ground truth, body → earth (NaN: occluded or outside the trial)
    movement: np.ndarray  #: (M,) bool, the step counts for the metric

    def __len__(self) -> int:
        return int(self.step.shape[0])


class StepTruth:
    """The ground truth each AHRS step of an ``Emulation`` of a BROAD trial saw; attach before running.

    Trial time 0 is the first TIM9 tick (the trials start at rest, so the 2 s calibration sees a level pose). A step
    averages the 5 ISR samples up to tick ``k_last`` (recorded at ``ahrs_fusion_ag``); its truth is at tick
    ``k_last − 2``, as in :func:`steval_view`. Step ``i`` is the ``i``-th call of ``ahrs_fusion_ag`` (from 0).
    """

    def __init__(self, emu) -> None:
        if emu.motion.trial is None:
            raise ValueError("ground truth needs a BROAD trial (the emulation's broad option)")
        self.emu = emu
        self.trial: BroadTrial = emu.motion.trial
        self._last_tick: list[int] = []
        self._taken = 0
        emu.step_start_observers.append(lambda mark: self._last_tick.append(emu.tick_index(mark)))

    @property
    def last_ticks(self) -> np.ndarray:
        """(M,) int64 motion tick of the newest sample in each step's FIFO window."""
        return np.asarray(self._last_tick, dtype=np.int64)

    def rows(self, start: int = 0, stop: int | None = None) -> TruthRows:
        """The truth of steps ``start`` .. ``stop`` (default: every step so far)."""
        ticks = self.last_ticks[start:stop]
        mid = ticks - C.FIFO_ORDER // 2
        step = np.arange(start, start + ticks.shape[0], dtype=np.int64)
        if ticks.shape[0] == 0:
            return TruthRows(step, np.zeros(0), np.zeros(0), *truth_at_trial_time(self.trial, np.zeros(0)))
        t_trial = np.asarray(self.emu.trial_time_s(mid), dtype=np.float64)
        t_emu = np.asarray(self.emu.tick_time_s(mid), dtype=np.float64)
        return TruthRows(step, t_emu, t_trial, *truth_at_trial_time(self.trial, t_trial))

    def take(self) -> TruthRows:
        """The truth of the steps recorded since the last call (for a capture's truth chunks as it grows)."""
        start, self._taken = self._taken, len(self._last_tick)
        return self.rows(start, self._taken)


def score_euler(thx_rad, thy_rad, q_true_wxyz, movement) -> tuple[np.ndarray, float]:
    """(inclination error (M,) rad, RMSE deg over ``movement``) of the attitude thx/thy against the truth."""
    q = quaternion_from_euler(np.asarray(thx_rad, np.float64), np.asarray(thy_rad, np.float64), 0.0)
    err = inclination_error_rad(q, q_true_wxyz)
    return err, rmse_deg(err, movement)

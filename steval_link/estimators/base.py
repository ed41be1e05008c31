"""The interface every attitude estimator shares, and the firmware's Euler-angle convention in float64.

All estimators take the firmware's units and axes: accelerometer in mg, gyro in mdps, throttle as ``gTHR``; axes
x right, y forward, z up (at rest acc ≈ (0, 0, +1000) mg). Angles follow ``QuaternionToEuler``:
``thx_rad`` is the rotation about x (pitch, nose up +), ``thy_rad`` about y (roll), ``thz_rad`` about z (yaw).

Your own estimator needs no base class: ``reset()`` and ``step()`` are enough (docs/ESTIMATORS.md: units, dt, what
``step()`` returns, how invalid samples are flagged); :meth:`Estimator.run` is the default ``run()`` it gets.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from steval_link.fw_math import choose_native
from steval_link.quat import euler_from_quaternion


@dataclass(frozen=True)
class AttitudeEstimate:
    """The attitude of every step of a run.

    Attributes:
        q_wxyz: (N, 4) quaternion, scalar first (float64, or float32 for the bit-exact firmware replica).
        thx_rad: (N,) rotation about x, rad (pitch, nose up +).
        thy_rad: (N,) rotation about y, rad (roll).
        thz_rad: (N,) rotation about z, rad (yaw); NaN where the estimator has none.
        valid: (N,) bool, False where the estimate is not defined (e.g. zero acceleration vector, NaN state).
    """

    q_wxyz: np.ndarray
    thx_rad: np.ndarray
    thy_rad: np.ndarray
    thz_rad: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.thx_rad.shape[0])


class Estimator(abc.ABC):
    """An attitude estimator fed with the firmware's inputs, one AHRS step at a time or a whole run at once.

    Subclasses set :attr:`name` (the registry name) and implement :meth:`reset` and :meth:`step`; :meth:`run` has a
    generic implementation over :meth:`step` that fast estimators override.
    """

    #: registry name, e.g. ``"st-mahony"``
    name: str = "estimator"

    @abc.abstractmethod
    def reset(self) -> None:
        """Return to the power-up state (identity attitude, no accumulated bias)."""

    @abc.abstractmethod
    def step(self, acc_mg, gyro_mdps, thr: int = 0) -> np.ndarray:
        """Advance one AHRS step.

        Args:
            acc_mg: (3,) accelerometer, mg.
            gyro_mdps: (3,) gyro rate, mdps.
            thr: throttle ``gTHR`` of the step (only estimators that switch gains on it use it).

        Returns:
            (4,) quaternion after the step, scalar first.
        """

    def run(self, acc_mg, gyro_mdps, thr=None) -> AttitudeEstimate:
        """Run :meth:`step` over N steps (continuing from the current state, no reset) and return every step's
        attitude: ``q_wxyz`` as step() returned it, the angles derived from it (``QuaternionToEuler``'s formulas in
        float64), ``valid`` where q is finite (a step with no estimate returns NaN).

        Args:
            acc_mg: (N, 3) accelerometer, mg.
            gyro_mdps: (N, 3) gyro, mdps.
            thr: (N,) throttle, or None for 0 throughout.
        """
        acc, gyro, thr_arr = check_inputs(acc_mg, gyro_mdps, thr)
        q = np.empty((acc.shape[0], 4), dtype=np.float64)
        for k in range(acc.shape[0]):
            q[k] = self.step(acc[k], gyro[k], int(thr_arr[k]))
        thx, thy, thz = euler_from_quaternion(q)
        valid = np.isfinite(q).all(axis=1)
        return AttitudeEstimate(q_wxyz=q, thx_rad=thx, thy_rad=thy, thz_rad=thz, valid=valid)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"


def filter_rows(est, acc_mg, gyro_mdps, thr, native, built: bool, width: int, *, reject_g=np.inf, default=None):
    """The run() of a filter with a C loop and a Python reference (ekf3, mekf): its (N, width) output rows from
    ``est._run_native`` or ``est._row`` per step (``native``, ``built``, ``default``: :func:`choose_native`), and
    (N,) valid: finite, and not before the first tilt it accepts (|a| finite, > 1e-6 g, within ``reject_g`` of
    1 g): until then it has no attitude and does not integrate the gyro."""
    acc, gyro, _ = check_inputs(acc_mg, gyro_mdps, thr, dtype=np.float64)
    out = np.empty((acc.shape[0], width))
    a = acc * 1e-3
    an = np.sqrt(a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1] + a[:, 2] * a[:, 2])  # the filters' own order of operations
    with np.errstate(invalid="ignore"):
        tilt = np.isfinite(an) & (an > 1e-6) & (np.abs(an - 1.0) <= reject_g)
    waiting = ~np.logical_or.accumulate(tilt) & (not est._initialised)
    if choose_native(native, built, "EKF", default):
        est._run_native(acc, gyro, out)
    else:
        for k, (a, g) in enumerate(zip(acc.tolist(), gyro.tolist())):
            out[k] = est._row(a, g)
    return out, np.isfinite(out).all(axis=1) & ~waiting


def check_inputs(acc_mg, gyro_mdps, thr=None, dtype=np.float32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate run inputs: (N, 3) acc and gyro as ``dtype``, (N,) int64 throttle (zeros when None)."""
    acc = np.ascontiguousarray(acc_mg, dtype=dtype)
    gyro = np.ascontiguousarray(gyro_mdps, dtype=dtype)
    if acc.ndim != 2 or acc.shape[1] != 3:
        raise ValueError(f"acc_mg must be (N, 3), got shape {acc.shape}")
    if gyro.shape != acc.shape:
        raise ValueError(f"gyro_mdps must have the shape of acc_mg {acc.shape}, got {gyro.shape}")
    thr_arr = np.asarray(0 if thr is None else thr)
    if thr_arr.ndim == 0:
        thr_arr = np.full(acc.shape[0], int(thr_arr), dtype=np.int64)
    thr_arr = np.ascontiguousarray(thr_arr, dtype=np.int64)
    if thr_arr.shape != (acc.shape[0],):
        raise ValueError(f"thr must be (N,) = ({acc.shape[0]},), got shape {thr_arr.shape}")
    return acc, gyro, thr_arr

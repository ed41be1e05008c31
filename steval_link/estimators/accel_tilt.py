"""Accelerometer-only tilt (ETH lecture 4, exercise 8): pitch and roll from the direction of gravity alone.

Firmware axes and ``QuaternionToEuler``'s names: ``thx_rad`` = atan2(ay, az) is the rotation about x (pitch, nose
up +), ``thy_rad`` = atan2(−ax, √(ay² + az²)) about y (roll); yaw is unobservable (NaN). Exact only when the drone
is not accelerating, which is what the exercise shows next to the Mahony filter.
"""

from __future__ import annotations

import numpy as np

from steval_link.estimators.base import AttitudeEstimate, Estimator, check_inputs
from steval_link.quat import quaternion_from_euler


def accel_tilt(acc_mg, *, max_dev_mg: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(thx_rad, thy_rad, valid)`` of (..., 3) accelerometer samples, mg. ``valid`` is False for a zero vector (thx =
    thy = 0) or non-finite input (NaN), and with ``max_dev_mg`` where |a| is that far from 1000 mg (accelerating)."""
    a = np.asarray(acc_mg, dtype=np.float64)
    if a.shape[-1] != 3:
        raise ValueError(f"acc_mg must have 3 components in its last axis, got shape {a.shape}")
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    thx = np.arctan2(ay, az)  # atan2(0, 0) = 0: defined for a zero vector
    thy = np.arctan2(-ax, np.hypot(ay, az))
    norm = np.sqrt(ax * ax + ay * ay + az * az)
    valid = np.isfinite(norm) & (norm > 0.0)
    if max_dev_mg is not None:
        valid &= np.abs(norm - 1000.0) <= float(max_dev_mg)
    return thx, thy, valid


def tilt_quaternion(thx_rad, thy_rad) -> np.ndarray:
    """Quaternion (wxyz, float64) of pitch ``thx_rad`` (about x), roll ``thy_rad`` (about y) and zero yaw."""
    return quaternion_from_euler(thx_rad, thy_rad, 0.0)


class AccelTilt(Estimator):
    """Accelerometer-only tilt as an estimator (``accel``): memoryless, gyro ignored; options: :func:`accel_tilt`."""

    name = "accel"

    def __init__(self, *, max_dev_mg: float | None = None) -> None:
        self.max_dev_mg = max_dev_mg

    def reset(self) -> None:
        """Nothing to reset: memoryless."""

    def step(self, acc_mg, gyro_mdps=None, thr: int = 0) -> np.ndarray:
        thx, thy, _ = accel_tilt(np.asarray(acc_mg, dtype=np.float64).reshape(3), max_dev_mg=self.max_dev_mg)
        return tilt_quaternion(thx, thy)

    def run(self, acc_mg, gyro_mdps=None, thr=None) -> AttitudeEstimate:
        acc, _, _ = check_inputs(acc_mg, acc_mg, dtype=np.float64)  # the gyro is not used
        thx, thy, valid = accel_tilt(acc, max_dev_mg=self.max_dev_mg)
        thz = np.full(acc.shape[0], np.nan)  # yaw is unobservable from gravity
        return AttitudeEstimate(q_wxyz=tilt_quaternion(thx, thy), thx_rad=thx, thy_rad=thy, thz_rad=thz, valid=valid)

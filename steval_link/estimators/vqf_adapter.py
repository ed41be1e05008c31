"""VQF (Laidig & Seel 2023, the ``vqf`` package) as an :class:`Estimator`: the 6-axis state of the art, for reference.

Install with ``pip install "steval-link[vqf]"``. Inputs are converted from the firmware's units to SI (acc mg →
m/s² with g = 9.81, gyro mdps → rad/s); the axes already match (x right, y forward, z up). The output is VQF's
6D quaternion (gyro + accelerometer; body → earth, scalar first; heading arbitrary).
"""

from __future__ import annotations

import numpy as np

from steval_link.constants import AHRS_RATE_HZ
from steval_link.estimators.base import AttitudeEstimate, Estimator, check_inputs
from steval_link.quat import euler_from_quaternion, quat_multiply
from steval_link.units import MDPS_TO_RADPS

INSTALL_HINT = 'the VQF estimator needs the vqf package: pip install "steval-link[vqf]"'

try:  # optional dependency: importing this module without it fails with the install hint (registry: unavailable)
    from vqf import VQF as _VQF
except ImportError:  # pragma: no cover - exercised only without the extra
    raise ImportError(INSTALL_HINT) from None

_MG_TO_MPS2 = 9.81e-3


class VqfEstimator(Estimator):
    """VQF's 6D orientation at ``rate_hz``. ``latency_s`` > 0 predicts the output ahead like ``mekf``'s (default 0:
    VQF untouched); ``params`` go to ``VQF`` by name (e.g. ``tauAcc=3.0``)."""

    name = "vqf"

    def __init__(self, rate_hz: float = AHRS_RATE_HZ, latency_s: float = 0.0, **params) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.params = dict(params)
        self.latency_s = float(latency_s)
        self.reset()

    def reset(self) -> None:
        self._vqf = _VQF(1.0 / self.rate_hz, **self.params)

    def step(self, acc_mg, gyro_mdps, thr: int = 0) -> np.ndarray:
        gyr = np.asarray(gyro_mdps, dtype=np.float64).reshape(3) * MDPS_TO_RADPS
        acc = np.asarray(acc_mg, dtype=np.float64).reshape(3) * _MG_TO_MPS2
        self._vqf.update(np.ascontiguousarray(gyr), np.ascontiguousarray(acc))
        q = np.asarray(self._vqf.getQuat6D(), dtype=np.float64)
        return self._predict(q[None], gyr[None])[0] if self.latency_s else q

    def run(self, acc_mg, gyro_mdps, thr=None) -> AttitudeEstimate:
        acc, gyro, _ = check_inputs(acc_mg, gyro_mdps, thr, dtype=np.float64)
        out = self._vqf.updateBatch(np.ascontiguousarray(gyro * MDPS_TO_RADPS), np.ascontiguousarray(acc * _MG_TO_MPS2))
        q = np.asarray(out["quat6D"], dtype=np.float64)
        if self.latency_s:
            q = self._predict(q, gyro * MDPS_TO_RADPS)
        thx, thy, thz = euler_from_quaternion(q)
        return AttitudeEstimate(q_wxyz=q, thx_rad=thx, thy_rad=thy, thz_rad=thz, valid=np.isfinite(q).all(axis=1))

    def _predict(self, q: np.ndarray, gyr_radps: np.ndarray) -> np.ndarray:
        """q ⊗ Exp(ω·latency_s) for (N, 4) q and (N, 3) ω (rad/s, bias not removed: VQF's is not exposed)."""
        r = gyr_radps * self.latency_s
        ang = np.linalg.norm(r, axis=1)
        s = np.where(ang > 1e-12, np.sin(0.5 * ang) / np.maximum(ang, 1e-12), 0.5)
        return quat_multiply(q, np.column_stack([np.cos(0.5 * ang), r * s[:, None]]))

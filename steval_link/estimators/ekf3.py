"""The 3-state attitude EKF of the ETH PBL course project (lecture 4): Euler angles, gyro prediction, accelerometer
update.

State ``x = (φ, θ, ψ)``, rad, in the firmware's convention (ZYX / Tait–Bryan: body → earth ``R = Rz(ψ)·Ry(θ)·Rx(φ)``):
φ = ``thx`` (rotation about x, the firmware's "pitch"), θ = ``thy`` (about y, "roll"), ψ = ``thz`` (yaw).

Prediction with the body rates ``ω = (p, q, r)`` (gyro, rad/s) and the Euler-rate kinematics::

    φ̇ = p + sinφ·tanθ·q + cosφ·tanθ·r
    θ̇ = cosφ·q − sinφ·r
    ψ̇ = (sinφ·q + cosφ·r) / cosθ

    x ← x + dt·f(x, ω),   F = I + dt·∂f/∂x,   P ← F P Fᵀ + Q

(by default the mean takes the exact solution for a rate constant over the step: no forward-Euler error, no
tan θ blow-up near ±90°; ``exact_propagation=False`` gives the course's forward-Euler step)

    ∂φ̇/∂φ = tanθ·(cosφ·q − sinφ·r)       ∂φ̇/∂θ = (sinφ·q + cosφ·r) / cos²θ
    ∂θ̇/∂φ = −sinφ·q − cosφ·r              ∂θ̇/∂θ = 0
    ∂ψ̇/∂φ = (cosφ·q − sinφ·r) / cosθ      ∂ψ̇/∂θ = (sinφ·q + cosφ·r)·sinθ / cos²θ      (ψ column: 0)

    Q = dt²·W·(σ_ω²·I)·Wᵀ + dt·σ_p²·I     (W: the matrix of the Euler-rate equations above, f = W·ω)

σ_ω is the gyro noise per sample (``gyro_noise_mdps``, mdps RMS), σ_p what the gyro model leaves out
(``process_noise_dps_rthz``, dps/√Hz). Update with ``y = a / |a|`` against the gravity direction in the body frame
(the third row of R, as in the firmware)::

    h(x) = (−sinθ, sinφ·cosθ, cosφ·cosθ)
    H = ∂h/∂x = [[0, −cosθ, 0], [cosφ·cosθ, −sinφ·sinθ, 0], [−sinφ·cosθ, −cosφ·sinθ, 0]]
    K = P Hᵀ (H P Hᵀ + R)⁻¹,   x ← x + K (y − h(x)),   P ← (I − K H) P

with ``R = σ_a²·I``, ``σ_a² = σ_n² + σ_m²`` in g²: sensor noise (``acc_noise_mg``) and unmodelled linear acceleration
(``acc_motion_mg``); ``adaptive=True`` adds ``(k·| |a| − 1 g |)²`` (``norm_gain`` k; off: it biases the tilt in
back-and-forth translation). ψ only integrates the gyro (no magnetometer). The filter starts from the first
accelerometer sample's tilt (ψ = 0); cos θ is kept away from 0 (gimbal lock at θ = ±90°).

Units at the interface are the firmware's: acc in mg, gyro in mdps, axes x right, y forward, z up.
"""

from __future__ import annotations

import math

import numpy as np

from steval_link.constants import AHRS_RATE_HZ
from steval_link.estimators.base import AttitudeEstimate, Estimator, filter_rows
from steval_link.quat import qexp, qmul, quaternion_from_euler
from steval_link.units import MDPS_TO_RADPS

try:  # the C loop of run() (built by setup.py, optional); the Python step below is the reference and fallback
    from steval_link.estimators import _ekf_native as _native
except ImportError:  # pragma: no cover - depends on the build
    _native = None

#: True when the C loop of :meth:`Ekf3.run` is built (≈ 100× faster; the Python step is the reference).
NATIVE_AVAILABLE = _native is not None

_MIN_COS = 1e-3
_DIAG = np.diag_indices(3)  # the diagonal of a 3×3 matrix


def _propagate_exact(x, rx: float, ry: float, rz: float) -> tuple[float, float, float]:
    """Euler angles after rotating the body by the rotation vector (rx, ry, rz), rad, body frame."""
    w, x_, y, z = qmul(quaternion_from_euler(*x).tolist(), qexp(rx, ry, rz))
    phi = math.atan2(2 * (w * x_ + y * z), w * w - x_ * x_ - y * y + z * z)
    th = math.asin(max(-1.0, min(1.0, 2 * (w * y - x_ * z))))
    psi = math.atan2(2 * (x_ * y + w * z), w * w + x_ * x_ - y * y - z * z)
    return phi, th, psi


class Ekf3(Estimator):
    """3-state Euler-angle EKF; its options are the module docstring's symbols, in their units. :meth:`step` is the
    Python reference; :meth:`run` uses the C loop when built (equal to rounding), except with a zero accelerometer
    variance (Python's ``np.linalg.solve`` may raise on the singular innovation covariance)."""

    name = "ekf3"

    def __init__(
        self,
        rate_hz: float = AHRS_RATE_HZ,
        gyro_noise_mdps: float = 75.0,
        process_noise_dps_rthz: float = 0.05,
        acc_noise_mg: float = 2.0,
        acc_motion_mg: float = 50.0,
        adaptive: bool = False,
        norm_gain: float = 2.0,
        exact_propagation: bool = True,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.dt = 1.0 / self.rate_hz
        self.gyro_var = (gyro_noise_mdps * MDPS_TO_RADPS) ** 2
        self.proc_var = (math.radians(process_noise_dps_rthz)) ** 2
        self.acc_var = (acc_noise_mg * 1e-3) ** 2 + (acc_motion_mg * 1e-3) ** 2
        self.adaptive = bool(adaptive)
        self.norm_gain = float(norm_gain)
        self.exact_propagation = bool(exact_propagation)
        self.reset()

    def reset(self) -> None:
        self.x = np.zeros(3)
        self.P = np.diag([0.1**2, 0.1**2, 0.0])
        self._initialised = False

    @property
    def q(self) -> np.ndarray:
        return quaternion_from_euler(*self.x)

    def step(self, acc_mg, gyro_mdps, thr: int = 0) -> np.ndarray:
        self._row(acc_mg, gyro_mdps)
        return self.q

    def _row(self, acc_mg, gyro_mdps) -> np.ndarray:
        """One step of the Python reference; returns the state x (φ, θ, ψ)."""
        ax, ay, az = (float(v) * 1e-3 for v in acc_mg)
        p, q, r = (float(v) * MDPS_TO_RADPS for v in gyro_mdps)
        an = math.sqrt(ax * ax + ay * ay + az * az)
        acc_ok = math.isfinite(an) and an > 1e-6
        if not self._initialised:
            if acc_ok:
                self.x[:] = (math.atan2(ay, az), math.asin(max(-1.0, min(1.0, -ax / an))), 0.0)
                self._initialised = True
            return self.x
        if math.isfinite(p) and math.isfinite(q) and math.isfinite(r):
            self._predict(p, q, r)
        if acc_ok:
            self._update(ax / an, ay / an, az / an, an)
        return self.x

    def _predict(self, p: float, q: float, r: float) -> None:
        dt = self.dt
        phi, th, _ = self.x
        sp, cp = math.sin(phi), math.cos(phi)
        ct = math.cos(th)
        if abs(ct) < _MIN_COS:
            ct = math.copysign(_MIN_COS, ct)
        st = math.sin(th)
        tt = st / ct
        a = sp * q + cp * r  # appears in φ̇, ψ̇
        c = cp * q - sp * r
        F = np.array(
            [
                [1.0 + dt * tt * c, dt * a / (ct * ct), 0.0],
                [-dt * a, 1.0, 0.0],
                [dt * c / ct, dt * a * st / (ct * ct), 1.0],
            ]
        )
        W = np.array([[1.0, sp * tt, cp * tt], [0.0, cp, -sp], [0.0, sp / ct, cp / ct]])
        if self.exact_propagation:
            self.x[:] = _propagate_exact(self.x, p * dt, q * dt, r * dt)
        else:
            self.x[0] = math.remainder(self.x[0] + dt * (p + tt * a), 2 * math.pi)
            self.x[1] += dt * c
            self.x[2] = math.remainder(self.x[2] + dt * (a / ct), 2 * math.pi)
        Q = (dt * dt * self.gyro_var) * (W @ W.T)
        Q[_DIAG] += dt * self.proc_var
        self.P = F @ self.P @ F.T + Q

    def _update(self, ux: float, uy: float, uz: float, an: float) -> None:
        phi, th, _ = self.x
        sp, cp, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
        h = (-st, sp * ct, cp * ct)
        H = np.array([[0.0, -ct, 0.0], [cp * ct, -sp * st, 0.0], [-sp * ct, -cp * st, 0.0]])
        var = self.acc_var + ((self.norm_gain * (an - 1.0)) ** 2 if self.adaptive else 0.0)
        P = self.P
        PHt = P @ H.T
        S = H @ PHt
        S[_DIAG] += var
        K = np.linalg.solve(S, PHt.T).T
        self.x += K @ np.array([ux - h[0], uy - h[1], uz - h[2]])
        IKH = np.eye(3) - K @ H
        P = IKH @ P @ IKH.T + var * (K @ K.T)
        self.P = 0.5 * (P + P.T)

    def run(self, acc_mg, gyro_mdps, thr=None, *, native: bool | None = None) -> AttitudeEstimate:
        """N steps from the current state; ``native`` True/False forces the C loop or the Python reference."""
        default = NATIVE_AVAILABLE and self.acc_var > 0.0
        x, valid = filter_rows(self, acc_mg, gyro_mdps, thr, native, NATIVE_AVAILABLE, 3, default=default)
        q = quaternion_from_euler(x[:, 0], x[:, 1], x[:, 2])
        return AttitudeEstimate(q_wxyz=q, thx_rad=x[:, 0], thy_rad=x[:, 1], thz_rad=x[:, 2], valid=valid)

    def _run_native(self, acc: np.ndarray, gyro: np.ndarray, x_out: np.ndarray) -> None:
        """The C loop over float64 (N, 3) inputs; writes (N, 3) angles and carries the state in and out."""
        st = np.concatenate([self.x, np.ravel(self.P), [float(self._initialised)]])  # the layout EKF3_* of the C file
        params = np.array([self.dt, self.gyro_var, self.proc_var, self.acc_var, self.norm_gain, MDPS_TO_RADPS])
        flags = int(self.adaptive) | (int(self.exact_propagation) << 1)
        _native.ekf3_run(acc, gyro, x_out, st, params, flags)
        self.x[:] = st[0:3]
        self.P = st[3:12].reshape(3, 3).copy()
        self._initialised = bool(st[12])

"""MyEkf: a 3-state extended Kalman filter for the STEVAL-FCU001V1's attitude (ETH PBL lecture 4, the course project).

Written by ``steval estimator new``; it works as it is. Try it, then make it yours:

    steval estimator check my_ekf.py:MyEkf                       interface checks, then its RMSE next to ST-Mahony
    steval compare recordings/demo.stv -e my_ekf.py:MyEkf        against the firmware on a capture
    steval estimator check 'my_ekf.py:MyEkf(r_acc=1e-3)'         one gain changed: watch the score move

The interface (docs/ESTIMATORS.md): ``reset()`` goes back to power-up; ``step(acc_mg, gyro_mdps, thr)`` takes one
AHRS step's inputs in the firmware's units and axes and returns the attitude as a quaternion (w, x, y, z).

Units and axes, as the firmware has them: acc in mg, gyro in mdps (millidegrees per second); x right, y forward,
z up, so at rest acc ≈ (0, 0, +1000) mg. The state is the lecture's Euler angles, in the firmware's names:

    phi   = thx, the rotation about x: pitch, nose up positive
    theta = thy, the rotation about y: roll
    psi   = thz, the rotation about z: yaw (the gyro alone: without a magnetometer nothing corrects it)

with body → earth ``R = Rz(psi)·Ry(theta)·Rx(phi)`` (first about z by psi, then about y by theta, then about x by
phi: the lecture's order). The lecture's EKF steps are marked below: 1 collect a(k), g(k); 2 prediction from the
previous estimate and g(k)·Δt; 3 update from a(k).

Tuning knobs (constructor options, e.g. ``-e 'my_ekf.py:MyEkf(q_gyro=1e-5, r_acc=0.05)'``):

    q_gyro   process noise of the gyro-driven prediction, rad²/s: how fast the angles may drift away from what
             the gyro says (gyro noise, bias, scale errors). Larger: trust the accelerometer more.
    r_acc    measurement noise of the accelerometer's direction, g²: sensor noise plus everything that is not
             gravity (the drone accelerating, vibration). Larger: trust the gyro more.
    p0       initial covariance of pitch and roll, rad²: how sure the first estimate (from the first
             accelerometer sample) is.
    max_dev_g  accelerometer samples whose magnitude is further than this from 1 g skip the update (hard shocks;
             free fall, |a| < 0.1 g, always does). Gating tighter than about 1 g loses more than it gains on the
             BROAD trials: the drone's own accelerations last long enough for the gyro to drift meanwhile.
    euler_step  True: predict with the plain x + dt·f (forward Euler); False (default): the same kinematics
             as an exact rotation by g(k)·Δt, which matters in fast turns (BROAD trial 07).

Only numpy: the same steps translate line by line to C for ``ahrs.c`` (3×3 matrices, no library needed).
"""

from __future__ import annotations

import math

import numpy as np

#: AHRS steps per second on the drone: the TIM9 interrupt at 807.7 Hz, the filter on every 5th tick
RATE_HZ = 84e6 / (52 * 2000) / 5


class MyEkf:
    """3-state EKF: x = (phi, theta, psi), gyro prediction, accelerometer update."""

    def __init__(
        self,
        q_gyro: float = 1e-6,
        r_acc: float = 1e-2,
        p0: float = 0.1,
        max_dev_g: float = 2.0,
        euler_step: bool = False,
        rate_hz: float = RATE_HZ,
    ) -> None:
        self.q_gyro = float(q_gyro)  # process noise of the gyro, rad²/s
        self.r_acc = float(r_acc)  # measurement noise of the accelerometer direction, g²
        self.p0 = float(p0)  # initial covariance of pitch and roll, rad²
        self.max_dev_g = float(max_dev_g)  # |a| further than this from 1 g: no update
        self.euler_step = bool(euler_step)  # True: predict with x + dt·f (more error in fast turns)
        self.dt = 1.0 / float(rate_hz)  # s per step (steval passes rate_hz when the rows come at another rate)
        self.reset()

    def reset(self) -> None:
        """Power-up: no attitude yet (the first accelerometer sample gives it)."""
        self.x = np.zeros(3)  # phi, theta, psi, rad
        self.P = np.diag([self.p0, self.p0, 0.0])  # covariance of x, rad²
        self.started = False

    def step(self, acc_mg, gyro_mdps, thr: int = 0) -> np.ndarray:
        """One AHRS step: acc (3,) mg, gyro (3,) mdps → quaternion (w, x, y, z) after the step."""
        # ---- Step 1: collect a(k), g(k) ------------------------------------------------------------------------
        a = np.asarray(acc_mg, dtype=float) * 1e-3  # g
        w = np.radians(np.asarray(gyro_mdps, dtype=float) * 1e-3)  # rad/s: p, q, r about x, y, z
        a_norm = math.sqrt(a @ a)

        if not self.started:  # the first estimate: tilt from gravity (the lecture's accelerometer formulas)
            if not 0.5 < a_norm < 1.5:
                return np.full(4, np.nan)  # no estimate yet: NaN marks the step invalid
            self.x[:] = (math.atan2(a[1], a[2]), math.atan2(-a[0], math.hypot(a[1], a[2])), 0.0)
            self.started = True
            return self.quaternion()

        # ---- Step 2: prediction x_p(k) from x_m(k-1) and g(k)·Δt ----------------------------------------------
        dt = self.dt
        phi, theta, _ = self.x
        sp, cp = math.sin(phi), math.cos(phi)
        st, ct = math.sin(theta), max(math.cos(theta), 0.05)  # cos θ kept off 0 (gimbal lock at θ = ±90°)
        tt = st / ct
        p, q, r = w
        # Euler-angle rates from the body rates
        f = np.array(
            [
                p + sp * tt * q + cp * tt * r,  # phi dot
                cp * q - sp * r,  # theta dot
                (sp * q + cp * r) / ct,  # psi dot
            ]
        )
        # Jacobian F = I + dt·∂f/∂x
        F = np.eye(3) + dt * np.array(
            [
                [tt * (cp * q - sp * r), (sp * q + cp * r) / (ct * ct), 0.0],
                [-sp * q - cp * r, 0.0, 0.0],
                [(cp * q - sp * r) / ct, (sp * q + cp * r) * st / (ct * ct), 0.0],
            ]
        )
        Q = self.q_gyro * dt * np.eye(3)  # process noise of this step
        if self.euler_step:  # the lecture's integration as it stands
            self.x = self.x + dt * f
        else:  # the same, computed as the rotation by g(k)·Δt: exact for a rate constant over the step, so fast
            # turns add no integration error and theta never leaves ±90°
            self.x = euler_of(rotate(self.quaternion(), w * dt))
        self.P = F @ self.P @ F.T + Q

        # ---- Step 3: update x_m(k) from x_p(k) and a(k) -------------------------------------------------------
        if a_norm > 0.1 and abs(a_norm - 1.0) <= self.max_dev_g:  # not in free fall, not a hard shock
            phi, theta, _ = self.x
            sp, cp, st, ct = math.sin(phi), math.cos(phi), math.sin(theta), math.cos(theta)
            h = np.array([-st, sp * ct, cp * ct])  # gravity as the accelerometer should see it, g
            H = np.array(
                [  # ∂h/∂x
                    [0.0, -ct, 0.0],
                    [cp * ct, -sp * st, 0.0],
                    [-sp * ct, -cp * st, 0.0],
                ]
            )
            R = self.r_acc * np.eye(3)  # measurement noise
            S = H @ self.P @ H.T + R  # innovation covariance
            K = self.P @ H.T @ np.linalg.inv(S)  # Kalman gain
            self.x = self.x + K @ (a / a_norm - h)
            self.P = (np.eye(3) - K @ H) @ self.P
            self.P = 0.5 * (self.P + self.P.T)  # kept symmetric against rounding
        self.x[0] = math.remainder(self.x[0], 2 * math.pi)  # angles kept in (−π, π]
        self.x[2] = math.remainder(self.x[2], 2 * math.pi)
        return self.quaternion()

    def quaternion(self) -> np.ndarray:
        """The state as a quaternion (w, x, y, z), body → earth, R = Rz(psi)·Ry(theta)·Rx(phi)."""
        cx, sx = math.cos(self.x[0] / 2), math.sin(self.x[0] / 2)
        cy, sy = math.cos(self.x[1] / 2), math.sin(self.x[1] / 2)
        cz, sz = math.cos(self.x[2] / 2), math.sin(self.x[2] / 2)
        return np.array(
            [
                cz * cy * cx + sz * sy * sx,
                cz * cy * sx - sz * sy * cx,
                cz * sy * cx + sz * cy * sx,
                sz * cy * cx - cz * sy * sx,
            ]
        )


def rotate(q: np.ndarray, rv: np.ndarray) -> np.ndarray:
    """Quaternion q (w, x, y, z) turned further by the body-frame rotation vector rv (rad): q ⊗ exp(rv / 2)."""
    angle = math.sqrt(rv @ rv)
    s = math.sin(angle / 2) / angle if angle > 1e-12 else 0.5
    dw, dx, dy, dz = math.cos(angle / 2), rv[0] * s, rv[1] * s, rv[2] * s
    w, x, y, z = q
    return np.array(
        [
            w * dw - x * dx - y * dy - z * dz,
            w * dx + x * dw + y * dz - z * dy,
            w * dy - x * dz + y * dw + z * dx,
            w * dz + x * dy - y * dx + z * dw,
        ]
    )


def euler_of(q: np.ndarray) -> np.ndarray:
    """(phi, theta, psi) of a quaternion, the firmware's QuaternionToEuler formulas (theta within ±90°)."""
    w, x, y, z = q / math.sqrt(q @ q)
    return np.array(
        [
            math.atan2(2 * (w * x + y * z), w * w - x * x - y * y + z * z),
            math.asin(max(-1.0, min(1.0, 2 * (w * y - x * z)))),
            math.atan2(2 * (x * y + w * z), w * w + x * x - y * y - z * z),
        ]
    )

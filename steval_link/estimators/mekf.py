"""Multiplicative quaternion EKF (MEKF) with gyro-bias states and inertial-frame accelerometer averaging:
steval-link's most accurate 6-axis estimator.

Why: linear acceleration averages out over seconds in the earth frame (the velocity stays bounded), not in the body
frame. So, like VQF (Laidig & Seel 2023), the accelerometer is rotated into a strapdown ("inertial", I) frame
integrated from the gyro alone, low-pass filtered there, and only that gravity direction corrects the attitude.

Attitude ``q = q_c ⊗ q_s`` (body → earth, wxyz): ``q_s`` (body → I) ``← q_s ⊗ Exp((gyro − b)·dt)``, never corrected;
``q_c`` (I → earth) and the gyro bias ``b`` (rad/s) are the EKF's. Error state ``δx = (δθ, δb)``, with
``q_c,true = q_c ⊗ Exp(δθ)`` (δθ in the I frame)::

    δθ ← δθ − dt·R(q_s)·δb,   P ← F P Fᵀ + diag(σ_g²·dt·I, σ_b²·dt·I),   F = [[I, −dt·R(q_s)], [0, I]]

``a_I = R(q_s)·a`` (g) goes through a 2nd-order Butterworth low-pass of time constant τ (``acc_tau_s``, cut-off
√2 / (2πτ); the running mean during the first τ seconds, as VQF), giving ``ā_I``. Measurement ``y = ā_I / |ā_I|``,
prediction ``h = R(q_c)ᵀ·e_z``::

    H = [[h]×, [h]×·D],   D = C − LP(C),   C = Σ dt·R(q_s),   R = σ_a²·I,   σ_a² = σ_n² + (k_n·d)²

D models the low-pass' delay (the drift a bias error caused over the last ≈ τ s); without it the bias loop
oscillates. While the low-pass warms up the bias is not updated. σ_n is ``acc_noise_mg``; k_n (``norm_gain``,
off: it hurt on the BROAD trials) scales d, the low-passed | |a| − 1 g |. Samples with | |a| − 1 g | above
``reject_mg`` (default: none; dropping biases the average) or zero are skipped. Joseph-form update; the bias
variance is capped at its initial value (the bias about the vertical is unobservable without a magnetometer). The
first valid accelerometer sample sets the tilt (heading 0). ``acc_tau_s = 0`` is the direct MEKF (``H = [[h]×, 0]``).

Latency: the STEVAL pipeline's gyro lags its accelerometer by ``constants.GYRO_LATENCY_S`` (≈ 3.3 ms); the output is
predicted that far ahead (``latency_s``; ≈ 1° in fast rotation).

Units at the interface are the firmware's: acc in mg, gyro in mdps, axes x right, y forward, z up.
"""

from __future__ import annotations

import math

import numpy as np

from steval_link.constants import AHRS_RATE_HZ, GYRO_LATENCY_S
from steval_link.estimators.base import AttitudeEstimate, Estimator, filter_rows
from steval_link.quat import euler_from_quaternion, qexp, qmul
from steval_link.units import MDPS_TO_RADPS

try:  # the C loop of run() (built by setup.py, optional); the Python step below is the reference and fallback
    from steval_link.estimators import _ekf_native as _native
except ImportError:  # pragma: no cover - depends on the build
    _native = None

#: True when the C loop of :meth:`Mekf.run` is built (≈ 100× faster; the Python step is the reference).
NATIVE_AVAILABLE = _native is not None
_DIAG = np.diag_indices(3)  # the diagonal of a 3×3 matrix


def _tilt_quat(ax: float, ay: float, az: float) -> tuple[float, float, float, float]:
    """Body → earth quaternion with zero heading whose gravity direction Rᵀe_z is (ax, ay, az)/|a|."""
    n = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / n, ay / n, az / n
    w = 1.0 + az  # shortest arc taking a to e_z: (1 + a·e_z, a × e_z)
    if w < 1e-9:  # upside down
        return 0.0, 1.0, 0.0, 0.0
    x, y = ay, -ax
    s = math.sqrt(w * w + x * x + y * y)
    return w / s, x / s, y / s, 0.0


def _rotmat(w: float, x: float, y: float, z: float) -> np.ndarray:
    """R(q) of a unit quaternion (maps body vectors to the reference frame)."""
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _inv3(S: np.ndarray) -> np.ndarray:
    """Inverse of a 3×3 matrix by its adjugate, as the C loop (S = H P Hᵀ + σ²I is symmetric positive definite)."""
    a, b, c = S[0]
    d, e, f = S[1]
    g, h, i = S[2]
    A = e * i - f * h
    B = f * g - d * i
    C = d * h - e * g
    det = a * A + b * B + c * C
    return (
        np.array(
            [[A, c * h - b * i, b * f - c * e], [B, a * i - c * g, c * d - a * f], [C, b * g - a * h, a * e - b * d]]
        )
        / det
    )


def _butter2(fc_hz: float, fs_hz: float) -> tuple[float, float, float, float, float]:
    """2nd-order Butterworth low-pass (bilinear): (b0, b1, b2, a1, a2), y = b·x − a1·y1 − a2·y2."""
    k = math.tan(math.pi * min(fc_hz, 0.45 * fs_hz) / fs_hz)
    norm = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * norm
    return b0, 2 * b0, b0, 2 * (k * k - 1) * norm, (1 - math.sqrt(2.0) * k + k * k) * norm


class _LowPass:
    """Vector 2nd-order Butterworth low-pass (direct form I), started like VQF's with the running mean of its first
    ``warmup`` inputs. It copies its inputs (a caller may pass a view it updates later); do not modify its output."""

    __slots__ = ("c", "x1", "x2", "y1", "y2", "ready", "warmup", "n", "acc")

    def __init__(self, coeffs, warmup: int = 0) -> None:
        self.c = coeffs
        self.ready = False
        self.warmup = int(warmup)
        self.n = 0

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.n < self.warmup or not self.ready:  # warming up (the running mean), or the first sample
            if self.n < self.warmup:
                self.acc = x.copy() if self.n == 0 else self.acc + x
                self.n += 1
            start = self.acc / self.n if self.n else x.copy()
            self.x1 = self.x2 = self.y1 = self.y2 = start
            self.ready = True
            return start
        b0, b1, b2, a1, a2 = self.c
        y = b0 * x + b1 * self.x1 + b2 * self.x2 - a1 * self.y1 - a2 * self.y2
        self.x2, self.x1 = self.x1, x.copy()
        self.y2, self.y1 = self.y1, y
        return y


class Mekf(Estimator):
    """MEKF with gyro bias and inertial-frame accelerometer averaging; its options are the module docstring's
    symbols in their units (σ_g ``gyro_noise_mdps_rthz``, σ_b ``bias_rw_mdps_per_sqrt_s``); ``init_bias_mdps`` is the
    initial bias σ (and cap); ``latency_s`` 0 for data without the STEVAL pipeline (BROAD).

    :meth:`step` is the Python reference; :meth:`run` uses the C loop of ``_ekf_native`` when built and leaves the
    same state. They agree to rounding (≈ 1e-12 rad on the BROAD trials).
    """

    name = "mekf"

    def __init__(
        self,
        rate_hz: float = AHRS_RATE_HZ,
        acc_tau_s: float = 3.0,
        gyro_noise_mdps_rthz: float = 10.0,
        bias_rw_mdps_per_sqrt_s: float = 0.3,
        acc_noise_mg: float = 3.0,
        norm_gain: float = 0.0,
        reject_mg: float = math.inf,
        init_bias_mdps: float = 100.0,
        estimate_bias: bool = True,
        latency_s: float = GYRO_LATENCY_S,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        if acc_tau_s < 0:
            raise ValueError(f"acc_tau_s must be ≥ 0, got {acc_tau_s}")
        if not acc_noise_mg > 0:
            raise ValueError(f"acc_noise_mg must be > 0, got {acc_noise_mg}")
        self.rate_hz = float(rate_hz)
        self.dt = 1.0 / self.rate_hz
        self.acc_tau_s = float(acc_tau_s)
        self.gyro_noise = gyro_noise_mdps_rthz * MDPS_TO_RADPS
        self.bias_rw = bias_rw_mdps_per_sqrt_s * MDPS_TO_RADPS
        self.acc_noise = acc_noise_mg / 1000.0
        self.norm_gain = float(norm_gain)
        self.reject = reject_mg / 1000.0
        self.init_bias = init_bias_mdps * MDPS_TO_RADPS
        self.estimate_bias = bool(estimate_bias)
        self.latency_s = float(latency_s)
        self._q_att = self.gyro_noise**2 * self.dt
        self._q_bias = self.bias_rw**2 * self.dt
        self._lp_coeffs = (
            _butter2(math.sqrt(2.0) / (2 * math.pi * self.acc_tau_s), self.rate_hz) if self.acc_tau_s > 0 else None
        )
        self.reset()

    def reset(self) -> None:
        self.qs = (1.0, 0.0, 0.0, 0.0)
        self.qc = (1.0, 0.0, 0.0, 0.0)
        self.b = np.zeros(3)
        nb = 6 if self.estimate_bias else 3
        self.P = np.diag([0.05**2] * 3 + [self.init_bias**2] * (nb - 3))
        warm = int(round(self.acc_tau_s * self.rate_hz))
        self._acc_lp = _LowPass(self._lp_coeffs, warm) if self._lp_coeffs else None
        self._norm_lp = _LowPass(self._lp_coeffs) if self._lp_coeffs else None
        self._cum_lp = _LowPass(self._lp_coeffs) if self._lp_coeffs else None
        self._cum_rs = np.zeros((3, 3))
        self._initialised = False
        self._eye = np.eye(nb)
        self._w = (0.0, 0.0, 0.0)

    @property
    def q(self) -> np.ndarray:
        """Current attitude, body → earth, (4,) wxyz."""
        return np.array(qmul(self.qc, self.qs))

    @property
    def bias_mdps(self) -> np.ndarray:
        """Current gyro bias estimate, mdps."""
        return self.b / MDPS_TO_RADPS

    def step(self, acc_mg, gyro_mdps, thr: int = 0) -> np.ndarray:
        ax, ay, az = (float(v) * 1e-3 for v in acc_mg)  # g
        gx, gy, gz = (float(v) * MDPS_TO_RADPS for v in gyro_mdps)  # rad/s
        an = math.sqrt(ax * ax + ay * ay + az * az)
        acc_ok = math.isfinite(an) and an > 1e-6 and abs(an - 1.0) <= self.reject
        if not self._initialised:
            if acc_ok:
                self.qc = _tilt_quat(ax, ay, az)
                self._initialised = True
            return self.q
        if math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz):
            self._w = (gx - self.b[0], gy - self.b[1], gz - self.b[2])
            self._predict(*self._w)
        if acc_ok:
            self._correct(ax, ay, az, an)
        rx, ry, rz = (v * self.latency_s for v in self._w)  # the attitude latency_s ahead at the last rate
        if self.latency_s > 0.0 and not math.sqrt(rx * rx + ry * ry + rz * rz) < 1e-12:
            return np.array(qmul(qmul(self.qc, self.qs), qexp(rx, ry, rz)))
        return self.q

    def _predict(self, wx: float, wy: float, wz: float) -> None:
        dt = self.dt
        w, x, y, z = qmul(self.qs, qexp(wx * dt, wy * dt, wz * dt))
        n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
        self.qs = (w * n, x * n, y * n, z * n)
        P = self.P
        if self.estimate_bias:
            rs = _rotmat(*self.qs)
            self._cum_rs += dt * rs  # C_k = Σ dt·R(q_s): the strapdown frame's drift per unit bias error
            G = -dt * rs  # ∂δθ/∂δb
            Pab = P[:3, 3:]
            Pbb = P[3:, 3:]
            GPbb = G @ Pbb
            P[:3, :3] += G @ Pab.T + Pab @ G.T + GPbb @ G.T
            Pab = Pab + GPbb
            P[:3, 3:] = Pab
            P[3:, :3] = Pab.T
            P[3:, 3:][_DIAG] += self._q_bias
        P[_DIAG] += self._q_att

    def _correct(self, ax: float, ay: float, az: float, an: float) -> None:
        dev = abs(an - 1.0)
        if self._acc_lp is not None:
            m = self._acc_lp(_rotmat(*self.qs) @ np.array([ax, ay, az]))  # a_I, low-passed
            d = float(self._norm_lp(np.array([dev]))[0]) if self.norm_gain > 0.0 else 0.0
            mn = math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
            if mn < 1e-6:
                return
            ux, uy, uz = m[0] / mn, m[1] / mn, m[2] / mn
        else:
            ux, uy, uz = ax / an, ay / an, az / an
            d = dev
        var = self.acc_noise**2 + (self.norm_gain * d) ** 2
        w, x, y, z = self.qc
        hx = 2.0 * (x * z - w * y)
        hy = 2.0 * (w * x + y * z)
        hz = w * w - x * x - y * y + z * z
        Hh = np.array([[0.0, -hz, hy], [hz, 0.0, -hx], [-hy, hx, 0.0]])
        P = self.P
        H = Hh
        if self.estimate_bias:  # D = 0: the direct MEKF, or the low-pass still warming up (its mean has no such model)
            D = np.zeros((3, 3))
            if self._cum_lp is not None and self._acc_lp.n >= self._acc_lp.warmup:
                # the low-passed measurement lags: a bias error shows as the drift of the last ≈ τ s, D = C − LP(C)
                # (LP the measurement's low-pass; it copies the view of _cum_rs, which _predict updates in place)
                D = self._cum_rs - self._cum_lp(self._cum_rs.ravel()).reshape(3, 3)
            H = np.hstack([Hh, Hh @ D])
        PHt = P @ H.T
        S = H @ PHt
        S[_DIAG] += var
        K = PHt @ _inv3(S)
        if self.estimate_bias and self._acc_lp is not None and self._acc_lp.n < self._acc_lp.warmup:
            K[3:] = 0.0  # the warm-up mean says nothing about the bias: attitude-only (Joseph form stays valid)
        dxs = K @ np.array([ux - hx, uy - hy, uz - hz])
        IKH = self._eye - K @ H
        P = IKH @ P @ IKH.T + var * (K @ K.T)
        self.P = 0.5 * (P + P.T)
        ex, ey, ez = 0.5 * dxs[0], 0.5 * dxs[1], 0.5 * dxs[2]
        w, x, y, z = qmul(self.qc, (1.0, ex, ey, ez))
        n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
        self.qc = (w * n, x * n, y * n, z * n)
        if self.estimate_bias:
            self.b += dxs[3:]
            Pbb = self.P[3:, 3:]
            tr = Pbb[0, 0] + Pbb[1, 1] + Pbb[2, 2]
            cap = 3 * self.init_bias**2
            if tr > cap:
                self.P[3:, 3:] *= cap / tr

    def run(self, acc_mg, gyro_mdps, thr=None, *, native: bool | None = None) -> AttitudeEstimate:
        """N steps from the current state; ``native`` True/False forces the C loop or the Python reference."""
        q, valid = filter_rows(self, acc_mg, gyro_mdps, thr, native, NATIVE_AVAILABLE, 4, reject_g=self.reject)
        thx, thy, thz = euler_from_quaternion(q)
        return AttitudeEstimate(q_wxyz=q, thx_rad=thx, thy_rad=thy, thz_rad=thz, valid=valid)

    _row = step  # the Python reference's step, for filter_rows

    # --- the C loop: the state packed into flat buffers (layout of _ekf_native.c, MEKF_*) ---------------------
    def _run_native(self, acc: np.ndarray, gyro: np.ndarray, q_out: np.ndarray) -> None:
        st = np.zeros(_native.MEKF_STATE)
        ist = np.zeros(_native.MEKF_ISTATE, dtype=np.int64)
        nb = self.P.shape[0]
        st[0:14] = (*self.qs, *self.qc, *self.b, *self._w)
        st[14 : 14 + nb * nb] = self.P.ravel()
        st[50:59] = self._cum_rs.ravel()
        ist[0] = self._initialised
        # each low-pass: its history x1, x2, y1, y2 at ``at`` (``m`` each), its ready flag at ``flag`` in ist
        slots = ((self._acc_lp, 59, 1, 3), (self._norm_lp, 74, 4, 1), (self._cum_lp, 78, 5, 9))
        for lp, at, flag, _ in slots:
            if lp is not None and lp.ready:
                st[at : at + 4 * lp.x1.size] = np.concatenate([lp.x1, lp.x2, lp.y1, lp.y2])
                ist[flag] = 1
        if self._acc_lp is not None:
            if self._acc_lp.n > 0:
                st[71:74] = self._acc_lp.acc
            ist[2], ist[3] = self._acc_lp.n, self._acc_lp.warmup
        params = np.array(
            [self.dt, MDPS_TO_RADPS, self.reject, self._q_att, self._q_bias, self.acc_noise, self.norm_gain]
            + [self.init_bias, self.latency_s, *(self._lp_coeffs or (0.0,) * 5)]  # b0, b1, b2, a1, a2
        )
        flags = int(self.estimate_bias) | (int(self._acc_lp is not None) << 1)
        _native.mekf_run(acc, gyro, q_out, st, ist, params, flags)
        self.qs, self.qc, self._w = tuple(st[0:4].tolist()), tuple(st[4:8].tolist()), tuple(st[11:14].tolist())
        self.b[:] = st[8:11]
        self.P = st[14 : 14 + nb * nb].reshape(nb, nb).copy()
        self._cum_rs = st[50:59].reshape(3, 3).copy()
        self._initialised = bool(ist[0])
        for lp, at, flag, m in slots:
            if lp is not None and ist[flag]:
                lp.ready = True
                lp.x1, lp.x2, lp.y1, lp.y2 = (st[at + m * i : at + m * (i + 1)].copy() for i in range(4))
        if self._acc_lp is not None:
            self._acc_lp.ready, self._acc_lp.n = bool(ist[1]), int(ist[2])
            if self._acc_lp.n > 0:
                self._acc_lp.acc = st[71:74].copy()

"""Smooth functions of time that motion scenarios are built of (float64, s since power-up): eased moves
(:class:`Steps`), random wander (:class:`Sines`), and a scenario's attitude, translation and throttle as functions of
time (:class:`Kinematics`). Rates and accelerations are exact derivatives, so the sensors can sample anywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from steval_link.quat import quaternion_from_euler

__all__ = ["G_MPS2", "MG_PER_MPS2", "DEG", "rotmat", "Steps", "Sines", "Kinematics"]

#: standard gravity, m/s² (the mg ↔ m/s² conversion of the kinematics)
G_MPS2 = 9.80665
MG_PER_MPS2 = 1000.0 / G_MPS2
DEG = np.pi / 180.0


def rotmat(q) -> np.ndarray:
    """(N, 3, 3) rotation matrices body → earth of unit quaternions (N, 4)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


# ---- smooth building blocks -------------------------------------------------------------------------------------


def _s(u):
    """Quintic smootherstep on [0, 1] (C² at both ends)."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (u * (6 * u - 15) + 10)


def _s_int(u):
    """∫₀ᵘ smootherstep (for u in [0, 1])."""
    u = np.clip(u, 0.0, 1.0)
    return u**4 * (u * (u - 3) + 2.5)


def _s_dd(u):
    """Second derivative of smootherstep in u (0 outside [0, 1])."""
    inside = (u > 0) & (u < 1)
    return np.where(inside, 60 * u * (u * (2 * u - 3) + 1), 0.0)


class Steps:
    """``base + Σ delta_i · S((t − t0_i) / dur_i)``: smooth moves that do not overlap (sorted by t0)."""

    def __init__(self, base: float = 0.0) -> None:
        self.base = float(base)
        self.moves: list[tuple[float, float, float]] = []

    def move(self, t0: float, dur: float, delta: float) -> None:
        if self.moves:
            p0, pd, _ = self.moves[-1]
            if t0 < p0 + pd - 1e-12:
                raise ValueError("moves on one axis must not overlap")
        self.moves.append((float(t0), float(dur), float(delta)))

    def _arrays(self):
        m = np.array(self.moves, dtype=np.float64).reshape(-1, 3)
        return m[:, 0], m[:, 1], m[:, 2]

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        if not self.moves:
            return np.full(t.shape, self.base)
        t0, dur, delta = self._arrays()
        i = np.searchsorted(t0, t, side="right") - 1
        before = np.concatenate(([0.0], np.cumsum(delta)))  # sum of deltas of moves < i
        ic = np.clip(i, 0, len(t0) - 1)
        partial = np.where(i >= 0, delta[ic] * _s((t - t0[ic]) / dur[ic]), 0.0)
        return self.base + np.where(i >= 0, before[ic], 0.0) + partial

    def integral(self, t) -> np.ndarray:
        """∫ from 0 to t (t ≥ 0), for angles integrated from rates."""
        t = np.asarray(t, dtype=np.float64)
        if not self.moves:
            return self.base * t
        t0, dur, delta = self._arrays()
        i = np.searchsorted(t0, t, side="right") - 1
        ic = np.clip(i, 0, len(t0) - 1)
        # completed moves j < i contribute delta_j · (t − t0_j − dur_j/2)
        cd = np.concatenate(([0.0], np.cumsum(delta)))
        cm = np.concatenate(([0.0], np.cumsum(delta * (t0 + dur / 2))))
        done = np.where(i >= 0, t * cd[ic] - cm[ic], 0.0)
        u = (t - t0[ic]) / dur[ic]
        active = np.where(
            i >= 0, np.where(u >= 1, delta[ic] * (t - t0[ic] - dur[ic] / 2), delta[ic] * dur[ic] * _s_int(u)), 0.0
        )
        return self.base * t + done + active

    def accel(self, t) -> np.ndarray:
        """Second time derivative (for positions)."""
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros(t.shape)
        for t0, dur, delta in self.moves:
            out += delta * _s_dd((t - t0) / dur) / (dur * dur)
        return out


@dataclass
class Sines:
    """Σ a_k sin(2π f_k t + φ_k): smooth random wander / tremor, evaluable at any time."""

    amp: np.ndarray
    freq_hz: np.ndarray
    phase: np.ndarray

    @classmethod
    def random(cls, rng: np.random.Generator, rms: float, f_lo: float, f_hi: float, n: int = 5) -> Sines:
        f = rng.uniform(f_lo, f_hi, n)
        a = rng.uniform(0.5, 1.0, n)
        a *= rms * np.sqrt(2.0) / np.sqrt(np.sum(a * a))
        return cls(a, f, rng.uniform(0, 2 * np.pi, n))

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        return np.sin(2 * np.pi * self.freq_hz * t[..., None] + self.phase) @ self.amp


def _zero(t):
    return np.zeros(np.shape(t))


@dataclass
class Kinematics:
    """A scenario as functions of time (s since power-up)."""

    thx: Callable = _zero  #: rad
    thy: Callable = _zero  #: rad
    yaw: Callable = _zero  #: rad
    lin_acc_mg: Callable | None = None  #: (N,) → (N, 3) earth-frame translational acceleration, mg
    lever_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  #: pivot → IMU, body axes, m
    lever_weight: Callable | None = None  #: (N,) 0..1: how much the pivot is held fixed (0 in free fall)
    airborne: Callable | None = None  #: (N,) 0..1: thrust model weight
    thr: Callable = _zero  #: throttle profile (float, before RC sampling)
    sticks: Callable | None = None  #: (N,) → (N, 3) gAIL, gELE, gRUD (float, before RC sampling)
    armed: Callable | None = None  #: (N,) → (N,) 0/1 arming switch

    def q(self, t) -> np.ndarray:
        return quaternion_from_euler(self.thx(t), self.thy(t), self.yaw(t))

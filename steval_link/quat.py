"""Quaternion helpers in float64, wxyz (scalar first), in the firmware's Euler convention (x right, y forward, z up;
``thx`` about x = pitch, ``thy`` about y = roll, ``thz`` about z = yaw). The firmware's own float32
``QuaternionToEuler`` is :func:`steval_link.fw_math.quaternion_to_euler`.
"""

from __future__ import annotations

import math

import numpy as np


def quaternion_from_euler(thx_rad, thy_rad, thz_rad) -> np.ndarray:
    """Body → earth quaternion (..., 4) wxyz of ZYX Euler angles (``R = Rz(thz)·Ry(thy)·Rx(thx)``), float64: the
    inverse of :func:`euler_from_quaternion` (the firmware's ``QuaternionToEuler`` of it gives back thx, thy)."""
    hx, hy, hz = (0.5 * np.asarray(a, dtype=np.float64) for a in (thx_rad, thy_rad, thz_rad))
    cx, sx, cy, sy, cz, sz = np.cos(hx), np.sin(hx), np.cos(hy), np.sin(hy), np.cos(hz), np.sin(hz)
    return np.stack(
        [
            cz * cy * cx + sz * sy * sx,
            cz * cy * sx - sz * sy * cx,
            cz * sy * cx + sz * cy * sx,
            sz * cy * cx - cz * sy * sx,
        ],
        axis=-1,
    )


def euler_from_quaternion(q_wxyz) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(thx_rad, thy_rad, thz_rad) in float64 of (..., 4) wxyz quaternions: ``QuaternionToEuler``'s thx (about x,
    pitch) and thy (about y, roll; asin's argument clipped: no NaN), and the Lab 5 handout's thz (about z, yaw)."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    if q.shape[-1] != 4:
        raise ValueError(f"q_wxyz must have 4 components in its last axis, got shape {q.shape}")
    q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    thx = np.arctan2(2.0 * (q0 * q1 + q2 * q3), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)
    with np.errstate(invalid="ignore"):
        thy = np.arcsin(np.clip(2.0 * (q0 * q2 - q1 * q3), -1.0, 1.0))
    thz = np.arctan2(2.0 * (q1 * q2 + q0 * q3), q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3)
    return thx, thy, thz


def qmul(a, b) -> tuple[float, float, float, float]:
    """Hamilton product a ⊗ b of two wxyz quaternions (Python floats in a filter step: no numpy overhead)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_multiply(a, b) -> np.ndarray:
    """Hamilton product a ⊗ b of (..., 4) wxyz quaternions, float64."""
    a = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    b = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack(qmul(a, b), axis=-1)


def qexp(rx: float, ry: float, rz: float) -> tuple[float, float, float, float]:
    """The wxyz quaternion of the rotation vector (rx, ry, rz), rad, in Python floats (first order below 1e-12)."""
    ang = math.sqrt(rx * rx + ry * ry + rz * rz)
    if ang > 1e-12:
        s = math.sin(0.5 * ang) / ang
        return math.cos(0.5 * ang), rx * s, ry * s, rz * s
    return 1.0, 0.5 * rx, 0.5 * ry, 0.5 * rz


def quat_conjugate(q) -> np.ndarray:
    """Conjugate (inverse of a unit quaternion), (..., 4) wxyz."""
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q) -> np.ndarray:
    """Unit quaternions (the firmware's |q| ≈ 0.998 is rescaled); zero rows become NaN."""
    q = np.asarray(q, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return q / np.linalg.norm(q, axis=-1, keepdims=True)


def interpolate_quat(t_s, q_wxyz, t_new_s) -> np.ndarray:
    """Normalised linear interpolation (nlerp, sign-consistent) to new times; NaN near NaN input and outside ``t_s``."""
    t = np.asarray(t_s, dtype=np.float64)
    q = np.asarray(q_wxyz, dtype=np.float64).copy()
    tn = np.asarray(t_new_s, dtype=np.float64)
    # make neighbours sign-consistent so the interpolation takes the short way
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    flip = np.cumsum(np.nan_to_num(dots) < 0) % 2 == 1
    q[1:][flip] *= -1.0
    i = np.clip(np.searchsorted(t, tn, side="right") - 1, 0, len(t) - 2)
    w = ((tn - t[i]) / (t[i + 1] - t[i]))[:, None]
    out = quat_normalize((1 - w) * q[i] + w * q[i + 1])
    out[(tn < t[0]) | (tn > t[-1])] = np.nan
    return out

"""The firmware's float32 arithmetic that more than one layer needs, bit-exact: the fast inverse square root and
``QuaternionToEuler``. The compiled ``steval_link._st_mahony_native`` gives the same bits faster when it is built.
"""

from __future__ import annotations

import numpy as np

try:  # the C loops (built by setup.py, optional); the pure-numpy paths give the same bits, slower
    from steval_link import _st_mahony_native as _native
except ImportError:  # pragma: no cover - depends on the build
    _native = None

#: True when the compiled loops are available (≈ 100× faster than the pure paths, same bits).
NATIVE_AVAILABLE = _native is not None

_F32 = np.float32
_TWO = _F32(2.0)
_HALF = _F32(0.5)


def inv_sqrt(x) -> np.ndarray:
    """The firmware's ``invSqrt`` of float32 ``x``: 0x5f3759df guess and one Newton step, all float32 (finite for 0)."""
    x = np.asarray(x, dtype=_F32)
    halfx = _HALF * x
    i = x.view(np.int32)
    i = np.int32(0x5F3759DF) - (i >> 1)  # arithmetic shift, as ``long`` on the Cortex-M4
    y = i.view(_F32)
    return y * (_F32(1.5) - (halfx * y * y))


def choose_native(native: bool | None, built: bool, loop: str, default: bool | None = None) -> bool:
    """Whether to run a C loop: ``native`` True forces it (RuntimeError when it is not ``built``), False the Python
    one, None ``default`` (by default: the C loop when built)."""
    if native and not built:
        raise RuntimeError(f"the native {loop} loop is not built (reinstall steval-link with a C compiler)")
    return (built if default is None else default) if native is None else bool(native)


def quaternion_to_euler(q_wxyz, *, native: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The firmware's ``QuaternionToEuler``: (thx_rad, thy_rad) as float32 arrays, bit-exact.

    ``q_wxyz`` is (..., 4) float32 ``ahrs.q``; only ``atan2``/``asin`` run in double. thx = atan2(2q0q1 + 2q2q3,
    q0² + q3² − q1² − q2²) is the rotation about x (pitch, nose up +), thy = asin(2q0q2 − 2q1q3) about y (roll): the
    lab handouts' textbook formulas name these the other way round. thy is NaN where asin's argument leaves [−1, 1],
    as on the drone. ``native=False`` forces numpy's atan2/asin instead of the C library's.
    """
    q = np.asarray(q_wxyz, dtype=_F32)
    if q.shape[-1] != 4:
        raise ValueError(f"q_wxyz must have 4 components in its last axis, got shape {q.shape}")
    if choose_native(native, NATIVE_AVAILABLE, "Mahony"):
        thx, thy = (np.empty(q.shape[:-1], dtype=_F32) for _ in range(2))
        _native.euler(np.ascontiguousarray(q), thx, thy)  # the C library's atan2/asin, as the native filter loop
        return thx, thy
    with np.errstate(invalid="ignore", over="ignore"):
        q0, q1, q2, q3 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
        num_x = (_TWO * q0) * q1 + (_TWO * q2) * q3  # float32 products and sums in the C source's order
        den_x = ((q0 * q0 + q3 * q3) - q1 * q1) - q2 * q2
        arg_y = (_TWO * q0) * q2 - (_TWO * q1) * q3
        thx = np.arctan2(num_x.astype(np.float64), den_x.astype(np.float64)).astype(_F32)
        thy = np.arcsin(arg_y.astype(np.float64)).astype(_F32)
    return thx, thy

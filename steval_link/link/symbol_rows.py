"""A capture's symbol chunks ``S`` (the attitude the emulator read from the firmware's globals by symbol) in its
``Telemetry``: :func:`merge_symbol_attitude`.

Without attitude frames the rows become ``tel.attitude`` (``tel.source["attitude_from"]`` = ``"symbols"``); with
frames the frames stay and ``tel.source["symbols"]`` says whether the two agree bit for bit.
"""

from __future__ import annotations

import numpy as np

from steval_link.link.capture import SYMBOL_DTYPE
from steval_link.link.telemetry import AttitudeArrays, Telemetry

_F32 = np.float32


def _bits(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=_F32)
    return np.where(np.isnan(a), np.uint32(0x7FC00000), a.view(np.uint32))


def merge_symbol_attitude(tel: Telemetry, rows: np.ndarray | None) -> Telemetry:
    """Put the symbol rows into ``tel`` (see the module docstring); ``rows`` None or empty: ``tel`` unchanged."""
    if rows is None or len(rows) == 0:
        return tel
    rows = np.asarray(rows, dtype=SYMBOL_DTYPE)
    t_s = rows["t_s"].astype(np.float64)  # emulated s since power-up, as firmware and host time
    args = (rows["step"], t_s, t_s.copy(), rows["acc_mg"], rows["gyro_mdps"], rows["euler_rad"])
    read = AttitudeArrays.of(*args, thr=rows["thr"], q_wxyz=rows["q_wxyz"], exact=True)
    if len(tel.attitude) == 0:
        tel.attitude = read
        tel.source["attitude_from"] = "symbols"
        tel.source["symbols"] = (
            f"no attitude frames: the attitude of {len(read)} AHRS steps as the emulator read it from the "
            "firmware's globals by symbol (acc_ahrs, gyro_ahrs, gTHR, ahrs, euler_ahrs), not frames it sent"
        )
        return tel
    a = tel.attitude
    frames = np.flatnonzero(np.asarray(a.exact, bool))
    common, fi, ri = np.intersect1d(np.asarray(a.step)[frames], read.step, return_indices=True)
    fi = frames[fi]
    tel.source["attitude_from"] = "frames"
    if common.size == 0:  # text-mode frames (rounded) or no step in common: nothing to compare bit for bit
        tel.source["symbols"] = (
            f"the emulator also read the attitude of {len(read)} AHRS steps by symbol (chunks S); no binary frame "
            "shares a step with them, so they are not compared bit for bit"
        )
        return tel
    fields = ("acc_mg", "gyro_mdps", "q_wxyz", "thx_rad", "thy_rad")
    same = np.ones(common.size, dtype=bool)
    for name in fields:
        x, y = _bits(getattr(a, name)[fi]), _bits(getattr(read, name)[ri])
        same &= (x == y).reshape(common.size, -1).all(axis=1)
    same &= np.asarray(a.thr)[fi] == read.thr[ri]
    if same.all():
        tel.source["symbols"] = (
            f"the emulator also read the attitude by symbol: the frames agree with it bit for bit on all "
            f"{common.size} steps both have"
        )
    else:
        first = int(common[np.argmax(~same)])
        tel.source["symbols"] = (
            f"the emulator also read the attitude by symbol: the frames differ from it on {int((~same).sum())} of "
            f"{common.size} steps (first at step {first}): the frames do not carry the filter's globals"
        )
    return tel

"""Plausibility checks behind the frame check: a CRC-valid frame that cannot be what the firmware sent is held back.

A frame check passes a damaged candidate now and then (v1's CRC-16: one in 65 536; v2's CRC-32: one in 4.3·10⁹):

* **Values** (binary frames of protocol **v1** only): every float finite; ``|acc_mg|`` ≤ 10⁵ and ``|gyro_mdps|`` ≤
  2·10⁷, several times the sensors' full scale (±16 g, ±2000 dps); quaternion components within ±2.
* **Sequence and time** (both versions): against the last accepted attitude frame (the anchor), the step
  difference ``d = (seq - seq_anchor) mod 2¹⁶`` is within ``1 .. WINDOW_STEPS`` and ``d·P − TOL_US ≤ Δt_us ≤ 3·d·P +
  0.5 s`` (P the AHRS period; the upper side allows skipped steps). A status frame must fit with ``d ≥ 0``.

A v2 frame with bad values that continues the sequence and time is what the firmware sent (its filter diverged):
kept and flagged (``values_bad``). An attitude frame that does not fit the anchor is held back; ``confirm`` such
frames in a row that fit each other (a restart) are released as the new anchor, else dropped (``held_back``).
Other frames, text-mode rows and the first attitude frame pass. :class:`PlausibilityGate` is the one implementation,
fed frames by the incremental decoder and rows by the bulk one.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from steval_link import constants as C
from steval_link.link import protocol as P

#: Largest plausible magnitudes of the AHRS inputs (see the module docstring).
ACC_MAX_MG = 1.0e5
GYRO_MAX_MDPS = 2.0e7
Q_MAX = 2.0
#: The firmware keeps |q| ≈ 0.9983 (release 170120 normalises with the squares from before the update); a q further
#: than this from the unit sphere means its filter left it (compare's divergence diagnosis, the replay summary).
Q_NORM_TOL = 0.05
#: The gate's rule: at most this many steps forward, time within ``TOL_US`` of them, ``CONFIRM`` frames a restart.
WINDOW_STEPS = 8192  # 50.7 s of AHRS steps
TOL_US = 5_000.0
CONFIRM = 3
PERIOD_US = 1e6 / C.AHRS_RATE_HZ


def _all_within(values, limit: float) -> bool:
    return all(-limit <= v <= limit for v in values)  # also False for NaN


def attitude_values_ok(acc_mg, gyro_mdps, q_wxyz, thz_rad) -> bool:
    """True when an attitude frame's values are ones the firmware can send."""
    inputs_ok = _all_within(acc_mg, ACC_MAX_MG) and _all_within(gyro_mdps, GYRO_MAX_MDPS)
    return inputs_ok and _all_within(q_wxyz, Q_MAX) and math.isfinite(thz_rad)


def status_values_ok(q_wxyz, int_xyz, kp_ground, kp_flight, ki, dt_s) -> bool:
    """True when a status frame's filter snapshot and settings are finite (and q within ±2)."""
    return _all_within(q_wxyz, Q_MAX) and all(math.isfinite(v) for v in (*int_xyz, kp_ground, kp_flight, ki, dt_s))


def attitude_frame_bad(frame) -> bool:
    """``values_bad`` of an ``AttitudeFrame``: see :func:`attitude_rows_bad`."""
    if frame.exact:
        return not attitude_values_ok(frame.acc_mg, frame.gyro_mdps, frame.q_wxyz, frame.thz_rad)
    vals = (*frame.acc_mg, *frame.gyro_mdps, frame.thz_rad, frame.thx_rad, frame.thy_rad)
    if any(math.isinf(v) for v in vals):
        return True
    # a row of text telemetry: what was printed, NaN for the rest; an angle or the accelerometer
    return not (
        math.isfinite(frame.thx_rad) or math.isfinite(frame.thy_rad) or all(math.isfinite(v) for v in frame.acc_mg)
    )


def _within(v, limit: float, width: int) -> np.ndarray:
    """(N,) bool: every one of the ``width`` values of each row is within ±``limit`` (False for NaN)."""
    v = np.asarray(v).reshape(-1, width)
    ok = np.abs(v[:, 0]) <= limit  # column by column: much faster than a reduction over a short axis
    for k in range(1, width):
        ok &= np.abs(v[:, k]) <= limit
    return ok


def attitude_rows_bad(exact, acc_mg, gyro_mdps, q_wxyz, thz_rad, thx_rad, thy_rad) -> np.ndarray:
    """(N,) bool: a binary row failing :func:`attitude_values_ok`; a text row with an infinite value, or with neither
    an angle nor the accelerometer."""
    thz = np.asarray(thz_rad).reshape(-1)
    n = thz.shape[0]
    exact = np.broadcast_to(np.asarray(exact, bool), (n,))
    ok = _within(acc_mg, ACC_MAX_MG, 3) & _within(gyro_mdps, GYRO_MAX_MDPS, 3) & np.isfinite(thz)
    if exact.all():
        return ~(ok & _within(q_wxyz, Q_MAX, 4))
    # text rows (no q): no infinity, and an angle or the accelerometer
    acc = np.asarray(acc_mg, np.float64).reshape(-1, 3)
    gyro = np.asarray(gyro_mdps, np.float64).reshape(-1, 3)
    thx = np.broadcast_to(np.asarray(thx_rad, np.float64), (n,))
    thy = np.broadcast_to(np.asarray(thy_rad, np.float64), (n,))
    no_inf = ~(np.isinf(acc).any(axis=1) | np.isinf(gyro).any(axis=1) | np.isinf(thz) | np.isinf(thx) | np.isinf(thy))
    ok_txt = no_inf & (np.isfinite(thx) | np.isfinite(thy) | np.isfinite(acc).all(axis=1))
    return ~np.where(exact, ok & _within(q_wxyz, Q_MAX, 4), ok_txt)


def attitude_inputs_bad(acc_mg, gyro_mdps) -> np.ndarray:
    """(N,) bool, rows whose filter inputs (acc, gyro) are non-finite or beyond the limits."""
    return ~(_within(acc_mg, ACC_MAX_MG, 3) & _within(gyro_mdps, GYRO_MAX_MDPS, 3))


def status_rows_bad(exact, q_wxyz, int_xyz, kp_ground, kp_flight, ki, dt_s) -> np.ndarray:
    """(N,) bool, binary status rows failing :func:`status_values_ok`."""
    ok = _within(q_wxyz, Q_MAX, 4)
    ints = np.asarray(int_xyz).reshape(-1, 3)
    for v in (ints[:, 0], ints[:, 1], ints[:, 2], kp_ground, kp_flight, ki, dt_s):
        ok &= np.isfinite(np.asarray(v))
    return np.asarray(exact, bool) & ~ok


def q_off_sphere(q_wxyz) -> np.ndarray:
    """(N,) bool: q non-finite or ``| |q| − 1 |`` > :data:`Q_NORM_TOL`."""
    q = np.asarray(q_wxyz, dtype=np.float64).reshape(-1, 4)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.sqrt((q * q).sum(axis=1))
        return ~(np.abs(norm - 1.0) <= Q_NORM_TOL)


def _count(n: int) -> str:
    return f"{n:,}"


def values_bad_sentence(n: int, first_step: int | None, first_t_s: float | None, *, inputs: bool = False) -> str:
    """The sentence on ``n`` kept frames with bad values from ``first_step`` on; ``inputs``: acc and gyro bad too."""
    where = "" if first_step is None else f" from step {first_step} on"
    if first_t_s is not None and math.isfinite(first_t_s):
        where += f" (t = {first_t_s:.3f} s)"
    noun = "frame carries" if n == 1 else "frames carry"
    if inputs:
        return (
            f"{_count(n)} {noun} NaN or out-of-range values{where}, the filter inputs (acc, gyro) too: the "
            "firmware's sensor path before the filter; check the ISR, offsets and averaging"
        )
    return f"{_count(n)} {noun} NaN or |q| > 2{where}: the firmware's own filter output; check ahrs.c"


def held_back_sentence(n: int, held_values: int = 0) -> str:
    """The sentence about ``n`` CRC-valid frames held back, ``held_values`` of them (v1 only) for their values."""
    noun = "frame" if n == 1 else "frames"
    parts = []
    if held_values:
        parts.append(
            f"{_count(held_values)} for NaN or out-of-range values (protocol v1: its CRC-16 cannot tell the "
            "firmware's own filter output from damage; if the firmware's filter diverged, check ahrs.c)"
        )
    if n - held_values:
        parts.append(
            f"{_count(n - held_values)} for a sequence and time that do not continue (a damaged or foreign "
            "frame that passed its CRC, or a firmware restart not confirmed)"
        )
    return f"{_count(n)} CRC-valid {noun} held back, not shown: " + "; ".join(parts)


def _steps_fit(d, dt, d_min: int):
    """The sequence-and-time rule for ``d`` steps and ``dt`` µs forward (Python ints or numpy arrays alike)."""
    return (d >= d_min) & (d <= WINDOW_STEPS) & (dt >= d * PERIOD_US - TOL_US) & (dt <= 3.0 * d * PERIOD_US + 500_000.0)


def _fits(seq_a: int, t_a: int, seq: int, t_us: int, d_min: int) -> bool:
    return bool(_steps_fit((seq - seq_a) % P.SEQ_MODULUS, (t_us - t_a) % P.T_US_MODULUS, d_min))


class PlausibilityGate:
    """Sequential gate over attitude/status rows (see the module docstring). Items are opaque to the gate."""

    def __init__(self) -> None:
        self.held_back = 0  #: frames dropped for good
        self.held_values = 0  #: of those, frames offered with ``values_ok`` False (protocol v1's value checks)
        self._anchor: tuple[int, int] | None = None
        self._pending: list[tuple[int, int, Any]] = []

    def offer(self, kind: int, seq: int, t_us: int, values_ok: bool, item: Any) -> list[Any]:
        """Offer one row (``seq``: the attitude ``seq`` or status ``step``); returns the items it releases, in order."""
        if not values_ok:
            self.held_back += 1
            self.held_values += 1
            return []
        seq %= P.SEQ_MODULUS
        anchor = self._anchor
        if kind == P.TYPE_STATUS:
            if anchor is None or _fits(anchor[0], anchor[1], seq, t_us, 0):
                return [item]
            self.held_back += 1
            return []
        if anchor is None or _fits(anchor[0], anchor[1], seq, t_us, 1):
            self._anchor = (seq, t_us)
            self.held_back += len(self._pending)  # a restart not confirmed
            self._pending.clear()
            return [item]
        pend = self._pending
        if pend and _fits(pend[-1][0], pend[-1][1], seq, t_us, 1):
            pend.append((seq, t_us, item))
        else:
            self.held_back += len(pend)
            pend[:] = [(seq, t_us, item)]
        if len(pend) >= CONFIRM:
            self._anchor = (pend[-1][0], pend[-1][1])
            items = [x[2] for x in pend]
            pend.clear()
            return items
        return []

    def finish(self) -> None:
        """End of stream: frames still held are dropped (counted)."""
        self.held_back += len(self._pending)
        self._pending = []


def gate_rows(att: np.ndarray, sta: np.ndarray, gate: PlausibilityGate | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Keep masks of attitude and status records (stream order) as ``gate`` fed row by row would decide them."""
    gate = gate or PlausibilityGate()
    keep_a, keep_s = np.ones(len(att), bool), np.ones(len(sta), bool)
    ea, es = np.flatnonzero(att["exact"]), np.flatnonzero(sta["exact"])
    if len(ea) == 0 and len(es) == 0:
        return keep_a, keep_s
    a, s = att[ea], sta[es]
    # values gate protocol v1 frames only (v2: kept and flagged); the frame size tells the version
    vals_a, vals_s = np.ones(len(a), bool), np.ones(len(s), bool)
    b = a[a["nbytes"] != P.ATTITUDE_FRAME_SIZE]
    vals_a[a["nbytes"] != P.ATTITUDE_FRAME_SIZE] = ~attitude_rows_bad(
        True, b["acc_mg"], b["gyro_mdps"], b["q_wxyz"], b["thz_rad"], 0.0, 0.0
    )
    b = s[s["nbytes"] != P.STATUS_FRAME_SIZE]
    vals_s[s["nbytes"] != P.STATUS_FRAME_SIZE] = ~status_rows_bad(
        True, b["q_wxyz"], b["int_xyz"], b["kp_ground"], b["kp_flight"], b["ki"], b["dt_s"]
    )
    # fast path: every attitude row fits the previous one and every status the attitude row before it
    clean = bool(vals_a.all() and vals_s.all()) and gate._anchor is None and not gate._pending
    if clean and len(a) > 1:
        d = (a["seq"][1:].astype(np.int64) - a["seq"][:-1]) % P.SEQ_MODULUS
        dt = (a["t_us"][1:].astype(np.int64) - a["t_us"][:-1]) % P.T_US_MODULUS
        clean = bool(np.all(_steps_fit(d, dt, 1)))
    if clean and len(s):
        j = np.searchsorted(a["offset"], s["offset"]) - 1
        has = j >= 0
        if has.any():
            jj = j[has]
            d = (s["step"][has].astype(np.int64) - a["seq"][jj]) % P.SEQ_MODULUS
            dt = (s["t_us"][has].astype(np.int64) - a["t_us"][jj]) % P.T_US_MODULUS
            clean = bool(np.all(_steps_fit(d, dt, 0)))
    if clean:
        if len(a):
            gate._anchor = (int(a["seq"][-1]), int(a["t_us"][-1]))
        return keep_a, keep_s
    # slow path: the gate row by row, in stream order
    keep_a[ea], keep_s[es] = False, False
    rows = [(o, P.TYPE_ATTITUDE, j) for j, o in enumerate(a["offset"].tolist())]
    rows += [(o, P.TYPE_STATUS, j) for j, o in enumerate(s["offset"].tolist())]
    for _, kind, j in sorted(rows):
        r, idx, vals, key = (a, ea, vals_a, "seq") if kind == P.TYPE_ATTITUDE else (s, es, vals_s, "step")
        released = gate.offer(kind, int(r[key][j]), int(r["t_us"][j]), bool(vals[j]), (kind, int(idx[j])))
        for k, i in released:
            (keep_a if k == P.TYPE_ATTITUDE else keep_s)[i] = True
    return keep_a, keep_s

"""A BLE capture's notifications as arrays with units in the names (:class:`BleTelemetry`,
:func:`decode_notifications`), and its motion samples on a uniform time grid for the estimators
(:func:`uniform_inputs`: dt from the cadence found, :mod:`steval_link.link.ble_cadence`).

Payloads and ticks: :mod:`steval_link.link.ble_payloads`. Pure functions and small classes over numpy arrays; no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from steval_link.link.ble_cadence import (
    POLLED,
    Cadence,
    break_mask,
    cadence_numbers,
    motion_cadence,
    sender_phase,
)
from steval_link.link.ble_payloads import (
    CHAR_ARMING,
    CHAR_ENV,
    CHAR_MOTION,
    CHAR_NAMES,
    TICK_S,
    BadPayload,
    unpack_payload,
    unwrap_ticks,
)

__all__ = ["BleTelemetry", "decode_notifications", "UniformInputs", "uniform_inputs"]


@dataclass
class BleTelemetry:
    """Every notification of a BLE capture as arrays (units in the names). ``t_fw_s`` = unwrapped tick × 8 ms
    (the drone's clock, 8 ms resolution); ``t_host_s`` = arrival, s since the capture started."""

    motion_t_host_s: np.ndarray
    motion_tick: np.ndarray  #: (N,) int64, unwrapped
    motion_t_fw_s: np.ndarray
    acc_mg: np.ndarray  #: (N,3) float32
    gyro_mdps: np.ndarray  #: (N,3) float32 (payload × 100)
    mag_mgauss: np.ndarray  #: (N,3) float32
    env_t_host_s: np.ndarray
    env_t_fw_s: np.ndarray
    pressure_hpa: np.ndarray
    battery_pct: np.ndarray
    temperature_c: np.ndarray
    rssi_dbm: np.ndarray
    arming_t_host_s: np.ndarray
    arming_t_fw_s: np.ndarray
    armed: np.ndarray
    console: list[tuple[float, str, str]] = field(default_factory=list)  #: (t_host_s, "stdout"/"stderr", text)
    counts: dict[str, int] = field(default_factory=dict)  #: notifications per characteristic name
    bad_payloads: int = 0  #: notifications of the wrong length (skipped)
    unknown: int = 0  #: notifications of an unknown characteristic id (skipped)
    repeated_reads: int = 0  #: motion samples received again (same tick and payload: a read of an unchanged value)
    #: motion rows that are the first after a reconnection (the link was lost before them: the samples in between
    #: were never sent, so that gap is no drop); set from the capture's events (``analysis.ble.load_ble``)
    motion_breaks: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __len__(self) -> int:
        return len(self.motion_tick)

    def cadence(self) -> Cadence | None:
        """The motion stream's cadence (:func:`motion_cadence`), None below 2 samples."""
        return motion_cadence(self.motion_tick, self.repeated_reads, self.motion_breaks)

    @property
    def interval_s(self) -> float | None:
        c = self.cadence()
        return None if c is None else c.interval_s

    def dropped_estimate(self) -> int:
        """Motion samples missing between the first and the last (:attr:`Cadence.dropped`)."""
        c = self.cadence()
        return 0 if c is None else c.dropped

    def motion_table(self) -> dict[str, np.ndarray]:
        """One row per motion notification, for CSV/Parquet (env and arming values held from their last one)."""
        tab = {"t_host_s": self.motion_t_host_s, "tick": self.motion_tick, "t_fw_s": self.motion_t_fw_s}
        for name, arr in (("acc", self.acc_mg), ("gyro", self.gyro_mdps), ("mag", self.mag_mgauss)):
            unit = {"acc": "mg", "gyro": "mdps", "mag": "mgauss"}[name]
            for i, ax in enumerate("xyz"):
                tab[f"{name}_{ax}_{unit}"] = arr[:, i]
        for key, t, v in (
            ("pressure_hpa", self.env_t_fw_s, self.pressure_hpa),
            ("battery_pct", self.env_t_fw_s, self.battery_pct),
            ("temperature_c", self.env_t_fw_s, self.temperature_c),
            ("rssi_dbm", self.env_t_fw_s, self.rssi_dbm),
            ("armed", self.arming_t_fw_s, self.armed.astype(np.float32)),
        ):
            tab[key] = _held(self.motion_t_fw_s, t, v)
        return tab


def _held(t_at: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v`` at each time of ``t_at``: its last value at or before it (NaN before the first)."""
    out = np.full(len(t_at), np.nan, dtype=np.float32)
    if len(t):
        i = np.searchsorted(t, t_at, side="right") - 1
        ok = i >= 0
        out[ok] = np.asarray(v, dtype=np.float32)[i[ok]]
    return out


def decode_notifications(records: Iterable[tuple[float, int, bytes]]) -> BleTelemetry:
    """``(t_host_s, char id, payload)`` in arrival order → :class:`BleTelemetry`. Wrong-length notifications are
    counted and skipped (never raise); a motion payload equal to the previous one (same tick, same values: a poller
    reading an unchanged characteristic) is one sample, counted in ``repeated_reads``."""
    mo: list[tuple] = []
    en: list[tuple] = []
    ar: list[tuple] = []
    console: list[tuple[float, str, str]] = []
    counts = {n: 0 for n in CHAR_NAMES.values()}
    bad = unknown = repeated = 0
    last_motion = None
    for t, cid, payload in records:
        name = CHAR_NAMES.get(cid)
        if name is None:
            unknown += 1
            continue
        counts[name] += 1
        try:
            if cid == CHAR_MOTION:
                row = unpack_payload(cid, payload)
                if bytes(payload) == last_motion:  # the same sample read again (same tick and values)
                    repeated += 1
                    continue
                last_motion = bytes(payload)
                mo.append((t, *row))
            elif cid == CHAR_ENV:
                en.append((t, *unpack_payload(cid, payload)))
            elif cid == CHAR_ARMING:
                ar.append((t, *unpack_payload(cid, payload)))
            else:
                console.append((t, name, bytes(payload).decode("utf-8", "replace")))
        except BadPayload:
            bad += 1
    m = np.array(mo, dtype=np.float64).reshape(-1, 11)
    e = np.array(en, dtype=np.float64).reshape(-1, 6)
    a = np.array(ar, dtype=np.float64).reshape(-1, 3)
    # one clock for all three: the ticks of every characteristic unwrapped together, in arrival order
    order = [(r[0], k, j) for k, rows in enumerate((mo, en, ar)) for j, r in enumerate(rows)]
    order.sort(key=lambda x: x[0])  # stable: arrival order kept for equal host times
    rows_of = (m, e, a)
    all_ticks = np.array([rows_of[k][j, 1] for _, k, j in order], dtype=np.int64)
    all_t = np.array([t for t, _, _ in order], dtype=np.float64)
    unwrapped = unwrap_ticks(all_ticks, all_t) if len(order) else np.zeros(0, np.int64)
    ticks_of: list[np.ndarray] = [np.zeros(len(r), np.int64) for r in rows_of]
    for (_, k, j), u in zip(order, unwrapped):
        ticks_of[k][j] = u
    mtick = ticks_of[0]

    return BleTelemetry(
        motion_t_host_s=m[:, 0].copy(),
        motion_tick=mtick,
        motion_t_fw_s=mtick * TICK_S,
        acc_mg=m[:, 2:5].astype(np.float32),
        gyro_mdps=(m[:, 5:8] * 100).astype(np.float32),
        mag_mgauss=m[:, 8:11].astype(np.float32),
        env_t_host_s=e[:, 0].copy(),
        env_t_fw_s=ticks_of[1] * TICK_S,
        pressure_hpa=(e[:, 2] / 100).astype(np.float32),
        battery_pct=(e[:, 3] / 10).astype(np.float32),
        temperature_c=(e[:, 4] / 10).astype(np.float32),
        rssi_dbm=(e[:, 5] / 10).astype(np.float32),
        arming_t_host_s=a[:, 0].copy(),
        arming_t_fw_s=ticks_of[2] * TICK_S,
        armed=a[:, 2].astype(bool),
        console=console,
        counts=counts,
        bad_payloads=bad,
        unknown=unknown,
        repeated_reads=repeated,
    )


@dataclass
class UniformInputs:
    """Motion samples on a uniform time grid for the estimators (fixed dt = ``dt_s``)."""

    t_s: np.ndarray  #: (M,) firmware time of each row, s (from the ticks)
    acc_mg: np.ndarray  #: (M,3) float32
    gyro_mdps: np.ndarray  #: (M,3) float32
    filled: np.ndarray  #: (M,) bool: True for rows held over a dropped notification
    dt_s: float
    source_row: np.ndarray  #: (M,) int64: the motion notification each row holds
    cadence: Cadence | None = None  #: the cadence the grid follows


def uniform_inputs(ble: BleTelemetry, cadence: Cadence | None = None) -> UniformInputs:
    """The estimators' inputs with dt from the cadence found (:func:`motion_cadence`): one row per sender sample
    (:func:`cadence_numbers`); a dropped notification's row holds the last sample received. A steady or polled
    stream has one row per sample received and none held; the samples a lost link never sent
    (:attr:`BleTelemetry.motion_breaks`) have no rows (the estimators step once over that gap)."""
    n = len(ble)
    c = cadence if cadence is not None else ble.cadence()
    if n == 0 or c is None:
        z = np.zeros((n, 3), np.float32)
        return UniformInputs(
            ble.motion_t_fw_s.copy(),
            ble.acc_mg.copy() if n else z,
            ble.gyro_mdps.copy() if n else z,
            np.zeros(n, bool),
            0.0,
            np.arange(n),
            c,
        )
    dt = c.interval_s
    k = cadence_numbers(ble.motion_tick, c)
    rows = np.ones(k[-1] + 1, bool)
    for b in np.flatnonzero(break_mask(n, ble.motion_breaks)):
        rows[k[b - 1] + 1 : k[b]] = False  # never sent: the link was down
    numbers = np.flatnonzero(rows)
    src = np.searchsorted(k, numbers, side="right") - 1  # the last sample received at or before
    filled = np.ones(len(numbers), bool)
    filled[np.searchsorted(numbers, k)] = False
    if c.kind == POLLED:  # reads at the host's moments: each row at its own tick (mid-tick)
        t_grid = ble.motion_t_fw_s + TICK_S / 2
    else:
        t_grid = sender_phase(ble.motion_t_fw_s, dt) + numbers * dt
    return UniformInputs(t_grid, ble.acc_mg[src], ble.gyro_mdps[src], filled, float(dt), src, c)

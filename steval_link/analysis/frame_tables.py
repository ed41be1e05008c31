"""A decoded capture as one column table per frame type, units in the column names (``steval export --mat``,
``--mcap``): ``attitude`` (the CSV's columns: :meth:`Telemetry.attitude_table` and the flight-control columns on
the rows of their steps), ``status``, ``fc`` (one row per flight-control frame), ``ack``, ``command`` and
``text``; and the capture's settings and header as plain dicts."""

from __future__ import annotations

from typing import Any

import numpy as np

from steval_link.analysis.diagnosis import filter_settings_report
from steval_link.link import protocol as P

#: columns of the status and flight-control tables (and MCAP messages) named otherwise in the frame tables
RENAMED = {
    "ahrs_cycles_min": "cyc_min",
    "ahrs_cycles_mean": "cyc_mean",
    "ahrs_cycles_max": "cyc_max",
    "ahrs_cycles_n": "cyc_n",
    "tx_dropped_frames": "tx_dropped",
    "queue_peak_bytes": "queue_peak",
    "target_rad": "euler_rc_rad",
}
_STATUS_COLUMNS = (
    "kp_ground kp_flight ki dt_s min_thr flags ahrs_cycles_min ahrs_cycles_mean ahrs_cycles_max ahrs_cycles_n "
    "cpu_hz tx_dropped_frames baud queue_peak_bytes"
)


def attitude_table(tel) -> dict[str, np.ndarray]:
    """The CSV's columns: one row per attitude frame, flight-control columns joined on by step (NaN elsewhere)."""
    return tel.attitude_table() | tel.flight_columns()


def status_table(tel) -> dict[str, np.ndarray]:
    """One row per status frame: the filter snapshot (q, integrals), the settings, the AHRS cycle counts, the link
    counters, the flags (bit 0 no correction, 1 fresh squares, 2 text mode, 3 event, 4 in-flight tuning, 5 armed)."""
    s = tel.status
    cols: dict[str, np.ndarray] = {"step": np.asarray(s.step, np.int64), "t_fw_s": s.t_fw_s, "t_host_s": s.t_host_s}
    for name, values, axes in (("q", s.q_wxyz, "wxyz"), ("int", s.int_xyz, "xyz")):
        for i, c in enumerate(axes):
            cols[f"{name}_{c}"] = np.asarray(values)[:, i] if len(s) else np.zeros(0, np.float32)
    for name in _STATUS_COLUMNS.split():
        cols[name] = getattr(s, RENAMED.get(name, name))
    version = np.asarray(s.fw_version) if len(s) else np.zeros((0, 2), np.uint8)
    cols["fw_version_major"], cols["fw_version_minor"] = version[:, 0], version[:, 1]
    for name in ("fc_every", "param_gen", "exact", "offset"):
        cols[name] = getattr(s, name)
    return {k: np.asarray(v) for k, v in cols.items()}


def fc_table(tel) -> dict[str, np.ndarray]:
    """One row per flight-control frame, with the CSV's flight-control column names."""
    fc = tel.fc
    cols: dict[str, np.ndarray] = {"step": fc.step, "t_fw_s": fc.t_fw_s, "t_host_s": fc.t_host_s}
    n = len(fc)

    def part(a, i, dtype=np.float32):
        a = np.asarray(a)
        return a[:, i] if n else np.zeros(0, dtype)

    xyz = ("x_pitch", "y_roll", "z_yaw")
    for values, pattern, names, dtype in (
        (fc.euler_rc_rad, "target_{}_rad", ("thx_pitch", "thy_roll", "thz_yaw"), np.float32),
        (fc.rc, "rc_{}", ("ail", "ele", "rud", "thr"), np.int16),
        (fc.outer_s1_radps, "outer_s1_{}_radps", xyz, np.float32),
        (fc.inner_s2_pwm, "inner_s2_{}_pwm", xyz, np.float32),
        (fc.motor_pwm, "motor{}_pwm", "1234", np.float32),
    ):
        for i, name in enumerate(names):
            cols[pattern.format(name)] = part(values, i, dtype)
    cols["vbat_v"] = fc.vbat_v
    flags = np.asarray(fc.fc_flags)
    for bit, name in ((P.FC_ARMED, "fc_armed"), (P.FC_RC_CONNECTED, "fc_rc_connected"), (P.FC_RC_CAL, "fc_rc_cal")):
        cols[name] = (flags & bit) != 0
    cols["fc_every"] = fc.fc_every
    cols["offset"] = fc.offset
    return {k: np.asarray(v) for k, v in cols.items()}


def record_table(rows: np.ndarray) -> dict[str, np.ndarray]:
    """A structured array (acks, commands) as columns; its (k,)-shaped fields split into ``name_0`` ..."""
    cols: dict[str, np.ndarray] = {}
    for name in rows.dtype.names or ():
        if name == "reserved":
            continue
        v = np.asarray(rows[name])
        if v.ndim == 1:
            cols[name] = v
        else:
            for i in range(v.shape[1]):
                cols[f"{name}_{i}"] = v[:, i]
    return cols


def frame_tables(tel) -> dict[str, dict[str, np.ndarray]]:
    """One column table per frame type the capture holds (``attitude`` always), text records and text lines."""
    out = {"attitude": attitude_table(tel)}
    if len(tel.status):
        out["status"] = status_table(tel)
    if len(tel.fc):
        out["fc"] = fc_table(tel)
    if len(tel.acks):
        out["ack"] = record_table(tel.acks)
    if len(tel.commands):
        out["command"] = record_table(tel.commands)
    if len(getattr(tel, "text_series", ())):
        out["text_records"] = tel.text_series.table()  # a row per record of text telemetry, a column per series
    if tel.text:
        out["text"] = {
            "t_host_s": np.array([t for t, _ in tel.text], np.float64),
            "text": np.array([s for _, s in tel.text], dtype=object),
        }
    return out


def _plain(v: Any) -> Any:
    """JSON-like values only (no None: MATLAB has no null; None becomes NaN or an empty string)."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if v is None:
        return ""
    return v


def settings_of(tel) -> dict[str, Any]:
    """The filter settings the status frames report, or ``{"from": "none"}`` without status frames."""
    return _plain(filter_settings_report(tel) or {"from": "none"})


def header_of(tel) -> dict[str, Any]:
    """The capture header (``port``, ``baud``, ``extra``, ...) and the file's ``path`` and ``kind``."""
    src = tel.source or {}
    return _plain(
        dict(src.get("header") or {}) | {"path": str(src.get("path") or ""), "kind": str(src.get("kind") or "")}
    )

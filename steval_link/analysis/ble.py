"""A BLE capture (ST's stock firmware over Bluetooth) replayed: notifications → arrays → estimators → summary.

The motion notifications carry one ISR sample each (after offset removal, before the gyro IIR and the boxcar),
with an 8 ms tick. The ticks tell the stream's cadence (:func:`steval_link.link.ble_cadence.motion_cadence`: the
sender's own rate, ST's congestion skips, gaps of another cadence, or a poller's reads), which the summary states;
the estimators run on a uniform grid with dt from that cadence, rows held only over notifications that were sent
and lost (:func:`steval_link.link.ble_telemetry.uniform_inputs`). The firmware's own attitude is not sent over
BLE, and the ST-Mahony replica run on these samples cannot be bit-exact with the drone (different inputs, different
dt): the summary and the viewer say so (:data:`NOT_BIT_EXACT`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.link.ble_payloads import TICK_WRAP, ble_records, layout_named
from steval_link.link.ble_telemetry import (
    NOT_BIT_EXACT,
    BleTelemetry,
    UniformInputs,
    decode_notifications,
    layout_rows,
    link_notes,
    uniform_inputs,
)

__all__ = [
    "NOT_BIT_EXACT",
    "ble_layout_of",
    "load_ble",
    "reconnect_rows",
    "run_ble_estimators",
    "summarize_ble",
    "format_ble_summary",
]


def load_ble(src) -> BleTelemetry:
    """The notifications of a BLE capture (a ``link.load.Recording``), with the motion rows that follow a
    reconnection (its ``reconnect`` events: the gap before them is the link's, not a drop); UserError without
    motion notifications."""
    ble = decode_notifications(ble_records(src.chunks or {}))
    if len(ble) == 0:
        n = sum(ble.counts.values())
        raise UserError(
            f"{src.path}: a BLE capture without motion notifications ({n} other notifications): nothing to replay."
        )
    ble.motion_breaks = reconnect_rows(ble, getattr(src, "events", None) or [])
    return ble


def reconnect_rows(ble: BleTelemetry, events) -> np.ndarray:
    """The motion rows that are the first to arrive after each ``reconnect`` event of a capture."""
    t = np.array([e.t_host_s for e in events if e.kind == "reconnect"], dtype=np.float64)
    rows = np.searchsorted(ble.motion_t_host_s, t, side="left")
    return np.unique(rows[(rows > 0) & (rows < len(ble))]).astype(np.int64)


def ble_layout_of(src) -> str:
    """The motion layout a BLE capture's header names (``extra.ble_layout``; stock when it names none)."""
    extra = (getattr(src, "header", None) or {}).get("extra") or {}
    return str(extra.get("ble_layout") or "stock") if isinstance(extra, dict) else "stock"


def run_ble_estimators(
    ble: BleTelemetry, names: Sequence[str], layout: str = "stock"
) -> tuple[UniformInputs, dict[str, Any], dict]:
    """Run each named estimator over the uniform inputs (dt = the interval of the cadence found in the ticks,
    :func:`~steval_link.link.ble_cadence.motion_cadence`; thr 0: BLE does not carry gTHR); returns (inputs,
    name → estimate, name → note). A layout that sends the drone's attitude has no sensor values: no estimator."""
    inputs = uniform_inputs(ble)
    dt = inputs.dt_s
    out, notes = {}, {}
    if layout_named(layout).sends_attitude:
        return inputs, out, notes
    if names and not dt > 0:
        raise UserError("the BLE capture's motion samples all share one tick: no interval for the estimators")
    thr = np.zeros(len(inputs.t_s), dtype=np.int16)
    for name in names:
        try:
            if name in ("st-mahony", "st_mahony"):
                est = registry.create(name, dt_s=dt)
            elif name == "accel" or not registry.accepts(name, "rate_hz"):
                est = registry.create(name)
            else:
                est = registry.create(name, rate_hz=1.0 / dt)
        except ImportError as exc:
            raise UserError(f"estimator {name!r} needs a package that is not installed ({exc})") from None
        except ValueError as exc:
            raise UserError(f"estimator {name!r}: {exc}") from None
        out[name] = est.run(inputs.acc_mg, inputs.gyro_mdps, thr)
        notes[name] = f"dt {dt * 1e3:.3f} ms from the ticks' cadence"
    return inputs, out, notes


def summarize_ble(ble: BleTelemetry, src, inputs: UniformInputs | None = None, layout: str = "stock") -> dict[str, Any]:
    """A JSON-ready summary of a BLE capture (``layout``: what its motion notifications hold)."""
    lay = layout_named(layout)
    header = getattr(src, "header", {}) or {}
    extra = header.get("extra") or {}
    t = ble.motion_t_host_s
    cadence = inputs.cadence if inputs is not None and inputs.cadence is not None else ble.cadence()
    interval = cadence.interval_s if cadence is not None else None
    wraps = int((ble.motion_tick[-1] // TICK_WRAP) - (ble.motion_tick[0] // TICK_WRAP)) if len(ble) else 0
    events = [
        {"t_host_s": round(e.t_host_s, 6), "kind": e.kind, "text": e.text} for e in getattr(src, "events", []) or []
    ]

    def stat(v: np.ndarray, how) -> float | None:
        v = np.asarray(v, dtype=np.float64)
        return round(float(how(v)), 3) if v.size else None

    s = {
        "kind": "ble",
        "file": str(getattr(src, "path", "")),
        "port": header.get("port"),
        "device": extra.get("device"),
        "address": extra.get("address"),
        "emulated": bool(extra.get("emulated", False)),
        "start_time_utc": header.get("start_time_utc"),
        "tool_version": header.get("tool_version"),
        "notifications": dict(ble.counts),
        "bad_payloads": ble.bad_payloads,
        "unknown_characteristics": ble.unknown,
        "duration_host_s": round(float(t[-1] - t[0]), 3) if len(t) > 1 else 0.0,
        "duration_fw_s": round(float(ble.motion_t_fw_s[-1] - ble.motion_t_fw_s[0]), 3) if len(ble) > 1 else 0.0,
        "motion_rate_hz": round(1.0 / interval, 2) if interval else None,
        "motion_interval_ms": round(interval * 1e3, 3) if interval else None,
        "motion_dropped_estimate": cadence.dropped if cadence is not None else 0,
        "motion_cadence": cadence.kind if cadence is not None else None,
        "motion_cadence_text": cadence.describe() if cadence is not None else None,
        "motion_gaps": cadence.gaps if cadence is not None else 0,
        "motion_repeated_reads": ble.repeated_reads,
        "tick_wraps": wraps,
        "estimator_dt_ms": round(inputs.dt_s * 1e3, 3) if inputs is not None and inputs.dt_s else None,
        "rows_held_over_drops": int(inputs.filled.sum()) if inputs is not None else None,
        "pressure_hpa_mean": stat(ble.pressure_hpa, np.mean),
        "temperature_c_mean": stat(ble.temperature_c, np.mean),
        "battery_pct_last": stat(ble.battery_pct[-1:], np.mean),
        "rssi_dbm_mean": stat(ble.rssi_dbm, np.mean),
        "armed_notifications": int(ble.armed.sum()),
        "console_lines": len(ble.console),
        "events": events,
        "ble_layout": lay.name,
        "note": " ".join(link_notes(ble.acc_mg, lay)),
        "attitude_deg_range": _attitude_range(ble, lay),
        "warnings": list(getattr(src, "warnings", []) or []),
    }
    return s


def _attitude_range(ble: BleTelemetry, layout) -> dict[str, list[float]] | None:
    """The drone's own pitch and roll range, deg, when the layout sends them (None: it does not)."""
    if not layout.sends_attitude or not len(ble):
        return None
    _, _, thx, thy, _ = layout_rows(ble.acc_mg, ble.gyro_mdps, layout)
    return {
        name: [round(float(np.degrees(v.min())), 2), round(float(np.degrees(v.max())), 2)]
        for name, v in (("thx", thx), ("thy", thy))
    }


def format_ble_summary(s: dict[str, Any]) -> list[str]:
    """The text lines of ``steval replay`` for a BLE capture."""
    counts = ", ".join(f"{k} {v}" for k, v in s["notifications"].items() if v)
    dev = " ".join(x for x in (s.get("device"), s.get("address")) if x) or s.get("port") or "?"
    lines = [
        f"file              {s['file']}  (BLE capture{', emulated firmware' if s['emulated'] else ''})",
        f"device            {dev}",
        f"notifications     {counts}",
        f"duration          {s['duration_fw_s']:.3f} s drone clock (8 ms ticks, {s['tick_wraps']} wrap(s)), "
        f"{s['duration_host_s']:.3f} s host",
    ]
    if s["motion_cadence_text"]:
        lines.append(f"cadence           {s['motion_cadence_text']}")
    if s["estimator_dt_ms"]:
        held = s["rows_held_over_drops"]
        lines.append(
            f"estimators        dt {s['estimator_dt_ms']:.3f} ms from the cadence; "
            + (f"{held} rows held over dropped notifications" if held else "no rows held (nothing dropped)")
        )
    env = []
    if s["pressure_hpa_mean"] is not None:
        env.append(f"pressure {s['pressure_hpa_mean']:.2f} hPa")
    if s["temperature_c_mean"] is not None:
        env.append(f"temperature {s['temperature_c_mean']:.1f} °C")
    if s["battery_pct_last"] is not None:
        env.append(f"battery {s['battery_pct_last']:.1f} %")
    if s["rssi_dbm_mean"] is not None:
        env.append(f"RSSI {s['rssi_dbm_mean']:.1f} dBm")
    if env:
        lines.append("environment       " + ", ".join(env))
    lines.append(
        f"arming            armed in {s['armed_notifications']} of {s['notifications']['arming']} notifications"
    )
    if s["bad_payloads"] or s["unknown_characteristics"]:
        lines.append(
            f"skipped           {s['bad_payloads']} wrong-length, {s['unknown_characteristics']} "
            "unknown-characteristic notifications"
        )
    for e in s["events"]:
        lines.append(f"event             {e['t_host_s']:.3f} s {e['kind']} {e['text']}".rstrip())
    rng = s.get("attitude_deg_range")
    if rng:
        lines.append(
            f"firmware attitude thx pitch {rng['thx'][0]:.1f}..{rng['thx'][1]:.1f} deg, thy roll "
            f"{rng['thy'][0]:.1f}..{rng['thy'][1]:.1f} deg (the drone's own, {s['ble_layout']} layout)"
        )
    lines.append("note              " + s["note"])
    return lines

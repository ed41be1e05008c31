"""The summary of a BLE capture's :class:`~steval_link.link.telemetry.Telemetry` (the one ``summarize`` hands a
telemetry whose ``link`` is BLE here): notifications, the motion cadence its ticks show, the estimators' dt,
environment, arming, and what the rows are (the firmware's attitude is not sent, so the replica on these samples
cannot be bit-exact with the drone).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from steval_link.link.ble_payloads import TICK_S, TICK_WRAP


def summarize_ble(tel) -> dict[str, Any]:
    """A JSON-ready summary of a BLE capture's telemetry (``tel.link``: its :class:`BleStream`)."""
    ble, src = tel.link, tel.source
    header = src.get("header") or {}
    extra = header.get("extra") or {}
    c = ble.cadence
    tick, t = ble.samples["tick"], ble.samples["t_host_s"]
    env = ble.environment

    def stat(v: np.ndarray, how) -> float | None:
        v = np.asarray(v, dtype=np.float64)
        return round(float(how(v)), 3) if v.size else None

    return {
        "kind": "ble",
        "file": src.get("path", ""),
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
        "duration_fw_s": round(float(tick[-1] * TICK_S - tick[0] * TICK_S), 3) if len(t) > 1 else 0.0,
        "motion_rate_hz": round(1.0 / c.interval_s, 2) if c else None,
        "motion_interval_ms": round(c.interval_s * 1e3, 3) if c else None,
        "motion_dropped_estimate": c.dropped if c else 0,
        "motion_cadence": c.kind if c else None,
        "motion_cadence_text": c.describe() if c else None,
        "motion_gaps": c.gaps if c else 0,
        "motion_repeated_reads": ble.repeated_reads,
        "tick_wraps": int(tick[-1] // TICK_WRAP - tick[0] // TICK_WRAP),
        "estimator_dt_ms": round(c.interval_s * 1e3, 3) if c else None,
        "rows_held_over_drops": ble.rows_held,
        "pressure_hpa_mean": stat(env["pressure_hpa"], np.mean),
        "temperature_c_mean": stat(env["temperature_c"], np.mean),
        "battery_pct_last": stat(env["battery_pct"][-1:], np.mean),
        "rssi_dbm_mean": stat(env["rssi_dbm"], np.mean),
        "armed_notifications": int(ble.arming["armed"].sum()),
        "console_lines": len(tel.text),
        "events": [{"t_host_s": round(e.t_host_s, 6), "kind": e.kind, "text": e.text} for e in tel.events],
        "ble_layout": ble.layout.name,
        "note": " ".join(ble.notes()),
        "attitude_deg_range": _attitude_range(tel),
        "warnings": list(src.get("warnings") or []),
    }


def _attitude_range(tel) -> dict[str, list[float]] | None:
    """The drone's own pitch and roll range, deg, when the layout sends them (None: it does not)."""
    if not tel.link.layout.sends_attitude:
        return None
    a = tel.attitude
    return {
        name: [round(float(np.degrees(v.min())), 2), round(float(np.degrees(v.max())), 2)]
        for name, v in (("thx", a.thx_rad), ("thy", a.thy_rad))
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
    env = [
        f"{label} {s[key]:{fmt}} {unit}"
        for label, key, fmt, unit in (
            ("pressure", "pressure_hpa_mean", ".2f", "hPa"),
            ("temperature", "temperature_c_mean", ".1f", "°C"),
            ("battery", "battery_pct_last", ".1f", "%"),
            ("RSSI", "rssi_dbm_mean", ".1f", "dBm"),
        )
        if s[key] is not None
    ]
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

"""Summary of a :class:`~steval_link.link.telemetry.Telemetry` as a plain dict (for ``--json``) and as text lines."""

from __future__ import annotations

from typing import Any

import numpy as np

from steval_link.analysis.diagnosis import q_norm, recognise_release
from steval_link.analysis.link_stats import step_cost
from steval_link.analysis.report import fmt_number, json_number
from steval_link.link import protocol as P
from steval_link.link.ble_payloads import TICK_S, TICK_WRAP
from steval_link.link.commands import command_log
from steval_link.link.plausibility import (
    Q_NORM_TOL,
    attitude_inputs_bad,
    held_back_sentence,
    q_off_sphere,
    values_bad_sentence,
)

_FLAG_NAMES = {
    P.FLAG_NO_CORRECTION: "no-correction",
    P.FLAG_FRESH_SQUARES: "fresh-squares",
    P.FLAG_TEXT_MODE: "text-mode",
    P.FLAG_EVENT: "event",
    P.FLAG_INFLIGHT_TUNING: "in-flight-tuning",
    P.FLAG_ARMED: "motors-may-spin",
}


def values_bad_report(tel) -> dict[str, Any] | None:
    """The rows kept with NaN or out-of-range values, the first of them and a sentence (None: none)."""
    a = tel.attitude
    bad = np.asarray(getattr(a, "values_bad", np.zeros(len(a), bool)), bool)
    sbad = np.asarray(getattr(tel.status, "values_bad", np.zeros(len(tel.status), bool)), bool)
    if not bad.any() and not sbad.any():
        return None
    n = int(bad.sum())
    i = int(np.argmax(bad)) if n else None
    inputs = bool(np.any(attitude_inputs_bad(a.acc_mg[bad], a.gyro_mdps[bad]))) if n else False
    first_step = int(a.step[i]) if i is not None else None
    first_t = float(a.t_fw_s[i]) if i is not None else None
    if n and tel.printed_only:  # rows of printed lines: the values are as printed, nothing says where they went wrong
        noun = "record has" if n == 1 else "records have"
        text = (
            f"{n:,} printed {noun} NaN or out-of-range values from step {first_step} on: as the lines print them "
            "(an empty field is NaN)"
        )
    elif n:
        text = values_bad_sentence(n, first_step, first_t, inputs=inputs)
    else:
        j = int(np.argmax(sbad))
        text = (
            f"{int(sbad.sum()):,} status snapshots carry NaN or |q| > 2 from step {int(tel.status.step[j])} on: "
            "the firmware's own filter state; check ahrs.c"
        )
    return {
        "frames": n,
        "status_frames": int(sbad.sum()),
        "first_row": i,
        "first_step": first_step,
        "first_t_fw_s": json_number(first_t) if first_t is not None else None,
        "inputs_bad": inputs,
        "text": text,
    }


def q_norm_report(tel) -> dict[str, Any] | None:
    """Binary rows whose q is off the unit sphere (``| |q| − 1 |`` > 0.05, or non-finite), the first of them and a
    sentence; None when there is none."""
    a = tel.attitude
    off = np.asarray(a.exact, bool) & q_off_sphere(a.q_wxyz)
    if not off.any():
        return None
    i = int(np.argmax(off))
    norm = q_norm(a.q_wxyz[i])
    n = int(off.sum())
    how = f"|q| = {norm:.4g}" if np.isfinite(norm) else "non-finite"
    text = (
        f"the firmware's q leaves the unit sphere from step {int(a.step[i])} on (t = {float(a.t_fw_s[i]):.3f} s, "
        f"{how}; the release keeps |q| ≈ 0.9983, ±{Q_NORM_TOL:g}), {n:,} frame{'s' if n != 1 else ''} off it: "
        "steval compare names the step and its inputs"
    )
    return {
        "frames": n,
        "first_step": int(a.step[i]),
        "first_t_fw_s": json_number(a.t_fw_s[i]),
        "q_norm": json_number(norm),
        "text": text,
    }


def text_telemetry_report(tel) -> dict[str, Any] | None:
    """The records of text telemetry: count, series, units, other lines, time source and notes (None: none)."""
    ts = getattr(tel, "text_series", None)
    if ts is None or not len(ts):
        return None
    return {
        "records": len(ts),
        "series": list(ts.names),
        "units": list(ts.units),
        "other_lines": len(tel.text),
        "dropped_lines": tel.stats.text_dropped,
        "time_source": ts.t_source,
        "notes": list(ts.notes),
        "attitude": list(getattr(tel, "text_attitude_notes", [])),
    }


def _text_telemetry_lines(t: dict[str, Any]) -> list[str]:
    units = [f"{n} ({u})" if u else n for n, u in zip(t["series"], t["units"])]
    lines = [
        f"text telemetry: {t['records']} records, {len(t['series'])} series: {', '.join(units)}; "
        f"{t['other_lines']} other text lines; times from {t['time_source']}"
    ]
    lines += [f"  note: {n}" for n in t["notes"]]
    lines += [f"  attitude: {n}" for n in t["attitude"]]
    return lines


def summarize(tel, *, variant: str | None = None, variant_source: str = "variant setting") -> dict[str, Any]:
    """Frames, duration (s of firmware time, else host time), rates, drops (``drop_ratio`` = missing / (received +
    missing)), CRC failures, text lines, events, the filter settings and the release (``variant`` forces one)."""
    if getattr(tel, "link", None) is not None:  # a BLE capture: its link's facts (cadence, notifications, environment)
        return summarize_ble(tel)
    a, s, st = tel.attitude, tel.status, tel.stats
    n = len(a)
    src = tel.source or {}
    header = src.get("header") or {}
    duration, host_duration, steps = _durations(a)
    out: dict[str, Any] = {
        "source": {
            "path": src.get("path"),
            "kind": src.get("kind"),
            **{k: header.get(k) for k in ("port", "baud", "start_time_utc", "tool_version")},
        },
        "frames": _frame_counts(tel),
        "duration_s": duration,
        "host_duration_s": host_duration,
        "rate_hz": (n - 1) / duration if duration > 0 and n > 1 else None,
        "step_rate_hz": steps / duration if duration > 0 and steps > 0 else None,
        "first_step": int(a.step[0]) if n else None,
        "last_step": int(a.step[-1]) if n else None,
        "drops": {
            "seq_gaps": st.seq_gaps,
            "frames_missing": st.frames_missing,
            "drop_ratio": st.frames_missing / (int(a.exact.sum()) + st.frames_missing)
            if (a.exact.any() or st.frames_missing)
            else 0.0,
            "seq_resets": st.seq_resets,
            "tx_dropped": int(s.tx_dropped[-1]) if len(s) else None,
        },
        "crc_failures": st.crc_failures,
        "bytes_skipped": st.bytes_skipped,
        "blank_bytes": st.blank_bytes,  # blank lines and the "\r" of "\n\r" endings: text, not damage
        "text_dropped": st.text_dropped,  # printable lines that did not read as text (random bytes), not kept
        "bytes_total": st.bytes_total,
        "unknown_frames": st.unknown_frames,
        "implausible": st.implausible,
        "held_back_for_values": st.held_values,
        "held_back_text": held_back_sentence(st.implausible, st.held_values) if st.implausible else None,
        "values_bad": values_bad_report(tel),
        "q_off_unit_sphere": q_norm_report(tel),
        "v1_frames": st.v1_frames,
        "commands": command_log(tel.commands, tel.acks),
        "events": [{"t_host_s": e.t_host_s, "kind": e.kind, "text": e.text} for e in tel.events],
        "warnings": list(src.get("warnings") or []),
        "text_lines": [t for _, t in tel.text[:20]],
        "text_telemetry": text_telemetry_report(tel),
        "filter": _filter_of_status(s) if len(s) else None,
        "release": recognise_release(tel, variant=variant, source=variant_source),
        "attitude_from": src.get("attitude_from", "frames"),
        "symbols": src.get("symbols"),
    }
    cost = step_cost(tel)  # the one AHRS step cost (compare --json gives the same)
    out["ahrs_step_cost"] = None if cost is None else cost.to_json()
    out["ahrs_step_cost_text"] = None if cost is None else cost.sentence()
    return out


def _durations(a) -> tuple[float, float | None, float]:
    """Firmware time the rows cover (host time when there is none), host time, and AHRS steps between restarts."""
    n = len(a)
    restarts = np.diff(a.step) <= 0 if n > 1 else np.zeros(0, bool)
    starts = np.flatnonzero(np.concatenate([[True], restarts]))  # of the stretches between firmware restarts
    duration = float(np.sum(a.t_fw_s[np.append(starts[1:], n) - 1] - a.t_fw_s[starts])) if n > 1 else 0.0
    host = a.t_host_s[np.isfinite(a.t_host_s)] if n else np.zeros(0)
    host_duration = float(host[-1] - host[0]) if len(host) > 1 else None
    duration = host_duration if duration <= 0 and host_duration else duration
    steps = float(np.sum(np.where(restarts, 0, np.diff(a.step)))) if n > 1 else 0.0
    return duration, host_duration, steps


def _frame_counts(tel) -> dict[str, Any]:
    a, s = tel.attitude, tel.status
    binary = tel.binary_rows
    return {
        "attitude": len(a),
        "attitude_binary": binary,
        "attitude_text_mode": len(a) - binary,
        "status": len(s),
        "text": len(tel.text),
        "flight_control": len(getattr(tel, "flight", ())),
        "flight_control_every": int(s.fc_every[-1]) if len(s) and s.exact[-1] else None,
        "acks": len(getattr(tel, "acks", ())),
    }


def _filter_of_status(s) -> dict[str, Any]:
    """The filter settings of the last status frame (text-mode status lines: no version, baud or queue)."""
    i = len(s) - 1
    flags = int(s.flags[i])
    return {
        "from_step": int(s.step[i]),
        "kp_ground": json_number(s.kp_ground[i]),
        "kp_flight": json_number(s.kp_flight[i]),
        "ki": json_number(s.ki[i]),
        "dt_s": json_number(s.dt_s[i]),
        "min_thr": int(s.min_thr[i]) if s.exact[i] else None,
        "flags": flags,
        "flag_names": [name for bit, name in _FLAG_NAMES.items() if flags & bit],
        "fw_version": ".".join(str(int(v)) for v in s.fw_version[i]) if s.exact[i] else None,
        "link_baud": int(s.baud[i]) if s.exact[i] else None,
        "queue_peak_bytes": int(s.queue_peak[i]) if s.exact[i] else None,
    }


def format_summary(summary: dict[str, Any], max_text_lines: int = 8) -> list[str]:
    """Human-readable lines of a :func:`summarize` dict (the first ``max_text_lines`` firmware log lines)."""
    s = summary
    if s.get("kind") == "ble":
        return format_ble_summary(s)
    lines = _source_lines(s) + _link_lines(s) + _command_lines(s.get("commands") or [], max_text_lines)
    if s.get("v1_frames"):
        lines.append(
            f"protocol v1 ({s['v1_frames']} frames, CRC-16): about 1 in 65 536 damaged frames passes its check, so a"
            " bad cable can show a frame that was never sent; the plausibility checks catch most, not all."
            " Firmware patch 2.0 sends protocol v2 (CRC-32)."
        )
    if s.get("filter"):
        lines += _filter_summary_lines(s["filter"])
    if s.get("ahrs_step_cost_text"):
        lines.append(s["ahrs_step_cost_text"])
    if s.get("text_telemetry"):
        lines += _text_telemetry_lines(s["text_telemetry"])
    for e in s["events"]:
        note = f" ({e['text']})" if e["text"] else ""
        lines.append(f"event at {e['t_host_s']:.3f} s host time: {e['kind']}{note}")
    n_text = s["frames"]["text"]
    if n_text:
        shown = s["text_lines"][:max_text_lines]
        lines += [f"text lines ({n_text}):"] + [f"  | {t}" for t in shown]
        if n_text > len(shown):
            lines.append(f"  | ... {n_text - len(shown)} more")
    return lines + [f"warning: {w}" for w in s["warnings"]]


def _source_lines(s: dict[str, Any]) -> list[str]:
    """Where the capture comes from, its frames, duration and rate, steps and the filter's release."""
    src, f = s["source"], s["frames"]
    lines = [f"source: {src['path']} ({src['kind']})"]
    if src.get("port") or src.get("start_time_utc"):
        lines.append(
            f"  recorded from {src.get('port')} at {src.get('baud')} baud, start {src.get('start_time_utc')}, "
            f"steval-link {src.get('tool_version')}"
        )
    text_mode = f["attitude_text_mode"]
    kinds = f"{f['attitude_binary']} binary" + (f", {text_mode} text-mode" if text_mode else "")
    fc = ""
    if f.get("flight_control"):
        every = f.get("flight_control_every")
        fc = f", {f['flight_control']} flight control" + (f" (every {every} steps)" if every else "")
    lines.append(f"frames: {f['attitude']} attitude ({kinds}), {f['status']} status, {f['text']} text{fc}")
    rate = f"{s['rate_hz']:.2f} Hz" if s["rate_hz"] else "n/a"
    step_rate = f", AHRS steps at {s['step_rate_hz']:.2f} Hz" if s["step_rate_hz"] else ""
    lines.append(f"duration: {s['duration_s']:.3f} s, attitude rate {rate}{step_rate}")
    if s["first_step"] is not None:
        lines.append(f"steps: {s['first_step']} .. {s['last_step']}")
    if s.get("symbols"):
        lines.append(f"attitude: {s['symbols']}")
    if s.get("release"):
        lines.append(s["release"]["text"])
    return lines


def _link_lines(s: dict[str, Any]) -> list[str]:
    """Drops, link damage, and the firmware output held back or out of range."""
    d = s["drops"]
    tx = "" if d["tx_dropped"] is None else f", firmware TX queue dropped {d['tx_dropped']}"
    lines = [
        f"drops: {d['frames_missing']} frames missing in {d['seq_gaps']} gaps ({100 * d['drop_ratio']:.3f} %)"
        f"{tx}" + (f", {d['seq_resets']} firmware restarts" if d["seq_resets"] else ""),
        f"link: {s['crc_failures']} CRC failures, {s['bytes_skipped']} of {s['bytes_total']} bytes skipped"
        + (f", {s['unknown_frames']} frames of unknown type" if s["unknown_frames"] else "")
        + (f", {s['text_dropped']} lines of garbage dropped" if s.get("text_dropped") else ""),
    ]
    if s.get("values_bad"):
        lines.append(f"firmware output: {s['values_bad']['text']}")
    off = s.get("q_off_unit_sphere")
    if off and (not s.get("values_bad") or s["values_bad"]["first_step"] != off["first_step"]):
        lines.append(f"firmware filter: {off['text']}")  # (said once when both start at the same step)
    if s.get("held_back_text"):
        lines.append(f"held back: {s['held_back_text']}")
    return lines


def _command_lines(cmds: list[dict], max_lines: int) -> list[str]:
    """The commands sent or answered, the first ``max_lines`` of them listed."""
    if not cmds:
        return []
    acked = sum(1 for c in cmds if c["result"] is not None)
    lines = [f"commands: {len(cmds)} sent to the drone or answered, {acked} acknowledged"]
    lines += [f"  {c['t_host_s']:8.3f} s  {c['text']}" for c in cmds[:max_lines]]
    if len(cmds) > max_lines:
        lines.append(f"  … {len(cmds) - max_lines} more (the JSON summary lists them all)")
    return lines


def _filter_summary_lines(flt: dict[str, Any]) -> list[str]:
    g = {k: fmt_number(flt[k], "g") for k in ("kp_ground", "kp_flight", "ki", "min_thr")}
    dt = "n/a" if flt["dt_s"] is None else f"{flt['dt_s']:g} s"
    lines = [
        f"filter (status at step {flt['from_step']}): kp_ground {g['kp_ground']}, kp_flight {g['kp_flight']}, "
        f"ki {g['ki']}, dt {dt}, min_thr {g['min_thr']}, flags {flt['flags']}"
        + (f" ({', '.join(flt['flag_names'])})" if flt["flag_names"] else "")
    ]
    if flt["fw_version"] is not None:
        lines.append(f"firmware: version {flt['fw_version']}, link {flt['link_baud']} baud")
    return lines


# ---- a BLE capture: notifications, cadence, dt, environment (no firmware attitude unless the layout sends it) ----


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
    lines += [f"event             {e['t_host_s']:.3f} s {e['kind']} {e['text']}".rstrip() for e in s["events"]]
    rng = s.get("attitude_deg_range")
    if rng:
        lines.append(
            f"firmware attitude thx pitch {rng['thx'][0]:.1f}..{rng['thx'][1]:.1f} deg, thy roll "
            f"{rng['thy'][0]:.1f}..{rng['thy'][1]:.1f} deg (the drone's own, {s['ble_layout']} layout)"
        )
    lines.append("note              " + s["note"])
    return lines

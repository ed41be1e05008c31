"""Labels for flights side by side (``steval compare``): a few words per flight naming what differs between them,
the filter settings of the status frames first (``ki``, ``kp_ground``, ``kp_flight``, ``correction``, ``min_thr``,
the normalisation variant, the build flags text mode and in-flight tuning: "ki 0.1" against "ki 1, correction off"),
else the capture headers (link, firmware ELF name, scenario, seed, serial port), else the file names. A flight
here is anything with ``settings`` (dict or None), ``facts`` (dict) and ``path`` (a Path), like
:class:`steval_link.analysis.side_by_side.Flight`.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from steval_link.estimators.st_mahony import MahonySettings

#: Settings in label order, with their names in a label (a label names a setting that differs from its default).
_SETTING_WORDS = {
    "ki": "ki",
    "correction": "correction",
    "kp_ground": "kp ground",
    "kp_flight": "kp flight",
    "min_thr": "min_thr",
    "dt_s": "dt",
    "variant": "filter",
    "text_mode": "text mode",
    "inflight_tuning": "in-flight tuning",
}
_FACT_KEYS = ("link", "firmware", "firmware_path", "scenario", "seed", "port")


def setting_f32(x) -> float:
    """A float32 setting as its shortest decimal (0.4, not 0.4000000059604645)."""
    return float(str(np.float32(x)))


def _defaults() -> dict[str, Any]:
    d = MahonySettings()
    return {
        "ki": setting_f32(d.ki),
        "correction": True,
        "kp_ground": setting_f32(d.kp_ground),
        "kp_flight": setting_f32(d.kp_flight),
        "min_thr": int(d.min_thr),
        "dt_s": setting_f32(d.dt_s),
        "variant": d.variant,
        "text_mode": False,
        "inflight_tuning": False,
    }


def _word(key: str, value) -> str:
    """How a setting reads in a label: "ki 1", "correction off", "binary", "filter ST 221117", ..."""
    name = _SETTING_WORDS[key]
    if key == "variant":
        return f"filter {value}"
    if key == "correction":
        return f"correction {'on' if value else 'off'}"
    if key == "text_mode":
        return "text mode" if value else "binary"
    if isinstance(value, bool):
        return name if value else f"no {name}"
    return f"{name} {value:g}" if isinstance(value, float) else f"{name} {value}"


def _fact_word(key: str, value) -> str:
    """How a header fact reads in a label: "BLE", "firmware X.elf", "scenario demo", ..."""
    if key == "link":
        return "BLE" if value == "ble" else "serial"
    return f"{key.replace('_path', '')} {value}"


def labels_by_difference(flights: Sequence) -> list[str]:
    """A label per flight naming what differs between them: the settings first ("ki 0.1" against "ki 1,
    correction off": a differing setting is named where it is not the default, and the first one where nothing
    else would be), else the header facts (link, firmware, scenario, seed, port), else the file names. Labels
    that still collide get their file name added."""
    n = len(flights)
    labels = [""] * n
    known = [f.settings for f in flights]
    defaults = _defaults()
    if all(s is not None for s in known):
        differing = [k for k in _SETTING_WORDS if len({repr(s.get(k, defaults[k])) for s in known}) > 1]
        if differing:
            for i, s in enumerate(known):
                words = [_word(k, s.get(k, defaults[k])) for k in differing if s.get(k, defaults[k]) != defaults[k]]
                labels[i] = ", ".join(words) or _word(differing[0], s.get(differing[0], defaults[differing[0]]))
    if not all(labels):
        facts = [f.facts for f in flights]
        differing = [k for k in _FACT_KEYS if len({repr(x.get(k)) for x in facts}) > 1]
        if "firmware" in differing:  # the ELF names tell them apart; else the paths may (other build folders)
            differing.remove("firmware_path")
        words: list[list[str]] = [[] for _ in flights]
        for k in differing:  # in order of priority, until the labels tell the flights apart
            for i, x in enumerate(facts):
                if x.get(k) is not None:
                    words[i].append(_fact_word(k, x[k]))
            if len({", ".join(w) for w in words}) == n:
                break
        for i in range(n):
            if not labels[i]:
                labels[i] = ", ".join(words[i])
    for i, f in enumerate(flights):
        if f.settings and f.settings.get("changes"):
            labels[i] = (labels[i] + ", " if labels[i] else "") + f"{f.settings['changes']} changes in flight"
    names = [f.path.name for f in flights]
    clash = [not labels[i] or labels.count(labels[i]) > 1 for i in range(n)]
    labels = [
        f"{labels[i]} ({names[i]})" if clash[i] and labels[i] else (names[i] if clash[i] else labels[i])
        for i in range(n)
    ]
    clash = [labels.count(labels[i]) > 1 for i in range(n)]  # the same file twice: its position tells them apart
    labels = [f"{labels[i]} #{i + 1}" if clash[i] else labels[i] for i in range(n)]
    return labels

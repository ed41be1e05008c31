"""Link and timing statistics of a decoded stream (:func:`rate_stats`), notes on what the link could not carry
(:func:`link_notes`), and the AHRS step cost (ETH exercise 6, :func:`step_cost`): the status frames' DWT cycles of
``ahrs_fusion_ag`` + ``QuaternionToEuler`` joined, weighted by ``cyc_n``; ``DWT cycles`` from a drone (µs at
``cpu_hz``), ``emulated instructions`` from an emulated capture (no time given)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from steval_link import constants as C
from steval_link.analysis.report import RateStats
from steval_link.link import protocol as P


def relative_time_s(step, t_fw_s) -> np.ndarray:
    """Firmware time since the first row, s, kept increasing across firmware restarts (plots never run backwards)."""
    t = np.asarray(t_fw_s, dtype=np.float64)
    if t.size == 0:
        return t
    dt = np.diff(t)
    bad = (np.diff(np.asarray(step, dtype=np.int64)) <= 0) | ~np.isfinite(dt) | (dt < 0)
    if bad.any():
        dt = np.where(bad, C.AHRS_PERIOD_S, dt)
    return np.concatenate([[0.0], np.cumsum(dt)])


def cycles_are_emulated(tel) -> bool:
    """Whether an emulator counted the status frames' ``cyc_*`` (``extra.emulated``): instructions, not cycles."""
    header = (getattr(tel, "source", None) or {}).get("header") or {}
    return bool((header.get("extra") or {}).get("emulated"))


def rate_stats(tel) -> RateStats:
    """Rate, period jitter, drops, CRC failures and AHRS cycles of a telemetry (see :class:`RateStats`)."""
    a, s, st = tel.attitude, tel.status, tel.stats
    n = len(a)
    step = np.asarray(a.step, dtype=np.int64)
    t = np.asarray(a.t_fw_s, dtype=np.float64)
    restart = np.diff(step) <= 0  # the step counter did not advance: a firmware restart
    dt = np.diff(t) if n > 1 else np.zeros(0)
    dstep = np.diff(step) if n > 1 else np.zeros(0, np.int64)
    ok = ~restart & np.isfinite(dt) & (dt >= 0)
    duration = float(np.sum(dt[ok])) if n > 1 else 0.0
    steps = float(np.sum(dstep[ok])) if n > 1 else 0.0
    per = dt[ok & (dstep == 1)] * 1e3
    if per.size == 0 and ok.any():  # text mode sends every k-th step: per-step period of each row pair
        per = (dt[ok] / dstep[ok]) * 1e3
    kw: dict[str, Any] = {}
    if len(s):
        n_cyc = np.asarray(s.cyc_n, dtype=np.float64)
        weighted = bool(np.any(n_cyc > 0))  # else (no step counts) each frame weighs the same
        have = n_cyc > 0 if weighted else np.ones(len(s), bool)
        if weighted or np.any(s.cyc_mean > 0):
            kw["ahrs_cycles_min"] = int(np.min(s.cyc_min[have]))
            kw["ahrs_cycles_max"] = int(np.max(s.cyc_max[have]))
            kw["ahrs_cycles_mean"] = float(np.average(s.cyc_mean[have], weights=n_cyc[have] if weighted else None))
        cpu = np.asarray(s.cpu_hz)[np.asarray(s.exact, bool)] if np.any(s.exact) else np.zeros(0)
        cpu = cpu[cpu > 0]
        kw["cpu_hz"] = int(cpu[-1]) if cpu.size else (C.CPU_HZ if kw.get("ahrs_cycles_mean") else None)
        kw["cycles_emulated"] = cycles_are_emulated(tel)
    return RateStats(
        duration_s=duration,
        rate_hz=(int(np.count_nonzero(ok)) / duration) if duration > 0 else None,
        step_rate_hz=(steps / duration) if duration > 0 and steps > 0 else None,
        period_mean_ms=float(np.mean(per)) if per.size else None,
        period_std_ms=float(np.std(per)) if per.size > 1 else None,
        period_p99_ms=float(np.percentile(per, 99)) if per.size else None,
        period_max_ms=float(np.max(per)) if per.size else None,
        seq_gaps=int(st.seq_gaps),
        frames_missing=int(st.frames_missing),
        seq_resets=int(getattr(st, "seq_resets", 0)),
        tx_dropped=int(s.tx_dropped[-1]) if len(s) else None,
        crc_failures=int(st.crc_failures),
        bytes_skipped=int(st.bytes_skipped),
        **kw,
    )


def link_notes(tel) -> list[str]:
    """A hint when the firmware's TX queue dropped frames because the baud rate cannot carry the stream."""
    s = tel.status
    if not len(s) or int(s.tx_dropped[-1]) == 0:
        return []
    ex = np.flatnonzero(np.asarray(s.exact, bool))
    baud = (int(s.baud[ex[-1]]) if ex.size else 0) or int(((tel.source or {}).get("header") or {}).get("baud") or 0)
    need = P.ATTITUDE_FRAME_SIZE * 10 * C.AHRS_RATE_HZ + P.STATUS_FRAME_SIZE * 10
    dropped = int(s.tx_dropped[-1])
    if baud and baud < need:
        return [
            f"the firmware's TX queue dropped {dropped} frames: at {baud} baud the link carries at most "
            f"{baud / (10 * P.ATTITUDE_FRAME_SIZE):.0f} attitude frames/s of the {C.AHRS_RATE_HZ:.1f} the AHRS "
            f"makes (≥ {need:,.0f} baud needed; the patch's default is 115200)"
        ]
    return [
        f"the firmware's TX queue dropped {dropped} frames since power-up (queue full: bursts of text or "
        "status frames); frames dropped before the capture started count too"
    ]


DWT_CYCLES = "DWT cycles"
EMULATED_INSTRUCTIONS = "emulated instructions"


@dataclass(frozen=True)
class StepCost:
    """One AHRS step's cost over ``steps`` steps, in ``unit``; ``cpu_hz`` the core clock (None: unknown)."""

    median: float
    mean: float
    max: int
    steps: int
    unit: str
    cpu_hz: int | None = None

    def _us(self, cycles: float) -> float | None:
        return cycles / self.cpu_hz * 1e6 if self.unit == DWT_CYCLES and self.cpu_hz else None

    def to_json(self) -> dict:
        """``ahrs_step_cost`` of ``--json``: median, mean, max, steps, unit (and µs for DWT cycles)."""
        return {
            "median": round(self.median, 1),
            "mean": round(self.mean, 1),
            "max": self.max,
            "steps": self.steps,
            "unit": self.unit,
            "cpu_hz": self.cpu_hz,
            "mean_us": None if self._us(self.mean) is None else round(self._us(self.mean), 2),
        }

    def sentence(self) -> str:
        """``AHRS step cost: median 4452, mean 4591.3, max 5514 emulated instructions over 9000 steps``."""
        us = self._us(self.mean)
        when = f" ({us:.1f} µs mean at {self.cpu_hz / 1e6:g} MHz)" if us is not None else ""
        if self.unit == EMULATED_INSTRUCTIONS:  # exercise 6 asks for cycles: say what an emulator counts
            when = " (an emulator's count: a real Cortex-M4 takes somewhat more cycles)"
        return (
            f"AHRS step cost: median {self.median:.0f}, mean {self.mean:.1f}, max {self.max} {self.unit} "
            f"over {self.steps} steps{when}"
        )


def step_cost(tel) -> StepCost | None:
    """The AHRS step cost of a telemetry's status frames (None without a frame that counted steps)."""
    s = tel.status
    if not len(s):
        return None
    n = np.asarray(s.cyc_n, np.int64)
    mean = np.asarray(s.cyc_mean, np.float64)
    have = (n > 0) & (mean > 0)
    if not have.any():
        return None
    w = n[have].astype(np.float64)
    means = mean[have]
    order = np.argsort(means, kind="stable")
    cum = np.cumsum(w[order])
    median = float(means[order][np.searchsorted(cum, cum[-1] / 2.0)])
    cpu = np.asarray(s.cpu_hz, np.int64)[have]
    cpu = cpu[cpu > 0]
    return StepCost(
        median=median,
        mean=float(np.sum(means * w) / np.sum(w)),
        max=int(np.max(np.asarray(s.cyc_max)[have])),
        steps=int(np.sum(n[have])),
        unit=EMULATED_INSTRUCTIONS if cycles_are_emulated(tel) else DWT_CYCLES,
        cpu_hz=int(cpu[-1]) if cpu.size else None,
    )

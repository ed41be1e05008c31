"""The AHRS step cost (ETH exercise 6), computed once from a capture's status frames and said one way everywhere.

Each status frame carries the min/mean/max DWT cycles of ``ahrs_fusion_ag`` + ``QuaternionToEuler`` over its
``cyc_n`` steps; :func:`step_cost` joins them (means and medians weighted by ``cyc_n``). The unit is said as it is:
``DWT cycles`` from a drone (µs at ``cpu_hz``), ``emulated instructions`` from an emulated capture (no time given)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from steval_link.analysis.link_stats import cycles_are_emulated

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

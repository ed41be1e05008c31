"""The ground truth each AHRS step of an emulated BROAD run saw, on the emulated board's time base.

At motion tick ``k`` the sensors hold the trial sample of trial time ``k · TICK_S − t_first`` (trial time 0 is the
first TIM9 tick, ≈ 1 s after power-up; the firmware takes the trial's pose during its 2 s offset calibration as
level, and the trials start at rest, so the truth is not corrected for it). A step averages the 5 ISR samples up to
tick ``k_last`` (a probe at ``ahrs_fusion_ag`` records it): its truth is taken at the window's centre, tick
``k_last − 2``, as :func:`steval_link.emulation.broad.steval_view` does. AHRS step ``i`` (from 0) is the ``i``-th
call of ``ahrs_fusion_ag``, the step counter of the patch's frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from steval_link import constants as C
from steval_link.emulation import broad
from steval_link.emulation.broad import BroadTrial, truth_at_trial_time
from steval_link.quat import quaternion_from_euler


@dataclass(frozen=True)
class TruthRows:
    """Ground truth per AHRS step."""

    step: np.ndarray  #: (M,) int64 AHRS step counter (0 = the first step after power-up)
    t_s: np.ndarray  #: (M,) emulated time of the step's middle input tick, s since power-up
    t_trial_s: np.ndarray  #: (M,) trial time of that tick, s (outside [0, trial end]: no truth)
    q_wxyz: np.ndarray  #: (M, 4) ground truth, body → earth (NaN: occluded or outside the trial)
    movement: np.ndarray  #: (M,) bool, the step counts for the metric

    def __len__(self) -> int:
        return int(self.step.shape[0])


class StepTruth:
    """Records each AHRS step's input window on an ``Emulation`` of a BROAD trial and gives its ground truth
    (see the module docstring). Attach before running: ``truth = StepTruth(emu)``."""

    def __init__(self, emu) -> None:
        if emu.motion.trial is None:
            raise ValueError("ground truth needs a BROAD trial (the emulation's broad option)")
        self.emu = emu
        self.trial: BroadTrial = emu.motion.trial
        self._last_tick: list[int] = []
        self._taken = 0
        emu.step_start_observers.append(self._on_step_start)

    def _on_step_start(self, board) -> None:
        self._last_tick.append(self.emu.tick_index())

    @property
    def last_ticks(self) -> np.ndarray:
        """(M,) int64 motion tick of the newest sample in each step's FIFO window."""
        return np.asarray(self._last_tick, dtype=np.int64)

    def rows(self, start: int = 0, stop: int | None = None) -> TruthRows:
        """The truth of steps ``start`` .. ``stop`` (default: every step so far)."""
        ticks = self.last_ticks[start:stop]
        mid = ticks - C.FIFO_ORDER // 2
        step = np.arange(start, start + ticks.shape[0], dtype=np.int64)
        if ticks.shape[0] == 0:
            empty = np.zeros(0)
            return TruthRows(step, empty, empty, np.zeros((0, 4)), np.zeros(0, dtype=bool))
        t_trial = np.asarray(self.emu.trial_time_s(mid), dtype=np.float64)
        t_emu = np.asarray(self.emu.tick_time_s(mid), dtype=np.float64)
        q, mov = truth_at_trial_time(self.trial, t_trial)
        return TruthRows(step, t_emu, t_trial, q, mov)

    def take(self) -> TruthRows:
        """The truth of the steps recorded since the last call (for a capture's truth chunks as it grows)."""
        start, self._taken = self._taken, len(self._last_tick)
        return self.rows(start, self._taken)


def score_euler(thx_rad, thy_rad, q_true_wxyz, movement) -> tuple[np.ndarray, float]:
    """(inclination error (M,) rad, RMSE deg over ``movement``) of the attitude thx/thy against the truth."""
    q = quaternion_from_euler(np.asarray(thx_rad, np.float64), np.asarray(thy_rad, np.float64), 0.0)
    err = broad.inclination_error_rad(q, q_true_wxyz)
    return err, broad.rmse_deg(err, movement)

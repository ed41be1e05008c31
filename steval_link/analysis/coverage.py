"""Coverage of a score: the share of the scored rows (movement rows with ground truth) an estimate covered.

An RMSE over the finite rows alone flatters a filter that gives up half-way: each score carries its coverage, where
it diverged for good, and why it has none. An incomplete cell is marked (``2.851 (63 %)``), has no mean and is not
ranked."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Coverage:
    """How much of the scored rows (movement with finite truth) one estimate covered (finite): ``diverged_at_step``
    starts its final non-finite run (``diverged_at_s``: its time, s), ``why`` it covered none."""

    scored_rows: int
    covered_rows: int
    diverged_at_step: int | None = None
    diverged_at_s: float | None = None
    why: str | None = None

    @property
    def scored_fraction(self) -> float | None:
        """Covered / scored rows (None: nothing to score)."""
        return self.covered_rows / self.scored_rows if self.scored_rows else None

    @property
    def complete(self) -> bool:
        """Every scored row covered (and at least one)."""
        return self.scored_rows > 0 and self.covered_rows == self.scored_rows

    def to_json(self) -> dict:
        """The JSON fields: ``scored_fraction``, ``diverged_at_step``, ``diverged_at_s``, ``no_score_reason``."""
        f = self.scored_fraction
        return {
            "scored_fraction": None if f is None else round(f, 4),
            "scored_rows": self.scored_rows,
            "covered_rows": self.covered_rows,
            "diverged_at_step": self.diverged_at_step,
            "diverged_at_s": None if self.diverged_at_s is None else round(self.diverged_at_s, 3),
            "no_score_reason": self.why,
        }

    def cell(self, rmse_text: str) -> str:
        """A table cell: the RMSE, marked with its coverage when incomplete (``2.851 (63 %)``)."""
        if self.complete:
            return rmse_text
        if self.covered_rows == 0:
            return "no score"
        return f"{rmse_text} ({percent(self.scored_fraction)})"

    def sentence(self) -> str | None:
        """What is missing, in words (None when complete): the share covered, where it diverged, or why no score."""
        if self.complete:
            return None
        if self.covered_rows == 0:
            return f"no score: {self.why}"
        text = f"scored on {percent(self.scored_fraction)} of the {self.scored_rows} movement rows with truth"
        if self.diverged_at_step is not None:
            text += f"; diverged at step {self.diverged_at_step}{_at(self.diverged_at_s)} (non-finite from there on)"
        return text


def percent(fraction: float | None) -> str:
    """``63 %``, rounded down (99.97 % is not called 100 %)."""
    return "—" if fraction is None else f"{math.floor(fraction * 100 + 1e-9):d} %"


def _at(t_s: float | None) -> str:
    return "" if t_s is None or not math.isfinite(t_s) else f", t = {t_s:.2f} s"


def coverage_of(estimate_ok, scored, steps=None, t_s=None) -> Coverage:
    """The coverage of one estimate: its finite rows among the ``scored`` ones (``steps`` default: row index)."""
    ok = np.asarray(estimate_ok, bool).reshape(-1)
    sc = np.asarray(scored, bool).reshape(-1)
    n = ok.shape[0]
    step_of = np.arange(n) if steps is None else np.asarray(steps).reshape(-1)
    scored_rows = int(np.count_nonzero(sc))
    covered = int(np.count_nonzero(sc & ok))
    finite_at = np.flatnonzero(ok)
    first_bad = int(finite_at[-1]) + 1 if finite_at.size else 0
    diverged = first_bad < n and bool(sc[first_bad:].any())
    at_step = int(step_of[first_bad]) if diverged else None
    at_s = float(t_s[first_bad]) if diverged and t_s is not None else None
    why = None
    if covered == 0:
        if scored_rows == 0:
            why = "no movement row with ground truth"
        elif not finite_at.size:
            why = f"its estimate is not finite on any of the {n} steps"
        elif diverged and not sc[:first_bad].any():
            why = f"it diverged at step {at_step}{_at(at_s)}, before the first movement row with truth"
        else:
            why = "its estimate is not finite on any movement row with truth"
    return Coverage(scored_rows, covered, at_step, at_s, why)

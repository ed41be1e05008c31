"""Run registry estimators over a whole :class:`~steval_link.link.telemetry.Telemetry` (replay, compare, the viewer),
at the row rate where rows are decimated (text mode) or at the link's cadence (BLE)."""

from __future__ import annotations

from typing import Any

import numpy as np

from steval_link import constants as C
from steval_link.estimators import registry

#: estimators without state, indifferent to the row rate
MEMORYLESS = frozenset({"accel"})


def row_decimation(tel) -> int:
    """AHRS steps per attitude row (1 for a binary stream; 16 for the text-mode build's ``$ATT`` lines)."""
    d = np.diff(np.asarray(tel.attitude.step, dtype=np.int64))
    d = d[d > 0]
    return int(np.median(d)) if d.size else 1


def run_estimator(name: str, tel, *, decimation: int | None = None) -> tuple[Any | None, str]:
    """Run estimator ``name`` (see :func:`registry.create`) from power-up over every attitude row: (estimate, note)
    or (None, why not). With ``decimation`` steps per row (default: :func:`row_decimation`) those that take
    ``rate_hz`` run at the row rate; the others assume one AHRS step per row (the note says which)."""
    decimation = row_decimation(tel) if decimation is None else decimation
    if not registry.is_known(name):
        return None, f"not available in this installation (known: {', '.join(registry.names())})"
    note = ""
    dt_s = getattr(getattr(tel, "link", None), "dt_s", None)  # rows at a link's own cadence (BLE)
    try:
        est = None
        if dt_s is not None:
            est, note = created_at(name, dt_s), f"dt {dt_s * 1e3:.3f} ms from the link's cadence"
        elif decimation > 1 and name not in MEMORYLESS:
            try:
                est = registry.create(name, rate_hz=C.AHRS_RATE_HZ / decimation)
                note = f"run at {C.AHRS_RATE_HZ / decimation:.2f} Hz: one row per {decimation} steps"
            except ValueError:
                note = f"assumes one AHRS step per row, but rows are {decimation} steps apart"
        if est is None:
            est = registry.create(name)
    except ImportError as exc:
        return None, f"needs a package that is not installed ({exc})"
    a = tel.attitude
    return est.run(a.acc_mg, a.gyro_mdps, a.thr), note


def created_at(name: str, dt_s: float):
    """A registry estimator at ``dt_s`` on rows no firmware filter produced (BLE): the replica at that dt, the others
    at 1/dt where they take a rate."""
    if name in ("st-mahony", "st_mahony"):
        return registry.create(name, dt_s=dt_s)
    if name not in MEMORYLESS and registry.accepts(name, "rate_hz"):
        return registry.create(name, rate_hz=1.0 / dt_s)
    return registry.create(name)

"""A ``steval simulate`` run (UMaine Lab 5 simulator) to an ``.rrd`` in the standard layout: the simulated filter in
the ``firmware`` series (labelled ``simulated <name>``), ``fw_time`` the simulated ``(step + 1) * dt_s``."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import rerun as rr

from steval_viewer import entities as ent
from steval_viewer.columns import series_style
from steval_viewer.replay_log import ReplaySummary, log_replay
from steval_viewer.sink_options import SinkOptions
from steval_viewer.sinks import open_session


def simulation_telemetry(res: Any) -> SimpleNamespace:
    """A Telemetry-shaped view of a ``SimulationResult`` (attitude rows only; no link, no status frames)."""
    step = np.asarray(res.step, dtype=np.int64)
    valid = np.asarray(res.valid, dtype=bool)
    q = np.asarray(res.q_wxyz, dtype=np.float64).copy()
    q[~valid] = np.nan
    angles = {f"th{a}_rad": np.where(valid, np.asarray(getattr(res, f"ea{a}_rad"), np.float64), np.nan) for a in "xyz"}
    raw = {name: np.asarray(getattr(res, name)) for name in ("acc_mg", "gyro_mdps", "thr")}
    att = SimpleNamespace(step=step, t_fw_s=(step + 1) * float(res.dt_s), q_wxyz=q, **angles, **raw)
    return SimpleNamespace(attitude=att, status=None, text=[], stats=None)


def log_simulation(res: Any, path: str | Path) -> ReplaySummary:
    """Log a ``SimulationResult`` to an ``.rrd`` file ``path`` (blueprint included), then close."""
    session = open_session(SinkOptions(rrd=Path(path)), recording_name=f"steval simulate ({res.estimator})")
    try:
        rec = session.rec
        summary = log_replay(rec, simulation_telemetry(res), {}, None, link=False)
        fw = ent.SOURCE_FIRMWARE
        paths = (ent.pitch_path(fw), ent.roll_path(fw), ent.yaw_path(fw))
        for path, angle in zip(paths, ("thx pitch", "thy roll", "thz yaw")):
            series_style(rec, path, f"{angle} (simulated {res.estimator})", ent.source_color(fw), 2.5)
        noise = ""
        if getattr(res, "gyro_noise_mdps", 0) or getattr(res, "acc_noise_mg", 0):
            noise = f", noise gyro {res.gyro_noise_mdps:g} mdps / acc {res.acc_noise_mg:g} mg (seed {res.seed})"
        note = f"steval simulate: {len(res.step)} iterations of {res.estimator}, dt {res.dt_s:g} s{noise}"
        rec.log(ent.LOG_HOST, rr.TextLog(note, level="INFO"), static=True)
        return summary
    finally:
        session.close()

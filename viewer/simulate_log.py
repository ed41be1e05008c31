"""Log a ``steval simulate`` run (UMaine Lab 5 simulator) to Rerun with the standard layout and blueprint.

The simulated filter takes the place of the drone's own filter: the solid quadcopter and the ``firmware`` series
show it, labelled ``simulated <estimator>``; ``fw_time`` is the simulated time ``(step + 1) * dt_s``. Called by
``steval simulate --rrd FILE``::

    log_simulation(result, "sim.rrd")
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import rerun as rr

from steval_viewer import entities as ent
from steval_viewer.replay_log import ReplaySummary, log_replay
from steval_viewer.sink_options import SinkOptions
from steval_viewer.sinks import ViewerSession, open_session


def simulation_telemetry(res: Any) -> SimpleNamespace:
    """A Telemetry-shaped view of a ``SimulationResult`` (attitude rows only; no link, no status frames)."""
    n = len(res.step)
    step = np.asarray(res.step, dtype=np.int64)
    valid = np.asarray(res.valid, dtype=bool)
    q = np.asarray(res.q_wxyz, dtype=np.float64).copy()
    q[~valid] = np.nan
    att = SimpleNamespace(
        step=step,
        t_fw_s=(step + 1) * float(res.dt_s),
        t_host_s=np.full(n, np.nan),
        acc_mg=np.asarray(res.acc_mg),
        gyro_mdps=np.asarray(res.gyro_mdps),
        thr=np.asarray(res.thr),
        q_wxyz=q,
        thz_rad=np.where(valid, np.asarray(res.eaz_rad, dtype=np.float64), np.nan),
        thx_rad=np.where(valid, np.asarray(res.eax_rad, dtype=np.float64), np.nan),
        thy_rad=np.where(valid, np.asarray(res.eay_rad, dtype=np.float64), np.nan),
    )
    return SimpleNamespace(attitude=att, status=None, text=[], stats=None)


def log_simulation_to(rec: rr.RecordingStream, res: Any) -> ReplaySummary:
    """Log a simulation result to an open recording (blueprint included)."""
    tel = simulation_telemetry(res)
    summary = log_replay(rec, tel, {}, None, link=False)
    label = f"simulated {res.estimator}"
    for path, name in (
        (ent.pitch_path(ent.SOURCE_FIRMWARE), f"thx pitch ({label})"),
        (ent.roll_path(ent.SOURCE_FIRMWARE), f"thy roll ({label})"),
        (ent.yaw_path(ent.SOURCE_FIRMWARE), f"thz yaw ({label})"),
    ):
        rec.log(
            path,
            rr.SeriesLines(names=[name], colors=[ent.source_color(ent.SOURCE_FIRMWARE)], widths=[2.5]),
            static=True,
        )
    noise = ""
    if getattr(res, "gyro_noise_mdps", 0) or getattr(res, "acc_noise_mg", 0):
        noise = f", noise gyro {res.gyro_noise_mdps:g} mdps / acc {res.acc_noise_mg:g} mg (seed {res.seed})"
    rec.log(
        ent.LOG_HOST,
        rr.TextLog(
            f"steval simulate: {len(tel.attitude.step)} iterations of {res.estimator}, dt {res.dt_s:g} s{noise}",
            level="INFO",
        ),
        static=True,
    )
    return summary


def log_simulation(res: Any, path: str | Path | None = None, *, options: SinkOptions | None = None) -> ReplaySummary:
    """Log a ``SimulationResult`` to an ``.rrd`` file ``path`` (and/or the viewers of ``options``), then close."""
    if options is None:
        options = SinkOptions(rrd=Path(path) if path is not None else None)
    elif path is not None:
        options.rrd = Path(path)
    session: ViewerSession = open_session(options, recording_name=f"steval simulate ({res.estimator})")
    try:
        return log_simulation_to(session.rec, res)
    finally:
        session.close()

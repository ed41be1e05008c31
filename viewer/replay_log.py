"""A whole Telemetry and its host estimates to Rerun, one ``rr.send_columns`` per entity. Estimates are duck-typed:
``q_wxyz`` (N, 4), ``thx_rad`` and ``thy_rad`` (N,), optionally a ``valid`` (N,) bool mask."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import rerun as rr

from steval_link.analysis.diagnosis import capture_variant_hint
from steval_link.analysis.flight_control import no_flight_figure_reason
from steval_link.analysis.summary import values_bad_report
from steval_link.estimators.firmware_replay import replay_variants
from steval_link.link.commands import command_log
from steval_link.quat import quaternion_from_euler
from steval_viewer import blueprint as bp
from steval_viewer import columns as col
from steval_viewer import drone_model, flight_log
from steval_viewer import entities as ent
from steval_viewer.sinks import log_whole

#: ``progress(fraction done 0..1, stage)``, e.g. ``steval_link.cli.progress``; None: no reports
Progress = Callable[[float, str], None] | None


def _part(progress: Progress, start: float = 0.0, span: float = 1.0) -> Callable[..., None]:
    """``progress`` for one part of a job: its 0..1 maps to ``start``..``start + span`` (None: no reports)."""
    return lambda f, stage="": None if progress is None else progress(start + span * f, stage)


def estimate_mask(est: Any, n: int) -> np.ndarray:
    """The rows of an estimate that hold a real value (its ``valid`` / ``mask`` / ``seeded`` array, else all)."""
    for name in ("valid", "mask", "seeded"):
        m = getattr(est, name, None)
        if m is not None and np.shape(m) == (n,):
            return np.asarray(m, dtype=bool)
    return np.ones(n, dtype=bool)


@dataclass
class ReplaySummary:
    """What :func:`log_replay` logged: samples per entity path (values sent, gaps excluded) and the sources."""

    samples: dict[str, int] = field(default_factory=dict)
    sources: list[str] = field(default_factory=list)


def _deg(rad: np.ndarray) -> np.ndarray:
    return np.degrees(np.asarray(rad, dtype=np.float64))


def firmware_series(att: Any) -> list[tuple[str, np.ndarray]]:
    """The firmware's plotted series of attitude rows: angles (deg), raw sensors (gyro in dps), throttle."""
    return [
        (ent.pitch_path(ent.SOURCE_FIRMWARE), _deg(att.thx_rad)),
        (ent.roll_path(ent.SOURCE_FIRMWARE), _deg(att.thy_rad)),
        (ent.yaw_path(ent.SOURCE_FIRMWARE), _deg(att.thz_rad)),
        (ent.PLOT_ACC, np.asarray(att.acc_mg, dtype=np.float64)),
        (ent.PLOT_GYRO, np.asarray(att.gyro_mdps, dtype=np.float64) / 1000.0),
        (ent.PLOT_THROTTLE, np.asarray(att.thr, dtype=np.float64)),
    ]


def display_quaternions(att: Any) -> np.ndarray:
    """The firmware attitude for the 3D view: ``q_wxyz``, else (text mode) from thx/thy/thz; NaN where values_bad."""
    q = np.asarray(att.q_wxyz, dtype=np.float64).copy()
    thx, thy = np.asarray(att.thx_rad, dtype=np.float64), np.asarray(att.thy_rad, dtype=np.float64)
    rows = ~np.isfinite(q).all(axis=1) & np.isfinite(thx) & np.isfinite(thy)
    if rows.any():
        q[rows] = quaternion_from_euler(thx[rows], thy[rows], np.nan_to_num(np.asarray(att.thz_rad)[rows]))
    bad = getattr(att, "values_bad", None)
    if bad is not None:
        q[np.asarray(bad, dtype=bool)] = np.nan
    return q


def send_values_bad_note(rec: rr.RecordingStream, at: col.Times, sentence: str, last_good_step: int | None) -> None:
    """The warning at the first row with bad values ``at``: ``sentence`` and where the 3D drone stays."""
    where = "without an attitude (no finite one before)"
    if last_good_step is not None:
        where = f"at its last finite attitude (step {last_good_step})"
    col.send_texts(rec, ent.LOG_FILTER, at, [f"{sentence}; the 3D drone stays {where}"], ["WARN"])


class _Replay:
    """One replay being logged: its recording, the attitude rows' times and the samples sent per entity path."""

    def __init__(self, rec: rr.RecordingStream, times: col.Times, summary: ReplaySummary) -> None:
        self.rec, self.times, self.summary = rec, times, summary

    def scalars(self, path: str, values: np.ndarray, valid: np.ndarray | None = None, times: col.Times | None = None):
        self.summary.samples[path] = col.send_scalars(self.rec, path, times or self.times, values, valid)

    def texts_at(self, path: str, t_host: np.ndarray, texts: list, levels: list) -> None:
        """Text entries at host times ``t_host`` (s), firmware time interpolated; one without a time has no timeline."""
        timed = np.isfinite(t_host) & (self.times.t_host_s is not None)
        idx = np.flatnonzero(timed)
        if idx.size:
            pairs = np.isfinite(self.times.t_host_s)
            at = col.Times(np.interp(t_host[idx], self.times.t_host_s[pairs], self.times.t_fw_s[pairs]), t_host[idx])
            col.send_texts(self.rec, path, at, [texts[i] for i in idx], [levels[i] for i in idx])
        for i in np.flatnonzero(~timed):
            self.rec.log(path, rr.TextLog(texts[i], level=levels[i]))
        self.summary.samples[path] = len(texts)

    def firmware(self, att: Any) -> None:
        """The firmware's side of each attitude row: 3D attitude, gravity arrow, angles, raw sensors, throttle."""
        samples = self.summary.samples
        q = display_quaternions(att)
        samples[ent.DRONE_FIRMWARE] = col.send_transforms(self.rec, ent.DRONE_FIRMWARE, self.times, q)
        with np.errstate(invalid="ignore"):  # body frame, 1 g = 1 unit; the accelerometer reads +1 g up at rest
            gravity = -np.asarray(att.acc_mg, dtype=np.float64) / 1000.0
        samples[ent.ACC_GRAVITY] = col.send_arrows(self.rec, ent.ACC_GRAVITY, self.times, gravity)
        for path, values in firmware_series(att):
            self.scalars(path, values)

    def estimate(self, source: str, est: Any, ghost: bool) -> None:
        """One host estimate: ghost drone (when ``ghost``), thx/thy series; invalid rows are gaps."""
        valid = estimate_mask(est, len(self.times))
        if ghost:
            path = ent.estimate_path(source)
            self.summary.samples[path] = col.send_transforms(self.rec, path, self.times, est.q_wxyz, valid)
        self.scalars(ent.pitch_path(source), _deg(est.thx_rad), valid)
        self.scalars(ent.roll_path(source), _deg(est.thy_rad), valid)

    def replica_difference(self, att: Any, replica: Any) -> None:
        """firmware − ST-Mahony replica for thx and thy, in degrees, where the replica is seeded (0 when bit-exact)."""
        valid = estimate_mask(replica, len(self.times))
        for path, angle in ((ent.DIFF_THX, "thx_rad"), (ent.DIFF_THY, "thy_rad")):
            diff = np.asarray(getattr(att, angle), np.float64) - np.asarray(getattr(replica, angle), np.float64)
            self.scalars(path, _deg(diff), valid)

    def link(self, tel: Any) -> None:
        """Link health over time: frame rate and missing frames per 1 s bin, status-frame counters, decoder totals."""
        times, n = self.times, len(self.times)
        if n:
            t = times.t_fw_s
            rows = np.flatnonzero(np.isfinite(t))
            # 1 s bins of firmware time (NaN rows ignored, time never goes back): each one's last row, rows per bin
            k = np.maximum.accumulate(np.floor(t[rows] - t[rows[:1]]).astype(np.int64))
            ends = np.flatnonzero(np.diff(k, append=k[-1:] + 1))
            last, counts = rows[ends], np.diff(np.concatenate(([-1], ends)))
            # frames per second of firmware time inside each bin (exact for partial first/last bins too)
            span = t[last] - t[np.concatenate(([0], last[:-1] + 1))]
            with np.errstate(invalid="ignore", divide="ignore"):
                rate = np.where((counts > 1) & (span > 0), (counts - 1) / span, np.nan)
            self.scalars(ent.LINK_RATE, rate, times=times.take(last))
            gaps = np.clip(np.diff(np.asarray(tel.attitude.step, dtype=np.int64)) - 1, 0, None)
            missing = np.cumsum(np.concatenate(([0], gaps)))[last].astype(np.float64)
            self.scalars(ent.LINK_MISSING, missing, times=times.take(last))
            crc = getattr(getattr(tel, "stats", None), "crc_failures", None)
            if crc is not None:  # the decoder counts CRC failures for the whole stream only: one sample at the end
                self.scalars(ent.LINK_CRC, np.array([float(crc)]), times=times.take(np.array([n - 1])))
        st = getattr(tel, "status", None)
        if st is not None and len(getattr(st, "t_fw_s", ())):
            stimes = col.Times(st.t_fw_s, getattr(st, "t_host_s", None), getattr(st, "step", None))
            cyc = np.stack([st.cyc_min, st.cyc_mean, st.cyc_max], axis=1).astype(np.float64)
            self.scalars(ent.LINK_CYCLES, cyc, np.asarray(st.cyc_n) > 0, stimes)  # no steps covered: no figures
            self.scalars(ent.LINK_TX_DROPPED, np.asarray(st.tx_dropped, dtype=np.float64), times=stimes)
            self.scalars(ent.LINK_QUEUE, np.asarray(st.queue_peak, dtype=np.float64), times=stimes)

    def text(self, tel: Any) -> None:
        """Firmware text lines, text telemetry and the commands the host sent (with the drone's acks)."""
        text = list(getattr(tel, "text", []) or [])
        if text:
            t_host = np.array([float(t) if t is not None else np.nan for t, _ in text], dtype=np.float64)
            self.texts_at(ent.LOG_FIRMWARE, t_host, [str(s) for _, s in text], ["INFO"] * len(text))
        series = getattr(tel, "text_series", None)
        if series is not None and len(series):
            # an entity per record shape under ``text/``, a named line per series, at each record's t_s and host time
            times = col.Times(series.t_s, series.t_host_s)
            for k, names in enumerate(series.shapes):
                rows = np.flatnonzero(series.shape == k)
                cols = [series.names.index(name) for name in names]
                col.log_text_style(self.rec, names, [series.units[c] for c in cols])
                col.send_records(self.rec, names, times.take(rows), series.values[np.ix_(rows, cols)])
                self.summary.samples[col.text_path(names)] = len(rows)
        # one entry per command at the time it was sent; a refusal or a missing ack as a warning
        entries = command_log(getattr(tel, "commands", ()), getattr(tel, "acks", ()))
        if entries:
            t_host = np.array([e["t_host_s"] for e in entries], dtype=np.float64)
            levels = ["INFO" if e["result"] == 0 else "WARN" for e in entries]
            self.texts_at(ent.LOG_COMMANDS, t_host, [e["text"] for e in entries], levels)

    def values_bad(self, tel: Any) -> None:
        """A warning at the first row flagged ``values_bad`` (the firmware's own filter went NaN or off range)."""
        att = tel.attitude
        rep = values_bad_report(tel) if hasattr(att, "values_bad") else None
        if rep is None or rep["first_row"] is None:
            return
        i = int(rep["first_row"])
        good = np.flatnonzero(np.isfinite(display_quaternions(att)[:i]).all(axis=1))
        last = int(np.asarray(att.step)[good[-1]]) if good.size else None
        send_values_bad_note(self.rec, self.times.take(np.array([i])), rep["text"], last)
        self.summary.samples[ent.LOG_FILTER] = 1


def absent_plots(tel, replica) -> list[str]:
    """The attitude plots a recording has no values for (a log of printed angles: its rows hold 0 for a throttle)."""
    att = tel.attitude
    printed = getattr(tel, "printed_only", False)  # a simulation logs a namespace, not a Telemetry
    values = {
        ent.PLOT_THROTTLE: not printed or bool(np.any(np.asarray(att.thr) != 0)),
        ent.PLOT_YAW: np.isfinite(att.thz_rad).any(),
        ent.PLOT_DIFF: replica is not None,
        ent.PLOT_ACC: np.isfinite(att.acc_mg).any(),
        ent.PLOT_GYRO: np.isfinite(att.gyro_mdps).any(),
    }
    return [plot for plot, has in values.items() if not has]


def log_replay(
    rec: rr.RecordingStream,
    tel: Any,
    estimates: Mapping[str, Any] | None = None,
    replica: Any | None = None,
    *,
    link: bool = True,
    progress: Progress = None,
) -> ReplaySummary:
    """Log a whole Telemetry, the ST-Mahony ``replica`` and host ``estimates`` (name -> one row per attitude row)
    with the default blueprint; returns the samples logged per entity path. ``link``: the link-health series."""
    att = tel.attitude
    n = len(att.t_fw_s)
    sources = [(ent.SOURCE_REPLICA, replica)] if replica is not None else []
    sources += [(ent.source_name(name), est) for name, est in (estimates or {}).items()]
    names = [s for s, _ in sources]
    for k, (source, est) in enumerate(sources):
        if source in names[:k] or source == ent.SOURCE_FIRMWARE:
            raise ValueError(f"estimate name {source!r} is used twice or clashes with the firmware")
        if len(np.asarray(est.thx_rad)) != n:
            raise ValueError(f"estimate {source!r} has {len(np.asarray(est.thx_rad))} rows, telemetry has {n}")
    ghost_sources = [s for s, e in sources if getattr(e, "q_wxyz", None) is not None]
    has_fc = len(getattr(tel, "fc", None) or ()) > 0
    gyro = np.abs(np.asarray(att.gyro_mdps, dtype=np.float64))
    bp.send_blueprint(
        rec,
        ghost_sources=ghost_sources,
        gyro_max_dps=float(gyro[np.isfinite(gyro)].max(initial=0.0)) / 1000.0,
        flight_control=has_fc,
        never_armed=has_fc and no_flight_figure_reason(tel.fc) is not None,
        replica_verdict=None if replica is None else bp.replica_verdict(att.step, replica.bit_exact, replica.seeded),
        y_ranges=replay_y_ranges(tel, [e for s, e in sources if s != ent.SOURCE_REPLICA]),
        absent=absent_plots(tel, replica),
        text=getattr(tel, "printed_only", False),
    )
    drone_model.log_static(rec, names, with_replica=replica is not None)
    if has_fc:
        flight_log.log_flight_static(rec)
        flight_log.log_motors_static(rec)

    summary = ReplaySummary(sources=names)
    log = _Replay(rec, col.Times(att.t_fw_s, getattr(att, "t_host_s", None), getattr(att, "step", None)), summary)
    report = _part(progress)
    report(0.0, "logging the firmware's series")
    log.firmware(att)
    for i, (source, est) in enumerate(sources):
        report((i + 1) / (len(sources) + 2), f"logging {source}")
        log.estimate(source, est, ghost=source in ghost_sources)
    report((len(sources) + 1) / (len(sources) + 2), "logging link health and text")
    if replica is not None:
        log.replica_difference(att, replica)
    if link:
        log.link(tel)
    log.text(tel)
    log.values_bad(tel)
    if has_fc:
        summary.samples[ent.FC_MOTORS] = flight_log.log_flight_control(rec, tel)
    return summary


def replay_y_ranges(tel: Any, estimates: list[Any]) -> dict[str, tuple[float, float]]:
    """Fixed y ranges of the plots whose legends would cover data: angles, accelerometer, link losses."""
    att = tel.attitude
    out: dict[str, tuple[float, float] | None] = {}
    for path, fw, attr in ((ent.PLOT_PITCH, att.thx_rad, "thx_rad"), (ent.PLOT_ROLL, att.thy_rad, "thy_rad")):
        vals = [_deg(fw)] + [_deg(getattr(e, attr))[estimate_mask(e, len(att.step))] for e in estimates]
        share = bp.LEGEND_SHARE["angles"] * min(len(vals), 5) / 5
        out[path] = bp.legend_room(np.concatenate(vals), share=share, bottom=False)
    acc = np.asarray(att.acc_mg, np.float64)
    out[ent.PLOT_ACC] = bp.legend_room(acc, share=bp.LEGEND_SHARE["sensors"], bottom=True)
    lost = [float(np.clip(np.diff(np.asarray(att.step, dtype=np.int64)) - 1, 0, None).sum())]
    lost.append(float(getattr(getattr(tel, "stats", None), "crc_failures", 0) or 0))
    st = getattr(tel, "status", None)
    if st is not None and len(getattr(st, "t_fw_s", ())):
        lost.append(float(np.nanmax(np.asarray(st.tx_dropped, np.float64))))
    out[ent.LINK] = bp.legend_room(np.asarray(lost), share=bp.LEGEND_SHARE["link"], bottom=False, floor=0.0)
    return {k: v for k, v in out.items() if v is not None}


#: Registry names that mean the firmware's own filter: replaced by the status-seeded bit-exact replica.
REPLICA_NAMES = ("st-mahony", "st_mahony")


def log_telemetry(
    rec: rr.RecordingStream, tel: Any, estimates: Mapping[str, Any] | None = None, *, progress: Progress = None
) -> ReplaySummary:
    """Log ``tel`` with its seeded bit-exact replica (none in text mode) and ``estimates``; ``st-mahony`` gives way."""
    _part(progress)(0.0, "ST-Mahony replica")
    replica = None
    if np.asarray(getattr(tel.attitude, "exact", True)).any():
        replica = replay_variants(tel, hint=capture_variant_hint(tel)).replay
    others = {k: v for k, v in (estimates or {}).items() if not (replica is not None and k in REPLICA_NAMES)}
    return log_replay(rec, tel, others, replica=replica, progress=_part(progress, 0.1, 0.9))


def replay_sink(options: Any, tel: Any, estimates: Mapping[str, Any], *, progress: Progress = None) -> None:
    """``steval replay`` to the sinks of ``options`` (:func:`~steval_viewer.sinks.log_whole`)."""
    src = getattr(tel, "source", None) or {}
    name = f"steval replay {Path(src['path']).name}" if src.get("path") else "steval replay"

    def log(rec):
        log_telemetry(rec, tel, estimates, progress=_part(progress, 0.0, 0.6))
        _part(progress)(0.6, "writing to Rerun")

    log_whole(options, name, log)

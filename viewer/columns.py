"""NaN-safe columnar logging shared by the replay and live paths (one ``rr.send_columns`` per entity and call): a
non-finite row is never sent as a value; a ``Clear`` where each bad run starts makes the plot draw a gap."""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np
import rerun as rr

from steval_viewer import entities as ent


@dataclass
class Times:
    """The timelines of N rows: ``t_fw_s`` (firmware s since boot, on ``timeline``), ``t_host_s`` (host s, may be
    None or contain NaN; None when no row has one), ``step`` (AHRS step counter, may be None)."""

    t_fw_s: np.ndarray
    t_host_s: np.ndarray | None = None
    step: np.ndarray | None = None
    timeline: str = ent.TIMELINE_FW

    def __post_init__(self) -> None:
        self.t_fw_s = np.asarray(self.t_fw_s, dtype=np.float64)
        host = None if self.t_host_s is None else np.asarray(self.t_host_s, dtype=np.float64)
        self.t_host_s = host if host is not None and np.isfinite(host).any() else None
        if self.step is not None:
            self.step = np.asarray(self.step, dtype=np.int64)

    def __len__(self) -> int:
        return len(self.t_fw_s)

    def take(self, idx: np.ndarray) -> "Times":
        """The rows ``idx`` (integer indices or a boolean mask)."""
        host, step = (None if a is None else a[idx] for a in (self.t_host_s, self.step))
        return replace(self, t_fw_s=self.t_fw_s[idx], t_host_s=host, step=step)

    def host_complete(self) -> bool:
        return self.t_host_s is not None and bool(np.isfinite(self.t_host_s).all())

    @functools.cached_property
    def indexes(self) -> list[rr.TimeColumn]:
        """Time columns for ``send_columns`` (host time only when every row has one; see :func:`send_rows`)."""
        cols = [rr.TimeColumn(self.timeline, duration=self.t_fw_s)]
        if self.host_complete():
            cols.append(rr.TimeColumn(ent.TIMELINE_HOST, duration=self.t_host_s))
        if self.step is not None:
            cols.append(rr.TimeColumn(ent.TIMELINE_STEP, sequence=self.step))
        return cols


def send_rows(rec: rr.RecordingStream, path: str, times: Times, make_columns, rows: np.ndarray | None = None) -> int:
    """Send ``make_columns(idx)`` for the rows (indices or a mask; all when None), split by host-time availability."""
    idx = np.arange(len(times)) if rows is None else np.asarray(rows)
    if idx.dtype == bool:
        rows = None if idx.all() else rows
        idx = np.flatnonzero(idx)
    if len(idx) == 0:
        return 0
    if rows is None and (times.t_host_s is None or times.host_complete()):
        rec.send_columns(path, indexes=times.indexes, columns=make_columns(None))
        return len(idx)
    has = np.ones(len(idx), bool) if times.t_host_s is None else np.isfinite(times.t_host_s[idx])
    for part in (idx[has], idx[~has]):
        if len(part):  # host times all finite, or all NaN (then dropped by Times)
            rec.send_columns(path, indexes=times.take(part).indexes, columns=make_columns(part))
    return len(idx)


def send_texts(rec: rr.RecordingStream, path: str, times: Times, texts: list[str], levels: list[str]) -> None:
    """Log one text entry per row (``texts``, each at its ``levels`` entry: INFO, WARN)."""
    texts, levels = np.array(texts, dtype=object), np.array(levels, dtype=object)
    send_rows(rec, path, times, lambda idx: rr.TextLog.columns(text=_take(texts, idx), level=_take(levels, idx)))


def send_scalars(
    rec: rr.RecordingStream, path: str, times: Times, values: np.ndarray, valid: np.ndarray | None = None, gaps=True
) -> int:
    """Log a scalar series (N,) or a group (N, k) on ``path``; non-finite or invalid rows are left out (``gaps``: a
    ``Clear`` where each run of them starts). Returns the rows with a value."""
    v = np.asarray(values, dtype=np.float64)
    good = np.isfinite(v) if v.ndim == 1 else np.isfinite(v).all(axis=1)
    if valid is not None:
        good &= np.asarray(valid, dtype=bool)
    sent = send_rows(rec, path, times, lambda idx: rr.Scalars.columns(scalars=_take(v, idx)), good)
    if gaps:
        starts = np.flatnonzero(~good & ~np.concatenate(([False], ~good[:-1])))
        send_rows(rec, path, times, lambda idx: rr.Clear.columns(is_recursive=np.zeros(len(idx), dtype=bool)), starts)
    return sent


def series_style(rec: rr.RecordingStream, path: str, names, colors, width: float = 1.5, visible=None) -> None:
    """A series' legend (static): ``names`` (one, or one per column) with their ``colors``, line ``width``."""
    names = [names] if isinstance(names, str) else list(names)
    colors = [colors] if isinstance(colors, tuple) else list(colors)
    lines = rr.SeriesLines(names=names, colors=colors, widths=[width] * len(names), visible_series=visible)
    rec.log(path, lines, static=True)


#: Text telemetry: one entity per record shape under this root (the blueprint's "Text telemetry" tab).
TEXT_ROOT = "text"


def text_path(names) -> str:
    """The entity of one record shape of text telemetry: its series' names joined by ``-``."""
    return f"{TEXT_ROOT}/{rr.escape_entity_path_part('-'.join(names))}"


#: Colours of a record shape's lines, in order (Tableau 10: ten that tell apart; Rerun's own may repeat in nine).
TEXT_COLORS = (0x1F77B4, 0xFF7F0E, 0x2CA02C, 0xD62728, 0x9467BD, 0x8C564B, 0xE377C2, 0x7F7F7F, 0xBCBD22, 0x17BECF)


def log_text_style(rec: rr.RecordingStream, names, units) -> None:
    """A record shape's legend (static): a line per series, named with its unit where one was printed."""
    labels = [f"{n} ({u})" if u else n for n, u in zip(names, units)]
    colors = [TEXT_COLORS[k % len(TEXT_COLORS)] << 8 | 0xFF for k in range(len(names))]
    rec.log(text_path(names), rr.SeriesLines(names=labels, colors=colors), static=True)


def send_records(rec: rr.RecordingStream, names, times: Times, values: np.ndarray) -> None:
    """Records of one shape, (N, k) values: one row of k scalars per record; a non-finite value is a gap."""
    v = np.asarray(values, dtype=np.float64).reshape(len(times), len(names))
    v = np.where(np.isfinite(v), v, np.nan)
    send_rows(rec, text_path(names), times, lambda idx: rr.Scalars.columns(scalars=_take(v, idx)))


def unit_xyzw(q_wxyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4) xyzw float32 of ``q_wxyz`` (body -> earth, q0 scalar first) normalised for display (the firmware's |q|
    is about 0.9983), and the rows whose quaternion is finite and not zero."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.sqrt((q * q).sum(axis=1))
        return (q[:, [1, 2, 3, 0]] / norm[:, None]).astype(np.float32), np.isfinite(norm) & (norm > 1e-6)


def send_transforms(
    rec: rr.RecordingStream, path: str, times: Times, q_wxyz: np.ndarray, valid: np.ndarray | None = None
) -> int:
    """Log ``q_wxyz`` as Transform3D rows on ``path``; a row without a quaternion or ``valid`` keeps the last one."""
    xyzw, good = unit_xyzw(q_wxyz)
    if valid is not None:
        good &= np.asarray(valid, dtype=bool)
    return send_rows(rec, path, times, lambda idx: rr.Transform3D.columns(quaternion=_take(xyzw, idx)), good)


def send_arrows(rec: rr.RecordingStream, path: str, times: Times, vectors: np.ndarray) -> int:
    """Log one arrow per row from the origin (``vectors`` (N, 3)); non-finite rows are skipped."""
    v = np.asarray(vectors, dtype=np.float32)
    good = np.isfinite(v).all(axis=1)
    return send_rows(rec, path, times, lambda idx: rr.Arrows3D.columns(vectors=_take(v, idx)), good)


def _take(values, idx):
    return values if idx is None else values[idx]

"""One Arrow record batch per live processing round for many entities at once (:class:`RowBatch`), sent with a
single ``RecordingStream.send_record_batch`` call; Rerun splits it into one chunk per entity.

Why not ``rr.send_columns`` per entity: a live round logs ~22 entities for a handful of frames, and one record
batch costs about half as much (the live latency goal, ``benchmarks/bench_live_latency.py``). The price: Rerun's
column metadata keys tie this module to the pinned Rerun SDK; ``tests/test_viewer.py`` reads every live entity
back, so a change of that format fails the tests, not the users.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from steval_viewer import entities as ent
from steval_viewer.columns import Times, unit_xyzw

#: (column name, archetype, component type) of each component kind a live round logs
_SCALAR = ("Scalars:scalars", "rerun.archetypes.Scalars", "rerun.components.Scalar")
_QUAT = ("Transform3D:quaternion", "rerun.archetypes.Transform3D", "rerun.components.RotationQuat")
_VEC = ("Arrows3D:vectors", "rerun.archetypes.Arrows3D", "rerun.components.Vector3D")


def _field(pa, cache: dict, name: str, typ, **meta: str):
    """The Arrow field ``name`` with Rerun's ``rerun:<key>`` metadata ``meta`` (cached in ``cache``)."""
    key = (name, str(typ))
    if key not in cache:
        cache[key] = pa.field(name, typ, metadata={f"rerun:{k}".encode(): v.encode() for k, v in meta.items()})
    return cache[key]


class RowBatch:
    """Many entities' columns for the same N rows in one record batch. A non-finite value is a null (no sample);
    a ``Clear`` is sent when an entity turns bad, so plots show a gap."""

    def __init__(self, times: Times, bad_state: dict[str, bool], cache: dict | None = None) -> None:
        import pyarrow as pa

        self._pa = pa
        self.times = times
        self.n = len(times)
        self.fields: list = []
        self.arrays: list = []
        self.bad_state = bad_state
        self.clear_rows: dict[str, np.ndarray] = {}
        self.cache = {} if cache is None else cache  # Arrow fields and offsets, reused across batches

    def _index(self) -> None:
        pa = self._pa
        t = self.times
        cols = [(ent.TIMELINE_FW, np.round(t.t_fw_s * 1e9).astype(np.int64))]
        if t.host_complete():
            cols.append((ent.TIMELINE_HOST, np.round(t.t_host_s * 1e9).astype(np.int64)))
        if t.step is not None:
            cols.append((ent.TIMELINE_STEP, t.step))
        for name, values in cols:
            typ = pa.int64() if name == ent.TIMELINE_STEP else pa.duration("ns")
            f = _field(pa, self.cache, name, typ, kind="index", index_name=name)
            self.fields.insert(0, f)
            self.arrays.insert(0, pa.array(values, type=f.type))

    def _add(
        self, path: str, kind: tuple[str, str, str], values: np.ndarray, width: int, good: np.ndarray, all_good: bool
    ) -> None:
        if not good.any() and self.bad_state.get(path, False):
            return  # a gap that goes on: nothing to send (its Clear was sent where it began)
        pa = self._pa
        if kind is _SCALAR:
            inner, step = pa.array(values.reshape(-1)), width
        else:
            inner, step = pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1).astype(np.float32)), width), 1
        mask = None if all_good else pa.array(~good)
        arr = pa.ListArray.from_arrays(self._offsets_for(self.n, step), inner, mask=mask)
        comp, arch, ctype = kind
        meta = dict(kind="data", entity_path="/" + path, component=comp, archetype=arch, component_type=ctype)
        self.fields.append(_field(pa, self.cache, f"/{path}:{comp}", arr.type, **meta))
        self.arrays.append(arr)
        # gaps: a Clear at each row where the entity turns bad (state carried across batches)
        bad = ~good
        if not all_good:
            starts = np.flatnonzero(bad & ~np.concatenate(([self.bad_state.get(path, False)], bad[:-1])))
            if starts.size:
                self.clear_rows[path] = starts
        self.bad_state[path] = bool(bad[-1])

    def _offsets_for(self, n: int, step: int):
        key = ("offsets", n, step)
        off = self.cache.get(key)
        if off is None:
            off = self._pa.array(np.arange(0, n * step + 1, step, dtype=np.int32))
            if n <= 64:
                self.cache[key] = off
        return off

    def scalars(self, path: str, values: np.ndarray) -> None:
        v2 = np.asarray(values, dtype=np.float64).reshape(self.n, -1)
        good = np.isfinite(v2).all(axis=1)
        all_good = bool(good.all())
        if not all_good:
            v2 = np.where(good[:, None], v2, 0.0)
        self._add(path, _SCALAR, v2, v2.shape[1], good, all_good)

    def quaternions(self, path: str, q_wxyz: np.ndarray, select: np.ndarray | None = None) -> None:
        self._kept(path, _QUAT, *unit_xyzw(np.reshape(q_wxyz, (self.n, 4))), select)

    def vectors(self, path: str, v: np.ndarray, select: np.ndarray | None = None) -> None:
        v = np.asarray(v, dtype=np.float64).reshape(self.n, 3)
        self._kept(path, _VEC, v, np.isfinite(v).all(axis=1), select)

    def _kept(self, path: str, kind, values: np.ndarray, good: np.ndarray, select: np.ndarray | None) -> None:
        """A 3D entity's ``good`` rows (and ``select``): it keeps its last value, never cleared. A path never good is
        not sent (the viewer rejects an all-null column); a path sent once is in ``bad_state``."""
        if select is not None:
            good = good & select
        if path not in self.bad_state and not good.any():
            return
        self._add(path, kind, np.where(good[:, None], values, 0.0), values.shape[1], good, bool(good.all()))
        self.bad_state[path] = False

    def send(self, rec: rr.RecordingStream) -> None:
        if not self.arrays:
            return
        self._index()
        pa = self._pa
        rec.send_record_batch(pa.RecordBatch.from_arrays(self.arrays, schema=pa.schema(self.fields)))
        for path, rows in self.clear_rows.items():
            if path.startswith(ent.PLOTS + "/") or path.startswith(ent.LINK + "/"):
                sub = self.times.take(rows)
                rec.send_columns(path, indexes=sub.indexes, columns=rr.Clear.columns(is_recursive=[False] * len(rows)))

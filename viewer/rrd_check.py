"""Read an ``.rrd`` back (tests, benchmarks): samples per entity path (gaps' Clear rows not counted), timelines,
the blueprint."""

from __future__ import annotations

import warnings
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class RrdInfo:
    """``samples``: temporal rows with data per entity path (no leading ``/``); ``clears``: Clear rows (gaps) per
    path; ``static``: paths with static data; ``timelines``; ``has_blueprint``; ``application_id``."""

    samples: dict[str, int] = field(default_factory=dict)
    clears: dict[str, int] = field(default_factory=dict)
    static: set[str] = field(default_factory=set)
    timelines: set[str] = field(default_factory=set)
    has_blueprint: bool = False
    application_id: str | None = None


def _reader(path: str | Path):
    """Rerun's reader of ``path``, without its warning about a file with no footer (ours: ``rrd_writer``)."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*no footer.*")
        return RrdReader(str(path))


def read_rrd(path: str | Path) -> RrdInfo:
    """Read every chunk of the first recording in ``path`` (raises on a file Rerun cannot read)."""
    reader = _reader(path)
    recordings = reader.recordings()
    if not recordings:
        raise ValueError(f"{path} holds no Rerun recording")
    info = RrdInfo(has_blueprint=bool(reader.blueprints()), application_id=recordings[0].application_id)
    samples: dict[str, int] = defaultdict(int)
    clears: dict[str, int] = defaultdict(int)
    for chunk in reader.stream(store=recordings[0]):
        entity = chunk.entity_path.lstrip("/")
        if chunk.is_static:
            info.static.add(entity)
            continue
        info.timelines.update(chunk.timeline_names)
        rb = chunk.to_record_batch()
        names = [f.name for f in rb.schema if ":" in f.name]
        data = [n for n in names if not n.startswith("Clear:")]
        if names and not data:
            clears[entity] += chunk.num_rows
        elif data:
            # rows with a value in at least one data column (a live batch leaves gaps as null rows)
            samples[entity] += max(rb.num_rows - rb.column(n).null_count for n in data)
    info.samples = dict(samples)
    info.clears = dict(clears)
    return info


def _last_values(chunk) -> dict[str, object]:
    """{component: its last value} of a chunk."""
    rb = chunk.to_record_batch()
    columns = {f.name: rb.column(f.name).to_pylist() for f in rb.schema if ":" in f.name}
    return {name: values[-1] if values else None for name, values in columns.items()}


def _blueprint_components(path: str | Path, every: bool) -> dict[str, dict[str, object]]:
    """The blueprint components in ``path`` (the first blueprint, or ``every`` one): entity path → {component: last
    value, a one-item list unwrapped}."""
    reader = _reader(path)
    stores = reader.blueprints()
    out: dict[str, dict[str, object]] = defaultdict(dict)
    for store in stores if every else stores[:1]:
        for chunk in reader.stream(store=store):
            for name, value in _last_values(chunk).items():
                one = isinstance(value, list) and len(value) == 1
                out[chunk.entity_path.strip("/")][name] = value[0] if one else value
    return out


def blueprint_views(path: str | Path) -> dict[str, dict[str, object]]:
    """The views of the blueprint embedded in ``path``: display name → {component: value} of the view and of its
    properties, e.g. ``"PlotLegend:corner"`` (1 left top, 2 right top, 3 left bottom, 4 right bottom)."""
    by_id: dict[str, dict[str, object]] = defaultdict(dict)
    for entity, comps in _blueprint_components(path, every=False).items():
        parts = entity.split("/")
        if len(parts) >= 2 and parts[0] == "view":
            by_id[parts[1]].update(comps)
    return {str(v.get("ViewBlueprint:display_name")): v for v in by_id.values()}


def active_tabs(path: str | Path) -> list[str]:
    """The display names of the tabs in front in every blueprint embedded in ``path``."""
    parts = _blueprint_components(path, every=True)
    names = {
        entity: comps.get("ViewBlueprint:display_name") or comps.get("ContainerBlueprint:display_name")
        for entity, comps in parts.items()
    }
    active = [comps.get("ContainerBlueprint:active_tab") for comps in parts.values()]
    return [str(names.get(str(a).strip("/"))) for a in active if a]


def static_values(path: str | Path, entity: str) -> dict[str, object]:
    """The static components logged to ``entity`` in the first recording of ``path``: {component: values}."""
    reader = _reader(path)
    out: dict[str, object] = {}
    for chunk in reader.stream(store=reader.recordings()[0]):
        if chunk.is_static and chunk.entity_path.strip("/") == entity:
            out.update(_last_values(chunk))
    return out

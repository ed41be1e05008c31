"""Records of text telemetry as named series (:class:`TextSeries`), their time, and the attitude they stand for.

* :func:`text_series`: the records as one array, a column per name (NaN where a record has none), a time per
  record: a timestamp column (``t``, ``t_ms``, ``millis``, ``NAME_t_ms``...), else the host's receive times, else
  ST's main-loop rate (161.5 Hz) for ST's line and printed angles, else the record index (1 s apart).
* :func:`attitude_plan`: which series are the attitude and inputs: ST's 221117 line, names (pitch/roll/yaw,
  thx/thy/thz, acc/gyro with a unit) or a user's mapping (``pitch=col2:deg``); angles in rad, acc in mg, gyro in mdps.

Axes are the board's: thx is about x = pitch (nose up +), thy about y = roll. The handouts' atan(ay/az), called roll
there, is the angle about x on this board: a note says so.
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field

import numpy as np

from steval_link import constants as C
from steval_link.errors import UserError
from steval_link.link.frames import AttitudeFrame

#: The sentence for ST's line with empty float fields.
FLOATLESS_NOTE = (
    "The output has empty float fields (newlib nano prints no %f): in STM32CubeIDE tick Project Properties > "
    "C/C++ Build > Settings > MCU Settings > 'Use float with printf from newlib-nano (-u _printf_float)', or "
    "apply steval-link's firmware patch."
)

#: What a mapping may name: the angles and the sensor axes, with the units each accepts.
MAP_TARGETS = ("pitch", "roll", "yaw", "acc_x", "acc_y", "acc_z", "gyro_x", "gyro_y", "gyro_z", "thr")
_ANGLE_UNITS = {"deg": math.pi / 180.0, "rad": 1.0, "mdeg": math.pi / 180_000.0, "cdeg": math.pi / 18_000.0}
_ACC_UNITS = {"mg": 1.0, "g": 1000.0, "m/s2": 1000.0 / 9.80665, "m/s^2": 1000.0 / 9.80665, "ms2": 1000.0 / 9.80665}
_GYRO_UNITS = {"mdps": 1.0, "dps": 1000.0, "deg/s": 1000.0, "°/s": 1000.0, "rad/s": 180_000 / math.pi}
_GYRO_UNITS["mrad/s"] = 180.0 / math.pi
_TARGET_UNITS = {
    **dict.fromkeys(("pitch", "roll", "yaw"), (_ANGLE_UNITS, "deg, rad, mdeg")),
    "acc": (_ACC_UNITS, "mg, g, m/s2"),
    "gyro": (_GYRO_UNITS, "mdps, dps, deg/s, rad/s"),
}
_UNIT_ALIASES = {"°": "deg", "degree": "deg", "degrees": "deg", "radian": "rad", "radians": "rad", "m/s²": "m/s2"}
_TIME_NAMES = {
    **dict.fromkeys(("t", "time", "t_s", "time_s", "timestamp"), 1.0),
    **dict.fromkeys(("t_ms", "time_ms", "millis", "ms"), 1e-3),
    **dict.fromkeys(("t_us", "time_us", "micros", "us"), 1e-6),
}
_TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}
#: a time by its name's unit suffix: ``t_fw_s``, ``time_host_ms``, ``t_boot_us``
_TIME_NAME_RE = re.compile(r"(?:t|time)(?:_[a-z0-9]+)*_(s|ms|us)")


@dataclass
class TextSeries:
    """Every record: ``values`` (N, M), a column per name (``units`` as written); per record ``t_s`` (s, see
    ``t_source``), ``t_host_s``, stream ``offset``, ``kind``, ``shape`` (index in ``shapes``); ``notes`` on them."""

    names: list[str] = field(default_factory=list)
    units: list[str] = field(default_factory=list)
    values: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    t_host_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    offset: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, object))
    t_source: str = ""
    notes: list[str] = field(default_factory=list)
    shape: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    shapes: list[tuple[str, ...]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.t_s)

    def column(self, name: str) -> np.ndarray:
        """The values of series ``name`` (KeyError naming the series there are)."""
        try:
            return self.values[:, self.names.index(name)]
        except ValueError:
            raise KeyError(f"no series {name!r}; the series are {', '.join(self.names) or 'none'}") from None

    def table(self) -> dict[str, np.ndarray]:
        """One column per series and the times (``t_s``, ``t_host_s``), units in the names where written."""
        cols: dict[str, np.ndarray] = {"t_s": self.t_s, "t_host_s": self.t_host_s}
        for k, (name, unit) in enumerate(zip(self.names, self.units)):
            key = f"{name}_{re.sub(r'[^0-9A-Za-zµ°]+', '_', unit).strip('_') or 'unit'}" if unit else name
            cols[key if key not in cols else f"text_{key}"] = self.values[:, k]
        return cols


@dataclass
class RecordBlock:
    """Records of one shape: ``values`` (k, m) float64, each record's bytes at ``offset`` (``nbytes`` long)."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    kind: str
    values: np.ndarray
    offset: np.ndarray
    nbytes: np.ndarray


def record_blocks(records: list) -> list[RecordBlock]:
    """``TextRecordFrame`` s as blocks: one per run of records of the same names."""
    out: list[RecordBlock] = []
    for names, group in itertools.groupby(records, key=lambda r: r.names):
        run = list(group)
        values = np.array([x.values for x in run], np.float64).reshape(len(run), len(names))
        offset, nbytes = (np.array([getattr(x, k) for x in run], np.int64) for k in ("offset", "nbytes"))
        out.append(RecordBlock(names, run[0].units, run[0].kind, values, offset, nbytes))
    return out


def text_series(blocks: list[RecordBlock], host_times) -> TextSeries:
    """The record blocks as one :class:`TextSeries` in stream order; ``host_times(last_byte_offsets)``: their times."""
    blocks = [b for b in blocks if len(b.offset)]
    if not blocks:
        return TextSeries()
    unit_of: dict[str, str] = {}  # each name's unit where it first comes
    for b in blocks:
        for name, unit in zip(b.names, b.units):
            unit_of.setdefault(name, unit)
    index = {name: k for k, name in enumerate(unit_of)}
    values = np.full((sum(len(b.offset) for b in blocks), len(index)), np.nan)
    offset = np.concatenate([b.offset for b in blocks])
    last = np.concatenate([b.offset + b.nbytes - 1 for b in blocks])
    kinds = np.concatenate([np.full(len(b.offset), b.kind, dtype=object) for b in blocks])
    shapes = list(dict.fromkeys(b.names for b in blocks))
    shape = np.concatenate([np.full(len(b.offset), shapes.index(b.names)) for b in blocks])
    row = 0
    for b in blocks:
        values[row : row + len(b.offset), [index[name] for name in b.names]] = b.values
        row += len(b.offset)
    order = np.argsort(offset, kind="stable")
    values, offset, last, kinds = values[order], offset[order], last[order], kinds[order]
    series = TextSeries(list(index), list(unit_of.values()), values, np.zeros(0), host_times(last), offset, kinds)
    series.shape, series.shapes = shape[order], shapes
    series.t_s, series.t_source = _record_times(series)
    st = kinds == "st-221117"
    if st.any() and np.isnan(values[st][:, 4:]).all():
        series.notes.append(FLOATLESS_NOTE)
    return series


#: words in a series name that make it an angle the firmware prints after each AHRS step
_ATTITUDE_WORDS = ("pitch", "roll", "yaw", "thx", "thy", "thz")


def _record_times(s: TextSeries) -> tuple[np.ndarray, str]:
    """Each record's time in s and where it comes from (see the module docstring)."""
    n = len(s.kind)
    for k, (name, unit) in enumerate(zip(s.names, s.units)):
        low = name.lower()
        scale = _TIME_UNITS.get(unit) if unit else None
        suffixed = _TIME_NAME_RE.fullmatch(low)
        if scale is None and (low in _TIME_NAMES or low.endswith("_t_ms")):
            scale = _TIME_NAMES.get(low, 1e-3)
        elif scale is None and suffixed:
            scale = _TIME_UNITS[suffixed.group(1)]
        elif scale is not None and low not in _TIME_NAMES and not suffixed:
            scale = None
        col = s.values[:, k]
        if scale is not None and np.isfinite(col).all() and n > 1 and (np.diff(col) >= 0).all():
            return (col - col[0]) * scale, f"the column {name}"
    if n and np.isfinite(s.t_host_s).all():
        return s.t_host_s.copy(), "host receive times"
    if n and (s.kind == "st-221117").all():
        return np.arange(n) * C.AHRS_PERIOD_S, f"ST's main-loop rate ({C.AHRS_RATE_HZ:g} Hz, one line a pass)"
    if n and any(w in name.lower() for name in s.names for w in _ATTITUDE_WORDS):  # exercise 2's print
        return np.arange(n) * C.AHRS_PERIOD_S, (
            f"one record per AHRS step ({C.AHRS_RATE_HZ:g} Hz), assumed: angles printed after each update, "
            "no times in the log"
        )
    return np.arange(n, dtype=np.float64), "the record index (no times in the log: 1 s apart)"


def parse_map(spec: str | list[str] | None) -> dict[str, tuple[str, str]]:
    """``pitch=col2:deg,roll=col3`` (or a list of such items) → {target: (series name, unit)}, else a UserError."""
    items = [spec] if isinstance(spec, str) else list(spec or [])
    out: dict[str, tuple[str, str]] = {}
    for item in (x.strip() for s in items for x in s.split(",")):
        if not item:
            continue
        target, eq, rest = item.partition("=")
        target = target.strip().lower()
        if not eq or not rest.strip():
            raise UserError(f"map item {item!r} does not read as TARGET=SERIES[:UNIT] (e.g. pitch=col2:deg).")
        if target not in MAP_TARGETS:
            raise UserError(f"map target {target!r} is not one of {', '.join(MAP_TARGETS)}.")
        name, _, unit = rest.strip().partition(":")
        out[target] = (name.strip(), _unit(unit))
    return out


def _unit(unit: str) -> str:
    u = unit.strip()
    return _UNIT_ALIASES.get(u.lower(), _UNIT_ALIASES.get(u, u))


def _scale(target: str, unit: str, name: str) -> float:
    """Factor from ``unit`` to the target's unit (rad, mg, mdps); UserError when the unit does not fit."""
    if target == "thr":
        return 1.0
    table, want = _TARGET_UNITS[target.split("_")[0]]
    u = unit if unit in table else unit.lower()
    if u not in table:
        raise UserError(f"{name} → {target}: unit {unit or '(none)'!r} is not one of {want}.")
    return table[u]


_SETPOINT = re.compile(r"(^|_)(rc|target|set|ref|cmd)(_|$)")  #: rc_pitch, target_roll...: not the attitude
#: an acc/gyro axis, its unit written apart or as the name's suffix (``acc_x_mg``, ``gyro_z_dps``)
_AXIS_NAME = re.compile(r"(acc|accel|accelerometer|a|gyro|gyr|g|gyroscope|w|omega)_?([xyz])(?:_(mg|g|mdps|dps))?")


def _auto_map(s: TextSeries) -> dict[str, tuple[str, str]]:
    """Targets found by name (see the module docstring)."""
    out: dict[str, tuple[str, str]] = {}
    if (s.kind == "st-221117").any():
        out.update(pitch=("thx", "deg"), roll=("thy", "deg"), thr=("gTHR", ""))
    for name, unit in zip(s.names, s.units):
        low = name.lower()
        unit_of_name = re.search(r"_(deg|rad)$", low)
        angle_unit = _unit(unit) or (unit_of_name.group(1) if unit_of_name else "deg")
        for target, words in (("pitch", ("pitch", "thx")), ("roll", ("roll", "thy")), ("yaw", ("yaw", "thz"))):
            if target not in out and (low in words or words[0] in low) and not _SETPOINT.search(low):
                out[target] = (name, angle_unit)
        if low in ("thr", "gthr", "throttle") and "thr" not in out:
            out["thr"] = (name, "")
        group = _AXIS_NAME.fullmatch(low)
        if group and (unit or group.group(3)):
            base = "acc" if group.group(1).startswith("a") else "gyro"
            target = f"{base}_{group.group(2)}"
            u = _unit(unit) if unit else group.group(3)
            table = _ACC_UNITS if base == "acc" else _GYRO_UNITS
            if target not in out and (u in table or u.lower() in table):
                out[target] = (name, u)
    return out


def attitude_plan(s: TextSeries, user_map: dict[str, tuple[str, str]] | None = None) -> tuple[list, list[str]]:
    """[(target, column, factor to rad / mg / mdps)] and a note per mapped name; ([], []) without an angle or acc and
    gyro. ``user_map`` (:func:`parse_map`) goes first; UserError for a series not there or a unit that does not fit."""
    mapped = {name for name, _ in (user_map or {}).values()}  # a series the user mapped is not also auto-mapped
    found = {t: v for t, v in _auto_map(s).items() if np.isfinite(s.column(v[0])).any() and v[0] not in mapped}
    defaulted = set()  # user-mapped angles without a unit anywhere: degrees, said as assumed
    for target, (name, unit) in (user_map or {}).items():
        if name not in s.names:
            raise UserError(
                f"map {target}={name}: the log has no series {name!r} (its series: {', '.join(s.names) or 'none'})."
            )
        unit = unit or (s.units[s.names.index(name)] if target != "thr" else "")
        if not unit and target in _ANGLE_COLUMN:
            unit = "deg"
            defaulted.add(target)
        found[target] = (name, unit)
    has_angle = any(t in found for t in ("pitch", "roll"))
    has_inputs = all(f"{b}_{a}" in found for b in ("acc", "gyro") for a in "xyz")
    if not len(s) or not (has_angle or has_inputs):
        return [], []
    plan, notes = [], []
    for target, (name, unit) in found.items():
        plan.append((target, s.names.index(name), _scale(target, unit, name)))
        if target == "thr":
            notes.append(f"{name} → thr (gTHR)")
        elif target in _ANGLE_COLUMN:
            assumed = "" if s.units[s.names.index(name)] or name.lower().endswith(("_deg", "_rad")) else " (assumed)"
            by_user = bool(user_map) and target in user_map
            if by_user:  # the user chose the axis: no advice to map it across
                assumed = " (assumed)" if target in defaulted else ""
            axis = "" if by_user else _axis_note(target, name)
            notes.append(f"{name} → {target}, {_UNIT_WORDS.get(unit, unit)}{assumed}" + axis)
        else:
            notes.append(f"{name} → {target}, {unit}")
    return plan, notes


_ANGLE_COLUMN = {"pitch": "thx_rad", "roll": "thy_rad", "yaw": "thz_rad"}


def apply_plan(plan: list, values: np.ndarray) -> dict[str, np.ndarray]:
    """The attitude columns (``thx_rad``, ``thy_rad``, ``thz_rad``, ``acc_mg``, ``gyro_mdps``, ``thr``) of ``values``
    by ``plan``; NaN / 0 where not mapped."""
    n = len(values)
    cols = {name: np.full(n, np.nan, np.float32) for name in _ANGLE_COLUMN.values()}
    cols |= {name: np.full((n, 3), np.nan, np.float32) for name in ("acc_mg", "gyro_mdps")}
    cols["thr"] = np.zeros(n, np.int16)
    for target, col, k in plan:
        v = values[:, col]
        if target == "thr":
            cols["thr"] = np.clip(np.nan_to_num(v), -32768, 32767).astype(np.int16)
        elif target in _ANGLE_COLUMN:
            cols[_ANGLE_COLUMN[target]] = (v * k).astype(np.float32)
        else:
            base, axis = target.split("_")
            cols[f"{base}_{'mg' if base == 'acc' else 'mdps'}"][:, "xyz".index(axis)] = v * k
    return cols


class RecordAttitude:
    """Records of a live stream as text-mode attitude frames (None: no attitude), mapped as a whole log is, a plan per
    record shape; steps count AHRS periods from the first record. :meth:`take_notes`: each new shape's mapping."""

    def __init__(self, user_map: dict[str, tuple[str, str]] | None = None) -> None:
        self.user_map = user_map
        self._plans: dict[tuple, list] = {}
        self._t0_s: float | None = None
        self._step = -1
        self._notes: list[str] = []

    def take_notes(self) -> list[str]:
        """The notes since the last call (one sentence each)."""
        notes, self._notes = self._notes, []
        return notes

    def frame(self, record, t_s: float) -> AttitudeFrame | None:
        values = np.array([record.values], np.float64)
        plan = self._plans.get(record.names)
        if plan is None:
            one = TextSeries(list(record.names), list(record.units), values, kind=np.array([record.kind], object))
            one.t_s = np.zeros(1)
            try:
                plan, notes = attitude_plan(one, self.user_map)
            except UserError as exc:  # the map names a series these records do not have, or a unit that does not fit
                plan, notes = [], [str(exc)]
            self._plans[record.names] = plan
            self._notes += notes
        if not plan or not math.isfinite(t_s):
            return None
        c = apply_plan(plan, values)
        if self._t0_s is None:
            self._t0_s = t_s
        self._step = max(self._step + 1, round((t_s - self._t0_s) / C.AHRS_PERIOD_S))
        t_us = int(round(max(t_s, 0.0) * 1e6))  # a line estimated to end before the start: 0
        acc, gyro = map(float, c["acc_mg"][0]), map(float, c["gyro_mdps"][0])
        euler = [float(c[k][0]) for k in ("thx_rad", "thy_rad", "thz_rad")]
        return AttitudeFrame.text_row(
            self._step, t_us, acc, gyro, euler, int(c["thr"][0]), record.offset, record.nbytes
        )


_UNIT_WORDS = {"deg": "degrees", "rad": "radians", "mdeg": "millidegrees", "cdeg": "centidegrees"}


def _axis_note(target: str, name: str) -> str:
    """Where the name and the board's axes may disagree (thx is about x = pitch; thy about y = roll; the handouts'
    textbook roll atan(ay/az) is the angle about x, so pitch on this board, and their pitch is roll)."""
    axis = name[:3].lower()
    if axis in ("thx", "thy", "thz") or target == "yaw":  # thx, thx_pitch_rad ...: the firmware's own axis name
        return {"thx": " (about x, nose up +)", "thy": " (about y)"}.get(axis, "")
    other = "pitch" if target == "roll" else "roll"
    return (
        f" (if it is the handouts' {target} formula, it is the angle about {'x' if target == 'roll' else 'y'}: "
        f"{other} on this board; map it as {other}={name})"
    )

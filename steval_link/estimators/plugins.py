"""Estimators from outside the package: your file, your module, an installed plug-in, with constructor options.

One reference names one estimator (``-e`` of every command, ``registry.create``, ``steval_link.run_estimator``)::

    ekf3                                  a built-in (registry name)
    ekf3(acc_motion_mg=20)                a built-in with constructor options
    my_ekf.py:MyEkf                       a class in a Python file (FILE.py alone: the one estimator class in it)
    'my_ekf.py:MyEkf(q_gyro=1e-4, r_acc=0.05)'
    mypkg.filters:MyEkf                   a class in an importable module
    my-ekf                                an installed package's entry point (group ``steval_link.estimators``)

Options are keyword arguments whose values are Python literals (numbers, strings, True/False/None, tuples,
lists, dicts), read with :func:`ast.literal_eval`: nothing in them is executed. A list of references is
comma-separated; commas inside the parentheses belong to the options. Plug-ins run behind :class:`Guarded`.
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import importlib
import importlib.metadata
import importlib.util
import inspect
import math
import os
import re
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from steval_link.errors import UserError
from steval_link.estimators.base import AttitudeEstimate, Estimator, check_inputs
from steval_link.quat import euler_from_quaternion

#: entry-point group under which installed packages register estimator classes (``name = "pkg.module:Class"``)
ENTRY_POINT_GROUP = "steval_link.estimators"

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_DOTTED = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
#: where steval's own code lives (frames there are not the user's)
_PACKAGE_DIR = str(Path(__file__).resolve().parents[1])


class PluginError(UserError):
    """A user's estimator failed (import, construction, a step): one line, exit 2; ``details``: their traceback,
    trimmed to their frames (printed before the line; "" without one)."""

    def __init__(self, message: str, details: str = "") -> None:
        super().__init__(message)
        self.details = details


@dataclass(frozen=True)
class Reference:
    """One parsed estimator reference: ``kind`` ``builtin``, ``file``, ``module`` or ``entry-point``; ``source`` the
    registry name, file path, module or entry point; ``attr`` the class in it (None: the file's only one)."""

    text: str
    kind: str
    source: str
    attr: str | None = None
    options: dict = field(default_factory=dict)

    @property
    def options_text(self) -> str:
        """``q_gyro=0.0001, r_acc=0.05``: the options in display names."""
        return ", ".join(f"{k}={v!r}" for k, v in self.options.items())


class Selected(str):
    """An estimator chosen on the command line: the ``str`` is its display name (table rows, plot labels, viewer
    entities), ``reference`` how to build it, ``factory`` the loaded constructor (keyword options only)."""

    reference: Reference
    factory: Callable[..., Any]
    label: str

    def __new__(cls, name: str, reference: Reference, factory: Callable[..., Any], label: str = "") -> "Selected":
        self = super().__new__(cls, name)
        self.reference = reference
        self.factory = factory
        self.label = label or str(name)
        return self

    def renamed(self, name: str) -> "Selected":
        """The same estimator under another display name."""
        return Selected(name, self.reference, self.factory, self.label)

    def __reduce__(self):  # copies keep the reference
        return (Selected, (str(self), self.reference, self.factory, self.label))


def split_list(spec: str) -> list[str]:
    """Split a comma-separated list of references, keeping commas inside ``(...)``, ``[...]``, ``{...}`` and quotes.

    >>> split_list("ekf3, my.py:A(q=1, r=2),accel")
    ['ekf3', 'my.py:A(q=1, r=2)', 'accel']
    """
    out: list[str] = []
    depth = 0
    quote = ""
    cur: list[str] = []
    for ch in spec:
        if quote:
            if ch == quote:
                quote = ""
        elif ch in "'\"":
            quote = ch
        elif ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth = max(0, depth - 1)
        elif ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    out.append("".join(cur).strip())
    return [s for s in out if s]


def _parse_options(text: str, ref: str) -> dict:
    """``q=1e-4, name='x'`` → dict, literal values only (UserError otherwise)."""
    if not text.strip():
        return {}
    hint = "options are keyword=value with Python literals, e.g. (q_gyro=1e-4, r_acc=0.05)"
    try:
        call = ast.parse(f"_({text})", mode="eval").body
    except SyntaxError:
        call = None
    if not isinstance(call, ast.Call) or call.args or any(kw.arg is None for kw in call.keywords):
        raise UserError(f"cannot read the options of {ref!r}: {hint}")
    options: dict = {}
    for kw in call.keywords:
        try:
            options[kw.arg] = ast.literal_eval(kw.value)
        except (ValueError, SyntaxError, TypeError):
            raise UserError(
                f"option {kw.arg} of {ref!r} is not a literal value ({ast.unparse(kw.value)}): {hint}"
            ) from None
    return options


def parse_reference(text: str) -> Reference:
    """Parse one reference (see the module doc); UserError for one that cannot be read."""
    raw = str(text).strip()
    head, args = raw, ""
    if raw.endswith(")") and "(" in raw:
        i = raw.index("(")
        head, args = raw[:i].strip(), raw[i + 1 : -1]
    if not head:
        raise UserError(f"estimator reference {raw!r} names nothing")
    options = _parse_options(args, raw)
    source, attr = head, None
    if ":" in head:
        left, right = head.rsplit(":", 1)
        if _IDENT.fullmatch(right) and left:
            source, attr = left, right
    if source.endswith(".py") or "/" in source or "\\" in source or (attr is None and os.path.isfile(source)):
        return Reference(raw, "file", source, attr, options)
    if attr is not None:
        if not _DOTTED.fullmatch(source):
            raise UserError(f"estimator reference {raw!r}: {source!r} is neither a .py file nor a module name")
        return Reference(raw, "module", source, attr, options)
    return Reference(raw, "builtin", source, None, options)  # a registry name or an entry point (registry decides)


def entry_point_names() -> dict[str, importlib.metadata.EntryPoint]:
    """Installed plug-ins: entry-point name → entry point (group :data:`ENTRY_POINT_GROUP`)."""
    try:
        eps = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
    except Exception:  # noqa: BLE001 - a broken distribution's metadata must not break the built-ins
        return {}
    return {ep.name: ep for ep in eps}


def _is_user_frame(filename: str, user_files: tuple[str, ...]) -> bool:
    try:
        f = str(Path(filename).resolve())
    except (OSError, ValueError):
        return False
    if user_files:
        return any(f == u or (u.endswith(os.sep) and f.startswith(u)) for u in user_files)
    return not f.startswith(_PACKAGE_DIR) and "site-packages" not in f and not f.startswith(sys.prefix)


def _user_trace(exc: BaseException, user_files: tuple[str, ...]) -> tuple[str, str]:
    """(where, details): the last frame of ``exc``'s traceback in the user's files as ``file.py, line N, in f``
    and their frames formatted like Python's traceback (with the exception line); ("", "") without such frames."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if _is_user_frame(f.filename, user_files)]
    line = "".join(traceback.format_exception_only(type(exc), exc))
    if isinstance(exc, SyntaxError) and exc.filename and _is_user_frame(exc.filename, user_files):
        return f"{Path(exc.filename).name}, line {exc.lineno}", line.rstrip()
    if not frames:
        return "", ""
    where = f"{Path(frames[-1].filename).name}, line {frames[-1].lineno}, in {frames[-1].name}"
    return where, ("Traceback (your code):\n" + "".join(traceback.format_list(frames)) + line).rstrip()


def _exc_text(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {msg[0]}" if msg else type(exc).__name__


def _failed(what: str, exc: BaseException, files: tuple[str, ...] = ()) -> PluginError:
    """``{what}: {exception} ({file, line})``, the user's traceback as ``details``."""
    where, details = _user_trace(exc, files)
    return PluginError(f"{what}: {_exc_text(exc)}" + (f" ({where})" if where else ""), details)


def missing_methods(obj) -> str:
    """``no step() and no reset() method (see docs/ESTIMATORS.md)``: what ``obj`` lacks of an estimator, or ""."""
    missing = [m + "()" for m in ("step", "reset") if not callable(getattr(obj, m, None))]
    return f"no {' and no '.join(missing)} method (see docs/ESTIMATORS.md)" if missing else ""


def _user_files(obj) -> tuple[str, ...]:
    """The file (or package directory, ending in os.sep) that holds ``obj``'s code."""
    f = getattr(sys.modules.get(getattr(obj, "__module__", "") or ""), "__file__", None)
    if not f:
        return ()
    p = Path(f).resolve()
    return (str(p.parent) + os.sep,) if p.name == "__init__.py" else (str(p),)


def _load_file(ref: Reference):
    path = Path(ref.source).expanduser()
    if not path.is_file():
        what = "a directory, not a file" if path.is_dir() else "not found"
        raise UserError(f"estimator file {ref.source} {what}")
    if path.suffix != ".py":
        raise UserError(f"estimator file {ref.source} is not a Python file (.py)")
    resolved = path.resolve()
    name = f"steval_user_{_IDENT_SAFE.sub('_', path.stem)}_{hashlib.sha1(str(resolved).encode()).hexdigest()[:8]}"
    spec = importlib.util.spec_from_file_location(name, resolved)
    if spec is None or spec.loader is None:
        raise UserError(f"cannot load {ref.source} as Python")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look their module up here
    folder = str(resolved.parent)
    sys.path.insert(0, folder)  # helper modules next to the file import as they would when run directly
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # noqa: BLE001 - the user's code: any failure is theirs to see
        sys.modules.pop(name, None)
        if isinstance(exc, SyntaxError):
            raise UserError(f"{path.name}, line {exc.lineno}: syntax error: {exc.msg}") from None
        err = _failed(f"{path.name} failed to load", exc, (str(resolved),))
        if isinstance(exc, ImportError):  # a package it needs is missing: the line says all
            err.details = ""
        raise err from None
    finally:
        with contextlib.suppress(ValueError):
            sys.path.remove(folder)
    return module, path.name


_IDENT_SAFE = re.compile(r"[^0-9A-Za-z_]")


def _load_module(ref: Reference):
    try:
        module = importlib.import_module(ref.source)
    except ModuleNotFoundError as exc:
        missing = exc.name or ""
        if missing and (ref.source == missing or ref.source.startswith(missing + ".")):
            raise UserError(
                f"no module named {ref.source} (not installed, and not on the path; for a file "
                f"write FILE.py:{ref.attr})"
            ) from None
        raise PluginError(f"module {ref.source} failed to load: {_exc_text(exc)}") from None
    except SyntaxError as exc:
        raise UserError(
            f"{Path(exc.filename or ref.source).name}, line {exc.lineno}: syntax error: {exc.msg}"
        ) from None
    except Exception as exc:  # noqa: BLE001
        raise _failed(f"module {ref.source} failed to load", exc) from None
    return module, ref.source


def _estimator_classes(module) -> list[type]:
    return [
        obj
        for obj in vars(module).values()
        if isinstance(obj, type)
        and obj.__module__ == module.__name__
        and callable(getattr(obj, "step", None))
        and not inspect.isabstract(obj)
    ]


def load_factory(ref: Reference) -> tuple[Callable[..., Any], str]:
    """The constructor a file, module or entry-point reference names, and its label (``MyEkf in my_ekf.py``); UserError
    when it is not a class with ``step()`` and ``reset()`` that can be constructed."""
    if ref.kind == "entry-point":
        ep = entry_point_names()[ref.source]
        label = f"plug-in {ref.source} ({ep.value})"
        try:
            factory = ep.load()
        except Exception as exc:  # noqa: BLE001
            raise _failed(f"{label} failed to load", exc) from None
    else:
        module, where = _load_file(ref) if ref.kind == "file" else _load_module(ref)
        found = _estimator_classes(module)
        if ref.attr is None and len(found) != 1:
            names = ", ".join(c.__name__ for c in found) or "none"
            raise UserError(
                f"{where} defines {len(found)} estimator classes ({names}): name one, "
                f"e.g. {ref.source}:{found[0].__name__ if found else 'MyEstimator'}"
            )
        factory = found[0] if ref.attr is None else getattr(module, ref.attr, None)
        if factory is None:
            hint = f" (estimator classes there: {', '.join(c.__name__ for c in found)})" if found else ""
            raise UserError(f"{where} has no class {ref.attr}{hint}")
        label = f"{getattr(factory, '__name__', ref.attr)} in {where}"
    if not callable(factory):
        raise UserError(f"{label} is not a class (it is a {type(factory).__name__})")
    if isinstance(factory, type):
        if lacks := missing_methods(factory):
            raise UserError(f"{label} is not an estimator: it has {lacks}")
        if inspect.isabstract(factory):
            left = ", ".join(sorted(factory.__abstractmethods__))
            raise UserError(f"{label} is not an estimator yet: it leaves {left} abstract")
    return factory, label


def display_name(factory, ref: Reference) -> str:
    """A plug-in's name in tables, plots and the viewer: the ``name`` its class sets, else the class name."""
    mro = getattr(factory, "__mro__", (object,))[:-1]
    mro = mro[: mro.index(Estimator)] if Estimator in mro else mro
    own = next((vars(k)["name"] for k in mro if isinstance(vars(k).get("name"), str)), None)
    return own or getattr(factory, "__name__", None) or ref.source


def construct(factory, label: str, options: dict):
    """``factory(**options)``: ValueError for options it does not take, PluginError when it raises."""
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):  # no signature to check the options against
        params = None
    names = [n for n, p in (params or {}).items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    unknown = [k for k in options if k not in names]
    if params is not None and unknown and not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        takes = f"it takes: {', '.join(names)}" if names else "it takes none"
        raise ValueError(
            f"{label} does not take the option{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} ({takes})"
        )
    try:
        return factory(**options)
    except Exception as exc:  # noqa: BLE001
        err = _failed(f"{label} could not be constructed", exc, _user_files(factory))
        if isinstance(exc, TypeError) and not err.details:
            raise ValueError(f"{label}: {exc}") from None
        raise err from None


class Guarded(Estimator):
    """A user's estimator behind checks: non-finite input rows skipped (invalid), output shapes checked, every
    exception a :class:`PluginError` naming their file and line. ``run()`` uses the estimator's own ``run()`` when it
    has one (an :class:`AttitudeEstimate`, an object with ``q_wxyz``, or (N, 4) quaternions), else ``step()``."""

    def __init__(self, inner, name: str) -> None:
        self.inner = inner
        self.name = str(name)
        self.files = _user_files(type(inner))
        own_run = getattr(type(inner), "run", None)
        self.own_run = callable(own_run) and own_run is not Estimator.run

    def _fail(self, method: str, exc: BaseException) -> PluginError:
        where, details = _user_trace(exc, self.files)
        return PluginError(f"estimator {self.name} failed in {where or self.origin(method)}: {_exc_text(exc)}", details)

    def origin(self, method: str = "step") -> str:
        """``my_ekf.py, line 57 (MyEkf.step)``: where the user's ``method`` (else ``step``) is defined."""
        cls = type(self.inner)
        method = method if hasattr(cls, method) else "step"
        code = getattr(getattr(cls, method, None), "__code__", None)
        if code is None:
            return f"{cls.__name__}.{method}"
        return f"{Path(code.co_filename).name}, line {code.co_firstlineno} ({cls.__name__}.{method})"

    def reset(self) -> None:
        try:
            self.inner.reset()
        except Exception as exc:  # noqa: BLE001
            raise self._fail("reset", exc) from None

    def step(self, acc_mg, gyro_mdps, thr: int = 0) -> np.ndarray:
        acc = np.asarray(acc_mg, dtype=np.float64).reshape(3)
        gyro = np.asarray(gyro_mdps, dtype=np.float64).reshape(3)
        if not (np.isfinite(acc).all() and np.isfinite(gyro).all()):
            return np.full(4, np.nan)
        try:
            q = self.inner.step(acc, gyro, int(thr))
        except Exception as exc:  # noqa: BLE001
            raise self._fail("step", exc) from None
        return self._quaternion(q)

    def _quaternion(self, q) -> np.ndarray:
        try:
            out = np.asarray(q, dtype=np.float64)
        except (TypeError, ValueError):
            out = None
        if out is None or out.shape != (4,):
            shape = "None" if q is None else (f"shape {out.shape}" if out is not None else type(q).__name__)
            raise PluginError(
                f"estimator {self.name}: step() returned {shape}, not the (4,) quaternion w, x, y, z "
                f"({self.origin('step')}; see docs/ESTIMATORS.md)"
            )
        return out

    def run(self, acc_mg, gyro_mdps, thr=None) -> AttitudeEstimate:
        acc, gyro, thr_arr = check_inputs(acc_mg, gyro_mdps, thr, dtype=np.float64)
        rows = np.isfinite(acc).all(axis=1) & np.isfinite(gyro).all(axis=1)
        a, g, t = acc[rows], gyro[rows], thr_arr[rows]
        m = a.shape[0]
        thx = thy = valid_in = None
        if m == 0:  # nothing to feed (no row, or none finite): the estimator is not called
            q = np.empty((0, 4))
        elif self.own_run:
            try:
                res = self.inner.run(a, g, t)
            except Exception as exc:  # noqa: BLE001
                raise self._fail("run", exc) from None
            q, thx, thy, valid_in = self._estimate(res, m)
        else:
            q = np.empty((m, 4), dtype=np.float64)
            inner_step = self.inner.step
            t_l = t.tolist()
            try:  # the first step's output checked in full, the others by the assignment's shape
                q[0] = self._quaternion(inner_step(a[0], g[0], t_l[0]))
                for k in range(1, m):
                    q[k] = inner_step(a[k], g[k], t_l[k])
            except PluginError:
                raise
            except Exception as exc:  # noqa: BLE001
                raise self._fail("step", exc) from None
        q, thx, thy, valid_in = (_scatter(v, rows) for v in (q, thx, thy, valid_in))  # skipped rows: NaN, invalid
        ex, ey, ez = euler_from_quaternion(q)
        thx = ex if thx is None else thx
        thy = ey if thy is None else thy
        valid = np.isfinite(q).all(axis=1) & np.isfinite(thx) & np.isfinite(thy)
        if valid_in is not None:
            valid &= valid_in
        return AttitudeEstimate(q_wxyz=q, thx_rad=thx, thy_rad=thy, thz_rad=ez, valid=valid)

    def _estimate(self, res, m: int):
        """(q, thx or None, thy or None, valid or None) of a user's run() result, shapes checked."""
        where = self.origin("run")
        optional = ("thx_rad", "thy_rad", "valid")
        if isinstance(res, (np.ndarray, list, tuple)):
            q, arrays = np.asarray(res, dtype=np.float64), (None, None, None)
        elif hasattr(res, "q_wxyz"):
            q, arrays = np.asarray(res.q_wxyz, dtype=np.float64), [getattr(res, k, None) for k in optional]
        else:
            raise PluginError(
                f"estimator {self.name}: run() returned {type(res).__name__}, not an AttitudeEstimate "
                f"or (N, 4) quaternions ({where}; see docs/ESTIMATORS.md)"
            )
        if q.shape != (m, 4):
            raise PluginError(
                f"estimator {self.name}: run() gave quaternions of shape {q.shape} for {m} rows, "
                f"expected ({m}, 4) ({where})"
            )
        out = []
        for k, a in zip(optional, arrays):
            arr = None if a is None else np.asarray(a, dtype=bool if k == "valid" else np.float64)
            if arr is not None and arr.shape != (m,):
                raise PluginError(f"estimator {self.name}: run() gave {k} of shape {arr.shape} for {m} rows ({where})")
            out.append(arr)
        return (q, *out)

    def __repr__(self) -> str:
        return f"<Guarded {self.name!r} {type(self.inner).__name__}>"


def _scatter(values: np.ndarray | None, rows: np.ndarray) -> np.ndarray | None:
    """``values`` of the ``rows`` (bool, n) spread over n rows; the others NaN (False for a bool array)."""
    if values is None:
        return None
    out = np.full((rows.size, *values.shape[1:]), False if values.dtype == bool else math.nan, dtype=values.dtype)
    out[rows] = values
    return out

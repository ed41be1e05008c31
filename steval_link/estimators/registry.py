"""Estimators by name: ``create("st-mahony", ki=1.0)``, ``names()``, and your own by reference
(:mod:`~steval_link.estimators.plugins`): :func:`parse_names` resolves it once into a ``Selected`` that :func:`create`
builds. A built-in's module is imported only when needed: a missing optional package breaks only that one.
"""

from __future__ import annotations

import functools
import importlib
import inspect
from collections.abc import Callable, Mapping
from types import MappingProxyType

from steval_link.errors import UserError
from steval_link.estimators import plugins
from steval_link.estimators.base import Estimator
from steval_link.estimators.plugins import PluginError as PluginError  # re-exported
from steval_link.estimators.plugins import Selected

#: registry name → ``module:Class`` of each built-in, read-only
ESTIMATORS: Mapping[str, str] = MappingProxyType(
    {
        "st-mahony": "steval_link.estimators.st_mahony:StMahony",
        "accel": "steval_link.estimators.accel_tilt:AccelTilt",
        "ekf3": "steval_link.estimators.ekf3:Ekf3",
        "mekf": "steval_link.estimators.mekf:Mekf",
        "vqf": "steval_link.estimators.vqf_adapter:VqfEstimator",
    }
)


def _class(name: str) -> Callable[..., Estimator]:
    """The class of built-in ``name``, its module imported now (ImportError: an optional package is missing)."""
    module, attr = ESTIMATORS[name].split(":")
    return getattr(importlib.import_module(module), attr)


#: what steval live, replay (with a viewer or a recording) and compare run next to the firmware by default
#: (uninstalled ones skipped)
LIVE_DEFAULT: tuple[str, ...] = ("st-mahony", "accel", "ekf3")
REPLAY_DEFAULT: tuple[str, ...] = ("st-mahony", "accel", "ekf3", "mekf")
COMPARE_DEFAULT: tuple[str, ...] = ("ekf3", "mekf", "accel")


def names() -> tuple[str, ...]:
    """Every registered estimator name, in registration order."""
    return tuple(ESTIMATORS)


def is_available(name: str) -> bool:
    """True when ``name`` is registered and its module and optional packages import (a :class:`Selected`: always)."""
    if isinstance(name, Selected):
        return True
    try:
        return name in ESTIMATORS and bool(_class(name))
    except ImportError:
        return False


def is_known(name: str) -> bool:
    """True for a registry name, a :class:`Selected`, or text that reads as a reference (:func:`resolve` loads it)."""
    if isinstance(name, Selected) or name in ESTIMATORS:
        return True
    try:
        ref = plugins.parse_reference(name)
    except UserError:  # meant as a reference (its options cannot be read): resolve() says why
        return any(c in str(name) for c in ":(/\\") or str(name).endswith(".py")
    return ref.kind != "builtin" or ref.source in ESTIMATORS or ref.source in plugins.entry_point_names()


def resolve(text: str) -> Selected:
    """Load and check what ``text`` names, constructing nothing: a :class:`Selected` whose ``str`` is the display
    name. UserError (one line) for every way it can fail; PluginError when the user's module raises."""
    if isinstance(text, Selected):
        return text
    ref = plugins.parse_reference(text)
    if ref.kind == "builtin":
        if ref.source in ESTIMATORS:
            name = ref.source + (f"({ref.options_text})" if ref.options else "")
            return Selected(name, ref, functools.partial(create, ref.source), name)
        if ref.source not in plugins.entry_point_names():
            raise UserError(
                f"unknown estimator {ref.source!r}; choose from: {', '.join(ESTIMATORS)}, an installed "
                "plug-in, FILE.py:CLASS or module:CLASS (or none)"
            )
        ref = plugins.Reference(ref.text, "entry-point", ref.source, None, ref.options)
    factory, label = plugins.load_factory(ref)
    name = plugins.display_name(factory, ref)
    if name.replace("_", "-") in ESTIMATORS:  # never taken for a built-in (st-mahony means the firmware's replica live)
        name = f"{name} ({getattr(factory, '__name__', ref.source)})"
    if ref.options:  # one label per variant: its options are part of it
        name = f"{name}({ref.options_text})"
    return Selected(name, ref, factory, label)


def accepts(name: str, option: str) -> bool:
    """True when the estimator ``name`` names takes the keyword ``option`` (e.g. ``rate_hz``)."""
    sel = name if isinstance(name, Selected) else resolve(name)
    try:
        ctor = _class(sel.reference.source) if sel.reference.kind == "builtin" else sel.factory
        params = inspect.signature(ctor).parameters
    except (ImportError, TypeError, ValueError):
        return False
    return option in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def create(name: str, **options) -> Estimator:
    """Build the estimator ``name`` names (a registry name, a :class:`Selected` or a reference) with keyword
    ``options`` on top of the reference's own; a user's estimator comes behind
    :class:`~steval_link.estimators.plugins.Guarded`.

    Raises:
        ValueError: unknown name (the message lists the known ones), or options the estimator does not take.
        ImportError: the estimator's optional dependency is not installed.
        UserError: a reference that cannot be loaded (PluginError when the user's code raised).
    """
    if not isinstance(name, Selected) and name not in ESTIMATORS:
        if not is_known(name):
            raise ValueError(f"unknown estimator {name!r}; choose one of: {', '.join(ESTIMATORS)}")
        name = resolve(name)
    if isinstance(name, Selected):
        opts = {**name.reference.options, **options}
        if name.reference.kind == "builtin":
            return create(name.reference.source, **opts)
        inst = plugins.construct(name.factory, name.label, opts)
        if lacks := plugins.missing_methods(inst):
            raise UserError(f"{name.label} made a {type(inst).__name__}, which has {lacks}")
        return plugins.Guarded(inst, str(name))
    try:
        return _class(name)(**options)
    except TypeError as exc:
        if "unexpected keyword" in str(exc) or "positional argument" in str(exc):
            raise ValueError(f"estimator {name!r} does not take these options: {exc}") from None
        raise


def parse_names(spec: str | None, default: tuple[str, ...], *, require_installed: bool = True) -> list[str]:
    """A comma-separated list of registry names, references or ``none`` (None: the installed ones of ``default``):
    names as they are, references as :class:`Selected`, each constructed once now (every mistake one line before any
    work). UserError for a display name given twice, an unknown name, or (``require_installed``) a missing package."""
    if spec is None:
        return [n for n in default if is_available(n) or not require_installed]
    chosen = plugins.split_list(spec)
    if chosen in (["none"], []):
        return []
    out: list[str] = []
    for n in chosen:
        sel = None if n in ESTIMATORS else resolve(n)
        builtin = n if sel is None else (sel.reference.source if sel.reference.kind == "builtin" else None)
        if builtin is not None and require_installed and not is_available(builtin):
            raise UserError(f"estimator {builtin!r} needs an optional package: pip install 'steval-link[{builtin}]'")
        try:
            if sel is not None:
                create(sel)  # the options and the constructor checked now, before any work
        except ValueError as exc:
            raise UserError(str(exc)) from None
        except ImportError as exc:
            if require_installed:
                raise UserError(f"estimator {sel.label} needs a package that is not installed ({exc})") from None
        out.append(n if sel is None else sel)
    seen: set[str] = set()
    for n in out:  # two variants under one display name would share one column
        seen.add(unique_name(n, seen))
    return out


def unique_name(name: str, taken: set[str]) -> str:
    """``name`` as a display name (a reference's options are part of it); UserError when it is in ``taken``."""
    if str(name) in taken:
        raise UserError(f"estimator {name} is chosen twice: give each variant its own options (labels must differ)")
    return str(name)

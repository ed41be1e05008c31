"""Estimators by name: ``create("st-mahony", ki=1.0)``, ``names()``.

:data:`ESTIMATORS` is an immutable mapping of registry name → constructor. Constructors import their module only
when called, so an estimator whose optional dependency is missing (e.g. ``vqf``) does not break the others.
To add an estimator, add one line to ``_ENTRIES``: ``"name": _lazy("steval_link.estimators.module", "ClassName"),``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from types import MappingProxyType

from steval_link.errors import UserError
from steval_link.estimators.base import Estimator

__all__ = ["ESTIMATORS", "LIVE_DEFAULT", "REPLAY_DEFAULT", "COMPARE_DEFAULT", "names", "create", "is_available",
           "available_names", "parse_names"]


class _lazy:
    """A constructor that imports ``module.attr`` on first call (keeps optional dependencies optional)."""

    __slots__ = ("module", "attr")

    def __init__(self, module: str, attr: str) -> None:
        self.module = module
        self.attr = attr

    def load(self) -> Callable[..., Estimator]:
        return getattr(importlib.import_module(self.module), self.attr)

    def __call__(self, **options) -> Estimator:
        return self.load()(**options)

    def __repr__(self) -> str:
        return f"{self.module}:{self.attr}"


_ENTRIES: dict[str, Callable[..., Estimator]] = {
    "st-mahony": _lazy("steval_link.estimators.st_mahony", "StMahony"),
    "accel": _lazy("steval_link.estimators.accel_tilt", "AccelTilt"),
    "ekf3": _lazy("steval_link.estimators.ekf3", "Ekf3"),
    "mekf": _lazy("steval_link.estimators.mekf", "Mekf"),
    "vqf": _lazy("steval_link.estimators.vqf_adapter", "VqfEstimator"),
}

#: registry name → constructor (keyword options only), read-only
ESTIMATORS: Mapping[str, Callable[..., Estimator]] = MappingProxyType(_ENTRIES)

#: what each command runs next to the firmware when ``--estimators`` is not given (uninstalled ones skipped):
#: ``steval live`` (every frame as it comes), ``steval replay`` with a viewer or ``--rrd``, ``steval compare``
LIVE_DEFAULT: tuple[str, ...] = ("st-mahony", "accel", "ekf3")
REPLAY_DEFAULT: tuple[str, ...] = ("st-mahony", "accel", "ekf3", "mekf")
COMPARE_DEFAULT: tuple[str, ...] = ("ekf3", "mekf", "accel")


def names() -> tuple[str, ...]:
    """Every registered estimator name, in registration order."""
    return tuple(ESTIMATORS)


def is_available(name: str) -> bool:
    """True when ``name`` is registered and its module (and optional dependencies) can be imported."""
    ctor = ESTIMATORS.get(name)
    if ctor is None:
        return False
    if isinstance(ctor, _lazy):
        try:
            ctor.load()
        except ImportError:
            return False
    return True


def available_names() -> tuple[str, ...]:
    """Registered names whose estimator can be built on this machine."""
    return tuple(n for n in ESTIMATORS if is_available(n))


def create(name: str, **options) -> Estimator:
    """Build the estimator registered as ``name`` with keyword ``options``.

    Raises:
        ValueError: unknown name (the message lists the known ones), or options the estimator does not take.
        ImportError: the estimator's optional dependency is not installed.
    """
    ctor = ESTIMATORS.get(name)
    if ctor is None:
        raise ValueError(f"unknown estimator {name!r}; choose one of: {', '.join(ESTIMATORS)}")
    try:
        return ctor(**options)
    except TypeError as exc:
        if "unexpected keyword" in str(exc) or "positional argument" in str(exc):
            raise ValueError(f"estimator {name!r} does not take these options: {exc}") from None
        raise


def parse_names(spec: str | None, default: tuple[str, ...], *, require_installed: bool = True) -> list[str]:
    """``--estimators``: a comma-separated list of registry names or ``none``; None gives those of ``default`` that
    are installed. UserError for an unknown name (the valid ones listed) or, with ``require_installed``, one whose
    package is missing (``steval compare`` reports those in its table instead)."""
    if spec is None:
        return [n for n in default if is_available(n) or not require_installed]
    chosen = [s.strip() for s in spec.split(",") if s.strip()]
    if chosen in (["none"], []):
        return []
    for n in chosen:
        if n not in ESTIMATORS:
            raise UserError(f"unknown estimator {n!r}; choose from: {', '.join(ESTIMATORS)} (or none)")
        if require_installed and not is_available(n):
            raise UserError(f"estimator {n!r} needs an optional package: pip install 'steval-link[{n}]'")
    return chosen

"""steval-link: telemetry, capture, replay and attitude estimation for the ST STEVAL-FCU001V1 drone.

For notebooks and scripts (:mod:`steval_link.api`, loaded on first use so that ``import steval_link`` stays cheap)::

    import steval_link as sl
    cap = sl.open_capture("recordings/demo.stv")        # arrays with units in their names; cap.to_pandas()
    est = sl.run_estimator("ekf3", cap)                  # or "my_ekf.py:MyEkf", or MyEkf()
    scores = sl.evaluate("../shared/datasets/broad", ["st-mahony-flight", "vqf", "my_ekf.py:MyEkf"])
"""

#: the names :mod:`steval_link.api` lends the package
_API = ("open_capture", "run_estimator", "evaluate", "Capture", "Scores")
__all__ = ["__version__", *_API]


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version  # costs ~100 ms: only when asked

    try:
        return version("steval-link")
    except PackageNotFoundError:  # running from a source tree that was not installed
        return "0.0.0+source"


def __getattr__(name: str):
    if name == "__version__":
        return _version()
    if name in _API:
        from steval_link import api  # lazy facade: numpy and the layers above load on the first use, not on import

        return getattr(api, name)
    raise AttributeError(f"module 'steval_link' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])

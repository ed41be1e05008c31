"""steval-link: telemetry, capture, replay and attitude estimation for the ST STEVAL-FCU001V1 drone."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("steval-link")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+source"

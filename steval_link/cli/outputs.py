"""Every output file of every command, one rule: checked before any work (:func:`check_output`), written whole or
not at all (:func:`atomic_output`: ``NAME.partial``, renamed into place when complete, removed on failure)."""

from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from steval_link.cli.app import option
from steval_link.errors import UserError

if TYPE_CHECKING:
    from steval_link.live.session import LiveOptions
    from steval_viewer.sink_options import SinkOptions

#: option names whose value is a file a command writes
OUTPUT_OPTIONS = frozenset({"--rrd", "--out", "--csv", "--parquet", "--plot", "--raw", "--mat", "--mcap", "--markdown"})
#: suffix of a file being written (renamed into place when complete)
PARTIAL = ".partial"

ForceOption = option(bool, "--force", "-f", help="Overwrite existing output files.")
JsonReportOption = option(bool, "--json", help="Print the report as one JSON object (nothing else on stdout).")


def print_json(d: dict) -> None:
    """A report as one indented JSON object on stdout (NaN refused: it is not JSON)."""
    json.dump(d, sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")


def print_warnings(warnings) -> None:
    """Each warning met on the way (e.g. a damaged capture), one ``steval: warning:`` line on stderr."""
    for w in warnings:
        print(f"steval: warning: {w}", file=sys.stderr)


def partial_path(path: Path, *, keep_suffix: bool = False) -> Path:
    """Where ``path`` is written until complete: ``NAME.partial``, or ``STEM.partial.EXT`` with ``keep_suffix``
    (for writers that pick the format from the extension, e.g. matplotlib)."""
    path = Path(path)
    if keep_suffix and path.suffix:
        return path.with_name(f"{path.stem}{PARTIAL}{path.suffix}")
    return path.with_name(path.name + PARTIAL)


def _why(exc: BaseException) -> str:
    if isinstance(exc, OSError):  # e.g. "read-only file system"
        return exc.strerror.rstrip(".").lower() if exc.strerror else str(exc)
    text = str(exc).strip()
    return (text.splitlines()[0] if text else type(exc).__name__).rstrip(".")


def _probe(folder: Path) -> OSError | None:
    """Create and remove a file in ``folder``: None when that works, else the error (root ignores permission bits,
    so ``os.access`` cannot tell a read-only mount or ``/proc``)."""
    try:
        fd, name = tempfile.mkstemp(prefix=".steval-probe-", dir=folder)
    except OSError as exc:
        return exc
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(name)
    return None


def check_output(
    path: str | os.PathLike,
    *,
    option: str,
    force: bool = False,
    overwrite: str = "force",
    inputs: tuple[str | os.PathLike | None, ...] = (),
) -> Path:
    """One output file, checked before any work (UserError naming ``option``); returns it as a Path. ``overwrite``:
    ``"force"`` (an existing file replaced only with ``force``), ``"never"`` (captures) or ``"always"``."""
    p = Path(path).expanduser()
    label = f"{option} {p}".lstrip()  # option "": a path argument, named by itself
    if p.is_dir():
        raise UserError(f"{label}: cannot write it, it is a folder (give a file name)")
    for given in inputs:
        if given is not None and _same(p, Path(given)):
            raise UserError(f"{label} is the input itself; choose another output file (inputs are never modified)")
    parent = p.parent
    if not parent.is_dir():
        what = "is not a folder" if parent.exists() else "does not exist"
        raise UserError(f"{label}: cannot write it, folder {parent} {what} (create it first)")
    if p.exists() and not p.is_file():  # a device or a pipe (/dev/null): never replaced by a file
        raise UserError(f"{label}: cannot write it, it is not a regular file (a device or a pipe)")
    if p.exists() or p.is_symlink():
        if overwrite == "never":
            raise UserError(f"{label} already exists; choose another name (this command never overwrites a file)")
        if overwrite == "force" and not force:
            raise UserError(f"{label} already exists (use --force to overwrite)")
    failed = _probe(parent)
    if failed is not None:
        raise UserError(f"{label}: cannot write it, folder {parent} takes no new file ({_why(failed)})")
    return p


def check_outputs(outputs: dict, *, force: bool = False, inputs: tuple = ()) -> None:
    """:func:`check_output` of each given ``{option: path}``; with a ``--plot``, matplotlib must be there too."""
    for flag, path in outputs.items():
        if path is not None:
            check_output(path, option=flag, force=force, inputs=inputs)
    if outputs.get("--plot") is not None:
        from steval_link.analysis.plots import require_matplotlib  # matplotlib loads only for --plot (start-up time)

        require_matplotlib()


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except OSError:
        return False


def check_input(path: str | os.PathLike, *, what: str = "file") -> Path:
    """An input file that exists and is a regular file (a device such as ``/dev/zero`` or a pipe may never end)."""
    p = Path(path).expanduser()
    if not p.exists():
        raise UserError(f"{p}: no such file ({what})")
    if p.is_dir():
        raise UserError(f"{p} is a folder, not a {what}")
    if not p.is_file():
        raise UserError(f"{p} is not a regular file (a device or a pipe), not a {what}")
    return p


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, *, option: str, keep_suffix: bool = False) -> Iterator[Path]:
    """Yield the partial path to write ``path`` to: renamed into place on a normal exit, removed on any exception."""
    final = Path(path)
    partial = partial_path(final, keep_suffix=keep_suffix)
    try:
        yield partial
        if partial.exists():  # else the writer wrote nothing there (e.g. a plot it had nothing for)
            os.replace(partial, final)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            partial.unlink()
        if isinstance(exc, (OSError, RuntimeError)):  # a writer that failed (disk full, folder removed, ...)
            raise UserError(
                f"{option} {final}: cannot write it ({_why(exc)}); nothing was written there".lstrip()
            ) from None
        raise


def write_atomic(path: Path, option: str, write, *, text: bool = False) -> None:
    """``write(file)`` into ``PATH.partial`` (binary, or UTF-8 ``text``), renamed to ``path`` when complete."""
    with atomic_output(path, option=option) as part:
        with open(part, "w", newline="", encoding="utf-8") if text else open(part, "wb") as f:
            write(f)


def check_duration(duration: float | None) -> None:
    if duration is not None and not duration > 0:
        raise UserError(f"--duration must be positive, got {duration}")


def session_outputs(options: LiveOptions, out: Path | None, sinks: SinkOptions | None = None, *, view: bool = False):
    """The checks of a session's outputs, run once its input is open: the capture and the ``.rrd`` (neither ever
    overwritten), then the Rerun sinks (``view``: not ``--no-view``)."""

    from steval_link.link.capture import resolve_capture_out  # reason: a live command's only
    from steval_viewer.sink_options import session_sinks  # reason: the same

    def check() -> None:
        options.out = resolve_capture_out(out)
        if options.out is not None:
            check_output(options.out, option="--out", overwrite="never")
        if sinks is not None and sinks.rrd is not None:
            check_output(sinks.rrd, option="--rrd", overwrite="never")
        options.sinks = session_sinks(sinks, view=view) if sinks is not None else None

    return check

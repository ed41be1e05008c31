"""``steval`` command line: one module per sub-command, all registered on :data:`steval_link.cli.app.app`."""

from __future__ import annotations

import sys

import typer

from steval_link.cli.app import app
from steval_link.errors import UserError

# Each import registers its sub-command(s) on ``app`` (one per line; add yours below).
from steval_link.cli import replay as _replay  # noqa: F401,E402
from steval_link.cli import live as _live  # noqa: F401,E402
from steval_link.cli import export as _export  # noqa: F401,E402
from steval_link.cli import ports as _ports  # noqa: F401,E402
from steval_link.cli import simulate as _simulate  # noqa: F401,E402
from steval_link.cli import synth as _synth  # noqa: F401,E402
from steval_link.cli import conformance as _conformance  # noqa: F401,E402
from steval_link.cli import compare as _compare  # noqa: F401,E402
from steval_link.cli import evaluate as _evaluate  # noqa: F401,E402
from steval_link.cli import emulate as _emulate  # noqa: F401,E402

__all__ = ["app", "main"]


def _exception_classes() -> tuple[tuple[type, ...], tuple[type, ...], tuple[type, ...]]:
    """(usage errors, exits, aborts) of typer and of the click it runs on (its own vendored copy in typer ≥ 0.25)."""
    usage: list[type] = []
    exits: list[type] = [typer.Exit]
    aborts: list[type] = [typer.Abort]
    try:
        import click

        usage.append(click.ClickException)
        exits.append(click.exceptions.Exit)
        aborts.append(click.exceptions.Abort)
    except ImportError:
        pass
    try:
        from typer._click import exceptions as vendored  # typer's vendored click

        usage.append(vendored.ClickException)
    except ImportError:
        pass
    return tuple(usage), tuple(exits), tuple(aborts)


_USAGE_ERRORS, _EXITS, _ABORTS = _exception_classes()


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``steval`` console script.

    User errors (:class:`UserError`) become one line on stderr and exit code 2; usage errors print the usage and
    exit 2; ``--help`` exits 0; Ctrl-C exits 130. Never a traceback for bad input.
    """
    try:
        rv = app(args=argv, prog_name="steval", standalone_mode=False)
    except UserError as exc:
        print(f"steval: error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except _USAGE_ERRORS as exc:  # usage errors, bad option values: usage line + message, exit 2
        exc.show()
        sys.exit(getattr(exc, "exit_code", 2))
    except _EXITS as exc:
        sys.exit(getattr(exc, "exit_code", getattr(exc, "code", 0)))
    except (*_ABORTS, KeyboardInterrupt):
        print("steval: interrupted", file=sys.stderr)
        sys.exit(130)
    except BrokenPipeError:  # e.g. `steval replay --json | head`
        sys.stderr.close()
        sys.exit(1)
    sys.exit(rv if isinstance(rv, int) else 0)

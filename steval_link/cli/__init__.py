"""``steval`` command line: one module per sub-command, all registered on :data:`steval_link.cli.app.app`."""

from __future__ import annotations

import contextlib
import importlib
import inspect
import os
import re
import shutil
import sys

# One BLAS thread: the arrays here are small, and more threads only spin on the core the emulated board runs on.
# (Read when numpy loads, so before the imports below.)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import typer  # noqa: E402

from steval_link.cli.app import HELP_OPTION_NAMES  # noqa: E402
from steval_link.cli.app import app as _app  # noqa: E402
from steval_link.errors import UserError, printable  # noqa: E402
from steval_link.stop_signals import interrupt, on_stop_signals  # noqa: E402

__all__ = ["main", "register"]

_MODULES = (
    "ble",
    "command",
    "compare",
    "conformance",
    "data",
    "emulate",
    "estimator",
    "evaluate",
    "export",
    "live",
    "ports",
    "preflight",
    "replay",
    "report",
    "simulate",
    "spectrum",
    "synth",
)
#: the sub-command modules by the command words they register (importing a module registers its commands): each
#: module its own word; "param" comes from the command module, "record" from the live module
COMMANDS = {word: word for word in _MODULES} | {"param": "command", "record": "live"}


def register(args: list[str] | None = None) -> typer.Typer:
    """The typer app with the sub-command that ``args`` start with registered (only its module imported), or all."""
    word = args[0] if args else None
    for module in [COMMANDS[word]] if word in COMMANDS else dict.fromkeys(COMMANDS.values()):
        importlib.import_module(f"steval_link.cli.{module}")
    return _app


def _exception_classes() -> tuple[tuple[type, ...], tuple[type, ...], tuple[type, ...]]:
    """(usage errors, exits, aborts) of typer and of the click it runs on (its own vendored copy in typer ≥ 0.25)."""
    usage, exits, aborts = [], [typer.Exit], [typer.Abort]
    with contextlib.suppress(ImportError):
        import click

        usage.append(click.ClickException)
        exits.append(click.exceptions.Exit)
        aborts.append(click.exceptions.Abort)
    with contextlib.suppress(ImportError):
        from typer._click import exceptions as vendored  # typer's vendored click

        usage.append(vendored.ClickException)
    return tuple(usage), tuple(exits), tuple(aborts)


_USAGE_ERRORS, _EXITS, _ABORTS = _exception_classes()
#: exit code of a command ended by Ctrl-C (128 + SIGINT), as shells report it
_INTERRUPTED = 130


#: below this many columns ``--help`` is click's plain layout: typer's option tables leave the help ~17 columns
HELP_TABLE_MIN_COLUMNS = 100


def _tidy_help(command, plain: bool) -> None:
    """``--help`` of every sub-command: flags show no ``<bool>``; a paragraph is one line the terminal wraps.
    ``plain``: a command's options in click's layout, without rich's markup escapes (groups keep typer's panels)."""
    subs = getattr(command, "commands", {})
    plain_here = plain and not subs
    help_option = command.get_help_option(command.context_class(command, help_option_names=HELP_OPTION_NAMES))
    for param in [*getattr(command, "params", ()), help_option]:
        if getattr(param, "is_flag", False) and param.metavar is None:
            param.metavar = ""
        if plain_here and getattr(param, "help", None):
            param.help = param.help.replace("\\[", "[")
    if command.help:
        command.help = re.sub(r"(?<=\S)\n(?!\n|\s*(?:[-*•]|\d+\.) )", " ", inspect.cleandoc(command.help))
        command.help = command.help.replace("\\[", "[") if plain_here else command.help
    if plain_here:
        command.rich_markup_mode = None
    for sub in subs.values():
        _tidy_help(sub, plain)


def _usage_line(exc, command, args: list[str]) -> str:
    """One ``steval: error:`` line for a typer/click usage error, with where to find help: the sub-command's
    (from the error, else from the words of ``args`` that name sub-commands of ``command``)."""
    message = exc.format_message().strip()
    message = message[:1].lower() + message[1:].rstrip(".")
    ctx = getattr(exc, "ctx", None)
    path = [ctx.command_path] if ctx is not None else ["steval"]
    for word in args if ctx is None else ():
        command = getattr(command, "commands", {}).get(word)
        if command is None:
            break
        path.append(word)
    return f"steval: error: {printable(message)} (see '{' '.join(path)} --help')"


def main(argv: list[str] | None = None) -> None:
    """The ``steval`` console script: user and usage errors are one ``steval: error:`` line (exit 2), never a
    traceback; Ctrl-C, SIGTERM and SIGHUP exit 130 after the cleanup."""
    args = sys.argv[1:] if argv is None else list(argv)
    command = typer.main.get_command(register(args))
    _tidy_help(command, plain=shutil.get_terminal_size().columns < HELP_TABLE_MIN_COLUMNS)
    try:
        with on_stop_signals(interrupt, sigint=False):
            rv = command.main(args=argv, prog_name="steval", standalone_mode=False)
    except UserError as exc:
        if details := getattr(exc, "details", ""):  # a user's estimator failed: their traceback, trimmed to their code
            print(details, file=sys.stderr)
        from steval_link.cli.checks import user_message  # reason: imports the estimators (only on an error)

        print(f"steval: error: {printable(user_message(exc))}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except _USAGE_ERRORS as exc:
        if type(exc).__name__ == "NoArgsIsHelpError":  # `steval` alone: the help, exit 2
            exc.show()
        elif hasattr(exc, "ctx"):  # usage errors, bad option values: one line, exit 2
            print(_usage_line(exc, command, args), file=sys.stderr)
        else:  # other click exceptions (e.g. a file error)
            print(f"steval: error: {printable(exc.format_message())}", file=sys.stderr)
        sys.exit(getattr(exc, "exit_code", 2))
    except _EXITS as exc:
        sys.exit(getattr(exc, "exit_code", getattr(exc, "code", 0)))
    except (*_ABORTS, KeyboardInterrupt):
        rv = _INTERRUPTED
    except BrokenPipeError:  # e.g. `steval replay --json | head`
        sys.stderr.close()
        sys.exit(1)
    if rv == _INTERRUPTED:  # Ctrl-C, or typer's exit code for it (which it gives without a word)
        print("steval: interrupted", file=sys.stderr)
    sys.exit(rv if isinstance(rv, int) else 0)

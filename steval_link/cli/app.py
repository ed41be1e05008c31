"""The typer application object that every ``steval`` sub-command registers on, with the top-level options
(``--version``; ``-h`` as well as ``--help`` everywhere)."""

from typing import Annotated, Any, Optional

import typer

from steval_link import __version__

#: ``-h`` as well as ``--help``, on every command
HELP_OPTION_NAMES = ["-h", "--help"]


def option(kind: Any, *flags: str, **kw: Any) -> Any:
    """A typer option declared once, as a parameter's type: ``Annotated[kind, typer.Option(*flags, **kw)]``."""
    return Annotated[kind, typer.Option(*flags, **kw)]


def argument(kind: Any, **kw: Any) -> Any:
    """A typer argument declared once, as a parameter's type: ``Annotated[kind, typer.Argument(**kw)]``."""
    return Annotated[kind, typer.Argument(**kw)]


app = typer.Typer(
    name="steval",
    help="steval-link: live telemetry, capture, replay and attitude estimation for the ST STEVAL-FCU001V1 drone.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": HELP_OPTION_NAMES},
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"steval-link {__version__}")
        raise typer.Exit(0)


@app.callback()
def _top_level(
    version: Optional[bool] = typer.Option(
        None, "--version", is_eager=True, callback=_print_version, help="Print the version and exit."
    ),
) -> None:
    """steval-link: live telemetry, capture, replay and attitude estimation for the ST STEVAL-FCU001V1 drone."""

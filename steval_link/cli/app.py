"""The typer ``app`` every ``steval`` sub-command registers on (``--version``; ``-h`` as well as ``--help``)."""

import functools
import inspect
from typing import Annotated, Any

import typer

from steval_link import __version__

HELP_OPTION_NAMES = ["-h", "--help"]


def option(kind: Any, *flags: str, **kw: Any) -> Any:
    """A typer option declared once, as a parameter's type: ``Annotated[kind, typer.Option(*flags, **kw)]``."""
    return Annotated[kind, typer.Option(*flags, **kw)]


def argument(kind: Any, **kw: Any) -> Any:
    """A typer argument declared once, as a parameter's type: ``Annotated[kind, typer.Argument(**kw)]``."""
    return Annotated[kind, typer.Argument(**kw)]


def with_options(keyword: str, params: tuple, build) -> Any:
    """The command takes ``params`` ((name, annotation, default), ...) in place of ``keyword``, as ``build(...)``."""

    def decorate(command):
        own = list(inspect.signature(command, eval_str=True).parameters.values())
        at = [p.name for p in own].index(keyword)
        kind = inspect.Parameter.POSITIONAL_OR_KEYWORD
        added = [inspect.Parameter(name, kind, annotation=a, default=d) for name, a, d in params]

        @functools.wraps(command)
        def run(**kwargs):
            bundle = build(**{name: kwargs.pop(name) for name, _, _ in params})
            return command(**kwargs, **{keyword: bundle})

        signature = [*own[:at], *added, *own[at + 1 :]]
        run.__signature__ = inspect.Signature(signature)
        run.__annotations__ = {p.name: p.annotation for p in signature}
        return run

    return decorate


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
    version: bool | None = typer.Option(
        None, "--version", is_eager=True, callback=_print_version, help="Print the version and exit."
    ),
) -> None:
    """steval-link: live telemetry, capture, replay and attitude estimation for the ST STEVAL-FCU001V1 drone."""


def sub_app(name: str, help: str) -> typer.Typer:
    """A command group ``steval NAME ...`` (e.g. ``steval param get``), registered on :data:`app`."""
    group = typer.Typer(help=help, no_args_is_help=True)
    app.add_typer(group, name=name)
    return group

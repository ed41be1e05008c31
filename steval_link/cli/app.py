"""The typer application object that every ``steval`` sub-command registers on."""

import typer

app = typer.Typer(
    name="steval",
    help="steval-link: live telemetry, capture, replay and attitude estimation for the ST STEVAL-FCU001V1 drone.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

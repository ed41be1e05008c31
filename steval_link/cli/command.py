"""``steval param get|set`` and ``steval command ...``: one command frame to the drone, its acknowledgement printed."""

from __future__ import annotations

from pathlib import Path

import typer

from steval_link import constants as C
from steval_link.cli.app import option, sub_app, with_options
from steval_link.errors import UserError
from steval_link.link import protocol as P
from steval_link.link.commands import PARAM_HELP, PARAMS, Command, describe_settings, param_of_status, set_param

_Port = option(
    str, "--port", "-p", help="Serial port of the drone's USB-UART adapter (e.g. /dev/ttyUSB0, COM3), or auto."
)
_Baud = option(int, "--baud", "-b", help="Baud rate of the firmware build.")
_Timeout = option(float, "--timeout", help="Seconds to wait for the drone's acknowledgement.")
_Out = option(
    Path | None, "--out", help="Also record this exchange (bytes received and sent) to this new capture file."
)
#: the four options every command here takes: (parameter, annotation, default)
_LINK_PARAMS = (("port", _Port, "auto"), ("baud", _Baud, C.BAUD), ("timeout", _Timeout, 2.0), ("out", _Out, None))


def _exchange(port: str, baud: int, timeout: float, out: Path | None):
    """The link options as one function: ``send(command)`` sends it and returns the drone's reply."""

    def send(command: Command):
        from steval_link.live.serial_source import run_command  # reason: start-up time

        if not (timeout > 0):
            raise UserError(f"--timeout must be a positive number of seconds, got {timeout}")
        return run_command(port, baud, command, timeout_s=timeout, out=out)

    return send


#: a command here takes the link options last and gets them as ``send``: :func:`_exchange`
_with_link = with_options("send", _LINK_PARAMS, _exchange)

param_app = sub_app("param", "Read or change a filter parameter of the drone's Mahony filter, live.")
command_app = sub_app("command", "Reset the drone's filter, ask it for a status frame, or switch its output mode.")

_NAMES = ", ".join(f"{k} ({v})" for k, v in PARAM_HELP.items())


def _finish(reply) -> None:
    if not reply.accepted:
        raise UserError(reply.text)
    typer.echo(reply.text)
    if reply.status is not None:
        typer.echo(f"drone: {describe_settings(reply.status)} (from step {int(reply.status.step) + 1})")


@param_app.command("get")
@_with_link
def param_get(
    name: str | None = typer.Argument(None, help=f"Parameter: {_NAMES}. Default: all of them."), send=None
) -> None:
    """Print a filter parameter as the drone reports it now (asks for a status frame)."""
    key = None if name is None else name.strip().lower().replace("-", "_")
    if key is not None and key not in PARAMS:
        raise UserError(f"unknown parameter {name!r}; parameters: {', '.join(PARAMS)}")
    reply = send(Command(P.CMD_REQUEST_STATUS))
    if reply.status is None:
        raise UserError("the drone acknowledged the status request but its status frame did not arrive; try again")
    what = describe_settings(reply.status) if key is None else f"{key} = {param_of_status(reply.status, key)}"
    typer.echo(f"{what} (after step {int(reply.status.step)})")


@param_app.command("set")
@_with_link
def param_set(
    name: str = typer.Argument(..., help=f"Parameter: {_NAMES}."),
    value: str = typer.Argument(..., help="New value (a number; correction: on or off)."),
    send=None,
) -> None:
    """Change a filter parameter between two AHRS steps (refused while the motors may spin)."""
    _finish(send(set_param(name, value)))


@command_app.command("reset-filter")
@_with_link
def reset_filter(send=None) -> None:
    """Reset the filter state (q = 1, 0, 0, 0; integrals 0) between two AHRS steps."""
    _finish(send(Command(P.CMD_RESET_FILTER)))


@command_app.command("status")
@_with_link
def request_status(send=None) -> None:
    """Ask the drone for a status frame now (settings and filter state snapshot)."""
    _finish(send(Command(P.CMD_REQUEST_STATUS)))


@command_app.command("mode")
@_with_link
def set_mode(
    mode: str = typer.Argument(..., help="text (readable lines for a serial terminal) or binary (frames)."), send=None
) -> None:
    """Switch the drone's output between binary frames and text lines."""
    key = mode.strip().lower()
    if key not in ("text", "binary"):
        raise UserError(f"mode takes text or binary, got {mode!r}")
    _finish(send(Command(P.CMD_SET_MODE, P.MODE_TEXT if key == "text" else P.MODE_BINARY)))

"""``steval ports``: the serial ports of this machine, with description and USB VID:PID."""

from __future__ import annotations

import json

import typer

from steval_link.cli.app import app, option
from steval_link.link.autodetect import list_ports


@app.command()
def ports(as_json: option(bool, "--json", help="Print the list as JSON (for scripts).") = False) -> None:
    """List serial ports (device, description, VID:PID) to find the drone's USB-serial adapter."""
    found = list_ports()
    if as_json:
        typer.echo(json.dumps([p.as_dict() for p in found], indent=2))
        return
    if not found:
        typer.echo("no serial ports found (is the USB-serial adapter plugged in?)")
        return
    width = max(len(p.device) for p in found)
    for p in found:
        extra = f"  serial {p.serial_number}" if p.serial_number else ""
        typer.echo(f"{p.device:<{width}}  {p.vid_pid or '-':<9}  {p.description or '-'}{extra}")

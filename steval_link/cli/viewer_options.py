"""The Rerun sink options every viewing command shares, defined once."""

from __future__ import annotations

from pathlib import Path

from steval_link.cli.app import option, with_options
from steval_link.cli.outputs import check_output
from steval_link.errors import UserError
from steval_viewer.sink_options import DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT, SinkOptions, check_sinks

RrdOption = option(
    Path | None, "--rrd", help="Also write a Rerun recording to this .rrd file (open it later with: rerun FILE)."
)
SpawnOption = option(bool, "--spawn", help="Show it in the desktop Rerun viewer (stays open when the command ends).")
ServeOption = option(bool, "--serve", help="Show it in the Rerun web viewer on 127.0.0.1 (until Ctrl-C).")
ConnectOption = option(
    str | None,
    "--connect",
    metavar="URL",
    help="Send it to a running Rerun viewer at this gRPC URL, e.g. rerun+http://127.0.0.1:9876/proxy.",
)
WebPortOption = option(int, "--web-port", metavar="PORT", help="HTTP port of the --serve web viewer (127.0.0.1).")
GrpcPortOption = option(
    int,
    "--grpc-port",
    metavar="PORT",
    help="gRPC port of the --spawn or --serve viewer (127.0.0.1); a --spawn viewer already on it is reused.",
)


#: the shared Rerun options: (parameter, annotation, default)
_RERUN_PARAMS = (
    ("rrd", RrdOption, None),
    ("spawn", SpawnOption, False),
    ("serve", ServeOption, False),
    ("connect", ConnectOption, None),
    ("web_port", WebPortOption, DEFAULT_WEB_PORT),
    ("grpc_port", GrpcPortOption, DEFAULT_GRPC_PORT),
)


#: a typer command that takes the shared Rerun options where its parameter ``rerun`` stands, as one
#: :class:`~steval_viewer.sink_options.SinkOptions`
with_rerun_options = with_options("rerun", _RERUN_PARAMS, SinkOptions)


NoViewOption = option(bool, "--no-view", help="No Rerun viewer (with no --rrd: no Rerun at all).")
CaptureOutOption = option(
    Path | None, "--out", "-o", help="Capture file (.stv); default recordings/steval-<UTC time>.stv. Always written."
)


def check_view_flags(rerun: SinkOptions, *, no_view: bool = False) -> None:
    """A session shows one viewer at most, and none with ``--no-view``: UserError otherwise."""
    if sum([rerun.spawn, rerun.serve, rerun.connect is not None]) > 1:
        raise UserError("choose one of --spawn, --serve and --connect")
    if no_view and (rerun.spawn or rerun.serve or rerun.connect):
        raise UserError("--no-view cannot be combined with --spawn, --serve or --connect")


def view_sinks(rerun: SinkOptions, *, force: bool, inputs: tuple = ()) -> SinkOptions | None:
    """A batch command's Rerun outputs, checked before its work (None when none was asked for)."""
    if rerun.rrd is not None:
        check_output(rerun.rrd, option="--rrd", force=force, inputs=inputs)
    if rerun.rrd is None and not (rerun.spawn or rerun.serve or rerun.connect is not None):
        return None
    check_sinks(rerun)
    return rerun

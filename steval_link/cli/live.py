"""``steval live`` (watch the drone: capture + estimators + Rerun) and ``steval record`` (capture only)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import typer

from steval_link import constants as C
from steval_link.cli.app import app
from steval_link.cli.ble import BLE_LAYOUT_HELP, check_ble_layout
from steval_link.cli.checks import VariantOption, check_variant, estimator_names, flag_of
from steval_link.cli.outputs import check_duration, session_outputs
from steval_link.cli.replay import MapOption, read_map_option
from steval_link.cli.viewer_options import CaptureOutOption, NoViewOption, check_view_flags, with_rerun_options
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.link.ble_transport import bleak_backend
from steval_link.live.session import BLE_SCHEME, LiveOptions, LiveSession, port_source, source_for
from steval_viewer.live_adapter import ViewerLogger
from steval_viewer.sink_options import SinkOptions

_PORT_HELP = (
    "Serial port (e.g. /dev/ttyUSB0, COM3), a glob (/dev/ttyUSB*), 'auto': the one that carries frames, or "
    "replay://CAPTURE.stv[?speed=5]: a recording played at its recorded pace (no drone needed)."
)
_BAUD_HELP = "Baud rate of the drone's USART1 (the firmware patch's default is 115200)."
_WAIT_HELP = "Keep waiting for the port to appear and for valid frames instead of stopping with an error."
_PROMPT_HELP = (
    "Read commands typed on stdin (set ki 1.0, correction off, reset, status, mode text; see steval "
    "param --help) and send them to the drone over USART1 RX. Default: when stdin is a terminal."
)


def run_session(session: LiveSession) -> None:
    """Run ``session`` and print its summary; an output that failed on the way makes the exit code non-zero."""
    session.options.word = flag_of  # its notes name flags
    summary = session.run()
    try:
        print(summary.line())
        sys.stdout.flush()
    except BrokenPipeError:  # later writes (and the interpreter's last flush) go nowhere instead of failing
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    if summary.failures:
        raise typer.Exit(1)  # it ran to its end, but an output (the .rrd) failed on the way


def check_baud(baud: int) -> None:
    if baud <= 0:
        raise UserError(f"--baud must be a positive baud rate, got {baud}")


@app.command("live")
@with_rerun_options
def live_command(
    port: str | None = typer.Option(None, "--port", "-p", help=_PORT_HELP + " Default: auto."),
    baud: int = typer.Option(C.BAUD, "--baud", "-b", help=_BAUD_HELP),
    out: CaptureOutOption = None,
    no_view: NoViewOption = False,
    estimators: list[str] | None = typer.Option(
        None,
        "--estimators",
        "-e",
        help="Host estimators next to the firmware, comma-separated or repeated (st-mahony, accel, ekf3, mekf, vqf, "
        "your own: FILE.py:CLASS, module:CLASS, options in parentheses, docs/ESTIMATORS.md) or 'none'; "
        "default: st-mahony,accel,ekf3 (those installed).",
    ),
    duration: float | None = typer.Option(None, "--duration", help="Stop after this many seconds."),
    wait: bool = typer.Option(False, "--wait", help=_WAIT_HELP),
    prompt: bool | None = typer.Option(None, "--prompt/--no-prompt", help=_PROMPT_HELP),
    ble: bool = typer.Option(
        False,
        "--ble",
        help="Over Bluetooth instead of the serial port, from ST's unmodified firmware: --ble alone connects to the "
        "strongest drone advertising DRN1…, --ble NAME or --ble ADDRESS to that one (see steval ble scan). Needs "
        'bleak: pip install "steval-link\\[ble]".',
    ),
    device: str | None = typer.Argument(
        None, metavar="[NAME|ADDRESS]", help="With --ble: the drone's BLE name or address."
    ),
    ble_layout: str = typer.Option("stock", "--ble-layout", help=BLE_LAYOUT_HELP),
    variant: VariantOption = None,
    text_map: MapOption = None,
    rerun: SinkOptions = None,
) -> None:
    """Watch the drone live: records the raw capture, runs the estimators and shows everything in Rerun.

    The link health (frame rate, missing frames, CRC failures) is shown continuously on stderr; Ctrl-C stops,
    closes the capture (and the .rrd) and prints a one-line summary. Unplugging the adapter is survived: the
    session waits and resumes when the port comes back. Commands typed in the terminal go to the drone (set ki
    1.0, correction off, reset, status, ...): each change is marked on the viewer's timeline and in the capture.
    """
    check_baud(baud)
    check_view_flags(rerun, no_view=no_view)
    check_duration(duration)
    variant = check_variant(variant)
    user_map = read_map_option(text_map)
    if device is not None and not ble:
        raise UserError(
            f"{device!r}: a device name or address goes with --ble (steval live --ble {device}); a serial "
            "port is given with --port"
        )
    if ble and port is not None:
        raise UserError(f"--ble and --port {port}: a session reads one source; drop one of them")
    if ble:  # a clear line without bleak, before anything else
        target = (device or "").strip() or "auto"
        source = source_for(BLE_SCHEME + target, layout=check_ble_layout(ble_layout), backend=bleak_backend())
    else:
        if ble_layout != "stock":
            raise UserError(f"--ble-layout {ble_layout} goes with --ble")
        source = port_source(port or "auto", baud=baud, wait=wait)
    options = LiveOptions(
        estimators=estimator_names(estimators, registry.LIVE_DEFAULT),
        duration_s=duration,
        prompt=prompt,
        variant=variant,
        text_map=user_map,
    )
    # the input first (the port, or BLE), then the capture, the .rrd and the viewer
    check = session_outputs(options, out, rerun, view=not no_view)
    run_session(LiveSession(options, source, viewer_factory=ViewerLogger, check_outputs=check))


@app.command("record")
def record_command(
    port: str = typer.Option(..., "--port", "-p", help=_PORT_HELP),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Capture file (.stv); default recordings/steval-<UTC time>.stv."
    ),
    baud: int = typer.Option(C.BAUD, "--baud", "-b", help=_BAUD_HELP),
    duration: float | None = typer.Option(None, "--duration", help="Stop after this many seconds."),
    wait: bool = typer.Option(False, "--wait", help=_WAIT_HELP),
) -> None:
    """Record the raw stream to a capture file, no viewer (field use, scripts).

    The stream is still decoded to show the link health and to stop with a clear message when the port carries no
    valid frames (wrong baud rate, another device). Ctrl-C or --duration ends the recording.
    """
    check_baud(baud)
    check_duration(duration)
    options = LiveOptions(duration_s=duration)
    source = port_source(port, baud=baud, wait=wait)
    run_session(LiveSession(options, source, check_outputs=session_outputs(options, out)))  # the port first

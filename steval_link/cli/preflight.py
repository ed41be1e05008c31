"""``steval preflight``: the guided wiring check, live on the drone's port (recorded) or on a capture."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import typer

from steval_link import constants as C
from steval_link.analysis.preflight import MOVES, check_preflight
from steval_link.cli.app import app
from steval_link.cli.checks import flag_of, require_attitude
from steval_link.cli.live import check_baud
from steval_link.cli.outputs import print_warnings, session_outputs
from steval_link.errors import UserError
from steval_link.link.load import read_recording, telemetry_of_recording
from steval_link.live.session import LiveOptions, LiveSession, port_source

#: the guided sequence: (seconds after the start, what to say)
SCRIPT: tuple[tuple[float, str], ...] = (
    (
        0.0,
        "PROPS OFF. Put the drone level on the table. In the ST app: connect, arm, and raise the throttle just "
        f"above idle (gTHR >= {C.MIN_THR}) so the motors idle; or leave the throttle at 0 to check with the "
        "motors off. Keep still.",
    ),
    (6.0, "Pick the drone up and hold it level."),
    (8.0, f"1/3 {MOVES[0].name.upper()}: {MOVES[0].instruction}."),
    (13.5, f"2/3 {MOVES[1].name.upper()}: {MOVES[1].instruction}."),
    (19.0, f"3/3 {MOVES[2].name.upper()}: {MOVES[2].instruction}."),
    (26.0, "Put the drone down, throttle to 0, disarm."),
)
#: how long the live check records, s
LIVE_S = 30.0


def _prompter(stop: threading.Event, stream, first_after_s: float = 0.8) -> threading.Thread:
    """Prints the guided moves on ``stream`` at their times; none before ``first_after_s`` (a port's error first)."""

    def run() -> None:
        if stop.wait(first_after_s):
            return
        t = 0.0
        for at, text in SCRIPT:
            if stop.wait(max(at - t, 0.0)):
                return
            t = at
            print(f"\nsteval preflight [{at:4.1f} s]: {text}", file=stream, flush=True)

    th = threading.Thread(target=run, name="preflight-prompts", daemon=True)
    th.start()
    return th


@app.command("preflight")
def preflight_command(
    capture: Path | None = typer.Argument(
        None, help="Check a recorded capture (.stv) of the guided moves instead of a live port."
    ),
    port: str | None = typer.Option(
        None,
        "--port",
        "-p",
        help="Guide the moves live on this serial port (e.g. /dev/ttyUSB0, or 'auto'), record them, then check.",
    ),
    baud: int = typer.Option(C.BAUD, "--baud", "-b", help="Baud rate of the drone's USART1."),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Live: the capture file (default recordings/steval-<UTC time>.stv)."
    ),
) -> None:
    """Preflight wiring check: tilt right, nose up, turn right with the props off, checked against the firmware.

    With the drone armed and the throttle at idle (or the motors off), each guided move is checked link by link:
    the gyro and the firmware's attitude (swapped or reversed sensor axes), the outer and inner PID loops (do they
    push back?), each motor against the firmware's mixer (motor1 = thr - x_s2 - y_s2 + z_s2, ...; wrong motor
    order), and every motor output against its mixer line. The report says OK or what is wrong per move, motor
    and axis, and which way each motor must spin. Exit 1 when it finds a problem.
    """
    if (capture is None) == (port is None):
        raise UserError("give a capture to check, or --port to guide the moves live (not both).")
    if capture is not None:
        if out is not None:
            raise UserError("--out is for the live check (--port); a capture is only read.")
        path = capture
    else:
        check_baud(baud)
        options, source = LiveOptions(duration_s=LIVE_S, word=flag_of), port_source(port, baud=baud)
        stop = threading.Event()
        th = _prompter(stop, sys.stderr)
        try:
            summary = LiveSession(options, source, check_outputs=session_outputs(options, out)).run()  # the port first
        finally:
            stop.set()
            th.join(timeout=1.0)
        print(summary.line())
        path = summary.capture_path
    src = read_recording(path)
    tel = telemetry_of_recording(src)
    require_attitude(tel, "check (is it a capture of the drone's stream?)")
    print_warnings(src.warnings)  # a damaged capture that still holds frames: the check goes on
    report = check_preflight(tel, str(path))
    print(f"steval preflight: {path}")
    print(report.text())
    sys.stdout.flush()
    if not report.passed:
        raise typer.Exit(1)

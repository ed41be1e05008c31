"""``steval synth``: emulated drone captures (motion → LSM6DSL → ISR → bit-exact filter replica → frames → capture)."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import typer

from steval_link.cli import checks
from steval_link.cli.app import app, option
from steval_link.cli.outputs import check_output
from steval_link.cli.progress import progress_bar, scaled
from steval_link.constants import BAUD, KI
from steval_link.emulation.scenarios import SCENARIOS
from steval_link.errors import UserError

_JoinAt = option(float, "--join-at", help="Start the capture this many s after power-up (mid-flight, mid-frame).")
_Encoder = option(str, "--encoder", help="Frame encoder: python, or c (the firmware's C encoder, host build).")


@app.command("synth")
def synth_cmd(
    scenario: option(
        str | None, "--scenario", "-s", help="Built-in scenario (see --list) or a BROAD trial .npz (real motion)."
    ) = None,
    out: option(
        Path | None,
        "--out",
        "-o",
        help="Output: FILE.stv (capture with host times) or any other name for the plain received bytes (like cat "
        "/dev/ttyUSB0 > FILE).",
    ) = None,
    duration: option(
        float | None, help="Capture length, s (default: the scenario's; a BROAD trial: all of it)."
    ) = None,
    seed: option(int, help="Seed of every random choice; same seed, same bytes.") = 0,
    baud: option(
        int, help="USART1 baud rate: in the header and status frames; byte timing and queue drain follow it."
    ) = BAUD,
    throttle_schedule: checks.ThrottleScheduleOption = None,
    throttle: checks.ThrottleFormerOption = None,
    ki: checks.KiOption = None,
    correction: checks.CorrectionOption = None,
    text_mode: option(
        bool, "--text-mode", help="The text-mode build: $ATT lines every 16th step, $STA lines, plain log lines."
    ) = False,
    join_at: _JoinAt = 0.0,
    drop_rate: option(
        float, help="Fraction of attitude frames the firmware's TX queue drops (seq gaps, tx_dropped)."
    ) = 0.0,
    encoder: _Encoder = "python",
    c_encoder: option(
        Path | None,
        help="Path of the host-built C encoder (default firmware_patch/host/stv_encode; implies --encoder c).",
    ) = None,
    vibration: option(
        list[str] | None,
        metavar="SENSOR-AXIS:HZ:AMP",
        help="Add a pure sinusoid to one sensor axis, e.g. gyro-x:47:2000 (mdps) or acc-z:130:200 (mg); repeatable. To "
        "check steval spectrum against known peaks.",
    ) = None,
    fmt: option(str, "--format", help="auto (by the --out extension), stv or raw.") = "auto",
    force: option(bool, "--force", help="Replace --out if it exists.") = False,
    list_: option(bool, "--list", help="List the built-in scenarios and exit.") = False,
) -> None:
    """Run the modelled drone (Python, no ELF) into a capture: motion, sensors, ISR, the replica, the link.

    Motion profile → LSM6DSL model → ISR pipeline at 807.7 Hz → the bit-exact replica of the filter → frames per
    PROTOCOL.md (status and boot text included) at the real timing → USB-UART adapter. Deterministic: the same
    options give the same bytes. Modelled, not a real drone nor a real firmware (steval emulate runs an ELF)."""
    from steval_link.emulation.synth import SynthOptions, synthesize, write_output  # reason: start-up time

    if list_:
        typer.echo("Built-in scenarios (steval synth --scenario NAME; or --scenario path/to/BROAD_trial.npz):")
        for sc in SCENARIOS.values():
            typer.echo(f"  {sc.name:<11} {sc.default_duration_s:>4.0f} s  {sc.summary}")
        return
    if scenario is None:
        raise UserError("--scenario is required (see steval synth --list)")
    if out is None:
        raise UserError("--out is required (FILE.stv for a capture)")
    check_output(out, option="--out", force=force)
    checks.check_gain("--ki", ki)
    opts = SynthOptions(
        scenario=scenario,
        duration_s=duration,
        seed=seed,
        baud=baud,
        throttle=throttle_schedule or throttle,
        ki=KI if ki is None else ki,
        correction=correction is not False,
        text_mode=text_mode,
        join_at_s=join_at,
        drop_rate=drop_rate,
        encoder="c" if c_encoder is not None else encoder.lower(),
        c_encoder=None if c_encoder is None else str(c_encoder),
        vibration=tuple(vibration or ()),
    )
    opts = replace(opts, command_line=checks.command_line(["steval", "synth"], opts.settings()))
    t0 = time.perf_counter()
    with progress_bar("synth") as progress:
        res = synthesize(opts, scaled(progress, 0.0, 0.95))
        progress(0.95, f"writing {out.name}")
        kind = write_output(res, out, fmt=fmt, force=force)
    c = res.counts
    frames = (
        f"{c['att_lines']} $ATT, {c['sta_lines']} $STA, {c['log_lines']} log lines"
        if opts.text_mode
        else f"{c['attitude']} attitude, {c['status']} status, {c['text']} text frames"
    )
    typer.echo(
        f"wrote {out} ({kind}, {out.stat().st_size / 1e6:.2f} MB): {res.header['extra']['synth']['duration_s']:.1f} s "
        f"emulated, {frames}, {res.tx_dropped} dropped by the TX queue; {opts.encoder} encoder; "
        f"{time.perf_counter() - t0:.1f} s"
    )

"""``steval emulate``: run a firmware ELF on the emulated board (no drone), through the same path as a real port."""

from __future__ import annotations

import sys
from pathlib import Path

from steval_link.cli import checks
from steval_link.cli.app import app, argument, option
from steval_link.cli.outputs import check_duration, check_input, check_output, session_outputs
from steval_link.cli.viewer_options import CaptureOutOption, NoViewOption, check_view_flags, with_rerun_options
from steval_link.emulation.runner import EmulationOptions
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.link.capture import default_capture_path, resolve_capture_out
from steval_link.link.commands import parse_script
from steval_link.live.emulated import EmulatedSource
from steval_viewer.sink_options import SinkOptions

_Realtime = option(bool, "--realtime", help="Pace the emulation to the wall clock (default: as fast as it runs).")
_BleConnectAt = option(float, "--ble-connect-at", help="With --ble: emulated s at which the central connects.")
_TickStartMs = option(
    int,
    "--tick-start-ms",
    help="HAL_GetTick() at main, ms (e.g. 494288: the BLE tick, HAL_GetTick()>>3 in u16, wraps 30 s after power-up).",
    min=0,
)


@app.command("emulate")
@with_rerun_options
def emulate_command(
    elf: argument(
        Path,
        help="Firmware ELF: the reference firmware (make -C firmware_patch reference: "
        "firmware_patch/build/reference/steval-reference.elf) or a build of ST's release (patched or stock, e.g. from "
        "STM32CubeIDE).",
    ),
    scenario: option(
        str,
        "--scenario",
        "-s",
        help="Built-in motion: bench, hand-tilts, yaw-spin, hover, freefall, demo, flight (armed, stick moves), "
        "preflight (the preflight check's hand moves).",
    ) = "bench",
    broad: option(
        Path | None,
        help="Feed a BROAD trial (.npz: real IMU signals) instead of a scenario, from the first TIM9 tick on; the "
        "capture keeps its ground truth per AHRS step (steval compare and evaluate score against it).",
    ) = None,
    duration: option(
        float | None,
        help="Emulated seconds from power-up (default: the scenario's length; the first attitude frame comes at ≈ "
        "2.985 s).",
    ) = None,
    seed: option(int, help="Seed of the motion and the sensor noise (same seed, same bytes).") = 0,
    throttle_schedule: checks.ThrottleScheduleOption = None,
    throttle: checks.ThrottleFormerOption = None,
    mount: option(
        str | None,
        help="Sensor fault: the board mounted turned on the frame (turned-90: x and y swapped; turned-180: x and y "
        "reversed), as a wrong COORDINATE_SYSTEM would read it.",
    ) = None,
    out: CaptureOutOption = None,
    no_view: NoViewOption = False,
    estimators: option(
        list[str] | None,
        "--estimators",
        "-e",
        help="Host estimators next to the firmware (as for steval live; comma-separated or repeated), or 'none'.",
    ) = None,
    realtime: _Realtime = False,
    commands: option(
        Path | None,
        help="Command script: lines 'TIME_S COMMAND' (emulated s since power-up; e.g. '6 set ki 1.0', '12 correction "
        "off', '15 reset'), sent to the firmware's USART1 RX at those times.",
    ) = None,
    prompt: option(
        bool | None,
        "--prompt/--no-prompt",
        help="Read commands typed on stdin (set ki 1.0, correction off, reset, status) and send them to the emulated "
        "firmware. Default: when stdin is a terminal.",
    ) = None,
    ble: option(
        bool,
        "--ble",
        help="Record the BLE notifications the firmware sends to a connected central (ST's stock build: motion, "
        "environment, arming) as a BLE capture (--out), instead of USART1; replay it with steval replay.",
    ) = False,
    ble_connect_at: _BleConnectAt = 0.5,
    tick_start_ms: _TickStartMs = 0,
    variant: checks.VariantOption = None,
    rerun: SinkOptions = None,
) -> None:
    """Run a real firmware ELF on an emulated STEVAL-FCU001V1 (STM32F401 + sensors), no drone needed.

    The board runs the whole ELF unchanged (boot, HAL, TIM9 ISR, AHRS, the patch's USART1 stream) with motion fed
    to its sensor registers. Its USART1 bytes go through the same capture -> decoder -> estimators -> viewer path
    as `steval live`; the capture replays and compares like a drone's (`steval compare X.stv`). At the end: the
    instructions per AHRS step and the firmware's DWT window (emulated instruction counts, not M4 cycles).
    Commands reach the firmware's USART1 RX from --commands at given times, or typed at the prompt (a terminal).
    The firmware's attitude is read by symbol every AHRS step (capture chunks S): a build without the patch shows
    it too. The ST release's filter is recognised from the ELF's code (or --variant) and named.
    """
    variant = checks.check_variant(variant)
    for path, what in ((elf, "firmware ELF"), (broad, "BROAD trial"), (commands, "command script")):
        if path is not None:
            check_input(path, what=what)  # the inputs first
    if broad is not None and scenario != "bench":
        raise UserError("choose --scenario or --broad, not both")
    check_duration(duration)
    emu_options = EmulationOptions(
        elf=elf, scenario=scenario, broad=broad, duration_s=duration, seed=seed, throttle=throttle_schedule or throttle
    )
    if ble:
        if rerun.any():
            raise UserError(
                "--ble records a BLE capture only; view it afterwards with steval replay CAPTURE.stv (--spawn, --rrd)"
            )
        _emulate_ble(emu_options, out, ble_connect_at, tick_start_ms)
        return
    check_view_flags(rerun, no_view=no_view)
    emu_options.mount = mount  # the USART1 path models the mount fault; the BLE recording does not take it
    emu_options.command_line = checks.command_line(
        ["steval", "emulate", str(elf)], {**emu_options.settings(), "commands": commands}
    )
    script, names = _script(commands), checks.estimator_names(estimators, registry.LIVE_DEFAULT)
    source = EmulatedSource(emu_options, realtime=realtime, commands=script, variant=variant, variant_from="--variant")
    # the ELF first (the input), then the capture, the .rrd and the viewer; the board runs from here (unpaced), so
    # the session's modules load beside it
    source.open()
    try:
        from steval_link.live.session import LiveOptions, LiveSession  # reason: loaded while the board runs
        from steval_viewer.live_adapter import ViewerLogger  # reason: the same

        options = LiveOptions(estimators=names, prompt=prompt, word=checks.flag_of)
        check = session_outputs(options, out, rerun, view=not no_view)
        session = LiveSession(options, source, viewer_factory=ViewerLogger, check_outputs=check)
    except BaseException:
        source.close()
        raise
    summary = session.run()
    print("\n".join([summary.line(), *_estimator_lines(summary, options.estimators)]))
    sys.stdout.flush()


def _script(commands: Path | None):
    """The command script of ``--commands``, read (None without one)."""
    if commands is None:
        return None
    try:
        text = commands.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"cannot read the command script {commands}: {getattr(exc, 'strerror', None) or exc}")
    return parse_script(text, str(commands))


def _estimator_lines(summary, names) -> list[str]:
    """One line per host estimator (``-e``) over the run's capture, as ``steval replay -e`` says it."""
    from steval_link.analysis.report import estimator_line, estimator_summary  # reason: after the run
    from steval_link.estimators.runner import run_estimator  # reason: the same
    from steval_link.link.load import load_telemetry  # reason: the same

    path = Path(summary.capture_path)
    if not names or summary.capture_discarded or not path.is_file():
        return []
    try:
        tel = load_telemetry(path)
    except UserError:
        return []
    out = []
    for name in names if len(tel.attitude) else []:
        est, why = run_estimator(name, tel)
        out.append(f"estimator {name}: {why}" if est is None else estimator_line(estimator_summary(name, est, tel)))
    return out


def _emulate_ble(emu_options: EmulationOptions, out, connect_s: float, tick_start_ms: int) -> None:
    from steval_link.emulation.ble_capture import record_ble  # reason: only for --ble (loads the BlueNRG model)

    if not connect_s >= 0:
        raise UserError(f"--ble-connect-at must be ≥ 0 s, got {connect_s}")
    path = resolve_capture_out(out)
    if path is not None:
        check_output(path, option="--out", overwrite="never")
    else:  # the default, recordings/steval-<UTC>.stv, as steval live makes it
        path = default_capture_path()
        path.parent.mkdir(parents=True, exist_ok=True)
    ble = {"ble": True, "ble_connect_at": connect_s, "tick_start_ms": tick_start_ms or None}
    command = checks.command_line(["steval", "emulate", str(emu_options.elf)], {**emu_options.settings(), **ble})
    rec = record_ble(emu_options, path, connect_s=connect_s, tick_start_ms=tick_start_ms, command=command)
    print("\n".join(rec.lines()))
    sys.stdout.flush()

"""Every way a user can get the command line wrong ends in one ``steval: error: ...`` line and exit code 2, never a
boxed usage panel, a traceback or the raw bytes of what they typed; ``--version`` and ``-h`` work."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest
from support.cli import run_cli

from steval_link import __version__
from steval_link.cli.checks import user_message
from steval_link.estimators import registry

COMMANDS = ["replay", "live", "record", "export", "ports", "simulate", "synth", "conformance", "compare", "evaluate"]


def _one_error_line(code, err):
    assert code == 2, err
    assert err.startswith("steval: error: ") and len(err.strip().splitlines()) == 1, err
    assert "╭" not in err and "Traceback" not in err and "Usage:" not in err


def test_version_and_short_help(monkeypatch, capsys):
    code, out, _ = run_cli(monkeypatch, capsys, "--version")
    assert code == 0 and out.strip() == f"steval-link {__version__}"
    code, out, _ = run_cli(monkeypatch, capsys, "-h")
    assert code == 0 and "Usage: steval" in out and "--version" in out
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "-h")
    assert code == 0 and "Usage: steval simulate" in out


@pytest.mark.parametrize("columns", ["80", "120"])
def test_help_at_80_and_120_columns_keeps_every_option_name_and_word(monkeypatch, capsys, columns):
    """A command's help fits the terminal without cutting an option name or a sentence short with '…'."""
    monkeypatch.setenv("COLUMNS", columns)
    code, out, _ = run_cli(monkeypatch, capsys, "compare", "--help")
    lines = out.splitlines()
    assert code == 0 and "…" not in out and max(map(len, lines)) <= int(columns)
    assert "--estimators" in out and "--throttle" not in out and "steval-link[plot]" in out.replace("\\[", "[")
    words = " ".join(line.strip(" │") for line in lines).split()
    assert "OUT-flight-control.png" in words and "comma-separated" in words


@pytest.mark.parametrize("command", COMMANDS)
def test_help_shows_no_bool_metavar(monkeypatch, capsys, command):
    code, out, _ = run_cli(monkeypatch, capsys, command, "--help")
    assert code == 0 and "<bool>" not in out


@pytest.mark.parametrize(
    "args, words",
    [
        (["simulate", "--iterations", "abc"], ["--iterations", "steval simulate --help"]),
        (["replay", "--bogus"], ["--bogus"]),
        (["no-such-command"], ["no-such-command"]),
        (["record"], ["--port"]),
        (["simulate", "--acc", "1", "2"], ["--acc"]),
        (["compare", "recordings/demo.stv", "--plot"], ["--plot", "see 'steval compare --help'"]),
        (["param", "get", "--port"], ["--port", "see 'steval param get --help'"]),
        (["--bogus"], ["--bogus", "see 'steval --help'"]),
    ],
)
def test_usage_errors_are_one_line(monkeypatch, capsys, args, words):
    code, _, err = run_cli(monkeypatch, capsys, *args)
    _one_error_line(code, err)
    assert all(w in err for w in words), err


def test_bad_input_is_never_echoed_raw(monkeypatch, capsys, tmp_path):
    # an escape sequence and a byte that is not UTF-8 (argv carries it as a surrogate escape)
    junk = "\x1b[2J\x07\udcff"
    for args in (["simulate", "--iterations", junk], ["replay", str(tmp_path / junk)], ["export", junk, "--csv", "x"]):
        code, _, err = run_cli(monkeypatch, capsys, *args)
        _one_error_line(code, err)
        assert "\x1b" not in err and "\x07" not in err and "\udcff" not in err
        if args[0] != "simulate":  # the file name is quoted, escaped
            assert "\\x1b[2J\\x07\\xff" in err
    code, _, err = run_cli(monkeypatch, capsys, "simulate", "--acc", "nan", "0", "0")
    _one_error_line(code, err)
    assert err == "steval: error: --acc takes finite numbers in mg, got nan 0 0\n"
    code, _, err = run_cli(monkeypatch, capsys, "simulate", "--gyro", "inf", "0", "0")
    _one_error_line(code, err)
    assert "--gyro" in err and "np.float64" not in err


def test_evaluate_junk_is_not_a_trial_or_capture(monkeypatch, capsys, tmp_path):
    junk = tmp_path / "junk.bin"
    junk.write_bytes(bytes(range(256)) * 12)
    code, _, err = run_cli(monkeypatch, capsys, "evaluate", junk)
    _one_error_line(code, err)
    assert "not a trial or capture" in err


@pytest.mark.parametrize(
    "args",
    [
        ["replay", "-e", "ekf9", "--json"],
        ["simulate", "-e", "ekf9"],
        ["compare", "-e", "ekf9"],
        ["evaluate", "-e", "ekf9", "recordings/demo.stv"],
    ],
)
def test_unknown_estimator_lists_the_valid_ones(monkeypatch, capsys, args):
    code, _, err = run_cli(monkeypatch, capsys, *args)
    _one_error_line(code, err)
    assert "'ekf9'" in err and "ekf3" in err and "mekf" in err and "accel" in err


@pytest.mark.parametrize(
    "args, option",
    [
        (["simulate", "-n", "1000000000"], "--iterations"),
        (["simulate", "-n", "-1"], "--iterations"),
        (["simulate", "--ki", "-1"], "--ki"),
        (["simulate", "--ki", "nan"], "--ki"),
        (["simulate", "--kp", "-0.5"], "--kp"),
        (["simulate", "--throttle", "-7"], "--throttle"),
        (["simulate", "--throttle", "40000"], "--throttle"),
        (["compare", "--ki", "-1"], "--ki"),
        (["compare", "--kp-flight", "inf"], "--kp-flight"),
        (["compare", "--min-thr", "-1"], "--min-thr"),
        (["conformance", "--kp-ground", "-1", "x.csv"], "--kp-ground"),
        (["synth", "--scenario", "demo", "--out", "x.stv", "--ki", "-1"], "--ki"),
        (["synth", "--scenario", "demo", "--out", "x.stv", "--throttle-schedule", "-5"], "--throttle-schedule"),
    ],
)
def test_range_checks(monkeypatch, capsys, tmp_path, args, option):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(monkeypatch, capsys, *args)
    _one_error_line(code, err)
    assert option in err
    assert not list(tmp_path.iterdir())  # checked before any work


def test_registry_names_are_what_the_messages_list():
    assert {"st-mahony", "accel", "ekf3", "mekf"} <= set(registry.names())
    assert re.match(r"^\d+\.\d+", __version__)


# -- issue 25: errors in the command line's order, the one capture rule, outputs, small defects ---------------


@pytest.fixture(scope="module")
def small_capture(tmp_path_factory):
    from steval_link.emulation.synth import SynthOptions, synthesize, write_output

    path = tmp_path_factory.mktemp("small") / "small.stv"
    write_output(synthesize(SynthOptions(scenario="bench", duration_s=5.0)), path, fmt="stv")
    return path


def test_live_complains_about_the_port_before_the_display(monkeypatch, capsys):
    # no display and no --rrd is an error too, but the port comes first on the command line
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("steval_link.link.autodetect.list_candidate_ports", lambda: ["/dev/ttyS7"])
    code, _, err = run_cli(monkeypatch, capsys, "live", "--port", "/dev/steval-nonexistent")
    _one_error_line(code, err)
    assert "/dev/steval-nonexistent" in err and "display" not in err
    # param and command list the ports as live does
    live_line = err
    for args in (["param", "get"], ["command", "status"], ["command", "mode", "text"]):
        code, _, err = run_cli(monkeypatch, capsys, *args, "--port", "/dev/steval-nonexistent")
        _one_error_line(code, err)
        assert err == live_line and "available ports: /dev/ttyS7" in err


def test_export_checks_its_input_before_its_output(monkeypatch, capsys, tmp_path):
    existing = tmp_path / "j.csv"
    existing.write_text("keep")
    code, _, err = run_cli(monkeypatch, capsys, "export", tmp_path / "missing.stv", "--csv", existing)
    _one_error_line(code, err)
    assert "missing.stv" in err and "already exists" not in err and existing.read_text() == "keep"


def test_replay_rrd_refuses_an_existing_file_without_force(monkeypatch, capsys, tmp_path, small_capture):
    rrd = tmp_path / "old.rrd"
    rrd.write_bytes(b"an earlier recording")
    code, out, err = run_cli(monkeypatch, capsys, "replay", small_capture, "--rrd", rrd)
    _one_error_line(code, err)
    assert "already exists (use --force to overwrite)" in err and out == ""  # before the summary
    assert rrd.read_bytes() == b"an earlier recording"
    code, out, err = run_cli(monkeypatch, capsys, "replay", small_capture, "--rrd", rrd, "--force", "-e", "none")
    assert code == 0, err
    assert rrd.read_bytes()[:4] == b"RRF2" and sorted(p.name for p in tmp_path.iterdir()) == ["old.rrd"]


def test_capture_without_attitude_frames_is_one_rule(monkeypatch, capsys, tmp_path, small_capture):
    # the first 1000 bytes of a capture: its header and a few boot text frames, cut mid-chunk
    cut = tmp_path / "cut.stv"
    cut.write_bytes(small_capture.read_bytes()[:1000])
    for args in (["export", cut, "--csv", tmp_path / "o.csv"], ["compare", cut], ["spectrum", cut], ["preflight", cut]):
        code, _, err = run_cli(monkeypatch, capsys, *args)
        _one_error_line(code, err)
        assert "1000 bytes" in err and "no attitude frames" in err, err
    assert not (tmp_path / "o.csv").exists()
    code, out, err = run_cli(monkeypatch, capsys, "replay", cut)  # replay summarises whatever frames there are
    assert code == 0 and err.count("\n") == 1 and err.startswith("steval: warning: ") and "cut short" in err
    head = tmp_path / "head.stv"
    head.write_bytes(small_capture.read_bytes()[:300])
    code, _, err = run_cli(monkeypatch, capsys, "replay", head)
    assert err == f"steval: error: {head}: 300 bytes, capture truncated in its header: no frames.\n"


def test_atomic_output_is_whole_or_absent(tmp_path):
    from steval_link.cli.outputs import atomic_output, check_output, partial_path
    from steval_link.errors import UserError

    final = tmp_path / "out.csv"
    final.write_text("earlier")
    with pytest.raises(KeyboardInterrupt):
        with atomic_output(final, option="--csv") as part:
            assert part == partial_path(final) == tmp_path / "out.csv.partial"
            part.write_text("half")
            raise KeyboardInterrupt
    assert final.read_text() == "earlier" and not part.exists()
    with pytest.raises(UserError, match=r"^--csv .*out.csv: cannot write it \(no space left on device\)"):
        with atomic_output(final, option="--csv") as part:
            raise OSError(28, "No space left on device")
    with pytest.raises(UserError, match="Failed to create file"):
        with atomic_output(final, option="--rrd") as part:
            raise RuntimeError("Failed to create file\nmore lines of Rerun's")
    with atomic_output(final, option="--csv") as part:
        part.write_text("new")
    assert final.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]
    assert partial_path(tmp_path / "fig.png", keep_suffix=True).name == "fig.partial.png"
    with pytest.raises(UserError, match="is the input itself"):
        check_output(final, option="--csv", force=True, inputs=(final,))
    with pytest.raises(UserError, match="takes no new file"):
        check_output("/proc/steval.csv", option="--csv")


def test_live_help_shows_the_ble_extra(monkeypatch, capsys):
    code, out, _ = run_cli(monkeypatch, capsys, "live", "--help")
    assert code == 0 and 'pip install "steval-link[ble]"' in " ".join(out.replace("│", " ").split())


def test_simulate_json_final_is_null_where_the_text_says_n_a(monkeypatch, capsys):
    import json

    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "-e", "ekf3", "--json")
    assert code == 0 and set(json.loads(out)["final"].values()) == {None}
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "-e", "ekf3")
    assert code == 0 and out.count("n/a") == 3
    code, out, _ = run_cli(monkeypatch, capsys, "simulate", "--json")
    assert code == 0 and None not in json.loads(out)["final"].values()


FAKE_RERUN = """
import socket, sys, time
args = sys.argv[1:]
port = int(args[args.index("--port") + 1])
if "--listen-first" in sys.argv[0] or {listen}:
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", port))
    s.listen()
    time.sleep(0.3)
print("[2026-11-24T02:00:00Z ERROR re_viewer] Failed to create wgpu adapter: no suitable GPU adapter", flush=True)
sys.exit(1)
"""


@pytest.mark.parametrize("listen", [False, True], ids=["exits-at-once", "listens-then-dies"])
def test_spawn_reports_a_viewer_that_dies(monkeypatch, capsys, tmp_path, small_capture, listen):
    from steval_viewer import sinks
    from steval_viewer.sink_options import free_port

    fake = tmp_path / "rerun.py"
    fake.write_text(FAKE_RERUN.format(listen=listen))
    monkeypatch.setattr(sinks, "rerun_command", lambda: [sys.executable, str(fake)])
    monkeypatch.setenv("DISPLAY", ":0")  # a display is there, the viewer still dies (its GPU)
    port = free_port()
    code, out, err = run_cli(monkeypatch, capsys, "replay", small_capture, "--spawn", "--grpc-port", port, "-e", "none")
    _one_error_line(code, err)
    assert "no suitable GPU adapter" in err and "Rerun viewer exited" in err


def test_emulated_stop_event_is_in_emulated_time(monkeypatch, tmp_path, small_capture):
    # an emulated board (its bytes from a capture) whose frames carry emulated times: the stop event must too
    from types import SimpleNamespace

    from steval_link.emulation.runner import EmulationOptions
    from steval_link.link.capture import read_capture
    from steval_link.live import emulated
    from steval_link.live.session import LiveOptions, LiveSession

    cap = read_capture(small_capture)
    bounds = [*cap.chunk_offsets.tolist(), len(cap.data)]
    pieces = [(cap.data[bounds[i] : bounds[i + 1]], 0.05 * (i + 1)) for i in range(len(bounds) - 1)]

    class FakeEmulation:
        def __init__(self, options):
            self.elf = SimpleNamespace(path=Path("fake.elf"), by_name={}, addr=lambda name: None)  # no symbols
            self.motion = SimpleNamespace(name="bench", trial=None)  # scripted motion: no ground truth to keep
            self.duration_s = pieces[-1][1]

        def chunks(self, stop=None):
            yield from pieces

        def send(self, data, at_s=None):
            pass

        def take_host_bytes(self):
            return []

        def report(self):
            return None

    monkeypatch.setattr(emulated, "Emulation", FakeEmulation)
    out = tmp_path / "emu.stv"
    live = LiveOptions(out=out, estimators=[], prompt=False)
    LiveSession(live, emulated.EmulatedSource(EmulationOptions(elf=Path("fake.elf"))), tty=False).run()
    got = read_capture(out)
    stop = [e for e in got.events if e.kind == "stop"]
    assert len(stop) == 1 and stop[0].t_host_s == pytest.approx(pieces[-1][1])
    assert got.chunk_times_s.max() == pytest.approx(pieces[-1][1])


def test_a_sink_that_cannot_create_its_file_is_one_sentence():
    # past the CLI's own checks (a library caller): Rerun's "RuntimeError: Failed to create file" becomes a UserError
    from steval_link.errors import UserError
    from steval_viewer.sink_options import SinkOptions
    from steval_viewer.sinks import open_session

    if not Path("/proc").is_dir():
        pytest.skip("needs /proc")
    with pytest.raises(UserError, match=r"^rrd= /proc/steval-sink\.rrd: cannot write it \(") as exc:
        open_session(SinkOptions(rrd=Path("/proc/steval-sink.rrd")))
    assert "\n" not in str(exc.value)
    assert user_message(exc.value).startswith("--rrd /proc/steval-sink.rrd: cannot write it (")  # the CLI's words


@pytest.mark.slow
def test_the_readme_screenshot_is_made_by_its_script(tmp_path):
    """docs/make_screenshot.py: today's viewer on a virtual display, the viewer's own screenshot of each tab."""
    import subprocess

    from support.xdisplay import require_display_tools

    require_display_tools()
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run(
        [sys.executable, str(root / "docs" / "make_screenshot.py"), "viewer", str(tmp_path)],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    shots = sorted(tmp_path.glob("viewer-*.png"))
    assert len(shots) >= 3
    for out in shots:
        png = out.read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 100_000  # a rendered window, not a blank one
        width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        assert (width, height) == (1600, 1000)


@pytest.mark.parametrize("command", ["compare", "spectrum", "preflight"])
def test_a_ble_capture_where_serial_frames_are_needed_is_named(monkeypatch, capsys, command):
    ble = Path(__file__).resolve().parents[1] / "recordings" / "ble_demo.stv"
    code, _, err = run_cli(monkeypatch, capsys, command, ble)
    _one_error_line(code, err)
    assert "a BLE capture (" in err and "no serial frames" in err

"""Every way a user can get the command line wrong ends in one ``steval: error: ...`` line and exit code 2, never a
boxed usage panel, a traceback or the raw bytes of what they typed; ``--version`` and ``-h`` work."""

from __future__ import annotations

import re

import pytest

from steval_link import __version__
from steval_link.estimators import registry

from conftest import run_cli

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
        (["synth", "--scenario", "demo", "--out", "x.stv", "--throttle", "-5"], "--throttle"),
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

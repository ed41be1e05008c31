"""Every command of the typer app, found by walking the app's own command list (sub-apps included, and any command
added later), against a matrix of bad inputs and unwritable outputs.

For each case: exit code 2, exactly one ``steval: error:`` line on stderr, no traceback, no output file left
behind (no ``.partial`` either), and the input's bytes unchanged. The cases of a command are derived from its typer
parameters: its path arguments get the bad inputs, its options named in
:data:`steval_link.cli.outputs.OUTPUT_OPTIONS` get the bad outputs. :data:`BASE` gives the arguments of a valid
call where a command needs more than its path argument; a new command not in it still gets every case that applies
(with no other argument: a missing one is then a usage error, which must be one line too).

Unwritable outputs: ``/proc`` (no file can be created there), a missing folder, an existing folder, an existing file
without ``--force`` (it must stay as it was), and a read-only folder. The suite runs as root, which ignores
permission bits, and cannot mount a read-only file system in its container: ``/sys`` (sysfs refuses new files even
for root) stands in for it, and a ``chmod 555`` folder is added when not root. ``check_output`` tries to create a
file for real, so it fails the same way on any of them.

In-process (``support.cli.run_cli``): the whole matrix runs in a few seconds. Serial-port commands open a
pseudo-terminal (POSIX; they skip on Windows) so that their output checks are reached.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import typing
import warnings
from pathlib import Path

import numpy as np
import pytest
import typer
from support.cli import run_cli

from steval_link.cli import register
from steval_link.cli.outputs import OUTPUT_OPTIONS

app = register()  # the typer app with every command

#: file name extension given to a bad output of each option
EXTENSION = {
    "--rrd": ".rrd",
    "--csv": ".csv",
    "--parquet": ".parquet",
    "--plot": ".png",
    "--raw": ".bin",
    "--out": ".stv",
    "--mat": ".mat",
    "--mcap": ".mcap",
}

#: a valid call of a command, where it needs more than its path argument. {capture}: a good capture, {port}: a
#: pseudo-terminal, {trial}: a small BROAD-like trial, {elf}: a file standing in for a firmware ELF, {tmp}: the
#: folder outputs may go to.
BASE: dict[str, list[str]] = {
    "replay": ["{capture}"],
    "compare": ["{capture}"],
    "spectrum": ["{capture}"],
    "report": ["{capture}", "--out", "{tmp}/report.html", "-e", "accel"],
    "export": ["{capture}", "--csv", "{tmp}/rows.csv"],
    "preflight": ["{capture}"],
    "evaluate": ["{trial}"],
    "emulate": ["{elf}", "--no-view"],
    "simulate": ["-n", "5"],
    "synth": ["--scenario", "bench", "--duration", "3", "--out", "{tmp}/synth.stv"],
    "live": ["--port", "{port}", "--no-view", "--duration", "0.2"],
    "record": ["--port", "{port}", "--duration", "0.2"],
    "param get": ["--port", "{port}", "--timeout", "0.2"],
    "param set": ["ki", "1.0", "--port", "{port}", "--timeout", "0.2"],
    "command reset-filter": ["--port", "{port}", "--timeout", "0.2"],
    "command status": ["--port", "{port}", "--timeout", "0.2"],
    "command mode": ["text", "--port", "{port}", "--timeout", "0.2"],
}
#: a valid call for one output option where it differs from BASE (preflight --out records a live check)
BASE_FOR_OUTPUT: dict[tuple[str, str], list[str]] = {
    ("preflight", "--out"): ["--port", "{port}"],
}
#: (command, option) whose output may be an existing folder (documented: a capture is made inside it)
FOLDER_OK = {("live", "--out"), ("record", "--out"), ("emulate", "--out"), ("preflight", "--out")}
#: path arguments that are outputs, not inputs (a command that creates FILE)
OUTPUT_ARGUMENTS: set[tuple[str, str]] = {("estimator new", "file")}


# -- the commands, from the app itself ------------------------------------------------------------------------


def _leaves(group, path=()):
    for name, cmd in sorted(group.commands.items()):
        if hasattr(cmd, "commands"):
            yield from _leaves(cmd, (*path, name))
        else:
            yield " ".join((*path, name)), cmd


def _is_path(annotation) -> bool:
    """Whether a parameter's annotation is a Path (Optional, list and Annotated ones included)."""
    if annotation is Path:
        return True
    return any(_is_path(a) for a in typing.get_args(annotation))


def command_table() -> dict[str, dict]:
    """name → {"path_args": [param names], "outputs": [option names], "has_force": bool} of every leaf command."""
    out = {}
    for name, cmd in _leaves(typer.main.get_command(app)):
        hints = typing.get_type_hints(cmd.callback, include_extras=True) if cmd.callback else {}
        path_args, outputs, force = [], [], False
        for p in cmd.params:
            if p.param_type_name == "argument" and _is_path(hints.get(p.name)):
                path_args.append(p.name)
            opts = set(p.opts) | set(getattr(p, "secondary_opts", ()))
            outputs += sorted(opts & OUTPUT_OPTIONS)
            force = force or "--force" in opts
        out[name] = {"path_args": path_args, "outputs": outputs, "has_force": force}
    return out


COMMANDS = command_table()


def test_the_walk_finds_every_command_and_its_files():
    # the walk sees the sub-apps and what each command reads and writes; a new command appears by itself
    assert {"replay", "export", "live", "ble scan", "param get", "param set", "command mode"} <= set(COMMANDS)
    assert COMMANDS["export"]["outputs"] == ["--csv", "--parquet", "--raw", "--mat", "--mcap"]
    assert COMMANDS["replay"]["path_args"] == ["capture"] and COMMANDS["replay"]["outputs"] == ["--rrd"]
    assert set(COMMANDS["spectrum"]["outputs"]) == {"--csv", "--plot", "--rrd"}
    assert COMMANDS["ports"] == {"path_args": [], "outputs": [], "has_force": False}


def test_each_command_word_starts_with_its_own_module_only():
    # `steval WORD ...` imports WORD's module, not every command's (start-up time): in a fresh process, that module
    # registers WORD, and the modules of commands it does not use stay unloaded
    code = (
        "import sys, typer\n"
        "from steval_link.cli import COMMANDS, register\n"
        "word = sys.argv[1]\n"
        "names = set(typer.main.get_command(register([word, '--help'])).commands)\n"
        "print(word in names, 'steval_link.cli.simulate' in sys.modules, 'steval_link.cli.evaluate' in sys.modules)\n"
    )
    from steval_link.cli import COMMANDS

    for word in ("emulate", "record", "param", "data"):
        out = subprocess.run([sys.executable, "-c", code, word], capture_output=True, text=True, check=True).stdout
        assert out.split() == ["True", "False", "False"], (word, COMMANDS[word], out)
    # a word that is no command: every command is registered (click then suggests the right one)
    every = set(typer.main.get_command(register(["emulat"])).commands)
    assert set(COMMANDS) == every


# -- fixtures -------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """A good capture, a small BROAD-like trial, a stand-in ELF and the bad inputs, made once."""
    d = tmp_path_factory.mktemp("matrix-inputs")
    from steval_link.emulation.synth import SynthOptions, synthesize, write_output

    good = d / "good.stv"
    write_output(synthesize(SynthOptions(scenario="bench", duration_s=9.0)), good, fmt="stv", force=True)
    data = good.read_bytes()
    head = _header_size(data)
    rng = np.random.default_rng(25)
    n = 700
    t = np.arange(n) / 285.7
    np.savez(
        d / "trial.npz",
        acc=np.tile([0.0, 0.0, 9.81], (n, 1)),
        gyr=np.zeros((n, 3)),
        quat=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
        movement=t > 0.5,
        fs=np.float64(285.7),
    )
    (d / "firmware.elf").write_bytes(b"\x7fELF" + rng.bytes(2000))
    bad = {
        "missing": d / "missing.stv",
        "empty": d / "empty.stv",
        "folder": d / "folder.stv",
        "junk": d / "junk.bin",
        "truncated-in-header": d / "cut-header.stv",
        "header-only": d / "header-only.stv",
        "random-bytes-appended": d / "appended.stv",
    }
    bad["empty"].write_bytes(b"")
    bad["folder"].mkdir()
    bad["junk"].write_bytes(rng.bytes(3000))
    bad["truncated-in-header"].write_bytes(data[: head - 7])
    bad["header-only"].write_bytes(data[:head])
    bad["random-bytes-appended"].write_bytes(data[:head] + rng.bytes(1000))
    bad["device"] = Path("/dev/zero")  # never ends
    bad["pipe"] = d / "pipe.stv"
    if hasattr(os, "mkfifo"):
        os.mkfifo(bad["pipe"])  # a reader would wait for ever
    return {"capture": good, "trial": d / "trial.npz", "elf": d / "firmware.elf", **bad}


def _header_size(data: bytes) -> int:
    """Bytes of a capture's magic, header length, header and header CRC."""
    from steval_link.link.capture import MAGIC

    hlen = int.from_bytes(data[len(MAGIC) : len(MAGIC) + 4], "little")
    return len(MAGIC) + 4 + hlen + 4


def _fill(args: list[str], files: dict[str, Path], tmp: Path, port: str | None) -> list[str]:
    values = {
        "capture": files["capture"],
        "trial": files["trial"],
        "elf": files["elf"],
        "tmp": tmp,
        "port": port or "/dev/steval-no-port",
    }
    return [a.format(**{k: str(v) for k, v in values.items()}) for a in args]


def _run(monkeypatch, capsys, *args):
    """``run_cli`` that also returns the Python warnings our own modules issued (they must print their own line)."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        code, out, err = run_cli(monkeypatch, capsys, *args)
    ours = [
        f"{w.filename}: {w.category.__name__}: {w.message}"
        for w in seen
        if any(part in ("steval_link", "viewer") for part in Path(w.filename).parts) or "Capture" in w.category.__name__
    ]
    return code, out, err, ours


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else b"<not a file>")
        for p in sorted(folder.rglob("*"))
    }


def _digest(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None  # a device: not read


def _assert_one_error(code: int, out: str, err: str, args) -> None:
    lines = err.strip().splitlines()
    assert code == 2, f"steval {' '.join(map(str, args))}: exit {code}\n{err}"
    assert len(lines) == 1 and lines[0].startswith("steval: error: "), f"steval {' '.join(map(str, args))}:\n{err}"
    assert "Traceback" not in err + out and "Warning:" not in err, err
    assert out == "", f"steval {' '.join(map(str, args))} printed before its error:\n{out}"  # no work was done


def _needs_port(args: list[str]) -> bool:
    return any("{port}" in a for a in args)


# -- bad inputs -----------------------------------------------------------------------------------------------

INPUT_CASES = [
    "missing",
    "empty",
    "folder",
    "junk",
    "truncated-in-header",
    "header-only",
    "random-bytes-appended",
    "device",
    "pipe",
]
INPUT_PARAMS = [
    (name, arg, case)
    for name, c in COMMANDS.items()
    for arg in c["path_args"]
    if (name, arg) not in OUTPUT_ARGUMENTS
    for case in INPUT_CASES
]


@pytest.mark.parametrize("name, arg, case", INPUT_PARAMS, ids=[f"{n}:{a}:{c}" for n, a, c in INPUT_PARAMS])
def test_bad_input(monkeypatch, capsys, tmp_path, files, name, arg, case):
    monkeypatch.chdir(tmp_path)
    base = BASE.get(name, ["{capture}"])
    args = _fill(base, files, tmp_path, None)
    good = {str(files[k]) for k in ("capture", "trial", "elf")}
    bad = files[case]
    if case in ("pipe", "device") and not bad.exists():
        pytest.skip(f"no {case} such as {bad} here (Windows)")
    args = [str(bad) if a in good else a for a in args]
    if str(bad) not in args:
        args.insert(0, str(bad))
    before_in, before_out = _digest(bad), _snapshot(tmp_path)
    code, out, err, ours = _run(monkeypatch, capsys, *name.split(), *args)
    _assert_one_error(code, out, err, args)
    assert not ours, ours
    assert _digest(bad) == before_in, "the input was modified"
    assert _snapshot(tmp_path) == before_out, "an output was left behind"


# -- bad outputs ----------------------------------------------------------------------------------------------


def _bad_outputs(tmp: Path, option: str, folder_ok: bool) -> dict[str, Path]:
    ext = EXTENSION.get(option, ".out")
    cases = {
        "proc": Path("/proc") / f"steval-matrix{ext}",
        "read-only-folder": Path("/sys") / f"steval-matrix{ext}",
        "missing-folder": tmp / "no" / "such" / f"x{ext}",
        "existing-file": tmp / f"exists{ext}",
    }
    if not folder_ok:
        cases["folder"] = tmp / "a-folder"
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        cases["chmod-555-folder"] = tmp / "ro" / f"x{ext}"
    return cases


OUTPUT_CASES = ["proc", "read-only-folder", "missing-folder", "existing-file", "folder"]
if hasattr(os, "geteuid") and os.geteuid() != 0:  # root ignores permission bits
    OUTPUT_CASES.append("chmod-555-folder")
OUTPUT_PARAMS = [(name, opt, case) for name, c in COMMANDS.items() for opt in c["outputs"] for case in OUTPUT_CASES]


def _with_output(args: list[str], option: str, value: str) -> list[str]:
    if option in args:
        i = args.index(option)
        return [*args[: i + 1], value, *args[i + 2 :]]
    return [*args, option, value]


@pytest.mark.parametrize("name, option, case", OUTPUT_PARAMS, ids=[f"{n}:{o}:{c}" for n, o, c in OUTPUT_PARAMS])
def test_bad_output(monkeypatch, capsys, tmp_path, files, name, option, case):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    outdir = tmp_path / "out"
    outdir.mkdir()
    cases = _bad_outputs(outdir, option, (name, option) in FOLDER_OK)
    if case not in cases:
        pytest.skip(f"{case} does not apply to {name} {option}")
    target = cases[case]
    if case == "existing-file":
        target.write_bytes(b"an earlier file, to be kept\n")
    elif case == "folder":
        target.mkdir()
    elif case == "chmod-555-folder":
        target.parent.mkdir()
        target.parent.chmod(0o555)
    base = BASE_FOR_OUTPUT.get((name, option), BASE.get(name, ["{capture}"] if COMMANDS[name]["path_args"] else []))
    port = None
    if _needs_port(base):
        if not hasattr(os, "openpty"):
            pytest.skip("serial-port commands need a pseudo-terminal (POSIX)")
        master, slave = os.openpty()
        port = os.ttyname(slave)
    try:
        args = _with_output(_fill(base, files, outdir, port), option, str(target))
        inputs = {k: _digest(files[k]) for k in ("capture", "trial", "elf")}
        before = _snapshot(outdir), _snapshot(work)
        code, out, err, ours = _run(monkeypatch, capsys, *name.split(), *args)
    finally:
        if port is not None:
            os.close(slave)
            os.close(master)
    _assert_one_error(code, out, err, args)
    assert not ours, ours
    assert {k: _digest(files[k]) for k in inputs} == inputs, "an input was modified"
    assert (_snapshot(outdir), _snapshot(work)) == before, "an output was left behind (or an earlier one changed)"
    assert not (Path("/proc") / f"steval-matrix{EXTENSION.get(option, '.out')}.partial").exists()


# -- damaged captures that still hold frames: one warning line of our own, the work goes on -------------------

CAPTURE_COMMANDS = [n for n in ("replay", "export", "compare", "spectrum", "preflight") if n in COMMANDS]


@pytest.mark.parametrize("damage", ["cut-mid-chunk", "random-bytes-appended", "damaged-middle"])
@pytest.mark.parametrize("name", CAPTURE_COMMANDS)
def test_damaged_capture_with_frames_warns_once(monkeypatch, capsys, tmp_path, files, name, damage):
    data = files["capture"].read_bytes()
    head = _header_size(data)
    rng = np.random.default_rng(7)
    damaged = {
        "cut-mid-chunk": data[: len(data) - 37],
        "random-bytes-appended": data + rng.bytes(1000),
        "damaged-middle": data[: len(data) // 2] + rng.bytes(64) + data[len(data) // 2 + 64 :],
    }[damage]
    assert len(damaged) > head
    path = tmp_path / "damaged.stv"
    path.write_bytes(damaged)
    monkeypatch.chdir(tmp_path)
    args = _fill(BASE[name], {**files, "capture": path}, tmp_path, None)
    code, out, err, ours = _run(monkeypatch, capsys, name, *args)
    lines = err.strip().splitlines()
    assert not ours, ours  # never Python's warnings output (".../preflight.py:96: CaptureTruncatedWarning: ...")
    assert code in (0, 1), err  # preflight: 1 is its finding on a bench capture, not an input error
    assert [ln for ln in lines if ln.startswith("steval: warning: ")] == lines and len(lines) == 1, err
    assert "damaged" in lines[0] or "cut short" in lines[0], err
    assert "Traceback" not in err and "Warning:" not in err
    assert path.read_bytes() == damaged


# -- the matrix itself cannot miss a command that leaks a traceback -------------------------------------------


def test_a_new_command_that_leaks_a_traceback_fails_the_matrix(monkeypatch, capsys, tmp_path, files):
    @app.command("matrix-probe")
    def matrix_probe(capture: Path = typer.Argument(...)) -> None:  # a command that forgot the rules
        capture.read_bytes()

    try:
        assert command_table()["matrix-probe"]["path_args"] == ["capture"]
        with pytest.raises((AssertionError, OSError)):
            test_bad_input(monkeypatch, capsys, tmp_path, files, "matrix-probe", "capture", "missing")
    finally:
        app.registered_commands[:] = [c for c in app.registered_commands if c.name != "matrix-probe"]
    assert "matrix-probe" not in command_table()


# -- the suite as Windows sees it ------------------------------------------------------------------------------


@pytest.mark.slow
def test_the_suite_collects_without_the_posix_modules():
    """``.ci/run`` collects the suite with pty, tty, termios, fcntl and resource blocked for the tests (as on
    Windows): no collection error, the pseudo-terminal modules skip with a reason."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    line = "PYTHONPATH=.ci python -m pytest -p block_posix --collect-only -q"
    assert line in (root / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    env = dict(os.environ, PYTHONPATH=str(root / ".ci"))
    r = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "block_posix", "--collect-only", "-q", "-rs"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0 and "errors during collection" not in r.stdout and "ERROR " not in r.stdout, (
        r.stdout[-3000:] + r.stderr[-2000:]
    )
    assert "pseudo-terminal (POSIX only)" in r.stdout
    probe = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "block_posix", "-q", "-rs", "tests/test_commands.py", "-k", "param"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert probe.returncode == 0 and "skipped" in probe.stdout and "POSIX only" in probe.stdout, probe.stdout[-2000:]

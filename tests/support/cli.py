"""``steval`` run as a user runs it: in-process with captured output, or on a pseudo-terminal."""

from __future__ import annotations


def _app_key(app) -> tuple:
    """What typer builds a command tree from: every (sub-)app, callback and command, by identity."""
    return (
        id(app),
        id(getattr(app.registered_callback, "callback", None)),
        tuple((c.name, id(c.callback)) for c in app.registered_commands),
        tuple((g.name, _app_key(g.typer_instance)) for g in app.registered_groups),
    )


def cached_get_command(build):
    """``typer.main.get_command`` (``build``) that builds each app's click tree once: building it is 80 % of a short
    in-process run (≈ 50 ms). A command added to the app (a test's probe) makes a new tree."""
    trees: dict[tuple, tuple] = {}  # the app is kept with its tree, so the ids in the key stay unique

    def get_command(app):
        key = _app_key(app)
        if key not in trees:
            trees[key] = (build(app), app)
        return trees[key][0]

    return get_command


def run_cli(monkeypatch, capsys, *args):
    """``steval`` as a user runs it (``sys.argv`` and ``main()``): returns (exit code, stdout, stderr)."""
    import sys

    from steval_link.cli import main

    monkeypatch.setattr(sys, "argv", ["steval", *map(str, args)])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    out, err = capsys.readouterr()
    return code, out, err


def run_steval(args, *, env=None, cwd=None, timeout: float = 120.0):
    """``steval ARGS`` in a subprocess as a user's shell runs it (stdin closed): the ``CompletedProcess`` with
    stdout and stderr as text."""
    import subprocess
    import sys

    return subprocess.run(
        [sys.executable, "-c", "from steval_link.cli import main; main()", *map(str, args)],
        env=env,
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def run_cli_tty(*args, timeout: float = 120.0):
    """``steval ARGS`` in a subprocess whose stderr is a terminal (a pseudo-terminal, 100 columns), as on a user's
    screen: returns (exit code, stdout text, everything written to the terminal as text)."""
    import os
    import select

    import pytest

    pty = pytest.importorskip("pty", reason="a pseudo-terminal for stderr (POSIX only)")
    import subprocess
    import sys
    import time

    master, slave = pty.openpty()
    env = dict(os.environ, TERM="xterm", COLUMNS="100", LINES="30")
    proc = subprocess.Popen(
        [sys.executable, "-c", "from steval_link.cli import main; main()", *map(str, args)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=slave,
        env=env,
    )
    os.close(slave)
    chunks = []
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # the child closed the terminal
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        else:
            proc.kill()
            raise AssertionError(f"steval {' '.join(map(str, args))} did not end within {timeout} s")
        stdout = proc.communicate(timeout=timeout)[0]
    finally:
        os.close(master)
    return proc.returncode, stdout.decode("utf-8", "replace"), b"".join(chunks).decode("utf-8", "replace")

"""The README's set-up commands are the ones CI runs, and the commands it tours exist."""

from __future__ import annotations

import re
from pathlib import Path

from typer.testing import CliRunner

from steval_link.cli import app

ROOT = Path(__file__).resolve().parents[1]


def _setup_block() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Set up", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    return [line.strip() for line in block.splitlines() if line.strip()]


def test_ci_runs_exactly_the_readme_setup_commands():
    install, test = _setup_block()
    assert "pip install" in install and "pytest" in test
    ci_lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    assert install in ci_lines
    assert test in ci_lines
    assert ci_lines.index(install) < ci_lines.index(test)


def test_every_toured_command_exists():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    toured = set(re.findall(r"\| `steval (\w+)", text))
    assert toured >= {"live", "record", "replay", "export", "compare", "simulate", "conformance", "evaluate"}
    runner = CliRunner()
    for name in sorted(toured):
        result = runner.invoke(app, [name, "--help"])
        assert result.exit_code == 0, (name, result.output)

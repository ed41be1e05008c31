"""The README's and the docs' commands are real: CI runs the README's set-up commands; every `steval` command line
in the README and the docs names a command and options that exist; the outputs the docs show are what those
commands print; the README's links lead to files; the error example in the docs is the error the code gives."""

from __future__ import annotations

import re
import shlex

import pytest
from support.cli import run_cli
from support.docs import ROOT, code_blocks, doc_pages, doc_text

from steval_link.cli import register

app = register()  # the typer app with every command


def _setup_block() -> list[str]:
    section = doc_text("README.md").split("## Set up", 1)[1]
    return [line.strip() for line in code_blocks(section, "sh")[0].splitlines() if line.strip()]


def _ci_lines() -> list[str]:
    return [line.split("#", 1)[0].strip() for line in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]


def test_ci_runs_the_readme_setup_commands_then_everything():
    install, test = _setup_block()
    assert "pip install" in install and test == "python -m pytest"
    ci = _ci_lines()
    assert install in ci
    full = [line for line in ci if line.startswith(test + " ")]
    assert full and set(full[0].split()[3:]) == {"--runslow", "-n", "2"}  # the quick command, plus the slow tests
    assert ci.index(install) < ci.index(full[0])
    assert any(line.startswith("python -m mkdocs build --strict") for line in ci)
    assert 'python -m pip install -e ".[docs]"' in ci


def test_the_readme_windows_setup_is_one_command_per_line():
    section = doc_text("README.md").split("## Set up", 1)[1]
    lines = code_blocks(section, "powershell")[0].strip().splitlines()
    assert lines == [
        "py -3 -m venv .venv",
        r".venv\Scripts\Activate.ps1",
        'python -m pip install -e ".[test]"',
        "python -m pytest",
    ]
    assert lines[2] == _setup_block()[0].split("&& ")[-1]  # the same install as on Linux and macOS


def test_every_toured_command_exists():
    toured = set(re.findall(r"\| `steval (\w+)", doc_text("README.md")))
    assert toured >= {"live", "replay", "compare", "simulate", "evaluate"}
    for name in sorted(toured):
        assert name in _commands(), name


def test_the_readme_links_lead_to_files():
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", doc_text("README.md")):
        if not re.match(r"[a-z]+:", target):
            assert (ROOT / target).exists(), target


# -- every steval command line in the README and the docs ------------------------------------------------------


def _commands() -> dict:
    """``steval`` sub-commands by name ("ble scan" for a group's), from the click tree typer builds."""
    import typer.main

    root = typer.main.get_command(app)
    found = {}
    for name, cmd in root.commands.items():
        found[name] = cmd
        for sub, subcmd in getattr(cmd, "commands", {}).items():
            found[f"{name} {sub}"] = subcmd
    return found


def _doc_command_lines() -> list[tuple[str, str]]:
    """(page, line) for every `steval ...` line of the sh code blocks of the README and the docs."""
    lines = []
    for page in doc_pages():
        rel = page.relative_to(ROOT).as_posix()
        for block in code_blocks(page.read_text(encoding="utf-8"), "sh"):
            joined = re.sub(r"\\\n\s*", "", block)  # continuation lines
            for line in joined.splitlines():
                line = line.split(" # ", 1)[0].strip()
                if line.startswith("steval "):
                    lines.append((rel, line))
    return lines


def test_the_docs_show_steval_commands():
    pages = {page for page, _ in _doc_command_lines()}
    assert {"README.md", "docs/tutorials/first-look.md", "docs/tutorials/umaine-lab5.md"} <= pages


@pytest.mark.parametrize(("page", "line"), _doc_command_lines(), ids=lambda v: v if "/" in v else None)
def test_every_documented_command_and_option_exists(page, line):
    argv = shlex.split(line)[1:]
    commands = _commands()
    name = " ".join(argv[:2]) if " ".join(argv[:2]) in commands else argv[0]
    assert name in commands, f"{page}: `{line}`: no command {name!r}"
    options = {opt for p in commands[name].params for opt in (*p.opts, *getattr(p, "secondary_opts", []))}
    options |= {"-h", "--help"}
    for word in argv[len(name.split()) :]:
        if word.startswith("-") and not re.fullmatch(r"-\d.*", word):  # a negative number is a value
            assert word.split("=", 1)[0] in options, f"{page}: `{line}`: steval {name} has no option {word}"


# -- outputs the docs show --------------------------------------------------------------------------------------


def _shown_outputs() -> list:
    """Every sh block of the docs followed by ``prints`` and a text block: (page, commands, the text shown)."""
    cases = []
    for page in sorted((ROOT / "docs").rglob("*.md")):
        text = page.read_text(encoding="utf-8")
        for m in re.finditer(r"```sh\n([^`]*?)```\s*\n+prints:?\n+```text\n(.*?)```", text, re.S):
            commands = [ln for ln in m.group(1).strip().splitlines() if ln.strip()]
            if not all(ln.startswith("steval ") for ln in commands):
                continue
            quick = all(ln.startswith("steval simulate") for ln in commands)
            rel = page.relative_to(ROOT).as_posix()
            marks = () if quick else (pytest.mark.slow,)
            cases.append(pytest.param(rel, commands, m.group(2), marks=marks, id=f"{rel}:{commands[-1][:40]}"))
    return cases


@pytest.mark.parametrize(("page", "commands", "shown"), _shown_outputs())
def test_the_docs_show_what_the_commands_print(page, commands, shown, monkeypatch, capsys, tmp_path):
    """Run as written in a fresh folder (with the bundled recordings): the last command prints what the page shows."""
    (tmp_path / "recordings").symlink_to(ROOT / "recordings")
    monkeypatch.chdir(tmp_path)
    out = ""
    for line in commands:
        code, out, err = run_cli(monkeypatch, capsys, *shlex.split(line)[1:])
        assert code == 0, f"{page}: `{line}`: {err}"
    assert [ln.rstrip() for ln in out.strip().splitlines()] == [ln.rstrip() for ln in shown.strip().splitlines()]


def test_there_are_shown_outputs_to_check():
    assert len(_shown_outputs()) >= 4


# -- the error example of docs/reference/errors-and-outputs.md is the code's --------------------------------------


def test_the_documented_truncation_error_is_the_one_the_code_gives(monkeypatch, capsys, tmp_path):
    from steval_link.emulation.synth import SynthOptions, synthesize, write_output

    text = " ".join(doc_text("docs/reference/errors-and-outputs.md").split())
    example = re.search(r"`\d+ bytes, capture truncated in its header: no frames`", text)
    assert example is not None
    capture = tmp_path / "small.stv"
    write_output(synthesize(SynthOptions(scenario="bench", duration_s=5.0)), capture, fmt="stv")
    cut = tmp_path / "cut.stv"
    cut.write_bytes(capture.read_bytes()[:300])  # inside its header
    code, _, err = run_cli(monkeypatch, capsys, "replay", cut)
    said = err.removeprefix(f"steval: error: {cut}: ").strip().rstrip(".")
    assert code == 2 and re.sub(r"\d+", "N", said) == re.sub(r"\d+", "N", example.group(0).strip("`"))


def test_the_documented_macos_ble_address_is_listed_as_the_scan_lists_it():
    from steval_link.cli.ble import format_devices
    from steval_link.link.ble_transport import BleDevice

    text = doc_text("docs/reference/ble-link.md")
    uuid = re.search(r"steval live --ble ([0-9A-F]{8}-[0-9A-F]{4}-[0-9A-F]{4}-[0-9A-F]{4}-[0-9A-F]{12}) +# macOS", text)
    assert uuid is not None
    (line,) = format_devices([BleDevice(name="DRN1110", address=uuid.group(1), rssi_dbm=-60)], show_all=False)
    assert line.split() == ["DRN1110", uuid.group(1), "-60", "dBm", "STEVAL", "drone", "(ST", "firmware)"]


def test_docs_pages_exist_for_the_site_nav():
    """Every page mkdocs.yml's nav names exists (mkdocs build --strict checks the rest in CI)."""
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = re.findall(r"^[^#\n]*:\s*([\w/.-]+\.md)\s*$", config, re.M)  # not the commented-out places
    assert len(nav) >= 20
    missing = [p for p in nav if not (ROOT / "docs" / p).is_file()]
    assert not missing, missing


def test_the_cli_reference_lists_every_option_of_every_command():
    """docs/hooks/cli_reference.py, which writes the site's CLI page at build time, names every command, argument
    and option of the typer app with its help."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("cli_reference", ROOT / "docs" / "hooks" / "cli_reference.py")
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    page = hook.cli_markdown()
    for name, cmd in _commands().items():
        if getattr(cmd, "commands", None):
            continue  # a group: its sub-commands are listed
        assert f"# steval {name}\n" in page, name
        section = page.split(f"# steval {name}\n", 1)[1].split("\n#", 1)[0]
        for p in cmd.params:
            if getattr(p, "hidden", False):
                continue
            names = [p.name.upper()] if type(p).__name__.endswith("Argument") else p.opts
            assert all(n in section for n in names), (name, p.name)
    marker_page = doc_text("docs/reference/cli.md")
    assert hook.MARKER in marker_page

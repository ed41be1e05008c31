"""MkDocs hook: the CLI reference page (reference/cli.md) generated at build time from the typer app itself
(``typer.main.get_command``), so every command and every option is listed as ``steval --help`` has it.

Written here rather than with mkdocs-click: typer ≥ 0.25 builds its commands on its own vendored click, which
mkdocs-click does not recognise; walking the command tree's parameters takes a few lines.
"""

from __future__ import annotations

import re

MARKER = "<!-- steval-cli -->"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, cli_markdown())


def cli_markdown() -> str:
    """Markdown of every ``steval`` command: usage, help, and a table of its arguments and options."""
    import typer.main

    from steval_link.cli import register

    root = typer.main.get_command(register())
    out: list[str] = []
    for name, cmd in sorted(root.commands.items()):
        if getattr(cmd, "hidden", False):
            continue
        subs = getattr(cmd, "commands", None)
        if subs:
            out += [f"## steval {name}", "", _text(cmd.help), ""]
            for sub, subcmd in sorted(subs.items()):
                out += _command(f"steval {name} {sub}", subcmd, level="###")
        else:
            out += _command(f"steval {name}", cmd, level="##")
    return "\n".join(out)


def _command(path: str, cmd, level: str) -> list[str]:
    ctx = cmd.context_class(cmd, info_name=path)
    params = [p for p in cmd.params if not getattr(p, "hidden", False)]
    args = " ".join(_metavar(p, ctx) if p.required else f"[{_metavar(p, ctx)}]" for p in params if _is_argument(p))
    lines = [f"{level} {path}", "", f"`{f'{path} [OPTIONS] {args}'.rstrip()}`", ""]
    lines += [_text(cmd.help), ""]
    lines += ["| argument or option | value | default | what |", "|---|---|---|---|"]
    for p in params:
        names = p.name.upper() if _is_argument(p) else ", ".join(p.opts + p.secondary_opts)
        value = "" if getattr(p, "is_flag", False) else _metavar(p, ctx)
        lines.append(f"| `{names}` | {_cell(value)} | {_cell(_default(p))} | {_cell(_text(getattr(p, 'help', '')))} |")
    lines.append("| `-h`, `--help` |  |  | Show the help and exit. |")
    return lines + [""]


def _is_argument(p) -> bool:
    return type(p).__name__.endswith("Argument")


def _metavar(p, ctx) -> str:
    if p.metavar:
        return p.metavar
    if _is_argument(p):
        return p.name.upper() + ("..." if p.nargs == -1 else "")
    display = getattr(p, "display_type", None)  # typer's own parameters
    if callable(display):
        return display(ctx).strip("<>").upper()
    return getattr(getattr(p, "type", None), "name", "value").upper()


def _default(p) -> str:
    if not getattr(p, "show_default", True) or p.default is None or getattr(p, "is_flag", False):
        return ""
    if isinstance(p.default, (list, tuple)):
        return " ".join(str(v) for v in p.default)
    return str(p.default)


def _text(text: str | None) -> str:
    """Typer's rich-markup escapes undone, paragraphs kept."""
    text = (text or "").replace("\\[", "[")
    paragraphs = [" ".join(par.split()) for par in re.split(r"\n\s*\n", text)]
    return "\n\n".join(par for par in paragraphs if par)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n\n", "<br>")

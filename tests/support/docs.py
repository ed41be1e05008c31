"""The README and the documentation pages as the tests read them: their text and their code blocks."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def doc_text(rel: str) -> str:
    """The text of ``rel`` (``README.md``, ``docs/howto/spectra.md``), relative to the project root."""
    return (ROOT / rel).read_text(encoding="utf-8")


def doc_pages() -> list[Path]:
    """README.md and every Markdown page under docs/."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def code_blocks(text: str, lang: str) -> list[str]:
    """The bodies of the fenced ``lang`` code blocks of ``text``, in order (indented fences too)."""
    blocks = []
    for m in re.finditer(rf"^( *)```{re.escape(lang)}\n(.*?)^\1```", text, re.S | re.M):
        indent = len(m.group(1))
        blocks.append("\n".join(line[indent:] for line in m.group(2).splitlines()))
    return blocks

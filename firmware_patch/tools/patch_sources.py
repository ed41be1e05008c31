"""The patch's added files: our modules (firmware_patch/src) as new files of ST's release, where its CubeIDE project
compiles them (``.c`` in ``Src/``, linked in ``CubeIDE/STEVAL-FCU/.project``; ``.h`` in ``Inc/``, on its include
path). This script rewrites those hunks of st-fcu-170120.patch from src/ (``make patch``) or checks them
(``--check``, exit 1 when they differ); the hunks that change ST's files are kept as they are.

Usage: python tools/patch_sources.py [--check]   (from anywhere)
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
PATCH = HERE / "st-fcu-170120.patch"
SRC = HERE / "src"
BASE = "STM32 FW Project/Official release - 170120/"
#: our modules the firmware compiles (host-only helpers stay out)
MODULES = ("stv_cmd", "stv_frame", "stv_fw", "stv_link", "stv_txq")
HEADERS = ("stv_cmd", "stv_config", "stv_crc_tables", "stv_frame", "stv_fw", "stv_link", "stv_txq")


def sources() -> dict[str, bytes]:
    """Path in ST's tree -> bytes of our file, for every file the patch adds."""
    out = {f"{BASE}Src/{m}.c": (SRC / f"{m}.c").read_bytes() for m in MODULES}
    out.update({f"{BASE}Inc/{h}.h": (SRC / f"{h}.h").read_bytes() for h in HEADERS})
    return dict(sorted(out.items()))


def split(text: str) -> list[tuple[str, str]]:
    """(path, diff text) of each file in a git patch."""
    parts = re.split(r"(?m)^(?=diff --git )", text)
    out = []
    for p in parts:
        if p.startswith("diff --git "):
            path = re.match(r"diff --git a/(.+?) b/", p).group(1)
            out.append((path, p))
    return out


def new_file_diff(path: str, data: bytes) -> str:
    text = data.decode("utf-8")
    lines = text.splitlines(keepends=True)
    body = "".join("+" + ln for ln in lines)
    if lines and not lines[-1].endswith("\n"):
        body += "\n\\ No newline at end of file\n"
    return (
        f"diff --git a/{path} b/{path}\nnew file mode 100644\n--- /dev/null\n+++ b/{path}\n"
        f"@@ -0,0 +1,{len(lines)} @@\n{body}"
    )


def added(text: str) -> dict[str, bytes]:
    """The files a patch adds, as their bytes."""
    out = {}
    for path, diff in split(text):
        if "\nnew file mode" not in diff.split("@@", 1)[0]:
            continue
        body = diff.split("\n@@", 1)[1].split("\n", 1)[1]
        data = "".join(ln[1:] + "\n" for ln in body.splitlines() if ln.startswith("+"))
        if body.rstrip("\n").endswith("\\ No newline at end of file"):
            data = data[:-1]
        out[path] = data.encode("utf-8")
    return out


def rebuild(text: str) -> str:
    """The patch with ST's file hunks as they are and the added files from src/."""
    kept = [d for _p, d in split(text) if "\nnew file mode" not in d.split("@@", 1)[0]]
    return "".join(kept) + "".join(new_file_diff(p, b) for p, b in sources().items())


def main(argv: list[str]) -> int:
    text = PATCH.read_text(encoding="utf-8")
    if "--check" in argv:
        if added(text) != sources():
            print(
                f"{PATCH.name}: the added files differ from src/ (run: make -C firmware_patch patch)", file=sys.stderr
            )
            return 1
        return 0
    new = rebuild(text)
    if new != text:
        PATCH.write_text(new, encoding="utf-8")
        print(f"{PATCH.name}: added files rewritten from src/")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""Shared by the firmware-in-the-loop tests and benchmarks: build the reference firmware
(``make -C firmware_patch reference``, firmware_patch/reference) and say why it cannot be built here."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware_patch"
sys.path.insert(0, str(FW / "tools"))
import stv_emu  # noqa: E402  (firmware_patch/tools: the emulated target harness and its tool checks)

#: the ELF ``make reference`` writes under its BUILD_DIR
ELF = Path("reference") / "steval-reference.elf"


def missing() -> str | None:
    """Why the reference firmware cannot be built and emulated here (None when it can). In CI (CI=true) always
    None: there the tests must fail on the missing tool (build_reference says which), never skip."""
    if os.environ.get("CI"):
        return None
    return stv_emu.missing_tools()  # the toolchain, newlib-nano and unicorn


def build_reference(build_dir: Path, *options: str) -> Path:
    """``make -C firmware_patch reference BUILD_DIR=build_dir options`` (e.g. ``"AHRS_KI=1.0f"``); returns the ELF."""
    why = stv_emu.missing_tools()
    if why:
        raise RuntimeError(f"cannot build the reference firmware: {why}")
    r = subprocess.run(
        ["make", "-s", "-C", str(FW), "reference", f"BUILD_DIR={Path(build_dir).resolve()}", "-j2", *options],
        capture_output=True,
        text=True,
    )
    if r.returncode != 0:
        raise RuntimeError(f"make reference failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return Path(build_dir).resolve() / ELF

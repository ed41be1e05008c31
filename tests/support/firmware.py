"""Shared by the firmware-in-the-loop tests and benchmarks: build ST's firmware (patched or stock) from
``../shared/st-fcu-f401`` into a temporary copy, with the reasons to skip when that cannot be done here."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware_patch"
ST_SHARED = ROOT.parent / "shared" / "st-fcu-f401"
ST_SUBDIR = Path("STM32 FW Project") / "Official release - 170120"


def missing() -> str | None:
    """Why the real firmware cannot be built and emulated here (None when it can)."""
    if not (ST_SHARED / ST_SUBDIR / "Src" / "main.c").is_file():
        return f"ST's firmware sources are not at {ST_SHARED} (../shared beside the project)"
    for tool in ("arm-none-eabi-gcc", "make", "git"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (Debian: apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi make)"
    libc = subprocess.run(["arm-none-eabi-gcc", "-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard",
                           "-mfpu=fpv4-sp-d16", "-print-file-name=libc_nano.a"], capture_output=True, text=True)
    if "/" not in libc.stdout:
        return "newlib-nano for arm-none-eabi is not installed (Debian: apt-get install libnewlib-arm-none-eabi)"
    try:
        import unicorn  # noqa: F401
    except ImportError:
        return "unicorn is not installed (pip install unicorn)"
    return None


def st_copy(dest: Path, *, patched: bool = True) -> Path:
    """A temporary copy of ST's release folder (as in ST's repository), with our patch applied when asked."""
    work = dest / ("st-patched" if patched else "st-stock")
    shutil.copytree(ST_SHARED / ST_SUBDIR, work / ST_SUBDIR)
    if patched:
        subprocess.run(["git", "init", "-q"], cwd=work, check=True)
        subprocess.run(["git", "apply", str(FW / "st-fcu-170120.patch")], cwd=work, check=True)
    return work


def build(st_dir: Path, build_dir: Path, *options: str, target: str = "firmware") -> Path:
    """``make -C firmware_patch <target> ST_DIR=... BUILD_DIR=... options``; returns the ELF."""
    r = subprocess.run(["make", "-s", "-C", str(FW), target, f"ST_DIR={st_dir}", f"BUILD_DIR={build_dir}", "-j2",
                        *options], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"make {target} failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    sub = "fw" if target == "firmware" else "stock"
    return next((build_dir / sub).glob("*.elf"))

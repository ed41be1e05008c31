"""Shared by the firmware-in-the-loop tests and benchmarks: build ST's firmware (patched or stock) from
``../shared/st-fcu-f401`` into a temporary copy, with the reasons to skip when that cannot be done here."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware_patch"
ST_SHARED = ROOT.parent / "shared" / "st-fcu-f401"
ST_SUBDIR = Path("STM32 FW Project") / "Official release - 170120"
sys.path.insert(0, str(FW / "tools"))
import stv_emu  # noqa: E402  (firmware_patch/tools: the emulated target harness and its tool checks)


def missing() -> str | None:
    """Why the real firmware cannot be built and emulated here (None when it can)."""
    if not (ST_SHARED / ST_SUBDIR / "Src" / "main.c").is_file():
        return f"ST's firmware sources are not at {ST_SHARED} (../shared beside the project)"
    if shutil.which("git") is None:
        return "git is not installed (the patch is applied with git apply)"
    return stv_emu.missing_tools()  # the toolchain, newlib-nano and unicorn, as the emulated target tests need


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


#: the mixer's lines in ST's flight_control.c whose outputs a "swapped motors" build exchanges
MIXER_FILE = ST_SUBDIR / "Src" / "flight_control.c"


def swap_motor_outputs(st_dir: Path, a: int = 3, b: int = 4) -> None:
    """Edit the copy's mixer so that outputs ``a`` and ``b`` carry each other's line (``motor_pwm->motor3_pwm =``
    becomes ``motor_pwm->motor4_pwm =`` and back): the motor order of a mixer renumbered for another frame, e.g.
    Betaflight's Quad-X order (3 rear left, 4 front left) where ST has 3 front left, 4 rear left. The same edit
    as recordings/make_recordings.sh makes for preflight_swapped_motors.stv."""
    path = st_dir / MIXER_FILE
    text = path.read_text(encoding="latin-1")
    pa, pb = f"motor_pwm->motor{a}_pwm =", f"motor_pwm->motor{b}_pwm ="
    assert text.count(pa) == 2 and text.count(pb) == 2, "ST's mixer lines not found"
    text = text.replace(pa, "@@A@@").replace(pb, pa).replace("@@A@@", pb)
    path.write_text(text, encoding="latin-1")

"""Run the cross-compiled firmware encoder (``make emu``: build/emu/stv_emu.elf) under unicorn (Cortex-M4).

Used by ``tests/test_firmware_emu.py`` and ``benchmarks/bench_firmware.py``: frame requests in, the bytes the
target build makes out, and the instructions executed per ``stv_send_attitude`` / ``stv_send_status`` call.
"""

from __future__ import annotations

import shutil
import struct
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

FIRMWARE_PATCH = Path(__file__).resolve().parents[1]
FLASH_BASE, FLASH_SIZE = 0x08000000, 256 * 1024
RAM_BASE, RAM_SIZE = 0x20000000, 64 * 1024
SCS_BASE, SCS_SIZE = 0xE0000000, 0x100000
EMU_IN_SIZE = 16384


def missing_tools() -> str | None:
    """Why the emulated target check cannot run here (None when it can)."""
    if shutil.which("arm-none-eabi-gcc") is None:
        return "arm-none-eabi-gcc is not installed (Debian: apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi)"
    if shutil.which("make") is None:
        return "make is not installed"
    libc = subprocess.run(
        [
            "arm-none-eabi-gcc",
            "-mcpu=cortex-m4",
            "-mthumb",
            "-mfloat-abi=hard",
            "-mfpu=fpv4-sp-d16",
            "-print-file-name=libc_nano.a",
        ],
        capture_output=True,
        text=True,
    )
    if "/" not in libc.stdout:
        return "newlib-nano for arm-none-eabi is not installed (Debian: apt-get install libnewlib-arm-none-eabi)"
    try:
        import unicorn  # noqa: F401
    except ImportError:
        return "unicorn is not installed (pip install unicorn)"
    return None


def build_emu(build_dir: Path) -> Path:
    """``make emu`` into build_dir; returns the ELF path."""
    subprocess.run(
        ["make", "-s", "-C", str(FIRMWARE_PATCH), "emu", f"BUILD_DIR={build_dir}"],
        check=True,
        capture_output=True,
    )
    return Path(build_dir) / "emu" / "stv_emu.elf"


def _load_segments(elf: bytes) -> list[tuple[int, bytes]]:
    """(address, bytes) of each PT_LOAD segment of a 32-bit little-endian ELF, at its run (virtual) address."""
    assert elf[:4] == b"\x7fELF" and elf[4] == 1 and elf[5] == 1, "not a 32-bit little-endian ELF"
    (e_phoff,) = struct.unpack_from("<I", elf, 28)
    e_phentsize, e_phnum = struct.unpack_from("<HH", elf, 42)
    out = []
    for i in range(e_phnum):
        p_type, p_offset, p_vaddr, _paddr, p_filesz, _memsz, _flags, _align = struct.unpack_from(
            "<8I", elf, e_phoff + i * e_phentsize
        )
        if p_type == 1 and p_filesz:
            out.append((p_vaddr, elf[p_offset : p_offset + p_filesz]))
    return out


def _symbols(elf_path: Path) -> dict[str, int]:
    nm = subprocess.run(["arm-none-eabi-nm", str(elf_path)], check=True, capture_output=True, text=True).stdout
    syms = {}
    for line in nm.splitlines():
        parts = line.split()
        if len(parts) == 3:
            syms[parts[2]] = int(parts[0], 16)
    return syms


@dataclass
class EmuResult:
    output: bytes
    rc: int
    instructions_total: int
    #: instructions of each call of a counted function, by function name
    calls: dict[str, list[int]] = field(default_factory=dict)


class TargetEncoder:
    """The target build of the encoder + TX queue in an emulated Cortex-M4."""

    def __init__(self, elf_path: Path):
        from unicorn import UC_ARCH_ARM, UC_MODE_MCLASS, UC_MODE_THUMB, Uc

        self.elf_path = Path(elf_path)
        self.syms = _symbols(self.elf_path)
        self.segments = _load_segments(self.elf_path.read_bytes())
        self._Uc = (Uc, UC_ARCH_ARM, UC_MODE_THUMB | UC_MODE_MCLASS)

    def _machine(self):
        import unicorn
        from unicorn.arm_const import UC_ARM_REG_LR, UC_ARM_REG_SP

        Uc, arch, mode = self._Uc
        mu = Uc(arch, mode)
        try:
            mu.ctl_set_cpu_model(unicorn.arm_const.UC_CPU_ARM_CORTEX_M4)
        except Exception:  # older unicorn: default M-profile model
            pass
        mu.mem_map(FLASH_BASE, FLASH_SIZE)
        mu.mem_map(RAM_BASE, RAM_SIZE)
        for addr, data in self.segments:
            mu.mem_write(addr, data)
        mu.reg_write(UC_ARM_REG_SP, RAM_BASE + RAM_SIZE)
        mu.reg_write(UC_ARM_REG_LR, self.syms["emu_halt"] | 1)
        return mu

    def run(
        self,
        requests: bytes,
        count: tuple[str, ...] = ("stv_send_attitude", "stv_send_status"),
        entry: str = "emu_run",
    ) -> EmuResult:
        """Run frame requests (``u8 type, u8 len, payload``) through the target code; count instructions.

        ``entry="emu_run_link"`` instead runs the main-loop side (``stv_link_step_begin/_end``) over steps of
        40 bytes each (f32 acc[3], gyro[3], q[4]).
        """
        from unicorn import UC_HOOK_CODE
        from unicorn.arm_const import UC_ARM_REG_LR

        if len(requests) > EMU_IN_SIZE:
            raise ValueError(f"at most {EMU_IN_SIZE} request bytes per run")
        mu = self._machine()
        s = self.syms
        mu.mem_write(s["emu_in"], requests)
        mu.mem_write(s["emu_in_len"], struct.pack("<I", len(requests)))
        entries = {s[name] & ~1: name for name in count}
        calls: dict[str, list[int]] = {name: [] for name in count}
        state = {"total": 0, "name": None, "ret": 0, "n": 0}

        def hook(uc, address, size, user):
            state["total"] += 1
            if state["name"] is not None:
                if address == state["ret"]:
                    calls[state["name"]].append(state["n"])
                    state["name"] = None
                else:
                    state["n"] += 1
                    return
            name = entries.get(address)
            if name is not None:
                state["name"] = name
                state["ret"] = uc.reg_read(UC_ARM_REG_LR) & ~1
                state["n"] = 1

        mu.hook_add(UC_HOOK_CODE, hook)
        halt = s["emu_halt"] & ~1
        mu.emu_start(s[entry] | 1, halt, count=50_000_000)
        (n_out,) = struct.unpack("<I", mu.mem_read(s["emu_out_len"], 4))
        (rc,) = struct.unpack("<i", mu.mem_read(s["emu_rc"], 4))
        out = bytes(mu.mem_read(s["emu_out"], n_out))
        return EmuResult(output=out, rc=rc, instructions_total=state["total"], calls=calls)

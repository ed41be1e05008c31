"""The emulated board's output does not change: a short run's USART1 bytes and attitude frames have the digests
recorded for this ELF in tests/data/emulate_digests.json (ELF sha256 → runs), and its instructions per AHRS step are
within 1 % of the recorded ones.

The ELF: ``STEVAL_DIGEST_ELF`` (a path), else the reference firmware (``make -C firmware_patch reference``), built
here into a temporary folder. An ELF whose digests were never recorded fails in CI, with its digests printed: record
them, with a reason, by ``python tests/support/emulate_digest.py ELF --record REASON`` (on the board before a change
that must not alter the output)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from support import emulate_digest as D

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[1]
FW = ROOT / "firmware_patch"


def _elf(tmp_path_factory, *options: str) -> Path:
    env = os.environ.get("STEVAL_DIGEST_ELF")
    if env and not options:
        return Path(env)
    why = None
    if shutil.which("arm-none-eabi-gcc") is None:
        why = "arm-none-eabi-gcc is not installed"
    elif "reference:" not in (FW / "Makefile").read_text(encoding="utf-8"):
        why = "firmware_patch/Makefile has no reference target"
    if why is None:
        build = tmp_path_factory.mktemp("digest-ref")
        r = subprocess.run(
            ["make", "-s", "-C", str(FW), "reference", f"BUILD_DIR={build}", "-j2", *options],
            capture_output=True,
            text=True,
        )
        elfs = sorted((build / "reference").glob("*.elf"))
        if r.returncode == 0 and elfs:
            return elfs[0]
        why = f"make reference failed: {(r.stdout + r.stderr)[-500:]}"
    if os.environ.get("CI") == "true":
        pytest.fail(f"no ELF for the digest test: {why}")
    pytest.skip(f"no ELF for the digest test: {why}")


def _need_core() -> None:
    pytest.importorskip("unicorn")
    from steval_link.emulation.board import core_library  # reason: after the unicorn check

    if core_library() is None:  # the digests are of the C core's per-instruction clock
        if os.environ.get("CI") == "true":
            pytest.fail("the board's C core (steval_link.emulation._core) is not built")
        pytest.skip("the board's C core is not built (no C compiler at install)")


@pytest.fixture(scope="module")
def elf(tmp_path_factory) -> Path:
    _need_core()
    return _elf(tmp_path_factory)


@pytest.fixture(scope="module")
def printf_elf(tmp_path_factory) -> Path:
    """The reference firmware printing a text line per loop pass by blocking transmit (TXE/TC polling)."""
    _need_core()
    return _elf(tmp_path_factory, "PRINTF_EVERY_LOOP=1")


@pytest.mark.parametrize("run", D.TEST_RUNS)
def test_the_firmware_output_is_the_recorded_one(elf, run):
    _check(elf, run)


def test_a_blocking_printf_build_is_the_recorded_one(printf_elf):
    """Its polling loops are where the board skips whole passes: the bytes and their times must not change."""
    _check(printf_elf, "hand-tilts")


def _check(elf: Path, run: str) -> None:
    table = json.loads(D.DIGESTS.read_text(encoding="utf-8"))
    sha = D.elf_sha256(elf)
    got = D.run(elf, run)
    want = table.get(sha, {}).get("runs", {}).get(run)
    if want is None:
        msg = (
            f"no digests recorded for {elf.name} (sha256 {sha}), run {run!r}: got {json.dumps(got)}. Record them "
            f"with a reason: python tests/support/emulate_digest.py {elf} --runs {run} --record 'REASON'"
        )
        if os.environ.get("CI") == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    steps = got.pop("step_instructions_median"), want.get("step_instructions_median")
    assert got == {k: v for k, v in want.items() if k != "step_instructions_median"}
    if steps[1]:
        assert abs(steps[0] - steps[1]) <= 0.01 * steps[1], f"instructions per AHRS step {steps[0]} vs {steps[1]}"


def test_the_poll_skip_changes_no_byte_and_no_instruction_count(printf_elf):
    """The same run with the C core's TXE/TC poll skip off and on: the same bytes, the same instruction counts."""
    from steval_link.emulation.runner import Emulation, EmulationOptions  # reason: after the C core check

    out = []
    for skip in (0, 1):
        emu = Emulation(EmulationOptions(elf=printf_elf, scenario="hand-tilts", duration_s=4.0, seed=3))
        emu.board.st.poll_skip = skip
        stream = emu.run()
        rep = emu.report()
        out.append((stream, rep.step_instructions, rep.instructions, emu.board.st.polled))
    assert out[0][0] and out[0][:3] == out[1][:3]
    assert out[0][3] == 0 and out[1][3] > out[1][2] // 2  # most of the executed instructions were polling passes


@pytest.mark.parametrize("throttle", [None, "0:0,4:0,4.5:600"])
def test_planned_ticks_change_no_byte_and_no_instruction_count(elf, throttle):
    """TIM9 updates applied by the C core from the runner's tables, and each through Python: the same bytes, the same
    instruction counts (with a throttle the remote connects at its first move, mid-run)."""
    from steval_link.emulation.runner import Emulation, EmulationOptions  # reason: after the C core check

    out = []
    for planned in (False, True):
        emu = Emulation(EmulationOptions(elf=elf, scenario="hand-tilts", duration_s=6.0, seed=3, throttle=throttle))
        calls = []
        emu.board.tick_observers[0] = lambda board, tick=emu._on_tick: (calls.append(1), tick(board))
        if not planned:
            emu.board.tick_planner = None
        stream = emu.run()
        rep = emu.report()
        out.append(
            (stream, rep.step_instructions, rep.instructions, rep.interrupts, len(calls), emu.board.tim9.updates)
        )
    assert out[0][0] and out[0][:4] == out[1][:4]
    assert out[0][4] == out[0][5] > 4000 and out[1][4] < out[0][4] // 100  # planned: Python at a few updates only

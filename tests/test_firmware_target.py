"""The firmware module as the Cortex-M4 gets it: strict cross-compile, and the target build's bytes under emulation.

CI installs Debian's arm-none-eabi-gcc (``.ci/run``) and unicorn (test extra); on a machine without them these
tests skip with the reason.
"""

from __future__ import annotations

import re
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from steval_link.link import protocol as P
from steval_link.link.decoder import StreamDecoder

ROOT = Path(__file__).resolve().parents[1]
FW = ROOT / "firmware_patch"
sys.path.insert(0, str(FW / "tools"))
import stv_emu  # noqa: E402

NO_ARM = shutil.which("arm-none-eabi-gcc") is None or shutil.which("make") is None
needs_arm = pytest.mark.skipif(NO_ARM, reason="arm-none-eabi-gcc (Debian: gcc-arm-none-eabi) or make not installed")


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_arm
@pytest.mark.parametrize(
    "options",
    [
        [],
        ["BAUD=921600", "TEXT_MODE=1", "TEXT_DECIMATION=8", "AHRS_KI=1.0f", "NO_CORRECTION=1", "INFLIGHT_TUNING=1"],
    ],
    ids=["default", "text-ki1-nocorr-921600"],
)
def test_cross_compile_strict(tmp_path, options):
    """-mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard -O2 -Wall -Wextra -Werror, every module."""
    r = subprocess.run(
        ["make", "-C", str(FW), "cross", f"BUILD_DIR={tmp_path}", *options], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stdout + r.stderr
    for flag in ("-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-O2", "-Werror"):
        assert flag in r.stdout
    objs = sorted(p.name for p in (tmp_path / "arm").glob("*.o"))
    assert objs == ["stv_cmd.o", "stv_frame.o", "stv_fw.o", "stv_link.o", "stv_txq.o"]
    # hard-float EABI objects for the M4
    attrs = subprocess.run(
        ["arm-none-eabi-readelf", "-A", str(tmp_path / "arm" / "stv_link.o")], capture_output=True, text=True
    ).stdout
    assert "Tag_CPU_arch: v7E-M" in attrs and "Tag_ABI_VFP_args: VFP registers" in attrs


@pytest.fixture(scope="module")
def target(tmp_path_factory):
    why = stv_emu.missing_tools()
    if why:
        pytest.skip(why)
    elf = stv_emu.build_emu(tmp_path_factory.mktemp("fw-emu"))
    return stv_emu.TargetEncoder(elf)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_target_build_bytes_decode_in_python(target):
    """Requests -> target code (Thumb-2, hard-float) under unicorn -> frames identical to steval_link.link.protocol's,
    decoded by StreamDecoder back to the exact payloads (CRC, ATTITUDE_DTYPE/STATUS_DTYPE)."""
    rng = np.random.default_rng(99)
    req, exp, payloads = bytearray(), bytearray(), []
    for i in range(150):
        if i % 10 == 9:
            payload = rng.integers(0, 256, P.STATUS_PAYLOAD_SIZE, dtype=np.uint8).tobytes()
            ftype = P.TYPE_STATUS
        elif i % 25 == 12:
            payload = bytes(rng.integers(32, 127, int(rng.integers(0, 256)), dtype=np.uint8))
            ftype = P.TYPE_TEXT
        else:
            payload = rng.integers(0, 256, P.ATTITUDE_PAYLOAD_SIZE, dtype=np.uint8).tobytes()
            ftype = P.TYPE_ATTITUDE
        req += bytes([ftype, len(payload)]) + payload
        exp += P.encode_frame(ftype, payload) if payload or ftype != P.TYPE_TEXT else P.encode_text("")
        payloads.append((ftype, payload))
    res = target.run(bytes(req))
    assert res.rc == 0
    assert res.output == bytes(exp)
    dec = StreamDecoder(plausibility=False)
    frames = dec.feed(res.output) + dec.finish()
    assert dec.stats.bytes_skipped == 0 and dec.stats.crc_failures == 0
    assert len(frames) == len(payloads)
    # attitude payloads: field by field through ATTITUDE_DTYPE, exact bits
    att_in = np.frombuffer(b"".join(p for t, p in payloads if t == P.TYPE_ATTITUDE), P.ATTITUDE_DTYPE)
    att_out = [f for f in frames if type(f).__name__ == "AttitudeFrame"]
    assert len(att_out) == len(att_in)
    for f, r in zip(att_out, att_in):
        assert f.t_us == r["t_us"] and f.seq == r["seq"] and f.thr == r["thr"]
        got = np.array([*f.acc_mg, *f.gyro_mdps, *f.q_wxyz, f.thz_rad], np.float32)
        want = np.concatenate([r["acc_mg"], r["gyro_mdps"], r["q_wxyz"], [r["thz_rad"]]]).astype(np.float32)
        finite = np.isfinite(want)
        assert got[finite].view(np.uint32).tolist() == want[finite].view(np.uint32).tolist()
        assert np.isnan(got[~finite]).tolist() == np.isnan(want[~finite]).tolist()
    # every attitude call counted (the benchmark's instruction figure comes from here)
    assert len(res.calls["stv_send_attitude"]) == len(att_in)
    assert all(n > 50 for n in res.calls["stv_send_attitude"])


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_target_and_host_builds_agree(target, tmp_path):
    """The host build (stv_encode, used for the bundled recordings) and the target build emit identical bytes."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    subprocess.run(
        ["make", "-s", "-C", str(FW), f"BUILD_DIR={tmp_path}", f"{tmp_path}/host/stv_encode"],
        check=True,
        capture_output=True,
    )
    rng = np.random.default_rng(5)
    req = b"".join(bytes([1, 52]) + rng.integers(0, 256, 52, dtype=np.uint8).tobytes() for _ in range(100))
    req += bytes([3, 0]) + bytes([2, 88]) + bytes(range(88))
    host = subprocess.run([tmp_path / "host" / "stv_encode"], input=req, capture_output=True, check=True).stdout
    assert target.run(req).output == host


def test_patch_is_small_and_touches_only_hook_points():
    """The ST patch carries our hooks plus git's few context lines, nothing else of ST's code; the rest is our own
    files added."""
    text = (FW / "st-fcu-170120.patch").read_text()
    diffs = re.split(r"(?m)^(?=diff --git )", text)[1:]
    base = "STM32 FW Project/Official release - 170120/"
    changed = [re.match(r"diff --git a/(.+?) b/", d).group(1) for d in diffs if "\nnew file mode" not in d[:300]]
    assert changed == [
        base + f
        for f in (
            "CubeIDE/STEVAL-FCU/.project",
            "Inc/ahrs.h",
            "Src/ahrs.c",
            "Src/debug.c",
            "Src/main.c",
            "Src/stm32f4xx_it.c",
        )
    ]
    total_context: list[str] = []
    for d in diffs:
        if "\nnew file mode" in d[:300]:
            continue
        for hunk in re.split(r"^@@.*@@.*$", d, flags=re.M)[1:]:
            body = [
                ln for ln in hunk.splitlines() if ln and not ln.startswith(("diff --git", "index ", "--- ", "+++ "))
            ]
            context = [ln for ln in body if ln.startswith(" ")]
            assert len(context) <= 12, hunk  # 3 lines before and after, plus the few lines between two hooks
            total_context.extend(context)
    assert len(total_context) <= 80
    assert "stv_fw_step_begin(gTHR)" in text and "stv_fw_step_end(" in text and "stv_fw_usart1_irq()" in text


def test_patch_adds_our_sources_byte_identical():
    """The files the patch adds (Src/*.c linked in CubeIDE's .project, Inc/*.h) are firmware_patch/src byte for byte
    (make -C firmware_patch patch rewrites them), and every added .c is linked in the CubeIDE project."""
    sys.path.insert(0, str(FW / "tools"))
    import patch_sources as PS

    text = (FW / "st-fcu-170120.patch").read_text()
    added = PS.added(text)
    assert added == PS.sources()
    assert {Path(p).name for p in added} >= {"stv_fw.c", "stv_fw.h", "stv_config.h", "stv_crc_tables.h"}
    for p in added:
        if p.endswith(".c"):
            name = Path(p).name
            assert f"+\t\t\t<name>Application/User/{name}</name>" in text
            assert f"+\t\t\t<locationURI>PARENT-2-PROJECT_LOC/Src/{name}</locationURI>" in text
    r = subprocess.run([sys.executable, str(FW / "tools" / "patch_sources.py"), "--check"], capture_output=True)
    assert r.returncode == 0, r.stderr


def test_target_text_mode_lines_match_python(target):
    """Text mode on the target (hardware float -> int): $ATT lines identical to steval_link.link.textmode's."""
    from steval_link.link.textmode import format_att

    rng = np.random.default_rng(3)
    n = 200
    recs, expect = [], b""
    rad2mdeg = np.float32(57295.78)
    for i in range(n):
        step, t_us, thr = int(rng.integers(0, 1 << 32)), int(rng.integers(0, 1 << 32)), int(rng.integers(-32768, 32768))
        ang = rng.uniform(-np.pi, np.pi, 3).astype(np.float32)
        acc = rng.uniform(-16000, 16000, 3).astype(np.float32)
        gyro = rng.uniform(-2e6, 2e6, 3).astype(np.float32)
        recs.append(
            struct.pack("<IIi", step, t_us, thr) + np.concatenate([ang, acc, gyro]).astype(np.float32).tobytes()
        )
        mdeg = [int(np.trunc(a * rad2mdeg)) for a in ang]  # float32 product, rounded toward zero
        expect += format_att(
            step=step,
            t_ms=t_us // 1000,
            thr=thr,
            thx_mdeg=mdeg[0],
            thy_mdeg=mdeg[1],
            thz_mdeg=mdeg[2],
            acc_mg=[int(np.trunc(x)) for x in acc],
            gyro_mdps=[int(np.trunc(x)) for x in gyro],
        )
    res = target.run(b"".join(recs), count=(), entry="emu_run_text")
    assert res.output == expect
    # out of int32 range saturates, NaN gives 0 (never undefined behaviour on the drone)
    sat = (
        struct.pack("<IIi", 1, 2000, 0)
        + np.array([0, 0, 0, 3e9, -3e9, np.nan, np.inf, -np.inf, 0], np.float32).tobytes()
    )
    line = target.run(sat, count=(), entry="emu_run_text").output
    assert line.split(b"*")[0] == b"$ATT,1,2,0,0,0,0,2147483647,-2147483648,0,2147483647,-2147483648,0"

"""A reference-firmware build whose filter goes NaN after N steps is scored with its coverage (issue #31):
``steval evaluate --firmware`` marks it, gives no plain mean and says the step; ``USER_CFLAGS`` reaches the
reference build (the switch that turns the NaN on is the student's own define, in a copy of ``ahrs.c``)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from support.cli import run_cli

try:
    from support import firmware as S
except ImportError:  # pragma: no cover - the support package always exists in this repo
    S = None

TRIAL = "07_undisturbed_fast_rotation_B.npz"
#: seconds of the trial: its movement starts at 26.5 s (AHRS step ≈ 4000)
CUT_S = 32.0
#: the step from which the copy's filter is NaN (inside the movement)
NAN_AFTER = 4400

#: added to a copy of reference/ahrs.c, after the normalisation: q0 = NaN from step NAN_AFTER on, only under the define
NAN_HOOK = """
#ifdef MY_TWEAK
  q0 = q0 * 1.00001f; /* a student's small change: the filter is no longer release 170120's */
#endif
#ifdef MY_NAN_AFTER
  {
    static unsigned long my_steps;
    if (++my_steps > MY_NAN_AFTER) q0 = __builtin_nanf("");
  }
#endif
  q_out->q0 = q0;"""


def _copy_with_hook(tmp_path: Path) -> Path:
    """firmware_patch copied to ``tmp_path`` with the NaN hook in its ahrs.c (the repository is left as it is)."""
    if S is None or S.missing():
        pytest.skip(S.missing() if S is not None else "no firmware support")
    fw = tmp_path / "firmware_patch"
    shutil.copytree(S.FW, fw, ignore=shutil.ignore_patterns("build", "*.o", "*.elf"))
    ahrs = fw / "reference" / "ahrs.c"
    src = ahrs.read_text()
    assert src.count("  q_out->q0 = q0;") == 1
    ahrs.write_text(src.replace("  q_out->q0 = q0;", NAN_HOOK, 1))
    return fw


def _make(fw: Path, build: Path, *options: str) -> Path:
    r = subprocess.run(
        ["make", "-s", "-C", str(fw), "reference", f"BUILD_DIR={build}", "-j2", *options],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return build / "reference" / "steval-reference.elf"


@pytest.mark.slow
def test_user_cflags_reach_the_reference_build(tmp_path):
    fw = _copy_with_hook(tmp_path)
    (fw / "reference" / "my_switch.c").write_text(
        "#ifndef USE_MY_EKF\n#error USE_MY_EKF is not defined\n#endif\nint my_switch_seen = USE_MY_EKF;\n"
    )
    r = subprocess.run(
        ["make", "-s", "-C", str(fw), "reference", f"BUILD_DIR={tmp_path / 'b0'}"], capture_output=True, text=True
    )
    assert r.returncode != 0 and "USE_MY_EKF is not defined" in r.stderr
    elf = _make(fw, tmp_path / "b1", "USER_CFLAGS=-DUSE_MY_EKF=7")
    assert elf.is_file() and (tmp_path / "b1" / "reference" / "options").read_text().strip().endswith("-DUSE_MY_EKF=7")


@pytest.mark.slow
def test_a_firmware_that_goes_nan_is_marked_with_its_step(monkeypatch, capsys, tmp_path, shared_dir):
    fw = _copy_with_hook(tmp_path)
    whole = _make(fw, tmp_path / "whole")
    nan = _make(fw, tmp_path / "nan", f"USER_CFLAGS=-DMY_NAN_AFTER={NAN_AFTER}")
    never = _make(fw, tmp_path / "build-never", "USER_CFLAGS=-DMY_NAN_AFTER=0")
    for name in ("ok", "gives-up", "never"):
        (tmp_path / name).mkdir()
    whole = shutil.copy(whole, tmp_path / "ok" / "fw.elf")
    nan = shutil.copy(nan, tmp_path / "gives-up" / "fw.elf")
    never = shutil.copy(never, tmp_path / "never" / "fw.elf")
    trial = shared_dir / "datasets" / "broad" / TRIAL
    png = tmp_path / "fw.png"
    args = ["evaluate", trial, "-e", "accel", "--firmware", whole, "--firmware", nan, "--firmware", never]
    args += ["--max-seconds", CUT_S]
    code, out, err = run_cli(monkeypatch, capsys, *args, "--json", "--plot", png)
    assert code == 0, err
    rep = json.loads(out)
    a, b = "fw:ok/fw.elf", "fw:gives-up/fw.elf"
    (t,) = rep["trials"]
    assert t["scored_fraction"][a] == 1.0 and 0 < t["scored_fraction"][b] < 1
    assert t["diverged_at_step"][b] == NAN_AFTER and t["diverged_at_step"][a] is None
    c = "fw:never/fw.elf"  # NaN throughout: no score, and the reason
    assert t["scored_fraction"][c] == 0 and t["rmse_deg"][c] is None
    assert t["no_score_reason"][c].startswith("its estimate is not finite on any of the")
    assert rep["incomplete"] == [b, c] and png.stat().st_size > 10_000
    fws = {f["firmware"]: f for f in rep["firmware"]}
    assert fws[b]["diverged_at_step"] == NAN_AFTER and fws[b]["scored_fraction"] == t["scored_fraction"][b]
    assert fws[a]["gains"].startswith("kp 10 (ground: thr < 200), ki 0.1")  # the gain it ran with, said
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 0, err
    assert f"{b} on {t['trial']}: scored on" in out and f"diverged at step {NAN_AFTER}" in out
    assert "ran with kp 10 (ground: thr < 200)" in out
    assert f"{c} on {t['trial']}: no score: its estimate is not finite on any of the" in out


@pytest.mark.slow
def test_a_clean_capture_of_a_modified_filter_gets_no_crc_hint(monkeypatch, capsys, tmp_path):
    """Skipped boot bytes are no damage: the hint about a corrupted frame that passes its CRC needs CRC failures."""
    fw = _copy_with_hook(tmp_path)
    elf = _make(fw, tmp_path / "tweak", "USER_CFLAGS=-DMY_TWEAK")
    cap = tmp_path / "tweak.stv"
    args = ["emulate", elf, "--scenario", "hand-tilts", "--duration", "8", "--out", cap, "--no-view", "-e", "none"]
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 0, err
    code, out, err = run_cli(monkeypatch, capsys, "compare", cap, "-e", "accel")
    assert code == 0, err
    assert "NOT bit-exact" in out and "0 CRC failures" in out
    assert "passes its CRC" not in out

"""``steval conformance`` over the shared firmware vectors, on modified firmware, and on bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.estimators.conformance import COLUMNS, check_conformance, load_conformance_csv
from steval_link.estimators.st_mahony import MahonySettings, run

CONFORMANCE_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "conformance" / "st-fcu-170120"
CSV_FILES = sorted(CONFORMANCE_DIR.glob("*.csv")) if CONFORMANCE_DIR.is_dir() else []
needs_shared = pytest.mark.skipif(not CSV_FILES, reason="shared conformance vectors (../shared) not present")
DIR_221117 = CONFORMANCE_DIR.parent / "st-fcu-221117"
CSV_221117 = sorted(DIR_221117.glob("*.csv")) if DIR_221117.is_dir() else []
needs_221117 = pytest.mark.skipif(not CSV_221117, reason="shared 221117 vectors (../shared) not present")


def write_vectors(path: Path, acc, gyro, thr, q, thx, thy, comment="# synthetic") -> Path:
    lines = [comment, ",".join(COLUMNS)]
    for k in range(len(thr)):
        vals = [*acc[k], *gyro[k], *q[k], thx[k], thy[k]]
        lines.append(f"{k},{int(thr[k])}," + ",".join(repr(float(v)) for v in vals))
    path.write_text("\n".join(lines) + "\n")
    return path


def modified_firmware_vectors(tmp_path: Path, settings: MahonySettings, n=400) -> Path:
    rng = np.random.default_rng(1)
    acc = rng.normal([0, 0, 1000], 200, size=(n, 3)).astype(np.float32)
    gyro = rng.normal(0, 20000, size=(n, 3)).astype(np.float32)
    thr = np.where(np.arange(n) < n // 2, 0, 450)
    q, thx, thy, _ = run(acc, gyro, thr, settings=settings)
    return write_vectors(tmp_path / "modified.csv", acc, gyro, thr, q, thx, thy)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_shared
def test_every_shared_vector_file_is_bit_exact(monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "conformance", "--json", *CSV_FILES)
    assert code == 0, err
    report = json.loads(out)
    assert report["ok"] is True
    assert [f["file"] for f in report["files"]] == [p.name for p in CSV_FILES]
    for f, path in zip(report["files"], CSV_FILES):
        rows = sum(1 for line in path.read_text().splitlines()[2:] if line.strip())
        assert f["steps"] == rows and f["bit_exact_steps"] == rows, f
        assert f["max_abs_dq"] == 0.0 and f["max_abs_dth_rad"] == 0.0 and f["first_mismatch_step"] is None


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_221117
@pytest.mark.parametrize("pure", [False, True])
def test_release_221117_is_recognised_and_bit_exact(monkeypatch, capsys, pure):
    """ST's 221117 binary's own vectors: every step bit-exact with 221117's filter, named from the data."""
    code, out, err = run_cli(monkeypatch, capsys, "conformance", "--json", *(["--pure"] if pure else []), DIR_221117)
    assert code == 0, err
    report = json.loads(out)
    total = sum(f["steps"] for f in report["files"])
    assert report["ok"] and report["filter"] == "ST 221117" and report["filter_from"] == "data"
    assert report["variant_bit_exact_steps"]["ST 221117"] == total > report["variant_bit_exact_steps"]["ST 170120"]
    assert all(f["bit_exact_steps"] == f["steps"] for f in report["files"])


@needs_221117
def test_a_forced_wrong_release_mismatches_and_says_so(monkeypatch, capsys):
    code, out, _ = run_cli(monkeypatch, capsys, "conformance", "--variant", "170318", DIR_221117 / "edge_cases.csv")
    assert code == 1 and "filter: ST 170120 (--variant)" in out
    code, _, err = run_cli(monkeypatch, capsys, "conformance", "--variant", "9999", DIR_221117)
    assert code == 2 and "--variant" in err and "no ST release" in err


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_shared
def test_release_170120_is_recognised(monkeypatch, capsys):
    code, out, _ = run_cli(monkeypatch, capsys, "conformance", CONFORMANCE_DIR)
    assert code == 0 and "filter: ST 170120 (recognised" in out


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@needs_shared
def test_a_directory_means_all_its_csv_files(monkeypatch, capsys, tmp_path):
    code, out, _ = run_cli(monkeypatch, capsys, "conformance", CONFORMANCE_DIR)
    assert code == 0 and f"{len(CSV_FILES)} file(s)" in out and "all bit-exact" in out
    code, _, err = run_cli(monkeypatch, capsys, "conformance", tmp_path)
    assert code == 2 and "no .csv" in err


@needs_shared
def test_text_report_and_pure_loop(monkeypatch, capsys):
    baseline = CONFORMANCE_DIR / "lab5_baseline.csv"
    code, out, _ = run_cli(monkeypatch, capsys, "conformance", "--pure", baseline, CONFORMANCE_DIR / "edge_cases.csv")
    assert code == 0
    assert "lab5_baseline.csv" in out and "1600 of 1600 steps bit-exact" in out


@needs_shared
def test_wrong_settings_fail_with_exit_1(monkeypatch, capsys):
    code, out, _ = run_cli(
        monkeypatch, capsys, "conformance", "--json", "--ki", "1.0", CONFORMANCE_DIR / "lab5_noise.csv"
    )
    assert code == 1
    f = json.loads(out)["files"][0]
    assert f["bit_exact_steps"] < f["steps"] and f["first_mismatch_step"] == 0 and f["max_abs_dq"] > 0


def test_a_modified_firmware_is_checked_with_its_settings(tmp_path, monkeypatch, capsys):
    s = MahonySettings(ki=1.0, correction=False, variant="ST 221117", kp_flight=0.5, min_thr=100, dt_s=0.00619)
    path = modified_firmware_vectors(tmp_path, s)
    args = ["--ki", "1", "--no-correction", "--variant", "221117", "--kp-flight", "0.5", "--min-thr", "100"]
    code, out, _ = run_cli(monkeypatch, capsys, "conformance", *args, "--dt", "0.00619", path)
    assert code == 0 and "400 of 400 steps bit-exact" in out
    code, out, _ = run_cli(monkeypatch, capsys, "conformance", *args, path)  # dt left at 0.00625
    assert code == 1 and "MISMATCH" in out


def test_one_flipped_bit_is_found(tmp_path):
    path = modified_firmware_vectors(tmp_path, MahonySettings(), n=300)
    v = load_conformance_csv(path)
    flipped = v.q_wxyz.copy()
    flipped[123, 1] = (np.array([v.q_wxyz[123, 1]]).view(np.uint32) ^ np.uint32(1)).view(np.float32)[0]
    thy = v.thy_rad.copy()
    thy[200] = np.nan  # NaN on one side only
    bad = write_vectors(tmp_path / "bad.csv", v.acc_mg, v.gyro_mdps, v.thr, flipped, v.thx_rad, thy)
    r = check_conformance(load_conformance_csv(bad))
    assert r.exact_steps == 298 and r.first_mismatch_step == 123 and r.nan_mismatches == 1
    assert 0 < r.max_abs_dq < 1e-6


def test_nan_against_nan_is_exact(tmp_path):
    # a firmware NaN (as in edge_cases.csv) must be matched by a NaN from the replica
    n = 50
    acc = np.zeros((n, 3), np.float32)
    gyro = np.full((n, 3), np.nan, np.float32)
    q, thx, thy, _ = run(acc, gyro)
    assert np.isnan(q).all()
    path = write_vectors(tmp_path / "nan.csv", acc, gyro, np.zeros(n), q, thx, thy)
    assert check_conformance(load_conformance_csv(path)).ok


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "no such file"),
        ("hello\n", "unexpected header"),
        ("# c\n" + ",".join(COLUMNS) + "\n", "no data rows"),
        ("# c\n" + ",".join(COLUMNS) + "\n0,0,1,2,3\n", "columns"),
        ("# c\n" + ",".join(COLUMNS) + "\n" + ",".join(["0"] * 14) + "\n0,0,1\n", "malformed"),
        ("# c\n" + ",".join(COLUMNS) + "\n0,0,1,2,3,4,5,6,7,8,9,x,1,2\n", "malformed"),
        ("# c\n" + ",".join(COLUMNS) + "\n0.5,0,1,2,3,4,5,6,7,8,9,1,1,2\n", "integers"),
    ],
)
def test_bad_files_are_one_line_user_errors(tmp_path, monkeypatch, capsys, content, message):
    path = tmp_path / "vectors.csv"
    if content is not None:
        path.write_text(content)
    code, out, err = run_cli(monkeypatch, capsys, "conformance", path)
    assert code == 2
    assert err.startswith("steval: error:") and message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1

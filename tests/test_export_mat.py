"""``steval export CAPTURE --mat OUT.mat``: read back with ``scipy.io.loadmat``, one struct per frame type with the
CSV's columns, settings and header; --force, OUT.partial, one line on bad input."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.link.load import load_telemetry

sio = pytest.importorskip("scipy.io")

REC = Path(__file__).resolve().parents[1] / "recordings"


def load(path: Path):
    return sio.loadmat(str(path), squeeze_me=True, struct_as_record=False)


def test_flight_as_matlab_structs(monkeypatch, capsys, tmp_path):
    cap = REC / "flight.stv"
    out, table = tmp_path / "flight.mat", tmp_path / "flight.csv"
    code, stdout, err = run_cli(monkeypatch, capsys, "export", cap, "--mat", out, "--csv", table)
    assert code == 0, err
    assert f"{out}: MATLAB structs attitude, status, fc, text" in stdout
    tel = load_telemetry(cap)
    m = load(out)
    a = m["attitude"]
    with open(table, newline="") as f:
        header = next(csv.reader(f))
    assert list(a._fieldnames) == header  # the CSV's columns, in its order
    assert a.thx_pitch_rad.shape == (len(tel.attitude),)  # one row per attitude frame
    assert a.thx_pitch_rad.dtype == np.float32
    assert np.array_equal(a.thx_pitch_rad, tel.attitude.thx_rad)  # the firmware's float32 bits
    assert np.array_equal(a.acc_z_mg, tel.attitude.acc_mg[:, 2])
    assert np.array_equal(a.step, tel.attitude.step)
    assert m["status"].ki.shape == (len(tel.status),)
    assert np.array_equal(m["status"].ki, tel.status.ki)
    assert m["fc"].motor1_pwm.shape == (len(tel.fc),)
    assert np.array_equal(m["fc"].motor1_pwm, tel.fc.motor_pwm[:, 0])
    assert float(m["settings"].ki) == pytest.approx(0.1)
    assert bool(m["settings"].correction)
    assert m["header"].port == "emulated:steval-fcu-link.elf"
    assert m["header"].extra.scenario == "flight"
    assert len(m["text"].text) == len(tel.text)
    assert not (tmp_path / "flight.mat.partial").exists()


def test_degrees_and_ble(monkeypatch, capsys, tmp_path):
    out = tmp_path / "deg.mat"
    code, _, _ = run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--mat", out, "--degrees")
    a = load(out)["attitude"]
    assert code == 0 and "thx_pitch_deg" in a._fieldnames and "thx_pitch_rad" not in a._fieldnames
    out = tmp_path / "ble.mat"
    code, stdout, err = run_cli(monkeypatch, capsys, "export", REC / "ble_demo.stv", "--mat", out)
    assert code == 0, err
    m = load(out)
    assert "motion" in m and m["motion"].gyro_x_mdps.size > 1000 and m["header"].kind == "ble"


def test_refuses_to_overwrite_and_reports_bad_input(monkeypatch, capsys, tmp_path):
    out = tmp_path / "x.mat"
    out.write_bytes(b"keep me")
    code, _, err = run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--mat", out)
    assert code == 2 and err == f"steval: error: --mat {out} already exists (use --force to overwrite)\n"
    assert out.read_bytes() == b"keep me"
    code, _, err = run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--mat", out, "--force")
    assert code == 0 and load(out)["attitude"].step.size == len(load_telemetry(REC / "demo.stv").attitude)
    code, _, err = run_cli(monkeypatch, capsys, "export", tmp_path / "missing.stv", "--mat", tmp_path / "y.mat")
    assert code == 2 and err.count("\n") == 1 and not (tmp_path / "y.mat").exists()
    code, _, err = run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--mat", tmp_path / "no" / "y.mat")
    assert code == 2 and "does not exist" in err and err.count("\n") == 1


def test_a_failed_write_leaves_nothing(monkeypatch, capsys, tmp_path):
    from steval_link.analysis import mat_export

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    out = tmp_path / "x.mat"
    monkeypatch.setattr(mat_export, "require_scipy", lambda: broken)
    code, _, err = run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--mat", out)
    assert code == 2 and "no space left on device" in err
    assert not out.exists() and not (tmp_path / "x.mat.partial").exists()


def test_without_scipy_one_line(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "scipy.io", None)
    code, out, err = run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--mat", tmp_path / "x.mat")
    assert (
        code == 2
        and err == 'steval: error: --mat needs scipy, which is not installed: pip install "steval-link[mat]"\n'
    )
    assert not (tmp_path / "x.mat").exists()


def test_readme_matlab_lines_name_real_fields(monkeypatch, capsys, tmp_path):
    """The docs' three MATLAB lines (docs/howto/export.md) use fields the file has (MATLAB itself is not run here)."""
    import re

    text = (REC.parent / "docs" / "howto" / "export.md").read_text(encoding="utf-8")
    lines = re.search(r"```matlab\n(.*?)```", text, re.S).group(1).strip().splitlines()
    assert len(lines) == 3 and lines[0] == "S = load('flight.mat');"
    out = tmp_path / "flight.mat"
    code, _, _ = run_cli(monkeypatch, capsys, "export", REC / "flight.stv", "--mat", out)
    m = load(out)
    for struct, field in re.findall(r"S\.(\w+)\.(\w+)", "\n".join(lines)):
        assert field in m[struct]._fieldnames, (struct, field)

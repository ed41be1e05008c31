"""``steval export``: CSV / Parquet rows with units in column names, exact raw bytes, safe outputs."""

from __future__ import annotations

import csv as csv_mod

import numpy as np
import pytest
from support.streams import StreamBuilder

from steval_link.cli import main
from steval_link.link.capture import CaptureWriter, read_capture
from steval_link.link.decoder import decode_bytes


def run(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in argv])
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


@pytest.fixture
def capture(tmp_path, make_stream):
    b: StreamBuilder = make_stream(11)
    b.flight(400)
    b.att_line(500)  # one rounded text-mode row (NaN quaternion)
    data = b.bytes()
    path = tmp_path / "c.stv"
    with CaptureWriter(path, port="COM3", baud=921600) as w:
        for j in range(0, len(data), 333):
            w.write(data[j : j + 333], t_host_s=j / 92160)
    return path


def test_csv_has_one_row_per_attitude_frame_exact_values(capture, tmp_path, capsys):
    out = tmp_path / "o.csv"
    code, stdout, err = run(["export", capture, "--csv", out], capsys)
    assert code == 0, err
    rows = list(csv_mod.DictReader(out.open()))
    tel = decode_bytes(read_capture(capture).data)
    assert len(rows) == len(tel.attitude) == 401
    assert list(rows[0])[:8] == ["step", "seq", "t_fw_s", "t_host_s", "acc_x_mg", "acc_y_mg", "acc_z_mg", "gyro_x_mdps"]
    assert {"q_w", "thx_pitch_rad", "thy_roll_rad", "thz_yaw_rad", "thr", "exact"} <= set(rows[0])
    # float32 values survive the text round trip bit for bit
    acc = np.array([[float(r[f"acc_{a}_mg"]) for a in "xyz"] for r in rows], np.float32)
    assert acc.tobytes() == tel.attitude.acc_mg.tobytes()
    q = np.array([float(rows[5][f"q_{c}"]) for c in "wxyz"], np.float32)
    assert q.tobytes() == tel.attitude.q_wxyz[5].tobytes()
    assert [int(r["step"]) for r in rows[:3]] == [0, 1, 2]
    assert rows[-1]["exact"] == "0" and rows[-1]["q_w"] == "" and rows[0]["exact"] == "1"
    assert float(rows[10]["t_fw_s"]) == pytest.approx(tel.attitude.t_fw_s[10], abs=1e-6)
    assert rows[10]["t_host_s"] != ""


def test_parquet(capture, tmp_path, capsys):
    pq = pytest.importorskip("pyarrow.parquet")
    out = tmp_path / "o.parquet"
    code, _, err = run(["export", capture, "--parquet", out], capsys)
    assert code == 0, err
    table = pq.read_table(out)
    assert table.num_rows == 401 and "gyro_z_mdps" in table.column_names
    assert table.column("acc_z_mg").type == "float"


def test_parquet_without_pyarrow_is_a_clear_error(capture, tmp_path, capsys, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_pyarrow(name, *a, **k):
        if name.startswith("pyarrow"):
            raise ImportError(name)
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_pyarrow)
    code, _, err = run(["export", capture, "--parquet", tmp_path / "o.parquet"], capsys)
    assert code == 2 and "pyarrow" in err and len(err.strip().splitlines()) == 1


def test_raw_writes_exact_serial_bytes(capture, tmp_path, capsys):
    out = tmp_path / "o.bin"
    code, _, _ = run(["export", capture, "--raw", out], capsys)
    assert code == 0 and out.read_bytes() == read_capture(capture).data
    # and the raw dump replays to the same frames
    assert len(decode_bytes(out.read_bytes()).attitude) == 401


def test_output_safety(capture, tmp_path, capsys):
    code, _, err = run(["export", capture], capsys)
    assert code == 2 and "nothing to export" in err
    existing = tmp_path / "exists.csv"
    existing.write_text("keep me")
    code, _, err = run(["export", capture, "--csv", existing], capsys)
    assert code == 2 and "already exists" in err and existing.read_text() == "keep me"
    code, _, _ = run(["export", capture, "--csv", existing, "--force"], capsys)
    assert code == 0 and existing.read_text().startswith("step,")
    code, _, err = run(["export", capture, "--raw", capture, "--force"], capsys)
    assert code == 2 and "input itself" in err
    code, _, err = run(["export", capture, "--csv", tmp_path / "no" / "dir.csv"], capsys)
    assert code == 2 and "does not exist" in err


def test_csv_floats_are_the_shortest_exact_decimals_for_excel(tmp_path, capsys):
    """A float32 999.4 is written 999.4 (not 999.400024), and still reads back as exactly the same float32."""
    from pathlib import Path

    from steval_link.link.load import load_telemetry

    demo = Path(__file__).resolve().parents[1] / "recordings" / "demo.stv"
    out = tmp_path / "demo.csv"
    code, _, err = run(["export", demo, "--csv", out], capsys)
    assert code == 0, err
    text = out.read_text()
    assert ",999.4," in text and "999.400024" not in text
    rows = list(csv_mod.DictReader(text.splitlines()))
    a = load_telemetry(demo).attitude
    acc_z = np.array([np.float32(r["acc_z_mg"]) for r in rows])
    assert np.array_equal(acc_z, a.acc_mg[:, 2])  # exact round trip
    for field in ("acc_z_mg", "gyro_x_mdps", "q_w", "thx_pitch_rad"):
        for r in rows[:200]:
            v = r[field]
            digits = len(v.split("e")[0].replace("-", "").replace(".", "").strip("0"))
            # no shorter decimal reads back as the same float32
            assert digits <= 1 or np.float32(float(f"%.{digits - 1}g" % float(v))) != np.float32(v), (field, v)


def test_csv_degrees(tmp_path, capsys):
    from pathlib import Path

    from steval_link.link.load import load_telemetry

    demo = Path(__file__).resolve().parents[1] / "recordings" / "demo.stv"
    out = tmp_path / "deg.csv"
    code, _, err = run(["export", demo, "--csv", out, "--degrees"], capsys)
    assert code == 0, err
    rows = list(csv_mod.DictReader(out.open()))
    assert {"thx_pitch_deg", "thy_roll_deg", "thz_yaw_deg"} <= set(rows[0]) and "thx_pitch_rad" not in rows[0]
    a = load_telemetry(demo).attitude
    pitch = np.array([float(r["thx_pitch_deg"]) for r in rows])
    assert np.allclose(pitch, np.degrees(a.thx_rad.astype(np.float64)), rtol=1e-6, atol=1e-9)
    assert np.abs(pitch).max() > 20  # degrees, not radians

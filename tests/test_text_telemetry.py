"""Text telemetry (``link/text_telemetry.py``, ``link/text_series.py``): any serial text as records of the one
decoder. Every log here is printed in the test from a real capture's values (``recordings/demo.stv``), in the
formats found in the field; the tests check records, series, values, times, the attitude they map to, and that
damage and random bytes never make a record."""

from __future__ import annotations

import json
import math
import random
import warnings
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.link.decoder import StreamDecoder, decode_bytes
from steval_link.link.frames import AttitudeFrame, TextFrame, TextRecordFrame
from steval_link.link.load import load_telemetry, read_recording
from steval_link.link.text_series import FLOATLESS_NOTE, parse_map
from steval_link.link.text_telemetry import parse_line
from steval_link.link.textmode import format_att

REC = Path(__file__).resolve().parents[1] / "recordings"
N = 240  # records per log
BANNER = [
    b"STEVAL-FCU001V1 FW rev.1.0 - Sep 2017",
    b"LSM6DSL MEMS Accelerometer initialized and enabled",
    b"LSM6DSL MEMS Gyroscope initialized and enabled",
]


@pytest.fixture(scope="module")
def demo():
    """The first N attitude rows of the bundled demo capture: degrees, g, rad/s as a student would print them."""
    a = load_telemetry(REC / "demo.stv").attitude
    rows = slice(100, 100 + N)
    return {
        "pitch_deg": np.degrees(a.thx_rad[rows].astype(np.float64)),
        "roll_deg": np.degrees(a.thy_rad[rows].astype(np.float64)),
        "acc_g": a.acc_mg[rows].astype(np.float64) / 1000.0,
        "gyro_dps": a.gyro_mdps[rows].astype(np.float64) / 1000.0,
        "thr": a.thr[rows].astype(int),
        "acc_mg": a.acc_mg[rows],
    }


def _decode_both(data: bytes, chunk: int = 97):
    """(frames of a StreamDecoder fed in chunks, its stats, decode_bytes' Telemetry): the one decoder both ways."""
    dec = StreamDecoder()
    frames = []
    for i in range(0, len(data), chunk):
        frames += dec.feed(data[i : i + chunk])
    frames += dec.finish()
    return frames, dec.stats, decode_bytes(data)


def _records(frames) -> list[TextRecordFrame]:
    return [f for f in frames if isinstance(f, TextRecordFrame)]


def _st_221117(d, floats: bool = True, n: int = N) -> bytes:
    """ST's release 221117 main loop: gELE, gAIL, gRUD, gTHR, motor1_pwm, thx*57.3, thy*57.3, rc thx/thy * 57.3."""
    lines = [b"\r\n".join(BANNER) + b"\r\n"]
    for i in range(n):
        if floats:
            thx, thy = math.radians(d["pitch_deg"][i]) * 57.3, math.radians(d["roll_deg"][i]) * 57.3
            vals = (0, 0, 0, d["thr"][i], 0.0, thx, thy, 0.0, 0.0)
            lines.append(b"%d\t%d\t%d\t%d\t%f\t%f\t%f\t%f\t%f\n" % vals)
        else:
            lines.append(b"%d\t%d\t%d\t%d\t\t\t\t\t\n" % (0, 0, 0, d["thr"][i]))
    return b"".join(lines)


def test_st_221117_lines_are_records_and_the_firmware_attitude(demo):
    data = _st_221117(demo)
    frames, stats, tel = _decode_both(data)
    recs = _records(frames)
    assert len(recs) == N and stats.text_records == N == tel.stats.text_records
    assert recs[0].names == ("gELE", "gAIL", "gRUD", "gTHR", "motor1_pwm", "thx", "thy", "rc_thx", "rc_thy")
    assert recs[0].kind == "st-221117" and recs[0].units[5:] == ("deg",) * 4
    # the banner (but the stream's first line, which nothing proves whole) is text, not data
    assert [f.text for f in frames if isinstance(f, TextFrame)] == [b.decode() for b in BANNER[1:]]
    printed = np.array([[float(x) for x in line.split(b"\t")] for line in data.split(b"\n")[3:-1]])
    np.testing.assert_array_equal(tel.text_series.values, printed)
    a = tel.attitude  # ST's thx/thy in degrees: the firmware's pitch/roll
    assert len(a) == N and not a.exact.any()
    np.testing.assert_allclose(a.thx_rad, np.radians(printed[:, 5]).astype(np.float32))
    np.testing.assert_allclose(a.thy_rad, np.radians(printed[:, 6]).astype(np.float32))
    np.testing.assert_array_equal(a.thr, demo["thr"])
    np.testing.assert_allclose(np.diff(a.t_fw_s), 1 / 161.538, rtol=1e-3)  # ST's main loop, one line a pass
    assert any("thx → pitch, degrees" in n for n in tel.text_attitude_notes)


def test_st_output_without_printf_float_is_recognised_and_explained(demo, tmp_path, monkeypatch, capsys):
    data = _st_221117(demo, floats=False)
    tel = decode_bytes(data)
    assert tel.stats.text_records == N and tel.text_series.notes == [FLOATLESS_NOTE]
    assert tel.stats.bytes_skipped == len(BANNER[0]) + 2  # the first line only: the empty fields are not garbage
    np.testing.assert_array_equal(tel.text_series.column("gTHR"), demo["thr"])
    log = tmp_path / "st_nofloat.log"
    log.write_bytes(data)
    code, out, err = run_cli(monkeypatch, capsys, "replay", log, "--json")
    assert code == 0
    t = json.loads(out)["text_telemetry"]
    assert t["records"] == N and "-u _printf_float" in t["notes"][0]


def _formats(d, N: int = N) -> dict[str, tuple[bytes, int, list[str]]]:  # noqa: N803 (the module's N)
    """name → (log, records, series) of each format, printed from the capture's values (N records)."""
    p, r, acc, gyr = d["pitch_deg"], d["roll_deg"], d["acc_g"], d["gyro_dps"]
    out = {}
    out["drone_pitch"] = (
        b"".join(b"Drone_Pitch = %f\tDrone_Roll = %f\n\n" % (p[i], r[i]) for i in range(N)),
        N - 1,  # the first line of a stream is not proven whole
        ["Drone_Pitch", "Drone_Roll"],
    )
    out["table_10_2f"] = (
        b"".join(b"%10.2f\t%10.2f\t%10.2f\n" % (p[i], r[i], acc[i, 2]) for i in range(N)),
        N - 1,
        ["col1", "col2", "col3"],
    )
    ms2, rads = acc * 9.80665, np.radians(gyr)
    out["accel_gyro_baro"] = (
        b"".join(
            b"Accel: %.3f %.3f %.3f m/s2  Gyro: %.4f %.4f %.4f rad/s\nBaro: %.2f hPa  Temp: %.1f C\n"
            % (*ms2[i], *rads[i], 1013.25 - i * 0.01, 25.0 + i * 0.01)
            for i in range(N)
        ),
        N - 1,
        ["Accel_x", "Accel_y", "Accel_z", "Gyro_x", "Gyro_y", "Gyro_z", "Baro", "Temp"],
    )
    out["matrix_x100"] = (
        b"".join(
            b"%d\t%d\t%d\n\r%d\t%d\t%d\n\r%d\t%d\t%d\n\r\n\r"
            % tuple(int(round(100 * v)) for v in _rotation(p[i], r[i]).ravel())
            for i in range(N)
        ),
        N - 1,
        [f"col{k}" for k in range(1, 10)],
    )
    out["matrix_rows"] = (  # the same matrix a row a line, nothing between two matrices: found by its values
        b"".join(
            b"%d\t%d\t%d\n\r" * 3 % tuple(int(round(100 * v)) for v in _rotation(p[i], r[i]).ravel()) for i in range(N)
        ),
        N - 1,
        [f"col{k}" for k in range(1, 10)],
    )
    for name, sep in (("arduino_space", b" "), ("arduino_tab", b"\t"), ("arduino_comma", b",")):
        out[name] = (
            b"".join(
                sep.join([b"pitch:%.2f" % p[i], b"roll:%.2f" % r[i], b"thr:%d" % d["thr"][i]]) + b"\r\n"
                for i in range(N)
            ),
            N - 1,
            ["pitch", "roll", "thr"],
        )
    out["arduino_header"] = (
        b"\r\npitch roll\r\n" + b"".join(b"%.2f %.2f\r\n" % (p[i], r[i]) for i in range(N)),
        N,
        ["pitch", "roll"],
    )
    out["bare_values"] = (b"".join(b"%.3f\n" % p[i] for i in range(N)), N - 1, ["col1"])
    out["teleplot"] = (
        b"".join(b">pitch:%.3f\n>roll:%.3f\n" % (p[i], r[i]) for i in range(N)),
        N - 1,
        ["pitch", "roll"],
    )
    out["csv_header"] = (
        b"\nt_ms,pitch(deg),roll(deg)\n" + b"".join(b"%d,%.3f,%.3f\n" % (10 * i, p[i], r[i]) for i in range(N)),
        N,
        ["t_ms", "pitch", "roll"],
    )
    return out


def _rotation(pitch_deg: float, roll_deg: float) -> np.ndarray:
    a, b = math.radians(pitch_deg), math.radians(roll_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    return rx @ ry


@pytest.mark.parametrize(
    "name",
    [
        "drone_pitch",
        "table_10_2f",
        "accel_gyro_baro",
        "matrix_x100",
        "matrix_rows",
        "arduino_space",
        "arduino_tab",
        "arduino_comma",
        "arduino_header",
        "bare_values",
        "teleplot",
        "csv_header",
    ],
)
def test_each_format_gives_its_records_and_series(demo, name):
    data, n, series = _formats(demo)[name]
    frames, stats, tel = _decode_both(data)
    assert stats.text_records == n == tel.stats.text_records == len(tel.text_series)
    assert tel.text_series.names == series
    # the rest of the first record, whose first line is not proven whole, is text; no other line is
    assert stats.text == {"accel_gyro_baro": 1, "matrix_x100": 2, "matrix_rows": 2, "teleplot": 1}.get(name, 0)
    # the values are those printed: the last record's numbers are the last lines' numbers
    last = _records(frames)[-1]
    tail = data.rstrip(b"\r\n").replace(b"\n\r", b"\n").split(b"\n")[-(1 if name != "teleplot" else 2) :]
    if name in ("drone_pitch", "table_10_2f", "bare_values", "arduino_comma", "csv_header"):
        words = tail[-1].replace(b"\t", b",").replace(b" ", b",").split(b",")
        nums = [float(w.split(b"=")[-1].split(b":")[-1]) for w in words if w.strip(b" =") and w[-1:].isdigit()]
        assert list(last.values) == nums


def test_records_map_to_the_attitude_and_the_sensors(demo):
    fm = _formats(demo)
    tel = decode_bytes(fm["accel_gyro_baro"][0])
    a = tel.attitude  # m/s2 and rad/s as printed, in the firmware's mg and mdps
    np.testing.assert_allclose(a.acc_mg[:, 2], demo["acc_mg"][1:, 2], atol=0.6)
    np.testing.assert_allclose(a.gyro_mdps, demo["gyro_dps"][1:] * 1000, atol=0.05 * 180 / math.pi)
    assert "Accel_x → acc_x, m/s2" in tel.text_attitude_notes
    tel = decode_bytes(fm["drone_pitch"][0])
    np.testing.assert_allclose(np.degrees(tel.attitude.thx_rad), demo["pitch_deg"][1:], atol=1e-5)
    notes = " ".join(tel.text_attitude_notes)
    assert "Drone_Pitch → pitch, degrees" in notes and "pitch on this board" in notes  # the handouts' roll
    tel = decode_bytes(b"t_s,thx_pitch_rad,thy_roll_rad\n" + b"".join(b"%d,0.1,-0.2\n" % i for i in range(20)))
    notes = " ".join(tel.text_attitude_notes)  # the firmware's axis names: no handouts' hedge
    assert "thx_pitch_rad → pitch, radians (about x, nose up +)" in notes and "handouts'" not in notes
    tel = decode_bytes(fm["csv_header"][0])
    assert tel.text_series.t_source == "the column t_ms"
    np.testing.assert_allclose(tel.attitude.t_fw_s, np.arange(N) * 0.01)


def test_map_option_and_its_errors(demo, tmp_path, monkeypatch, capsys):
    log = tmp_path / "table.log"
    log.write_bytes(_formats(demo)["table_10_2f"][0])
    code, out, err = run_cli(monkeypatch, capsys, "replay", log, "--json", "--map", "pitch=col1:deg,roll=col2:deg")
    assert code == 0
    s = json.loads(out)
    assert s["frames"]["attitude"] == N and s["text_telemetry"]["series"] == ["col1", "col2", "col3"]
    assert any(n.startswith("col1 → pitch, degrees") for n in s["text_telemetry"]["attitude"])
    for bad in ("pitch=col9", "elevation=col1", "pitch", "pitch=col1:furlong"):
        code, out, err = run_cli(monkeypatch, capsys, "replay", log, "--map", bad)
        assert code == 2 and err.count("\n") == 1 and "--map" in err or "col1" in err, (bad, err)
    assert parse_map(["acc_x=ax:g", "thr=col3"]) == {"acc_x": ("ax", "g"), "thr": ("col3", "")}


def test_replay_json_export_csv_and_compare_of_st_log(demo, tmp_path, monkeypatch, capsys):
    log = tmp_path / "exercise2.log"
    log.write_bytes(_st_221117(demo))
    code, out, _ = run_cli(monkeypatch, capsys, "replay", log, "--json")
    t = json.loads(out)["text_telemetry"]
    assert code == 0 and t["records"] == N and t["other_lines"] == 3 and len(t["series"]) == 9  # the whole banner
    csv = tmp_path / "x.csv"
    code, out, _ = run_cli(monkeypatch, capsys, "export", log, "--csv", csv)
    assert code == 0
    rows = csv.read_text().splitlines()
    assert rows[0].split(",")[2:] == ["gELE", "gAIL", "gRUD", "gTHR", "motor1_pwm"] + [
        f"{n}_deg" for n in ("thx", "thy", "rc_thx", "rc_thy")
    ]
    printed = [line.split("\t") for line in log.read_text().splitlines()[3:]]
    assert [r.split(",")[2:] for r in rows[1:]] == [[_short(v) for v in p] for p in printed]
    code, out, _ = run_cli(monkeypatch, capsys, "compare", log, "--json")
    assert code == 0
    report = json.loads(out)
    assert any("accel-only tilt needs acc" in n for n in report["notes"])


def _short(printed: str) -> str:
    v = float(printed)
    return str(int(v)) if v.is_integer() else repr(v)


def test_mixed_log_counts_every_frame_and_record_once(demo):
    """Binary frames, $ATT lines, a boot banner, plotter lines and garbage in one stream."""
    src = read_recording(REC / "demo.stv")
    full = load_telemetry(REC / "demo.stv").attitude
    off = full.offset
    rng = random.Random(7)

    def garbage(n: int) -> bytes:
        return bytes(b for b in rng.randbytes(4 * n) if b not in (0x0A, 0xA5, 0x24))[:n]

    def binary(i: int, j: int) -> bytes:  # attitude frames i..j-1 (and whatever frames lie between them)
        return src.data[off[i] : off[j]]

    p, r = demo["pitch_deg"], demo["roll_deg"]
    plotter = b"".join(b"pitch:%.2f,roll:%.2f\n" % (p[i], r[i]) for i in range(50))
    teleplot = b"".join(b">thx:%.3f\n>thy:%.3f\n" % (p[i], r[i]) for i in range(40))
    att = b"".join(
        format_att(
            step=5000 + 16 * i,
            t_ms=40_000 + 100 * i,
            thr=0,
            thx_mdeg=1000 * p[i],
            thy_mdeg=1000 * r[i],
            thz_mdeg=0,
            acc_mg=demo["acc_mg"][i],
            gyro_mdps=(0, 0, 0),
        )
        for i in range(30)
    )
    stream = (
        binary(0, 100)
        + b"\r\n".join(BANNER)
        + b"\r\n"
        + plotter
        + garbage(300)
        + binary(100, 200)
        + att
        + garbage(200)
        + binary(200, 300)
        + teleplot
        + binary(300, 400)
    )
    frames, stats, tel = _decode_both(stream)
    assert tel.stats.as_dict() == stats.as_dict()
    n_binary = sum(1 for f in frames if isinstance(f, AttitudeFrame) and f.exact)
    assert n_binary == 400 and stats.attitude == 430  # every binary frame and $ATT line, once
    assert stats.text_records == 50 + 40  # every plotter line and teleplot pair, once; nothing from the garbage
    assert [f.text for f in frames if isinstance(f, TextFrame)] == [b.decode() for b in BANNER]
    assert tel.text_series.names == ["pitch", "roll", "thx", "thy"]
    assert tel.has_own_attitude and len(tel.attitude) == 430  # the frames stay the attitude
    np.testing.assert_allclose(tel.text_series.column("thx")[-40:], np.round(p[:40], 3))


def test_damaged_lines_are_never_records(demo):
    lines = _st_221117(demo).split(b"\n")
    # a cut (a lost field), garbage bytes inside a line, a line cut and joined to the next
    lines[50] = lines[50].rsplit(b"\t", 1)[0]
    lines[80] = lines[80][:6] + b"\x13\x88" + lines[80][6:]
    lines[120] = lines[120][:15] + lines[121]
    del lines[121]
    data = b"\n".join(lines)
    frames, stats, tel = _decode_both(data)
    good = {bytes(x) for x in data.split(b"\n")[3:]} - {lines[50], lines[80], lines[120]}
    printed = {tuple(float(v) for v in x.split(b"\t")) for x in good if x}
    recs = _records(frames)
    # lost: the cut line, the line with garbage and the line after it (not trusted after damage), the joined pair
    assert len(recs) == N - 5 == tel.stats.text_records and {r.values for r in recs} <= printed


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_bytes_give_no_records_and_almost_no_text(seed):
    data = random.Random(seed).randbytes(2_000_000)
    frames, stats, tel = _decode_both(data, chunk=4096)
    assert stats.text_records == 0 == tel.stats.text_records
    assert stats.text <= 1 and stats.text_dropped >= 0


def test_live_replay_of_a_text_log_keeps_every_record(demo, tmp_path, monkeypatch, capsys):
    """A log's first line is whole live too: the capture of its live replay holds every record, as the log."""
    log = tmp_path / "exercise2.log"
    log.write_bytes(_formats(demo)["drone_pitch"][0])  # its first line is a record
    out = tmp_path / "x.stv"
    code, said, err = run_cli(
        monkeypatch, capsys, "live", "--port", f"replay://{log}?speed=4", "--no-view", "--duration", "3", "--out", out
    )
    assert code == 0 and f"text telemetry: {N} records" in said + err, err
    t = {}
    for path in (out, log):
        code, text, _ = run_cli(monkeypatch, capsys, "replay", path, "--json")
        t[path] = json.loads(text)["text_telemetry"]
        assert code == 0 and t[path]["records"] == N
    assert t[out]["time_source"] == "host receive times" and t[out]["series"] == t[log]["series"]
    np.testing.assert_array_equal(load_telemetry(out).text_series.values, load_telemetry(log).text_series.values)


def test_estimators_asked_for_on_printed_angles_say_why_they_did_not_run(demo, tmp_path, monkeypatch, capsys):
    """A log of printed angles has no sensor values: the estimators asked for are one line, not rows of NaN."""
    log = tmp_path / "exercise2.log"
    log.write_bytes(_formats(demo)["drone_pitch"][0])
    code, said, _ = run_cli(monkeypatch, capsys, "replay", log, "-e", "ekf3,accel", "--json")
    d = json.loads(said)
    assert code == 0 and d["estimators"] == [] and "ekf3, accel" in d["estimators_not_run"]
    code, said, _ = run_cli(monkeypatch, capsys, "replay", log, "-e", "accel")
    assert code == 0 and "estimators not run (accel)" in said and "valid rows" not in said


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@pytest.mark.parametrize("name", ["st", "st_nofloat", "drone_pitch", "table_10_2f", "arduino_comma", "csv_header"])
def test_bulk_and_stream_decoders_give_the_same_records(demo, name):
    """decode_bytes reads long runs of fitting lines as arrays; StreamDecoder line by line: the same records."""
    big = {k: np.tile(v, (8,) + (1,) * (np.ndim(v) - 1)) for k, v in demo.items()}
    n = len(big["thr"])
    st = {"st": _st_221117(big, n=n), "st_nofloat": _st_221117(big, floats=False, n=n)}
    data = st.get(name) or _formats(big, n)[name][0]
    # damage in the middle: a cut line and garbage, then the stream goes on
    k = len(data) // 2
    data = data[:k] + b"\x00\xff garbage\n" + data[k:]
    frames, stats, tel = _decode_both(data, chunk=4096)
    recs = _records(frames)
    assert stats.as_dict() == tel.stats.as_dict()
    assert len(recs) == len(tel.text_series) > 8 * 200
    np.testing.assert_array_equal(np.array([r.values for r in recs]), tel.text_series.values)
    np.testing.assert_array_equal([r.offset for r in recs], tel.text_series.offset)


def _rrd_series(path: Path, entity: str) -> tuple[list[str], np.ndarray]:
    """(legend names, values a row per record in time order) of one entity of text telemetry in an .rrd."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():  # a file written as the data came has no footer: read from its start
        warnings.filterwarnings("ignore", message=".*no footer.*")
        reader = RrdReader(str(path))
    names, rows = [], []
    for chunk in reader.stream(store=reader.recordings()[0]):
        if chunk.entity_path.strip("/") != entity:
            continue
        cols = chunk.to_record_batch().to_pydict()
        if chunk.is_static:
            names = cols["SeriesLines:names"][-1]
        else:
            rows += zip(cols["fw_time"], cols["Scalars:scalars"])
    return names, np.array([v for _, v in sorted(rows, key=lambda r: r[0])], np.float64)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_text_series_reach_rerun_replayed_and_live(demo, tmp_path, monkeypatch, capsys):
    """An entity per record shape under text/, a named line per series (units where printed) holding the printed
    values, from steval replay --rrd and from the live logger."""
    from steval_viewer.rrd_check import read_rrd  # Rerun: only this test needs it

    log = tmp_path / "ex2.log"
    log.write_bytes(_formats(demo)["drone_pitch"][0])
    printed = np.array([[float(b"%f" % v) for v in row] for row in zip(demo["pitch_deg"], demo["roll_deg"])])
    rrd = tmp_path / "replay.rrd"
    code, _, err = run_cli(monkeypatch, capsys, "replay", log, "--rrd", rrd)
    assert code == 0, err
    entity = "text/Drone_Pitch-Drone_Roll"
    names, values = _rrd_series(rrd, entity)
    assert names == ["Drone_Pitch", "Drone_Roll"] and read_rrd(rrd).samples[entity] == N
    np.testing.assert_array_equal(values, printed)
    live_rrd = tmp_path / "live.rrd"
    code, _, err = run_cli(
        monkeypatch, capsys, "live", "--port", f"replay://{log}?rate=400", "--no-view", "--duration", "2",
        "--out", tmp_path / "live.stv", "--rrd", live_rrd,
    )  # fmt: skip
    assert code == 0, err
    names, values = _rrd_series(live_rrd, entity)
    assert names == ["Drone_Pitch", "Drone_Roll"]
    np.testing.assert_array_equal(values, printed)  # every record, the first line's too
    st = tmp_path / "st.log"
    st.write_bytes(_st_221117(demo))
    code, _, err = run_cli(monkeypatch, capsys, "replay", st, "--rrd", tmp_path / "st.rrd")
    assert code == 0, err
    names, values = _rrd_series(tmp_path / "st.rrd", "text/gELE-gAIL-gRUD-gTHR-motor1_pwm-thx-thy-rc_thx-rc_thy")
    assert names[3:7] == ["gTHR", "motor1_pwm", "thx (deg)", "thy (deg)"] and values.shape == (N, 9)
    printed = [[float(v) for v in line.split(b"\t")] for line in st.read_bytes().splitlines()[3:]]
    np.testing.assert_array_equal(values, printed)
    st.write_bytes(_st_221117(demo, floats=False))  # %f prints nothing: the integers still plotted, the rest gaps
    code, _, err = run_cli(monkeypatch, capsys, "replay", st, "--rrd", tmp_path / "nofloat.rrd")
    assert code == 0, err
    _, values = _rrd_series(tmp_path / "nofloat.rrd", "text/gELE-gAIL-gRUD-gTHR-motor1_pwm-thx-thy-rc_thx-rc_thy")
    np.testing.assert_array_equal(values[:, 3], demo["thr"])
    assert values.shape == (N, 9) and np.isnan(values[:, 4:]).all()


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_live_on_a_pseudo_terminal_at_115200_baud_records_the_text(demo, tmp_path):
    """ST's output through a serial port at the pace of 115200 baud: live takes it, the capture replays it."""
    from support.ptyfeed import PtyFeeder, StevalProcess

    data = _st_221117(demo) * 3
    with PtyFeeder(data, tmp_path / "ttyUSB0", bytes_per_s=115200 / 10) as feeder:
        cap = tmp_path / "live.stv"
        proc = StevalProcess(
            ["live", "--no-view", "--port", str(feeder.link), "--out", str(cap), "--duration", "3"], cwd=tmp_path
        )
        assert proc.wait_line("reading ", 30) is not None, proc.stderr
        feeder.start()
        rc = proc.finish(timeout_s=60)
    assert rc == 0, proc.stderr
    tel = load_telemetry(cap)
    assert tel.stats.text_records > 300 and tel.text_series.t_source == "host receive times"
    assert tel.text_series.names[:4] == ["gELE", "gAIL", "gRUD", "gTHR"] and len(tel.attitude) == len(tel.text_series)


@pytest.mark.parametrize(
    "line, names, units, values",
    [
        ("Roll: 1.23, Pitch: 4.56, Yaw: 7.89", ("Roll", "Pitch", "Yaw"), ("", "", ""), (1.23, 4.56, 7.89)),
        ("Pitch: 1.23 deg  Roll: -4.5 deg", ("Pitch", "Roll"), ("deg", "deg"), (1.23, -4.5)),
        ("Temp: 25.3C Baro: 1013.2hPa", ("Temp", "Baro"), ("C", "hPa"), (25.3, 1013.2)),
        ("Accel: 0.1 0.2 9.81m/s2", ("Accel_x", "Accel_y", "Accel_z"), ("m/s2",) * 3, (0.1, 0.2, 9.81)),
        ("pitch(deg):1.5\troll(deg):-2", ("pitch", "roll"), ("deg", "deg"), (1.5, -2.0)),
        (">thx:1234:0.5§deg|g", ("thx_t_ms", "thx"), ("ms", "deg"), (1234.0, 0.5)),
        ("  1.50,  -2.25,3", None, ("", "", ""), (1.5, -2.25, 3.0)),
    ],
)
def test_one_line_read_as_numbers(line, names, units, values):
    p = parse_line(line)
    assert (p.names, p.units, p.values) == (names, units, values)


@pytest.mark.parametrize(
    "line", ["reg 0x1F", "STEVAL-FCU001V1 FW rev.1.0 - Sep 2017", "Calibrating 3 of 5", "OK", "a:1 a:2", "x: 1.2.3"]
)
def test_lines_that_are_text(line):
    assert parse_line(line) is None


def test_live_text_rows_start_their_firmware_time_at_zero(demo):
    """Lines that arrive with the capture's first chunk end, by the baud rate, before the capture started: their
    rows' firmware time is 0 there, not 2**32 µs later (the u32 wrap of a negative time)."""
    from steval_link.live.pipeline import LivePipeline

    class Viewer:
        def __init__(self):
            self.rows = []

        def log_batch(self, batch):
            self.rows.append(batch)

        def log_status(self, frame, at): ...
        def log_text(self, frame, at): ...
        def log_link(self, stats, t_unix_s): ...
        def log_event(self, text, at, level): ...
        def close(self): ...

    data, viewer = _st_221117(demo), Viewer()
    pipe = LivePipeline([], viewer, t0_unix_s=1000.0, baud=115200)
    for i in range(0, len(data), 600):
        pipe.feed([(data[i : i + 600], 1000.0 + i * 10 / 115200)])
    pipe.flush_view()
    t_fw_s = np.concatenate([b.attitude.t_fw_s for b in viewer.rows])
    assert len(t_fw_s) == N and 0.0 <= t_fw_s.min() and t_fw_s.max() < len(data) * 10 / 115200 + 1.0


def test_live_pipeline_makes_the_same_attitude_rows_of_records(demo):
    """ST's line live: each record an attitude row (pitch = thx, roll = thy), as the bulk path's Telemetry."""
    from steval_link.live.pipeline import LivePipeline, LiveRows

    class Viewer:  # the LiveViewer protocol, keeping what it is given
        def __init__(self):
            self.rows, self.records = [], []

        def log_batch(self, batch):
            self.rows.append(batch)

        def log_record(self, frame, at):
            self.records.append(frame)

        def log_status(self, frame, at): ...
        def log_text(self, frame, at): ...
        def log_link(self, stats, t_unix_s): ...
        def log_event(self, text, at, level): ...
        def close(self): ...

    data = _st_221117(demo)
    viewer = Viewer()
    pipe = LivePipeline(["accel"], viewer)
    for i in range(0, len(data), 200):
        pipe.feed([(data[i : i + 200], 1000.0 + i / 5000)])
    pipe.flush_view()
    rows = LiveRows.concat(viewer.rows)
    tel = decode_bytes(data)
    assert len(rows) == len(tel.attitude) == N == len(viewer.records)
    np.testing.assert_array_equal(rows.attitude.thx_rad, tel.attitude.thx_rad)
    np.testing.assert_array_equal(rows.attitude.thy_rad, tel.attitude.thy_rad)
    np.testing.assert_array_equal(rows.attitude.thr, demo["thr"])
    assert not rows.attitude.values_bad.any() and pipe.health.nonfinite == 0
    assert np.isnan(rows.estimates["accel"]).all()  # no accelerometer printed: no accel-only tilt, no warning
    assert list(pipe.notes) == tel.text_attitude_notes  # what was mapped, as replay says it; no warning
    assert (
        pipe.health.records_part() == f"text telemetry: {N} records, series gELE, gAIL, gRUD, gTHR, motor1_pwm, thx"
        " and 3 more"
    )


@pytest.mark.slow
def test_live_viewer_shows_a_printf_stream(demo, tmp_path):
    """ST's output on a pseudo-terminal at 115200 baud, `steval live` with the desktop viewer on a virtual display:
    the viewer gets the firmware's angles and one series per printed name; a screenshot is kept in tmp_path."""
    import signal

    from support.ptyfeed import PtyFeeder, StevalProcess
    from support.xdisplay import (
        kill_processes,
        rerun_processes,
        screenshot,
        viewer_port,
        viewer_recording,
        virtual_display,
    )

    data = _st_221117(demo) * 4
    with virtual_display() as display, viewer_port() as port:
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        try:
            with PtyFeeder(data, tmp_path / "ttyUSB0", bytes_per_s=115200 / 10) as feeder:
                proc = StevalProcess(
                    ["live", "--port", str(feeder.link), "--out", str(tmp_path / "cap.stv"), "--grpc-port", str(port)],
                    cwd=tmp_path,
                    env=display.env,
                )
                assert proc.wait_line("reading ", 90) is not None, proc.stderr
                feeder.start()
                rec = viewer_recording(url, timeline="ahrs_step", end=300, timeout_s=90)
                st_series = "/text/gELE-gAIL-gRUD-gTHR-motor1_pwm-thx-thy-rc_thx-rc_thy"  # a line per name
                assert {"/plots/pitch_thx_deg/firmware", st_series} <= rec.entities
                png = screenshot(url, tmp_path / "live_printf.png")
                assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 50_000
                rc = proc.finish(timeout_s=30, sig=signal.SIGINT)
            assert rc == 0, proc.stderr
        finally:
            kill_processes(rerun_processes(port))


def _decode_both_from(data: bytes, line_start: bool, chunk: int = 61):
    """As :func:`_decode_both`, the stream's first byte a line start or not."""
    dec = StreamDecoder(line_start=line_start)
    frames = []
    for i in range(0, len(data), chunk):
        frames += dec.feed(data[i : i + chunk])
    frames += dec.finish()
    return frames, dec.stats, decode_bytes(data, line_start=line_start)


@pytest.mark.parametrize("line_start", [False, True])
def test_blank_lines_are_blank_text_not_skipped_bytes(demo, line_start):
    p, r = demo["pitch_deg"], demo["roll_deg"]
    first = b"Drone_Pitch = %f\tDrone_Roll = %f\n" % (p[0], r[0])
    data = b"".join(b"Drone_Pitch = %f\tDrone_Roll = %f\n\n" % (p[i], r[i]) for i in range(N))
    # blank lines of spaces and tabs, "\r\n" and "\n\r" endings among them
    data += b"  \t \r\n" + b"".join(b"Drone_Pitch = %f\tDrone_Roll = %f\n\r\n\r" % (p[i], r[i]) for i in range(N))
    frames, stats, tel = _decode_both_from(data, line_start)
    assert tel.stats.as_dict() == stats.as_dict()
    assert stats.text_records == 2 * N - (not line_start) and stats.text == 0
    assert stats.blank_bytes == N + 6 + 3 * N  # "\n" a record, the spaces line, "\r\n\r" a record
    assert stats.bytes_skipped == (0 if line_start else len(first))  # the first line, when not known whole
    lines = decode_bytes(data, line_start=line_start)
    assert lines.stats.bytes_skipped + lines.stats.blank_bytes + sum(r.nbytes for r in _records(frames)) == len(data)


def test_replay_of_a_log_with_blank_lines_reports_no_damage(demo, tmp_path, monkeypatch, capsys):
    p, r = demo["pitch_deg"], demo["roll_deg"]
    log = tmp_path / "exercise2.log"
    log.write_bytes(b"".join(b"Drone_Pitch = %f\tDrone_Roll = %f\n\n" % (p[i], r[i]) for i in range(N)))
    code, out, _ = run_cli(monkeypatch, capsys, "replay", log)
    assert code == 0 and "0 CRC failures, 0 of" in out
    code, out, _ = run_cli(monkeypatch, capsys, "replay", log, "--json")
    s = json.loads(out)
    assert s["bytes_skipped"] == 0 and s["blank_bytes"] == N


def test_a_log_files_first_line_is_kept_when_whole_a_joined_stream_drops_it(demo, tmp_path):
    data = _st_221117(demo)
    log = tmp_path / "st.log"
    log.write_bytes(data)
    banner = [b.decode() for b in BANNER]
    # a log file holds what the port sent from its start: its first line, whole and printable, is the banner's
    tel = load_telemetry(log)
    assert [t for _, t in tel.text] == banner and tel.stats.bytes_skipped == 0
    frames, stats, tel = _decode_both_from(data, True)
    assert [f.text for f in frames if isinstance(f, TextFrame)] == banner and stats.as_dict() == tel.stats.as_dict()
    # a stream joined at an unknown point (live): the first line may be a tail, so it is not kept
    frames, stats, tel = _decode_both_from(data, False)
    assert [f.text for f in frames if isinstance(f, TextFrame)] == banner[1:]
    assert stats.bytes_skipped == len(BANNER[0]) + 2 == tel.stats.bytes_skipped
    # a log that starts in the middle of a line of numbers: its first line is not a whole record's shape, and a
    # log that starts with line noise has no whole first line
    cut = data[data.index(b"\n", 400) - 9 :]
    tel = decode_bytes(cut, line_start=True)
    assert tel.stats.text_records == len(cut.split(b"\n")) - 2 and tel.stats.text == 1  # the tail: a text line
    noisy = b"\x00\xff\x13" + data
    frames, stats, tel = _decode_both_from(noisy, True)
    assert [f.text for f in frames if isinstance(f, TextFrame)] == banner[2:]  # the line after damage: not trusted
    assert stats.bytes_skipped == 3 + len(BANNER[0]) + 2 + len(BANNER[1]) + 2 == tel.stats.bytes_skipped


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_live_says_the_records_and_takes_map(demo, tmp_path, monkeypatch, capsys):
    """steval live --map: the printed table's columns as the attitude live; the summary names the records."""
    log = tmp_path / "table.log"
    log.write_bytes(_formats(demo)["table_10_2f"][0])
    cap = tmp_path / "live.stv"
    code, out, err = run_cli(
        monkeypatch, capsys, "live", "--port", f"replay://{log}?rate=400", "--no-view", "--duration", "2",
        "--estimators", "none", "--out", cap, "--map", "pitch=col1:deg,roll=col2:deg",
    )  # fmt: skip
    assert code == 0, err
    # the replay of a log: its first line is whole, as offline
    assert f"text telemetry: {N} records, series col1, col2, col3" in out
    assert f"{N} attitude frames" in out  # the mapped rows
    assert "col1 → pitch, degrees" in err and "col2 → roll, degrees" in err
    code, out, err = run_cli(
        monkeypatch, capsys, "live", "--port", f"replay://{log}?rate=400", "--no-view", "--duration", "1",
        "--estimators", "none", "--out", tmp_path / "nine.stv", "--map", "pitch=col9:deg",
    )  # fmt: skip
    assert code == 0 and "map pitch=col9: the log has no series 'col9'" in err  # said once, the session goes on
    assert err.count("map pitch=col9") == 1 and "0 attitude frames" in out
    for bad in ("pitch", "elevation=col1"):
        code, out, err = run_cli(monkeypatch, capsys, "live", "--port", f"replay://{log}", "--map", bad)
        assert code == 2 and err.count("\n") == 1 and "--map" in err, (bad, err)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@pytest.mark.parametrize("seed", [4, 5])
def test_stats_do_not_depend_on_how_the_bytes_are_chunked(seed):
    """Text with blank lines of every kind, garbage and binary sync bytes: the same counters whatever the chunks,
    and the bulk decoder's, from a line start or not."""
    rng = random.Random(seed)
    pieces = [
        b"Drone_Pitch = %.2f\tDrone_Roll = %.2f\n", b"\n", b"  \t\r\n", b"\r\n", b"\n\r", b"%d,%d,%d\r\n",
        b"hello world\n", b"\x00\xa5\x5a\x13", b"   \n", b"\t\n", b"pitch:%.1f roll:%.1f\n", b"\rx\n",
    ]  # fmt: skip
    for _ in range(40):
        parts = []
        for _ in range(rng.randint(3, 120)):
            p = rng.choice(pieces)
            n = p.count(b"%")
            parts.append(p % tuple(rng.randint(-90, 90) for _ in range(n)) if n else p)
        data = b"".join(parts)
        for line_start in (False, True):
            ref = decode_bytes(data, line_start=line_start).stats.as_dict()
            for chunk in (1, rng.randint(2, 64), len(data)):
                assert _decode_both_from(data, line_start, chunk)[1].as_dict() == ref, (data, chunk)


def test_a_swap_by_map_takes_degrees_and_gives_no_advice_back(demo, tmp_path, monkeypatch, capsys):
    """Exercise 2's names the handouts' way round: `--map pitch=Drone_Roll,roll=Drone_Pitch` (no unit) swaps them."""
    log = tmp_path / "ex2.log"
    lines = [f"Drone_Pitch = {r:f}\tDrone_Roll = {p:f}\n\n" for p, r in zip(demo["pitch_deg"], demo["roll_deg"])]
    log.write_text("".join(lines))
    code, out, err = run_cli(monkeypatch, capsys, "replay", log, "--json", "--map", "pitch=Drone_Roll,roll=Drone_Pitch")
    assert code == 0, err
    notes = json.loads(out)["text_telemetry"]["attitude"]
    assert notes == ["Drone_Roll → pitch, degrees (assumed)", "Drone_Pitch → roll, degrees (assumed)"]
    a = load_telemetry(log, text_map=parse_map("pitch=Drone_Roll,roll=Drone_Pitch")).attitude
    np.testing.assert_allclose(np.degrees(a.thx_rad), demo["pitch_deg"], atol=1e-5)
    np.testing.assert_allclose(np.degrees(a.thy_rad), demo["roll_deg"], atol=1e-5)


def test_a_students_floatless_printf_is_explained(tmp_path, monkeypatch, capsys):
    """`PRINTF("Drone_Pitch = %f\\tDrone_Roll = %f\\n", ...)` on newlib nano prints the labels only: one sentence."""
    log = tmp_path / "nofloat.log"
    log.write_text("Drone_Pitch = \tDrone_Roll = \n\n" * 50)
    code, out, err = run_cli(monkeypatch, capsys, "replay", log)
    assert code == 2 and err.count("\n") == 1
    assert "no numbers after them" in err and "_printf_float" in err


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_our_own_csv_export_reads_back_as_text_telemetry(tmp_path, monkeypatch, capsys):
    """A CSV with a header and empty fields (steval export of the demo: flight-control columns empty on most rows,
    the last one too): every column a named series, the time from t_fw_s, acc/gyro/angles/thr mapped by their
    names, and the estimators score the same against the firmware as on the capture itself."""
    csv = tmp_path / "demo.csv"
    assert run_cli(monkeypatch, capsys, "export", REC / "demo.stv", "--csv", csv)[0] == 0
    code, said, err = run_cli(monkeypatch, capsys, "replay", csv, "--json", "-e", "accel")
    d = json.loads(said)
    t = d["text_telemetry"]
    header = csv.read_text().splitlines()[0].split(",")
    assert code == 0 and t["records"] == 9210 and t["series"] == header and t["time_source"] == "the column t_fw_s"
    code, said, _ = run_cli(monkeypatch, capsys, "replay", REC / "demo.stv", "--json", "-e", "accel")
    assert d["estimators"] == json.loads(said)["estimators"]
    # its step, exact and q columns carry the frames' own float32 values: the replica is bit-exact on them too
    code, said, _ = run_cli(monkeypatch, capsys, "compare", csv, "--json", "-e", "accel")
    replica = json.loads(said)["replica"]
    assert code == 0 and replica["rows"] == replica["bit_exact_steps"] == 9210 and replica["all_exact"]
    assert replica["filter"] == "ST 170120" and replica["seeds"][0]["source"] == "power-up"

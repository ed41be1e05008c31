"""The attitude the emulator reads by symbol (capture chunks S): loaded as the attitude when the firmware sent no
frames, checked against the frames when it did; bit-exact with the replica, the release named."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.cli import run_cli

from steval_link.estimators.st_mahony import MahonySettings, run
from steval_link.link import protocol as P
from steval_link.link.capture import CHUNK_SYMBOLS, SYMBOL_DTYPE, CaptureWriter, capture_symbol_rows, read_capture
from steval_link.link.decoder import decode_bytes
from steval_link.link.load import load_telemetry, merge_symbol_attitude


def symbol_rows(n: int, variant: str = "ST 221117", seed: int = 5) -> np.ndarray:
    """Rows a firmware with ``variant``'s filter would leave in its globals, from power-up."""
    rng = np.random.default_rng(seed)
    acc = rng.normal([0, 0, 1000], 80, (n, 3)).astype(np.float32)
    gyro = rng.normal(0, 3000, (n, 3)).astype(np.float32)
    thr = np.where(np.arange(n) < n // 2, 0, 400)
    q, thx, thy, _ = run(acc, gyro, thr, settings=MahonySettings(variant=variant))
    rows = np.zeros(n, SYMBOL_DTYPE)
    rows["step"] = np.arange(n)
    rows["t_s"] = 2.9848 + np.arange(n) / 161.54
    rows["acc_mg"], rows["gyro_mdps"], rows["thr"], rows["q_wxyz"] = acc, gyro, thr, q
    rows["euler_rad"][:, 0], rows["euler_rad"][:, 1] = thx, thy
    rows["read"] = 7
    return rows


def write_symbols_only(path, rows) -> None:
    with CaptureWriter(path, port="emulated:x.elf", baud=115200, extra={"emulated": True}) as w:
        for i in range(0, len(rows), 100):
            w.write_chunk(CHUNK_SYMBOLS, rows[i : i + 100].tobytes(), float(rows["t_s"][i]))


def test_symbol_chunks_round_trip(tmp_path):
    rows = symbol_rows(250)
    write_symbols_only(tmp_path / "s.stv", rows)
    back = capture_symbol_rows(read_capture(tmp_path / "s.stv").chunks)
    assert back.tobytes() == rows.tobytes()


def test_a_capture_without_frames_shows_the_symbol_attitude(tmp_path, monkeypatch, capsys):
    rows = symbol_rows(600)
    cap = tmp_path / "unpatched.stv"
    write_symbols_only(cap, rows)
    tel = load_telemetry(cap)
    assert tel.source["attitude_from"] == "symbols" and len(tel.attitude) == 600
    assert np.array_equal(tel.attitude.q_wxyz.view(np.uint32), rows["q_wxyz"].view(np.uint32))
    code, js, err = run_cli(monkeypatch, capsys, "compare", cap, "--json", "-e", "accel")
    assert code == 0, err
    d = json.loads(js)
    assert d["filter"] == "ST 221117" and d["replica"]["all_exact"] and d["replica"]["bit_exact_steps"] == 600
    assert any("by symbol" in n and "not frames it sent" in n for n in d["notes"])
    code, js, err = run_cli(monkeypatch, capsys, "replay", cap, "--json")
    assert code == 0, err
    s = json.loads(js)
    assert s["attitude_from"] == "symbols" and s["release"]["filter"] == "ST 221117"
    code, _, err = run_cli(monkeypatch, capsys, "export", cap, "--csv", tmp_path / "u.csv")
    assert code == 0, err
    assert len((tmp_path / "u.csv").read_text().splitlines()) == 601


def test_frames_and_symbols_are_checked_against_each_other():
    """A patched build: both exist; the frames stay, and a difference is said with its step."""
    rows = symbol_rows(50, variant="ST 170120")
    data = b"".join(
        P.encode_attitude(
            t_us=int(k * 6191.9),
            acc_mg=rows["acc_mg"][k],
            gyro_mdps=rows["gyro_mdps"][k],
            q_wxyz=rows["q_wxyz"][k],
            thz_rad=0.0,
            seq=k,
            thr=int(rows["thr"][k]),
        )
        for k in range(50)
    )
    tel = merge_symbol_attitude(decode_bytes(data), rows)
    assert tel.source["attitude_from"] == "frames" and "bit for bit on all 50 steps" in tel.source["symbols"]
    other = rows.copy()
    other["q_wxyz"][17, 2] = np.nextafter(other["q_wxyz"][17, 2], np.float32(1))
    tel = merge_symbol_attitude(decode_bytes(data), other)
    assert "differ from it on 1 of 50 steps (first at step 17)" in tel.source["symbols"]


@pytest.mark.slow
def test_the_reference_firmware_without_its_link_output(tmp_path, monkeypatch, capsys):
    """Built with 221117's filter and no frames on USART1 (an unpatched build's silence): steval emulate reads the
    attitude by symbol, compare shows it bit-exact with the release named."""
    from support import firmware as S

    why = S.missing()
    if why:
        pytest.skip(why)
    elf = S.build_reference(tmp_path / "b", "AHRS_VARIANT=221117", "LINK_OUTPUT=0")
    cap = tmp_path / "x.stv"
    args = ["emulate", elf, "--scenario", "hand-tilts", "--duration", "6", "--out", cap, "--no-view"]
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 0, err
    assert "0 attitude" in out and "by symbol" in out
    code, text, err = run_cli(monkeypatch, capsys, "compare", cap, "-e", "accel")
    assert code == 0, err
    assert "bit-exact on every step" in text and "filter: ST 221117 (recognised from the firmware ELF's code" in text
    assert "not frames it sent" in text


def test_the_live_replica_recognises_the_release_from_the_data():
    """ReplicaFollower.rows_recognising: a 221117 stream without status frames, followed from power-up, is
    bit-exact after the first rows with 221117's filter; a named release stays."""
    from steval_link.estimators.firmware_replay import ReplicaFollower

    rows = symbol_rows(300)
    args = (rows["step"].astype(np.int64), rows["acc_mg"], rows["gyro_mdps"], rows["thr"], np.ones(300, bool))
    f = ReplicaFollower(follow_snapshots=True, euler=False)
    out = [f.rows_recognising(*(a[k : k + 30] for a in args), rows["q_wxyz"][k : k + 30]) for k in range(0, 300, 30)]
    q = np.concatenate([o[0] for o in out])
    assert f.variant == "ST 221117" and np.array_equal(q.view(np.uint32), rows["q_wxyz"].view(np.uint32))
    named = ReplicaFollower(follow_snapshots=True, euler=False, variant="ST 170120")
    q = named.rows_recognising(*args, rows["q_wxyz"])[0]
    assert named.variant == "ST 170120" and not np.array_equal(q.view(np.uint32), rows["q_wxyz"].view(np.uint32))

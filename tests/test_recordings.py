"""The bundled recordings: each decodes with 0 CRC failures, its bytes are exactly what the Python encoder makes of
the decoded frames (they were made by the firmware's C encoder: C → Python conformance fixtures), the filter port
is bit-exact on every step it can seed, and the README says how each file was made."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import numpy as np
import pytest

from steval_link.estimators.st_mahony import MahonyState, bits_equal, replay_firmware
from steval_link.estimators.st_mahony import run as mahony_run
from steval_link.link import protocol as P
from steval_link.link.capture import demo_capture_path, load_telemetry, read_capture
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AttitudeFrame, FlightFrame, StatusFrame, TextFrame

REC = Path(__file__).resolve().parents[1] / "recordings"
BINARY = ["demo.stv", "midflight_drops.stv", "freefall.stv", "broad_07.stv", "flight.stv", "preflight_ok.stv",
          "preflight_swapped_motors.stv"]
ALL = BINARY + ["textmode.log"]


def encode(frame) -> bytes:
    """The Python encoder's bytes for a decoded frame."""
    if isinstance(frame, AttitudeFrame):
        return P.encode_attitude(
            t_us=frame.t_us,
            acc_mg=np.float32(frame.acc_mg),
            gyro_mdps=np.float32(frame.gyro_mdps),
            q_wxyz=np.float32(frame.q_wxyz),
            thz_rad=np.float32(frame.thz_rad),
            seq=frame.seq,
            thr=frame.thr,
        )
    if isinstance(frame, StatusFrame):
        names = [n for n in P.STATUS_DTYPE.names if n != "reserved"]
        return P.encode_status(**{n: getattr(frame, n) for n in names})
    if isinstance(frame, FlightFrame):
        names = [n for n in P.FLIGHT_DTYPE.names if n != "reserved"]
        return P.encode_flight(**{n: getattr(frame, n) for n in names})
    assert isinstance(frame, TextFrame)
    return P.encode_text(frame.text)


def test_readme_documents_every_file_and_says_emulated():
    text = (REC / "README.md").read_text(encoding="utf-8")
    assert "emulated" in text.lower() and "CC BY 4.0" in text and "make_recordings.sh" in text
    script = (REC / "make_recordings.sh").read_text(encoding="utf-8")
    for name in ALL:
        assert (REC / name).is_file(), name
        assert f"`{name}`" in text and name in script
    for name in BINARY:
        # the capture header's synthesis command appears in the README's command for that file
        cmd = read_capture(REC / name).header["extra"]["command"]
        args = shlex.split(cmd)[2:]
        row = next(line for line in text.splitlines() if line.startswith(f"| `{name}`"))
        for opt, val in zip(args[::2], args[1::2]):
            assert opt in row and val in row, (name, opt, val)


def test_readme_says_truly_where_the_synthesis_command_is(monkeypatch, capsys):
    """The README's way to print a capture's ``extra.command`` works, and it does not send readers to
    ``steval replay --json``, whose output has no ``extra``."""
    import json
    import re
    import subprocess
    import sys

    from support.cli import run_cli

    text = (REC / "README.md").read_text(encoding="utf-8")
    code, out, _ = run_cli(monkeypatch, capsys, "replay", REC / "demo.stv", "--json")
    assert code == 0 and "extra" not in json.loads(out)["source"]
    sentence = text[text.index("extra.command") - 400 : text.index("extra.command") + 400]
    assert "`steval replay FILE --json` or" not in sentence
    snippet = re.search(r'`(python -c ".*?read_capture.*?")`', text).group(1)
    run = subprocess.run(
        [sys.executable, "-c", shlex.split(snippet)[2]], capture_output=True, text=True, cwd=REC.parent, timeout=120
    )
    assert run.returncode == 0 and run.stdout.strip() == read_capture(REC / "demo.stv").header["extra"]["command"]


def test_sizes():
    sizes = {p.name: p.stat().st_size for p in REC.iterdir() if p.is_file()}
    assert sizes["demo.stv"] < 2_000_000
    assert sum(sizes.values()) < 3_000_000
    assert demo_capture_path().resolve() == (REC / "demo.stv").resolve()


@pytest.mark.parametrize("name", BINARY)
def test_binary_recording_is_a_c_to_python_conformance_fixture(name):
    cap = read_capture(REC / name)
    assert not cap.truncated and cap.header["extra"]["emulated"] is True
    assert np.all(np.diff(cap.chunk_times_s) >= 0) and cap.chunk_times_s[0] >= 0
    data = cap.data
    dec = StreamDecoder()
    frames = dec.feed(data) + dec.finish()
    assert dec.stats.crc_failures == 0 and dec.stats.unknown_frames == 0
    assert len(frames) > 1000
    # frames are back to back from the first to the last: only a partial frame at either end is skipped
    first, last = frames[0], frames[-1]
    assert first.offset < P.STATUS_FRAME_SIZE and len(data) - (last.offset + last.nbytes) < P.STATUS_FRAME_SIZE
    pos = first.offset
    for f in frames:
        assert f.offset == pos, f"gap before the frame at byte {f.offset}"
        assert data[f.offset : f.offset + f.nbytes] == encode(f), f"frame at byte {f.offset}"
        pos += f.nbytes


@pytest.mark.parametrize("name", BINARY)
def test_port_is_bit_exact_on_every_seeded_step(name):
    tel = load_telemetry(REC / name)
    a, s = tel.attitude, tel.status
    rep = replay_firmware(tel)
    assert rep.all_exact and rep.n_seeded > len(a) // 3
    full = a.step[0] == 0
    assert (rep.seeds[0].source == "power-up") == full
    if full:
        assert rep.n_seeded == len(a)
    # every status snapshot seeds the port bit-exact up to the next gap
    row_of = {int(k): i for i, k in enumerate(a.step)}
    settings = rep.seeds[0].settings
    checked = 0
    for j in range(len(s)):
        r0 = row_of.get(int(s.step[j]) + 1)
        if r0 is None:
            continue
        r1 = r0
        while r1 + 1 < len(a) and a.step[r1 + 1] == a.step[r1] + 1 and r1 - r0 < 400:
            r1 += 1
        q, thx, thy, _ = mahony_run(
            a.acc_mg[r0 : r1 + 1],
            a.gyro_mdps[r0 : r1 + 1],
            a.thr[r0 : r1 + 1],
            settings=settings,
            state=MahonyState(q_wxyz=s.q_wxyz[j], int_xyz=s.int_xyz[j]),
        )
        assert bits_equal(q, a.q_wxyz[r0 : r1 + 1]).all() and bits_equal(thx, a.thx_rad[r0 : r1 + 1]).all()
        checked += 1
    assert checked >= len(s) // 2


def test_demo_shows_bench_tilts_then_a_hover():
    tel = load_telemetry(REC / "demo.stv")
    a = tel.attitude
    assert len(a) > 9000 and len(tel.status) > 50 and len(tel.text) > 10 and tel.stats.seq_gaps == 0
    flying = a.thr >= 200
    assert flying.any() and not flying[: len(a) // 3].any()
    pitch = np.degrees(a.thx_rad[~flying])
    assert pitch.max() > 20 and pitch.min() < -20


def test_midflight_recording_joins_mid_frame_with_drops_counted():
    cap = read_capture(REC / "midflight_drops.stv")
    assert cap.data[:2] != P.SYNC
    tel = load_telemetry(REC / "midflight_drops.stv")
    a, s = tel.attitude, tel.status
    assert a.step[0] > 1000 and tel.stats.seq_gaps > 0 and tel.stats.crc_failures == 0
    for j in range(1, len(s)):
        lo, hi = int(s.step[j - 1]), int(s.step[j])
        have = np.count_nonzero((a.step > lo) & (a.step <= hi))
        assert s.tx_dropped[j] - s.tx_dropped[j - 1] == (hi - lo) - have


def test_freefall_recording():
    a = load_telemetry(REC / "freefall.stv").attitude
    norm = np.linalg.norm(a.acc_mg.astype(np.float64), axis=1)
    assert np.count_nonzero(norm < 100) > 50 and a.acc_mg[:, 2].max() > 3500


def test_textmode_log():
    raw = (REC / "textmode.log").read_bytes()
    assert raw.startswith(b"STEVAL-FCU001V1") and b"\xa5" not in raw
    tel = load_telemetry(REC / "textmode.log")
    a, s = tel.attitude, tel.status
    assert tel.source["kind"] == "text" and tel.stats.crc_failures == 0
    assert len(a) > 150 and np.all(np.diff(a.step) == 16) and not a.exact.any()
    assert len(s) >= 15 and np.all(s.flags & P.FLAG_TEXT_MODE)
    assert all(math.isfinite(v) for v in a.thx_rad)

"""The bundled recordings: each decodes with 0 CRC failures, its bytes are exactly what the Python encoder makes of
the decoded frames (they were made by the firmware's C encoder: C → Python conformance fixtures), the filter replica
is bit-exact on every step it can seed, and the README says how each file was made."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import numpy as np
import pytest

from steval_link.estimators.firmware_replay import replay_firmware
from steval_link.estimators.st_mahony import MahonySettings, MahonyState, bits_equal
from steval_link.estimators.st_mahony import run as mahony_run
from steval_link.link import protocol as P
from steval_link.link.capture import demo_capture_path, read_capture
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AckFrame, AttitudeFrame, FlightFrame, StatusFrame, TextFrame
from steval_link.link.load import load_telemetry

REC = Path(__file__).resolve().parents[1] / "recordings"
BINARY = [
    "demo.stv",
    "midflight_drops.stv",
    "freefall.stv",
    "broad_07.stv",
    "live_params.stv",
    "flight.stv",
    "preflight_ok.stv",
    "preflight_swapped_motors.stv",
]
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
    if isinstance(frame, AckFrame):
        return P.encode_ack(
            cmd_seq=frame.cmd_seq,
            cmd=frame.cmd,
            result=frame.result,
            step=frame.step,
            rx_ok=frame.rx_ok,
            rx_bad=frame.rx_bad,
        )
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
    # eleven recordings (serial, text mode, two-way, flight, preflight, BLE): kept small enough to clone quickly
    assert sum(sizes.values()) < 3_500_000
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
    # every status snapshot seeds the replica bit-exact up to the next gap
    row_of = {int(k): i for i, k in enumerate(a.step)}
    checked = 0
    for j in range(len(s)):
        r0 = row_of.get(int(s.step[j]) + 1)
        if r0 is None or (j + 1 < len(s) and s.step[j + 1] == s.step[j]):
            continue  # superseded: a later status names the same step (a command's change came between)
        settings = MahonySettings.of_status(s, j)  # each snapshot's own settings (they change in live_params)
        r1 = r0
        until = int(s.step[j + 1]) if j + 1 < len(s) else math.inf  # the next status may bring other settings
        while r1 + 1 < len(a) and a.step[r1 + 1] == a.step[r1] + 1 and r1 - r0 < 400 and a.step[r1 + 1] <= until:
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


def test_live_params_recording_shows_each_change_bit_exact(monkeypatch, capsys):
    """Lab exercises 4 and 5 live: KI and the correction changed through the emulated USART1 RX; the commands are
    in the capture (H chunks), each accepted change has its EVENT status, and compare is bit-exact on every step."""
    from support.cli import run_cli

    cap = read_capture(REC / "live_params.stv")
    assert cap.host and "--commands recordings/live_params.commands" in cap.header["extra"]["command"]
    tel = load_telemetry(REC / "live_params.stv")
    sent = [(int(c["cmd"]), int(c["param"]), float(c["value"])) for c in tel.commands]
    assert (P.CMD_SET_PARAM, P.PARAM_KI, 1.0) in sent and (P.CMD_SET_PARAM, P.PARAM_CORRECTION, 0.0) in sent
    assert len(tel.acks) == len(tel.commands)
    assert P.ACK_REFUSED_ARMED in set(tel.acks["result"].tolist())
    ev = np.flatnonzero(tel.status.flags & P.FLAG_EVENT)
    kis = {float(k) for k in tel.status.ki[ev]}
    assert {np.float32(0.1), np.float32(1.0)} <= {np.float32(k) for k in kis}
    assert (tel.status.flags[ev] & P.FLAG_NO_CORRECTION).any() and not (tel.status.flags[ev[-1]] & 1)
    code, out, err = run_cli(monkeypatch, capsys, "compare", REC / "live_params.stv")
    assert code == 0, err
    assert "replica vs firmware: bit-exact on every step" in out
    for change in ("ki 0.1 → 1", "correction on → off", "correction off → on", "filter reset", "ki 1 → 0.1"):
        assert change in out, change

"""A firmware whose own filter diverges (issue #24): protocol v2 keeps its CRC-valid frames, flags and counts them,
every summary says it in words, compare names the step and its inputs, the viewer marks it; protocol v1 holds
such frames back and says so. Real bytes from the protocol encoders throughout."""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import numpy as np
import pytest
from support.streams import stream_decode

from steval_link import constants as C
from steval_link.analysis import diagnosis
from steval_link.analysis.compare import compare_capture
from steval_link.analysis.report import format_report
from steval_link.analysis.summary import format_summary, summarize
from steval_link.estimators import st_mahony
from steval_link.link import protocol as P
from steval_link.link.decoder import StreamDecoder, decode_bytes
from steval_link.link.frames import AttitudeFrame, StatusFrame
from steval_link.link.telemetry import AttitudeArrays, TelemetryParts
from steval_link.live.health import LinkHealth
from steval_link.live.pipeline import LivePipeline, LiveRows

PERIOD_US = 1e6 / C.AHRS_RATE_HZ
T0_US = 2_985_000  # the first AHRS step of a real boot
N = 400
DIVERGE = 120  #: first step whose q leaves the unit sphere (|q| ≈ 3: components within ±2 up to step NAN)
NAN = 123  #: from this step on the firmware's q is NaN
STATUS_AT = (60, 221, 382)  #: status frames after these steps (the first with a finite snapshot)
KP_GROUND = 5.0  #: this build's AHRS_KP_BIG (not the default 10): the status frames report it


def _inputs(n: int = N):
    t = np.arange(n) * C.AHRS_PERIOD_S
    pitch = 0.3 * np.sin(2 * np.pi * 0.4 * t)
    acc = np.stack([np.zeros(n), 1000 * np.sin(pitch), 1000 * np.cos(pitch)], axis=1).astype(np.float32)
    gyro = np.stack([np.degrees(np.gradient(pitch, t)) * 1000, 30 * np.ones(n), -20 * np.ones(n)], axis=1).astype(
        np.float32
    )
    return acc, gyro, np.zeros(n, np.int64)


def diverging_stream(version: int = P.VERSION) -> tuple[bytes, np.ndarray]:
    """A capture from power-up of a firmware that runs the release's filter (bit-exact q, kp_ground 5) up to step
    DIVERGE - 1, then sends |q| ≈ 3, then NaN from step NAN on; status frames after STATUS_AT. (bytes, q sent)."""
    settings = st_mahony.MahonySettings(kp_ground=KP_GROUND)
    acc, gyro, thr = _inputs()
    q, _, _, _ = st_mahony.run(acc, gyro, thr, settings=settings, state=st_mahony.MahonyState())
    q = np.array(q, dtype=np.float32)
    q[DIVERGE:] *= np.float32(1.7)  # |q| ≈ 1.7: off the unit sphere, components still within ±2
    q[DIVERGE + 1 :] *= np.float32(1.8)  # |q| ≈ 3: q_w beyond 2
    q[NAN:] = np.nan
    # the filter's state after each step, for the status snapshots (the replica's integrals; the firmware's q)
    out = bytearray()
    rec = np.zeros(1, P.ATTITUDE_DTYPE)
    for s in range(N):
        t_us = int(T0_US + s * PERIOD_US)
        rec["t_us"], rec["acc_mg"], rec["gyro_mdps"], rec["q_wxyz"] = t_us, acc[s], gyro[s], q[s]
        rec["thz_rad"], rec["seq"], rec["thr"] = np.float32(0.01 * s), s, 0
        out += P.encode_frame(P.TYPE_ATTITUDE, rec.tobytes(), version=version)
        if s in STATUS_AT:
            state = st_mahony.run(
                acc[: s + 1], gyro[: s + 1], thr[: s + 1], settings=settings, state=st_mahony.MahonyState()
            )[3]
            sta = P.encode_status(step=s, t_us=t_us, q_wxyz=q[s], int_xyz=state.int_xyz, kp_ground=KP_GROUND)
            out += sta if version == P.VERSION else P.encode_frame(P.TYPE_STATUS, sta[4:-4], version=version)
    return bytes(out), q


SENTENCE = (
    f"{N - DIVERGE - 1} frames carry NaN or |q| > 2 from step {DIVERGE + 1} on (t = "
    f"{(T0_US + int((DIVERGE + 1) * PERIOD_US)) / 1e6:.3f} s): the firmware's own filter output; check ahrs.c"
)


# ------------------------------------------------------------------------------------------------ decoding


def test_v2_keeps_the_frames_of_a_diverged_filter_flagged_and_counted():
    data, q = diverging_stream()
    tel = decode_bytes(data)
    a = tel.attitude
    assert a.step.tolist() == list(range(N))  # nothing sent is lost
    assert tel.stats.implausible == 0 and tel.stats.crc_failures == 0
    # |q| ≈ 1.7 at DIVERGE has every component within ±2: not flagged; beyond that |q_w| > 2, then NaN
    assert np.flatnonzero(a.values_bad).tolist() == list(range(DIVERGE + 1, N))
    assert tel.stats.values_bad == N - DIVERGE - 1
    np.testing.assert_array_equal(a.q_wxyz.view(np.uint32), q.view(np.uint32))  # the very bits sent, NaN too
    assert np.isnan(a.thx_rad[NAN:]).all()
    # the status frames: kept, their NaN snapshots flagged
    assert tel.status.step.tolist() == list(STATUS_AT) and tel.status.values_bad.tolist() == [False, True, True]
    # the incremental decoder agrees, whatever the chunks
    for chunk in (1, 7, 60, 4096):
        frames, stats = stream_decode(data, chunk)
        assert stats.as_dict() == tel.stats.as_dict()
        att = [f for f in frames if isinstance(f, AttitudeFrame)]
        assert [f.seq for f in att] == list(range(N))
        assert [f.step for f in frames if isinstance(f, StatusFrame)] == list(STATUS_AT)


def test_v1_holds_the_same_frames_back_and_says_so():
    data, _ = diverging_stream(version=P.VERSION_1)
    tel = decode_bytes(data)
    assert tel.attitude.step.tolist() == list(range(DIVERGE + 1))
    assert tel.stats.implausible == (N - DIVERGE - 1) + 2  # the attitude frames and the two NaN snapshots
    assert tel.stats.values_bad == 0 and tel.stats.v1_frames == N + len(STATUS_AT)  # every CRC-valid v1 frame
    _, stats = stream_decode(data, 13)
    assert stats.as_dict() == tel.stats.as_dict()
    lines = format_summary(summarize(tel))
    held = [x for x in lines if x.startswith("held back: ")]
    assert tel.stats.held_values == N - DIVERGE + 1
    assert held == [
        f"held back: {N - DIVERGE + 1} CRC-valid frames held back, not shown: {N - DIVERGE + 1} for NaN or "
        "out-of-range values (protocol v1: its CRC-16 cannot tell the firmware's own filter output from "
        "damage; if the firmware's filter diverged, check ahrs.c)"
    ]
    assert not any(x.startswith("firmware output") for x in lines)


def test_the_sequence_gate_still_holds_back_a_crc_valid_frame_from_nowhere_with_nan():
    data, _ = diverging_stream()
    frame = P.encode_attitude(
        t_us=5, acc_mg=[np.nan] * 3, gyro_mdps=[0, 0, 0], q_wxyz=[np.nan] * 4, thz_rad=np.nan, seq=40_000, thr=0
    )
    cut = data.find(P.SYNC + bytes([(P.VERSION << 4) | P.TYPE_ATTITUDE]), 200 * P.ATTITUDE_FRAME_SIZE)
    tel = decode_bytes(data[:cut] + frame + data[cut:])
    assert tel.stats.implausible == 1 and len(tel.attitude) == N
    assert 40_000 not in tel.attitude.seq.tolist()


# ------------------------------------------------------------------------------------------------ summaries


def test_replay_summary_says_it_in_one_sentence_and_json_has_the_numbers():
    data, _ = diverging_stream()
    tel = decode_bytes(data)
    s = summarize(tel)
    assert s["values_bad"]["text"] == SENTENCE
    assert s["values_bad"]["frames"] == N - DIVERGE - 1 and s["values_bad"]["first_step"] == DIVERGE + 1
    assert s["values_bad"]["status_frames"] == 2 and s["values_bad"]["inputs_bad"] is False
    json.dumps(s, allow_nan=False)
    lines = format_summary(s)
    assert f"firmware output: {SENTENCE}" in lines
    # |q| ≈ 1.7 at DIVERGE is within ±2 per component (not flagged) but off the unit sphere: said too
    t = (T0_US + int(DIVERGE * PERIOD_US)) / 1e6
    assert s["q_off_unit_sphere"]["first_step"] == DIVERGE and s["q_off_unit_sphere"]["frames"] == N - DIVERGE
    assert (
        f"firmware filter: the firmware's q leaves the unit sphere from step {DIVERGE} on (t = {t:.3f} s, |q| = "
        f"{s['q_off_unit_sphere']['q_norm']:.4g}; the release keeps |q| ≈ 0.9983, ±0.05), {N - DIVERGE} frames "
        "off it: steval compare names the step and its inputs"
    ) in lines
    # the status frames are read for their settings although their snapshot is NaN
    assert s["filter"]["kp_ground"] == KP_GROUND and s["filter"]["from_step"] == STATUS_AT[-1]


def test_bad_inputs_are_named_as_such():
    data, _ = diverging_stream()
    # one frame whose acc is NaN (the sensor path, not the filter): kept on v2 and said differently
    k = 50 * P.ATTITUDE_FRAME_SIZE
    rec = np.frombuffer(data[k + 4 : k + 56], P.ATTITUDE_DTYPE).copy()
    assert int(rec["seq"][0]) == 50
    rec["acc_mg"][0, 2] = np.nan
    bad = data[:k] + P.encode_frame(P.TYPE_ATTITUDE, rec.tobytes()) + data[k + P.ATTITUDE_FRAME_SIZE :]
    s = summarize(decode_bytes(bad))
    assert s["values_bad"]["first_step"] == 50 and s["values_bad"]["inputs_bad"] is True
    assert s["values_bad"]["text"].startswith(
        f"{N - DIVERGE} frames carry NaN or out-of-range values from step 50 on (t = "
    )
    assert "the filter inputs (acc, gyro) too" in s["values_bad"]["text"]


def test_live_pipeline_health_and_note():
    data, _ = diverging_stream()
    pipe = LivePipeline(["st-mahony", "accel"], None)
    t = 1.7e9
    for i in range(0, len(data), 997):
        pipe.feed([(data[i : i + 997], t)])
        t += 0.05
    h = pipe.health
    assert h.values_bad == N - DIVERGE - 1 and h.first_bad_step == DIVERGE + 1
    assert h.values_sentence() == SENTENCE
    notes = list(pipe.notes)
    assert any(n.startswith(f"firmware values bad from step {DIVERGE + 1} on") for n in notes)
    # the port keeps running on the inputs (NaN snapshots seed nothing, their settings are the build's)
    assert pipe.mahony.seeded and pipe.mahony.settings.kp_ground == KP_GROUND
    # live, the replica starts with the defaults (kp_ground 10): bit-exact at step 0 (level: no correction), re-seeded
    # by the snapshot of step 60 (kp_ground 5), then bit-exact until the firmware's q left the unit sphere
    assert pipe.mahony.rows_exact == 1 + (DIVERGE - STATUS_AT[0] - 1)
    h2 = LinkHealth()
    assert h2.values_sentence() is None
    # the health lines of steval emulate and steval live say it
    from steval_link.live.health import emulated_health
    from steval_link.live.serial_source import serial_health
    from steval_link.live.sources import LinkStatus

    line = emulated_health(LinkStatus(t_link_s=5.0, duration_s=15.0), pipe, 5.0)
    assert line.split(" | ")[2] == SENTENCE
    status = LinkStatus(connected=True, port="/dev/ttyUSB0", bytes_total=len(data))
    line = serial_health(status, pipe, 0.0, t)
    assert line.split(" | ")[2] == SENTENCE and "held back" not in line


def test_live_and_emulate_summaries_carry_the_sentence():
    from pathlib import Path

    from steval_link.live.session import LiveSummary

    report = SimpleNamespace(emulated_s=15.0, lines=lambda: ["head", "TIM9 started at 1.0 s"])
    es = LiveSummary(
        Path("x.stv"),
        None,
        10.0,
        kind="emulated",
        report=report,
        attitude=400,
        status=3,
        values_sentence=SENTENCE,
        implausible=2,  # for a sequence and time that do not continue
    )
    lines = es.lines()
    assert lines[1] == SENTENCE and lines[2].startswith("2 CRC-valid frames held back")
    ls = LiveSummary(
        Path("x.stv"),
        None,
        10.0,
        9.0,
        1000,
        400,
        3,
        0,
        0,
        0,
        0,
        279,
        0,
        0.0,
        0,
        None,
        "end",
        implausible=2,
        values_sentence=SENTENCE,
    )
    line = ls.line()
    assert SENTENCE in line and "2 CRC-valid frames held back, not shown: 2 for a sequence and time" in line


# ------------------------------------------------------------------------------------------------ compare


def test_compare_names_the_step_its_inputs_and_the_finite_port_without_a_settings_search(monkeypatch):
    data, q = diverging_stream()
    tel = decode_bytes(data)

    def no_search(*_a, **_k):
        raise AssertionError("no setting explains a diverged filter: nothing may be searched")

    monkeypatch.setattr(diagnosis, "_diagnose", no_search)
    r = compare_capture(tel, estimators=("accel",))
    p = r.replica
    assert p.settings["kp_ground"] == KP_GROUND  # from the status frames, NaN snapshots and all
    assert p.first_mismatch["step"] == DIVERGE and p.bit_exact == DIVERGE
    d = p.divergence
    assert d["step"] == DIVERGE and d["first_nonfinite_step"] == NAN and d["replica"] == "finite"
    assert d["q_norm"] == pytest.approx(float(np.linalg.norm(q[DIVERGE].astype(np.float64))))
    acc, gyro, _ = _inputs()
    assert [x["step"] for x in d["inputs"]] == [DIVERGE - 1, DIVERGE]
    assert d["inputs"][1]["acc_mg"] == [float(v) for v in acc[DIVERGE]]
    assert d["inputs"][0]["gyro_mdps"] == [float(v) for v in gyro[DIVERGE - 1]]
    assert abs(np.linalg.norm(d["replica_q_wxyz"]) - 0.9983) < 0.01
    t = (T0_US + int(DIVERGE * PERIOD_US)) / 1e6
    assert p.diagnosis[0].startswith(
        f"the firmware's own filter left the unit sphere at step {DIVERGE} (t = {t:.3f} s): q = ("
    )
    assert f"non-finite from step {NAN} on" in p.diagnosis[0]
    assert p.diagnosis[1].startswith(f"inputs at step {DIVERGE - 1}: acc (")
    assert p.diagnosis[3].startswith("the bit-exact replica stayed finite on the same inputs")
    assert len(p.diagnosis) == 4
    lines = format_report(r)
    assert f"firmware output: {SENTENCE}" in lines
    assert any(x.startswith("  → the firmware's own filter left the unit sphere at step") for x in lines)
    assert not any("no status frames" in x for x in lines)
    assert "filter (status frames): kp_ground 5," in "\n".join(lines)
    out = r.as_dict()
    json.dumps(out, allow_nan=False)
    assert out["replica"]["divergence"]["step"] == DIVERGE and out["values_bad"]["text"] == SENTENCE


def test_compare_without_a_state_for_the_port_says_it_cannot_tell():
    data, _ = diverging_stream()
    # joined at step 300: after the divergence, every snapshot NaN, no power-up
    start = data.find(
        P.SYNC
        + bytes([(P.VERSION << 4) | P.TYPE_ATTITUDE, P.ATTITUDE_PAYLOAD_SIZE])
        + np.array([int(T0_US + 300 * PERIOD_US)], "<u4").tobytes()
    )
    tel = decode_bytes(data[start:])
    assert tel.attitude.step[0] % P.SEQ_MODULUS == 300
    r = compare_capture(tel, estimators=())
    d = r.replica.divergence
    assert d["replica"] == "unseeded" and d["first_nonfinite_step"] == d["step"]
    assert "the replica had no state at that step" in d["text"][-1]
    assert r.replica.settings["kp_ground"] == KP_GROUND
    lines = format_report(r)  # said although the replica has no step to compare
    assert f"  → {d['text'][0]}" in lines and f"  → {d['text'][-1]}" in lines


def test_a_healthy_capture_has_no_divergence():
    data, _ = diverging_stream()
    tel = decode_bytes(data[: 100 * P.ATTITUDE_FRAME_SIZE + P.STATUS_FRAME_SIZE])
    r = compare_capture(tel, estimators=())
    assert r.replica.divergence is None and r.values_bad is None and r.replica.all_exact
    assert summarize(tel)["values_bad"] is None


# ------------------------------------------------------------------------------------------------ export, viewer


def test_export_csv_and_parquet_carry_the_flag(tmp_path, monkeypatch, capsys):
    from support.cli import run_cli

    data, _ = diverging_stream()
    raw = tmp_path / "div.bin"
    raw.write_bytes(data)
    out = tmp_path / "div.csv"
    code, _, err = run_cli(monkeypatch, capsys, "export", raw, "--csv", out)
    assert code == 0, err
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == N
    flags = [r["values_bad"] for r in rows]
    assert set(flags[: DIVERGE + 1]) == {"0"} and set(flags[DIVERGE + 1 :]) == {"1"}
    assert rows[NAN]["q_w"] == ""  # NaN: an empty field, as everywhere in the CSV
    pa = pytest.importorskip("pyarrow.parquet")
    pq_out = tmp_path / "div.parquet"
    code, _, err = run_cli(monkeypatch, capsys, "export", raw, "--parquet", pq_out)
    assert code == 0, err
    col = pa.read_table(pq_out).column("values_bad").to_pylist()
    assert col == [False] * (DIVERGE + 1) + [True] * (N - DIVERGE - 1)


def test_replay_viewer_marks_the_step_and_the_drone_stops(tmp_path):
    from steval_viewer import entities as ent
    from steval_viewer.replay_log import log_telemetry
    from steval_viewer.rrd_check import read_rrd
    from steval_viewer.sink_options import SinkOptions
    from steval_viewer.sinks import open_session

    data, _ = diverging_stream()
    tel = decode_bytes(data)
    out = tmp_path / "div.rrd"
    session = open_session(SinkOptions(rrd=out), recording_name="test")
    summary = log_telemetry(session.rec, tel, {})
    session.close()
    assert summary.samples[ent.LOG_FILTER] == 1
    assert summary.samples[ent.DRONE_FIRMWARE] == DIVERGE + 1  # the 3D drone stops at the last finite attitude
    info = read_rrd(out)
    assert info.samples[ent.LOG_FILTER] == 1
    assert info.samples[ent.pitch_path("firmware")] == int(np.isfinite(tel.attitude.thx_rad).sum())
    assert info.samples[ent.pitch_path("st_mahony_replica")] == N  # the replica plots on, finite


def test_live_viewer_marks_the_first_bad_frame_once(tmp_path):
    from steval_viewer import entities as ent
    from steval_viewer.live_log import LiveLogger
    from steval_viewer.rrd_check import read_rrd
    from steval_viewer.sink_options import SinkOptions
    from steval_viewer.sinks import open_session

    data, _ = diverging_stream()
    frames = [f for f in StreamDecoder().feed(data) if isinstance(f, AttitudeFrame)]
    out = tmp_path / "live.rrd"
    session = open_session(SinkOptions(rrd=out))
    logger = LiveLogger(session.rec, [])
    for k in range(0, N, 50):
        att = frames[k : k + 50]
        n = len(att)
        parts = TelemetryParts()
        for f in att:
            parts.add_frame(f)
        rows = AttitudeArrays.from_records(
            parts.attitude_records(),
            step=np.array([f.seq for f in att]),
            t_fw_s=np.array([f.t_us for f in att]) / 1e6,
            t_host_s=np.full(n, k / 161.5),
        )
        logger.log_batch(LiveRows(rows))
    logger.close()
    session.close()
    info = read_rrd(out)
    assert info.samples[ent.LOG_FILTER] == 1
    assert logger._last_good_step == DIVERGE
    # the 3D drone: one update per batch up to the one holding step DIVERGE (its last good row), none after
    assert info.samples[ent.DRONE_FIRMWARE] == DIVERGE // 50 + 1


# ------------------------------------------------------------------------------------------------ end to end


@pytest.mark.slow
def test_a_reference_firmware_that_diverges_end_to_end(tmp_path, monkeypatch, capsys):
    """The reference firmware built with AHRS_DIVERGE=1 (the MISRA-refactor bug: halfT multiplies only the last term
    of the q0 update), through steval emulate, replay, compare and export --csv, as a student would."""
    import re

    from support import firmware as S
    from support.cli import run_cli

    why = S.missing()
    if why:
        pytest.skip(why)
    if not hasattr(S, "build_reference"):
        pytest.skip("tests/support/firmware.py has no build_reference (the reference firmware is not merged yet)")
    elf = S.build_reference(tmp_path, "AHRS_DIVERGE=1")
    cap = tmp_path / "div.stv"
    code, out, err = run_cli(
        monkeypatch, capsys, "emulate", elf, "--scenario", "hand-tilts", "--duration", "15", "--out", cap, "--no-view"
    )
    assert code == 0, err
    sent = int(re.search(r"(\d+) attitude, \d+ status", out).group(1))
    assert sent > 1800  # 15 s from a boot: about 12 s of AHRS steps at 161.5 Hz
    # the firmware's q leaves the unit sphere; once it is NaN or beyond ±2 the frames are flagged and said so
    code, js, err = run_cli(monkeypatch, capsys, "replay", cap, "--json")
    assert code == 0, err
    s = json.loads(js)
    assert s["frames"]["attitude"] == sent and s["implausible"] == 0  # nothing CRC-valid was held back
    off = s["q_off_unit_sphere"]
    assert off is not None  # the step where it leaves the unit sphere (compare names it below)
    bad = s["values_bad"]
    if bad is not None:  # NaN or |q| > 2: the sentence in the emulate summary, the replay text and compare
        assert bad["text"] in out
        code, text, err = run_cli(monkeypatch, capsys, "replay", cap)
        assert f"firmware output: {bad['text']}" in text
    code, text, err = run_cli(monkeypatch, capsys, "compare", cap)
    assert code == 0, err
    step = off["first_step"]
    assert re.search(rf"→ the firmware's own filter (left the unit sphere|went non-finite) at step {step} ", text)
    assert f"inputs at step {step}: acc (" in text
    assert "the bit-exact replica stayed finite on the same inputs" in text
    assert "no known setting reproduces it" not in text  # no settings were searched for a diverged filter
    assert "no status frames" not in text
    code, js, err = run_cli(monkeypatch, capsys, "compare", cap, "--json")
    assert code == 0, err
    d = json.loads(js)["replica"]["divergence"]
    assert d["step"] == step and d["replica"] == "finite" and len(d["inputs"]) == 2
    csv_path = tmp_path / "div.csv"
    code, _, err = run_cli(monkeypatch, capsys, "export", cap, "--csv", csv_path)
    assert code == 0, err
    rows = list(csv.DictReader(csv_path.open()))
    assert len(rows) == sent
    assert sum(r["values_bad"] == "1" for r in rows) == (bad["frames"] if bad else 0)


def test_the_row_checks_agree_with_the_frame_checks():
    """The vectorised checks (bulk decoder, Telemetry) and the per-frame ones (incremental decoder) flag the same."""
    from steval_link.link.plausibility import (
        attitude_frame_bad,
        attitude_rows_bad,
        status_rows_bad,
        status_values_ok,
    )

    rng = np.random.default_rng(5)
    specials = np.array([0.0, 1.0, -1.9, 2.0, 2.5, -3.0, 9e4, 1.1e5, 1.9e7, 2.1e7, np.nan, np.inf, -np.inf], np.float32)
    n = 3000
    pick = lambda *shape: specials[rng.integers(0, len(specials), shape)]  # noqa: E731
    acc, gyro, q, thz, thx, thy = pick(n, 3), pick(n, 3), pick(n, 4), pick(n), pick(n), pick(n)
    exact = rng.random(n) < 0.7
    rows = attitude_rows_bad(exact, acc, gyro, q, thz, thx, thy)
    frames = [
        attitude_frame_bad(
            AttitudeFrame(
                0,
                tuple(acc[i]),
                tuple(gyro[i]),
                tuple(q[i]),
                float(thz[i]),
                0,
                0,
                bool(exact[i]),
                thx_rad=float(thx[i]),
                thy_rad=float(thy[i]),
            )
        )
        for i in range(n)
    ]
    assert rows.tolist() == frames and 0 < rows.sum() < n
    ints, kp = pick(n, 3), pick(n, 4)
    rows = status_rows_bad(True, q, ints, kp[:, 0], kp[:, 1], kp[:, 2], kp[:, 3])
    ok = [status_values_ok(q[i], ints[i], *kp[i]) for i in range(n)]
    assert rows.tolist() == [not x for x in ok]

"""The motion stream's cadence (steval_link.link.ble_telemetry.motion_cadence) on streams a drone really sends: a
firmware that notifies at its own rate from its main loop (40, 50, 80 Hz and ST's 161.54 Hz), the same with ST's
congestion skips (30 motion updates after a refused one), across the 8 ms tick's wrap, with jittered host arrival
times, and a poller reading the characteristic at 30-40 Hz (repeated reads of one sample). Each is decoded from its
notification bytes, replayed from a capture (``steval replay``) and played through the fake BLE backend into the
live session (``steval live --ble``'s ``BleSource``)."""

from __future__ import annotations

import json
import struct
import sys

import numpy as np
import pytest
from support.ble import FakeBleBackend, RecordingViewer, held_rows, run_until_played, telemetry_of_records
from support.cli import run_cli

from steval_link.link import ble_payloads as B
from steval_link.link import ble_telemetry as BC
from steval_link.link.capture import CHUNK_BLE, CaptureWriter
from steval_link.link.load import load_telemetry

STEP_S = BC.STEP_PERIOD_S
WRAP_MS = 1 << 19  # HAL_GetTick() at which the u16 tick (>> 3) wraps


def send_times(rate_hz: float, duration_s: float, t0_s: float = 0.003) -> np.ndarray:
    """When a firmware whose main loop runs once per AHRS step sends motion "every 1/rate_hz": at the first step at
    or after each period boundary (ST's own 161.54 Hz: every step)."""
    steps = t0_s + np.arange(int(duration_s / STEP_S) + 1) * STEP_S
    if rate_hz >= 1 / STEP_S - 0.01:
        return steps
    period = 1.0 / rate_hz
    out, k = [], 0
    for t in steps:
        if t >= t0_s + k * period:
            out.append(t)
            k += 1
    return np.asarray(out)


def skip_runs(n: int, every: int = 150, skip: int = 30, first: int = 70) -> np.ndarray:
    """Which of n motion updates are sent when ST's congestion code skips ``skip`` after a refused one (a refused
    update is lost too: ``skip + 1`` missing), a refusal every ``every`` sent ones."""
    keep = np.ones(n, bool)
    i = first
    while i + skip + 1 < n:
        keep[i : i + skip + 1] = False
        i += skip + 1 + every
    return keep


def motion_payload(tick_ms: int, i: int) -> bytes:
    return struct.pack("<H3h3h3h", (tick_ms >> 3) & 0xFFFF, i % 1000, -(i % 977), 1000, i % 300, 5, -5, 1, 2, i % 7)


def arrivals(t_send: np.ndarray, rng, latency_s: float = 0.02, jitter_s: float = 0.006) -> np.ndarray:
    """Host arrival times, s since the capture started: delivered at the next 12.5 ms connection event, then a
    random host delay; never earlier than the one before (arrival order)."""
    t = np.ceil(t_send / 0.0125) * 0.0125 + latency_s + rng.uniform(0, jitter_s, len(t_send))
    return np.maximum.accumulate(t)


def drone_stream(
    rate_hz: float,
    *,
    duration_s: float = 12.0,
    congested: bool = False,
    start_ms: int = 123_456,
    others: bool = True,
    seed: int = 0,
):
    """(t_host_s, char id, payload) in arrival order, and the truth: motion samples sent, and missing."""
    rng = np.random.default_rng(seed)
    t = send_times(rate_hz, duration_s)
    keep = skip_runs(len(t)) if congested else np.ones(len(t), bool)
    recs = []
    host = arrivals(t, rng)
    for i in np.flatnonzero(keep):
        recs.append((float(host[i]), B.CHAR_MOTION, motion_payload(int(start_ms + t[i] * 1000), int(i))))
    if others:  # environment and arming once per AHRS step, as ST's main loop sends them
        steps = send_times(1 / STEP_S, duration_s)
        hs = arrivals(steps, rng)
        for j, ts in enumerate(steps):
            tick = (int(start_ms + ts * 1000) >> 3) & 0xFFFF
            recs.append((float(hs[j]) + 1e-5, B.CHAR_ENV, struct.pack("<HiHhh", tick, 101325, 926, 250, -620)))
            recs.append((float(hs[j]) + 2e-5, B.CHAR_ARMING, struct.pack("<HB", tick, 0)))
    recs.sort(key=lambda r: r[0])
    last = np.flatnonzero(keep)[[0, -1]]
    missing = int((~keep[last[0] : last[1] + 1]).sum())
    return recs, int(keep.sum()), missing


def poller_stream(
    read_hz: float, *, duration_s: float = 12.0, double_every: int = 9, seed: int = 1, start_ms: int = 40_000
):
    """A central that reads the motion characteristic of ST's firmware (updated every AHRS step) ``read_hz`` times a
    second at irregular host moments, reading twice in a row now and then (``double_every``): (records, distinct
    samples read, reads)."""
    rng = np.random.default_rng(seed)
    steps = send_times(1 / STEP_S, duration_s + 1)
    reads = 0.2 + np.cumsum(np.clip(rng.normal(1 / read_hz, 0.004, int(duration_s * read_hz)), 0.002, None))
    reads = np.sort(np.concatenate([reads, reads[::double_every] + 0.0005]))  # a second read 0.5 ms later
    j = np.searchsorted(steps, reads - 0.010, side="right") - 1  # the value as the firmware last wrote it
    recs = [
        (float(r), B.CHAR_MOTION, motion_payload(int(start_ms + steps[k] * 1000), int(k))) for r, k in zip(reads, j)
    ]
    return recs, len(np.unique(j)), len(reads)


# -- the cadence from the ticks -------------------------------------------------------------------------------------

RATES = [40.0, 50.0, 80.0, 1 / STEP_S]


@pytest.mark.parametrize("rate_hz", RATES, ids=["40Hz", "50Hz", "80Hz", "161.5Hz"])
def test_a_sender_at_its_own_rate_drops_nothing(rate_hz):
    recs, sent, _ = drone_stream(rate_hz)
    tel = telemetry_of_records(recs)
    assert len(tel.link.samples) == sent
    c = tel.link.cadence
    assert c.kind == BC.STEADY and c.dropped == 0 and c.gaps == 0 and c.repeats == 0
    assert c.rate_hz == pytest.approx(rate_hz, rel=2e-3)
    assert c.exact == (rate_hz > 160)  # ST's step is known exactly; other rates are measured
    a = tel.attitude
    assert tel.link.dt_s == c.interval_s and not held_rows(tel).any() and len(a) == sent
    assert (tel.link.samples["row"] == np.arange(sent)).all() and (np.diff(a.t_fw_s) > 0).all()
    assert "the sender's own rate), 0 dropped" in c.describe()


@pytest.mark.parametrize("rate_hz", RATES, ids=["40Hz", "50Hz", "80Hz", "161.5Hz"])
def test_congestion_gaps_count_at_the_senders_cadence(rate_hz):
    recs, sent, missing = drone_stream(rate_hz, congested=True)
    tel = telemetry_of_records(recs)
    c = tel.link.cadence
    assert missing >= 60 and c.gaps == missing // 31
    assert c.rate_hz == pytest.approx(rate_hz, rel=2e-3)
    assert c.dropped == missing  # every skipped update, counted at the sender's own period
    assert c.kind == (BC.CONGESTION if rate_hz > 160 else BC.GAPS)
    a, held = tel.attitude, held_rows(tel)
    assert int(held.sum()) == missing and len(a) == sent + missing and tel.link.dt_s == c.interval_s
    # a held row repeats the last sample received before the gap
    i = int(np.flatnonzero(held)[0])
    assert (a.acc_mg[i] == a.acc_mg[i - 1]).all() and not held[i - 1]
    text = c.describe()
    assert f"with {missing} dropped in {c.gaps} gap(s)" in text
    assert ("congestion" in text) == (rate_hz > 160)


@pytest.mark.parametrize("rate_hz", [50.0, 1 / STEP_S], ids=["50Hz", "161.5Hz"])
def test_across_the_tick_wrap(rate_hz):
    # HAL_GetTick() starts 3 s before the u16 tick wraps: the wrap falls in the middle of the stream
    for congested in (False, True):
        recs, sent, missing = drone_stream(rate_hz, congested=congested, start_ms=WRAP_MS - 3000, duration_s=8)
        ble = telemetry_of_records(recs).link
        tick = ble.samples["tick"]
        assert tick[0] < 1 << 16 <= tick[-1] and (np.diff(tick) >= 0).all()
        c = ble.cadence
        assert c.dropped == (missing if congested else 0) and c.rate_hz == pytest.approx(rate_hz, rel=3e-3)


def test_a_poller_reading_the_characteristic():
    for read_hz in (30.0, 35.0, 40.0):
        recs, distinct, reads = poller_stream(read_hz)
        tel = telemetry_of_records(recs)
        ble = tel.link
        # a repeated read of one sample (same tick and values) is that sample once
        assert len(ble.samples) == distinct and ble.repeated_reads == reads - distinct > 0
        assert ble.counts["motion"] == reads
        c = ble.cadence
        assert c.kind == BC.POLLED and c.dropped == 0 and c.repeats == reads - distinct
        span = float(ble.samples["tick"][-1] - ble.samples["tick"][0]) * B.TICK_S
        assert c.rate_hz == pytest.approx((distinct - 1) / span) and abs(c.rate_hz - read_hz) < 0.1 * read_hz
        assert len(tel.attitude) == distinct and not held_rows(tel).any()
        assert ble.dt_s == pytest.approx(span / (distinct - 1))
        assert "reads of the characteristic" in c.describe() and c.describe().endswith("0 dropped")
    # read without repeats, the same stream is a regular cadence at the read rate: still nothing dropped
    recs, distinct, reads = poller_stream(35.0, double_every=10**9)
    c = telemetry_of_records(recs).link.cadence
    assert c.dropped == 0 and abs(c.rate_hz - 35.0) < 3.5


def test_period_and_gap_rules_on_tick_deltas():
    # 50 Hz: deltas 2 and 3 ticks (2.5 on average); a jitter of one tick more is no gap, 1.5 periods + a tick is
    assert BC.period_ticks([2, 3] * 50) == 2.5
    assert BC.period_ticks([2, 3] * 50 + [40]) == pytest.approx(2.5, abs=0.03)
    assert BC.gap_mask(np.array([1, 2, 3, 4, 5, 6]), 2.5).tolist() == [False] * 4 + [True] * 2
    # ST's step (0.774 tick): two ticks already mean a notification missing
    assert BC.gap_mask(np.array([0, 1, 2, 24]), 0.774).tolist() == [False, False, False, True]
    assert BC.motion_cadence([5]) is None and BC.motion_cadence([5, 5, 5]) is None
    c = BC.Cadence(BC.CONGESTION, STEP_S, 1212, 40, 0, 30.0, True)
    assert c.describe().startswith("motion every 6.19 ms (161.54 Hz) with 1 212 dropped in 40 gap(s) (congestion")


# -- replayed (steval replay of a BLE capture) ------------------------------------------------------------------------


def write_capture(path, recs) -> None:
    with CaptureWriter(path, port="ble:DRN1110", baud=0, extra={"link": "ble", "device": "DRN1110"}) as w:
        for t, cid, p in recs:
            w.write_chunk(CHUNK_BLE, B.ble_chunk(cid, p), t)


@pytest.mark.parametrize(
    "rate_hz, congested",
    [(50.0, False), (50.0, True), (1 / STEP_S, True)],
    ids=["50Hz", "50Hz-gaps", "stock-congestion"],
)
def test_replay_says_the_cadence(monkeypatch, capsys, tmp_path, rate_hz, congested):
    recs, sent, missing = drone_stream(rate_hz, congested=congested, start_ms=WRAP_MS - 5000)
    path = tmp_path / "b.stv"
    write_capture(path, recs)
    code, out, err = run_cli(monkeypatch, capsys, "replay", path, "--json")
    assert code == 0, err
    s = json.loads(out)
    assert s["motion_dropped_estimate"] == missing and s["rows_held_over_drops"] == missing
    assert s["motion_rate_hz"] == pytest.approx(rate_hz, rel=2e-3) and s["tick_wraps"] == 1
    assert s["estimator_dt_ms"] == pytest.approx(1e3 / rate_hz, rel=2e-3)
    assert s["motion_cadence"] == (BC.STEADY if not congested else BC.CONGESTION if rate_hz > 160 else BC.GAPS)
    code, out, err = run_cli(monkeypatch, capsys, "replay", path)
    line = next(x for x in out.splitlines() if x.startswith("cadence"))
    if not congested:
        assert "motion every 20.0 ms (50.0 Hz, the sender's own rate), 0 dropped" in line
        assert "no rows held" in out
    else:
        assert f"with {missing} dropped" in line and f"{missing} rows held over dropped notifications" in out


def test_replay_of_a_poller_capture(monkeypatch, capsys, tmp_path):
    recs, distinct, reads = poller_stream(35.0)
    path = tmp_path / "p.stv"
    write_capture(path, recs)
    code, out, err = run_cli(monkeypatch, capsys, "replay", path, "--json", "-e", "accel")
    s = json.loads(out)
    assert code == 0 and s["motion_cadence"] == BC.POLLED and s["motion_dropped_estimate"] == 0
    assert s["motion_repeated_reads"] == reads - distinct and s["rows_held_over_drops"] == 0
    assert abs(s["motion_rate_hz"] - 35.0) < 3.5


# -- live (steval live --ble through the fake backend) ----------------------------------------------------------------


def run_live(tmp_path, recs, pace_s=0.0002, estimators=("st-mahony", "accel"), drop_after=()):
    from steval_link.live.session import LiveOptions, LiveSession, source_for
    from steval_viewer.sink_options import SinkOptions

    viewer = RecordingViewer()
    fake = FakeBleBackend([(c, p) for _, c, p in recs], pace_s=pace_s, drop_after=list(drop_after))
    opts = LiveOptions(
        out=tmp_path / "live.stv", sinks=SinkOptions(rrd=tmp_path / "x.rrd"), estimators=list(estimators)
    )
    source = source_for("ble:auto", backend=fake)
    session = LiveSession(opts, source, viewer_factory=lambda o, name: viewer, stream=sys.stderr)

    summary = run_until_played(session, fake)
    return summary, viewer.batches, session.pipeline  # the one pipeline holds the estimators and the grid


@pytest.mark.parametrize(
    "rate_hz, congested",
    [(50.0, False), (40.0, True), (1 / STEP_S, True)],
    ids=["50Hz", "40Hz-gaps", "stock-congestion"],
)
@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_live_session_says_the_cadence(tmp_path, rate_hz, congested):
    recs, sent, missing = drone_stream(
        rate_hz, congested=congested, duration_s=6, others=False, start_ms=WRAP_MS - 3000
    )
    summary, rows, pipe = run_live(tmp_path, recs)
    assert summary.counts["motion"] == sent
    c = summary.cadence
    assert c.dropped == summary.rows_held == missing
    assert c.kind == (BC.STEADY if not congested else BC.CONGESTION if rate_hz > 160 else BC.GAPS)
    assert c.rate_hz == pytest.approx(rate_hz, rel=5e-3)
    # the estimators' rows: one per sample sent, dt of the cadence found (the same grid as a replay's)
    t_grid = np.concatenate([r.attitude.t_fw_s for r in rows])
    assert len(t_grid) == sent + missing
    assert pipe.estimators.others["st-mahony"].settings.dt_s == pytest.approx(1 / rate_hz, rel=5e-3)
    replayed = load_telemetry(tmp_path / "live.stv")
    assert len(replayed.attitude) == len(t_grid) and int(held_rows(replayed).sum()) == missing
    # the same rows at the replay's times: within half a period while the live interval is refined, then closer
    err = np.abs(t_grid - replayed.attitude.t_fw_s)
    assert err.max() < 0.5 / rate_hz and err[-len(rows[-1]) :].max() < 0.05 / rate_hz
    text = summary.line()
    if congested:
        assert f"with {missing} dropped" in text
    else:
        assert "motion every 20.0 ms (50" in text and "the sender's own rate), 0 dropped" in text
    q = rows[-1].estimates["st-mahony"]
    assert q.shape == (len(rows[-1]), 4) and np.isfinite(q).all()


def test_live_session_of_a_poller(tmp_path):
    recs, distinct, reads = poller_stream(35.0, duration_s=6)
    summary, rows, pipe = run_live(tmp_path, recs, estimators=("accel",))
    c = summary.cadence
    assert summary.counts["motion"] == reads and pipe.grid.repeats == reads - distinct == c.repeats
    assert c.kind == BC.POLLED and summary.rows_held == 0 and abs(c.rate_hz - 35.0) < 3.5
    assert sum(len(r) for r in rows) == distinct  # one row per distinct sample read
    assert "reads of the characteristic" in summary.line()


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_a_lost_link_is_no_drop(tmp_path, monkeypatch, capsys):
    """The drone sends nothing while no central is connected: the gap of a link loss (the capture's reconnect
    event) is not counted as dropped and gets no held rows, live and replayed; the same gap without a reconnection
    is a gap of the sender's cadence."""
    recs, sent, _ = drone_stream(50.0, duration_s=6, others=False)
    lost = slice(120, 220)  # 2 s of samples never sent: the link was down
    recs = recs[: lost.start] + recs[lost.stop :]
    n = len(recs)
    summary, rows, pipe = run_live(tmp_path, recs, drop_after=[lost.start])
    assert summary.disconnects == 1 and summary.counts["motion"] == n
    c = summary.cadence
    assert c.kind == BC.STEADY and c.dropped == summary.rows_held == 0
    assert sum(len(r) for r in rows) == n  # no row over the 2 s the drone sent nothing
    t_grid = np.concatenate([r.attitude.t_fw_s for r in rows])
    assert np.diff(t_grid).max() == pytest.approx(101 * 0.02, abs=0.01)  # the estimators step once over it
    # replayed: the capture's reconnect event says the same
    code, out, err = run_cli(monkeypatch, capsys, "replay", tmp_path / "live.stv", "--json")
    s = json.loads(out)
    assert code == 0 and s["motion_cadence"] == BC.STEADY and s["motion_dropped_estimate"] == 0
    assert s["rows_held_over_drops"] == 0 and [e["kind"] for e in s["events"]].count("reconnect") == 1
    # without the reconnection the same ticks are a gap of the cadence: 100 dropped
    c = telemetry_of_records(recs).link.cadence
    assert c.kind == BC.GAPS and c.dropped == 100 and c.gaps == 1

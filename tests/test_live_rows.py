"""The live pipeline's rows are ``load_telemetry``'s rows: a real capture's bytes fed chunk by chunk, as received."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.viewers import NullViewer

from steval_link.link.capture import read_capture
from steval_link.link.load import load_telemetry
from steval_link.link.telemetry import AttitudeArrays
from steval_link.live.pipeline import LivePipeline, LiveRows

RECORDINGS = Path(__file__).resolve().parent.parent / "recordings"


class Rows(NullViewer):
    """The viewer side: keeps the rows and the status times it is given."""

    def __init__(self) -> None:
        self.rows: list[LiveRows] = []
        self.status: list[tuple[int, float, float]] = []

    def log_batch(self, rows: LiveRows) -> None:
        self.rows.append(rows)

    def log_status(self, frame, at) -> None:
        self.status.append((int(frame.step), at.t_fw_s, at.t_host_s))


def feed_capture(path: Path, t0_unix_s: float, seed: int = 0) -> Rows:
    """The capture's received chunks fed at their recorded times (on a clock starting at ``t0_unix_s``), a random
    number of chunks per processing round, as the session's main loop takes them from its inbox."""
    cap = read_capture(path)
    ends = np.append(cap.chunk_offsets[1:], len(cap.data))
    chunks = [(cap.data[a:b], t0_unix_s + t) for a, b, t in zip(cap.chunk_offsets, ends, cap.chunk_times_s)]
    log = Rows()
    pipe = LivePipeline(["st-mahony"], log, t0_unix_s=t0_unix_s, baud=cap.header["baud"])
    rng = np.random.default_rng(seed)
    i = 0
    while i < len(chunks):
        k = int(rng.integers(1, 6))
        pipe.feed(chunks[i : i + k])
        i += k
    pipe.flush_view()
    return log


FIELDS = [name for name in AttitudeArrays.__dataclass_fields__]


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@pytest.mark.parametrize("name", ["demo.stv", "midflight_drops.stv", "live_params.stv", "flight.stv"])
def test_live_rows_equal_load_telemetry_bit_for_bit(name):
    path = RECORDINGS / name
    tel = load_telemetry(path)
    # the capture's clock origin at 0: t_unix_s - t0 is then the capture's own chunk time, as in a live session,
    # where the recorder stores t_unix_s - t0 and the pipeline computes the same difference
    log = feed_capture(path, 0.0)
    live = AttitudeArrays.concat([r.attitude for r in log.rows])
    ref = tel.attitude
    assert len(live) == len(ref) > 1000
    for field in FIELDS:
        a, b = getattr(live, field), getattr(ref, field)
        assert a.dtype == b.dtype and a.shape == b.shape, field
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), field  # bit for bit (NaN included)
    # status frames: the same firmware and host times as the status rows
    st = np.array(log.status)
    assert np.array_equal(st[:, 0].astype(np.int64), tel.status.step.astype(np.int64))
    assert np.array_equal(st[:, 1], tel.status.t_fw_s) and np.array_equal(st[:, 2], tel.status.t_host_s)


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_live_rows_on_the_unix_clock_are_the_capture_times_within_its_resolution():
    # a real session's clock: Unix seconds; the capture's chunk times went through (t0 + t) - t0, exact to 1 ulp
    # of 1.7e9 s (0.24 µs) here only because the test rebuilds Unix times from the stored ones
    path = RECORDINGS / "demo.stv"
    tel = load_telemetry(path)
    log = feed_capture(path, float(read_capture(path).header["start_time_unix_s"]), seed=1)
    live = AttitudeArrays.concat([r.attitude for r in log.rows])
    assert np.array_equal(live.t_fw_s, tel.attitude.t_fw_s) and np.array_equal(live.step, tel.attitude.step)
    assert np.abs(live.t_host_s - tel.attitude.t_host_s).max() < 1e-6


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
@pytest.mark.parametrize("cut_at_restart", [False, True])
def test_a_restart_and_a_stream_joined_past_the_seq_wrap(tmp_path, cut_at_restart):
    # joined at step 70 000 (seq 4464: the high bits come with the first status frame) while t_us wraps (2³² µs),
    # then a firmware restart (cut_at_restart: its first frame begins a chunk, so it may begin a processing round)
    from support.streams import StreamBuilder

    from steval_link.link import protocol as P
    from steval_link.link.capture import CaptureWriter

    b = StreamBuilder(seed=3)
    for k in range(700):
        step, t_us = 70_000 + k, (4_294_000_000 + k * 6192) % P.T_US_MODULUS
        b.attitude(step % P.SEQ_MODULUS, t_us=t_us)
        if step % 161 == 160:
            b.status(step, t_us=t_us)
    first = b.bytes()
    b.text("STEVAL boot")
    data = b.flight(500).bytes()
    path = tmp_path / "restart.stv"
    rng = np.random.default_rng(4)
    with CaptureWriter(path, port="test", baud=115200) as cap:
        pos, t = 0, 0.5
        while pos < len(data):
            n = int(rng.integers(1, 300))
            if cut_at_restart and pos < len(first) < pos + n:
                n = len(first) - pos
            cap.write(data[pos : pos + n], t)
            pos, t = pos + n, t + n / 11520.0 + float(rng.uniform(0, 0.01))
    tel = load_telemetry(path)
    live = AttitudeArrays.concat([r.attitude for r in feed_capture(path, 0.0).rows])
    ref = tel.attitude
    assert len(live) == len(ref) == 1200
    for field in FIELDS:
        if field != "step":
            assert np.array_equal(getattr(live, field).view(np.uint8), getattr(ref, field).view(np.uint8)), field
    # t_us wrapped in the first run; the firmware restart: steps and firmware time from 0 again, on both paths
    assert ref.t_fw_s[699] > 2**32 / 1e6 and ref.step[700] == 0 and ref.t_fw_s[700] < 1.0
    # the one difference: the bulk path gives the high bits of the status frame to the rows before it too; live,
    # those rows are gone already, so they keep the seq's (one wrap, 65 536 steps, lower)
    first_status = int(np.flatnonzero(live.step != ref.step).max()) + 1
    assert np.array_equal(ref.step[:first_status] - live.step[:first_status], np.full(first_status, 65_536))
    assert np.array_equal(live.step[first_status:], ref.step[first_status:]) and 0 < first_status <= 161

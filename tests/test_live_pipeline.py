"""The live pipeline in-process: the seeded ST replica against the offline replay, batches, health, bounded memory."""

from __future__ import annotations

import io
import os
import threading
import time

import numpy as np
import pytest
from support.ptyfeed import REAL_BYTES_PER_S, PtyFeeder, flight_stream

from steval_link import constants as C
from steval_link.estimators.firmware_replay import replay_firmware
from steval_link.estimators.st_mahony import bits_equal
from steval_link.link import protocol
from steval_link.link.capture import default_capture_path
from steval_link.link.decoder import decode_bytes
from steval_link.live.health import HealthDisplay
from steval_link.live.pipeline import LivePipeline, StepUnwrapper
from steval_link.live.serial_source import Inbox
from steval_link.live.session import LiveOptions, LiveSession, source_for


class BatchLog:
    """Collects what the pipeline hands to the viewer (the viewer's side of the interface)."""

    def __init__(self) -> None:
        self.batches = []
        self.status = []
        self.text = []

    def log_batch(self, batch) -> None:
        self.batches.append(batch)

    def log_status(self, frame, at) -> None:
        self.status.append(frame)

    def log_text(self, frame, at) -> None:
        self.text.append(frame.text)

    def rows(self, name: str) -> np.ndarray:
        return np.concatenate([b.estimates[name] for b in self.batches])

    def column(self, field: str) -> np.ndarray:
        # a field of the rows (AttitudeArrays) or ``finite`` (a property of LiveRows)
        return np.concatenate([b.finite if field == "finite" else getattr(b.attitude, field) for b in self.batches])


def feed_in_chunks(pipe: LivePipeline, data: bytes, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    pos = 0
    t = 1.7e9
    while pos < len(data):
        n = int(rng.integers(1, 400))
        pipe.feed([(data[pos : pos + n], t)])
        pos += n
        t += n / 9788.0


@pytest.mark.parametrize("first_step", [0, 2500])
def test_port_matches_the_offline_replay_bit_for_bit(first_step):
    data = flight_stream(900, first_step=first_step, text_lines=("STEVAL boot",))
    log = BatchLog()
    pipe = LivePipeline(["st-mahony", "accel"], log)
    feed_in_chunks(pipe, data)
    live_q = log.rows("st-mahony")
    replay = replay_firmware(decode_bytes(data))
    assert live_q.shape == replay.q_wxyz.shape == (900, 4)
    # the same rows are seeded (power-up at step 0, else from the first status snapshot) with the same bits
    seeded = np.isfinite(live_q).all(axis=1)
    assert np.array_equal(seeded, replay.seeded)
    assert bits_equal(live_q[seeded], replay.q_wxyz[seeded]).all()
    assert bits_equal(live_q[seeded], log.column("q_wxyz")[seeded]).all()  # == the firmware's own q
    replica = pipe.mahony
    assert replica.rows_mismatch == 0 and replica.rows_exact == seeded.sum()
    if first_step == 0:
        assert seeded.all()
    else:
        assert 0 < seeded.argmax() <= 161 and not seeded[: seeded.argmax()].any()
    assert replica.confirmed >= 4  # later snapshots agree with the replica's own state
    assert log.text == ["STEVAL boot"] and len(log.status) == len(decode_bytes(data).status)
    assert list(pipe.texts) == ["STEVAL boot"]  # shown to the user by the session
    steps = log.column("step")
    assert np.array_equal(steps, np.arange(first_step, first_step + 900))
    assert np.isfinite(log.rows("accel")).all()


def test_status_and_text_frames_do_not_cut_a_view_batch():
    # 900 frames with 5 status frames and a text line, all within one view interval: one batch, then the events
    data = flight_stream(900, text_lines=("STEVAL boot",))

    class Ordered(BatchLog):
        def __init__(self) -> None:
            super().__init__()
            self.order = []

        def log_batch(self, batch) -> None:
            super().log_batch(batch)
            self.order.append("batch")

        def log_status(self, frame, at) -> None:
            super().log_status(frame, at)
            self.order.append("status")

        def log_text(self, frame, at) -> None:
            super().log_text(frame, at)
            self.order.append("text")

    log = Ordered()
    pipe = LivePipeline(["st-mahony"], log, view_interval_s=3600.0)
    feed_in_chunks(pipe, data)
    assert log.order == []  # 900 frames are 5.6 s of stream: still pending
    pipe.flush_view()
    n_status = len(decode_bytes(data).status)
    assert n_status >= 5
    assert log.order[0] == "batch"
    assert log.order.count("batch") == 1 and log.order.count("status") == n_status and log.order.count("text") == 1
    assert len(log.batches[0]) == 900
    assert pipe.mahony.rows_mismatch == 0 and pipe.mahony.rows_exact > 0  # the replica still saw each snapshot in order


def test_view_batches_are_bounded_in_stream_time():
    data = flight_stream(900)
    log = BatchLog()
    pipe = LivePipeline(["accel"], log, view_interval_s=1.0)  # at most ~162 frames per batch, however fast fed
    feed_in_chunks(pipe, data)  # fed in one go, far faster than real time
    pipe.flush_view()
    sizes = [len(b) for b in log.batches]
    assert sum(sizes) == 900 and max(sizes) <= 2 * 162 and len(sizes) >= 3


def test_port_resyncs_after_lost_frames_and_follows_lab_settings():
    # ETH exercise 4: KI = 1.0, reported by the status frames; frames 300..309 lost on the link
    data = flight_stream(800, first_step=1000, ki=1.0)
    # after two status frames (steps 1126, 1287)
    cut_a = 300 * protocol.ATTITUDE_FRAME_SIZE + 2 * protocol.STATUS_FRAME_SIZE
    lost = data[:cut_a] + data[cut_a + 10 * protocol.ATTITUDE_FRAME_SIZE :]
    log = BatchLog()
    pipe = LivePipeline(["st-mahony"], log)
    feed_in_chunks(pipe, lost, seed=3)
    q = log.rows("st-mahony")
    seeded = np.isfinite(q).all(axis=1)
    fw = log.column("q_wxyz")
    assert bits_equal(q[seeded], fw[seeded]).all() and pipe.mahony.rows_mismatch == 0
    assert pipe.mahony.settings.ki == np.float32(1.0)
    # unseeded from the gap to the next snapshot, then exact again
    steps = log.column("step")
    gap_row = int(np.flatnonzero(np.diff(steps) > 1)[0]) + 1
    assert seeded[gap_row - 1] and not seeded[gap_row]
    assert seeded[gap_row:].any() and seeded[-1]
    assert pipe.decoder.stats.frames_missing == 10
    assert pipe.mahony.seed_count == 2


def test_nonfinite_frames_are_counted_and_never_reach_an_estimator():
    good = flight_stream(400)
    FS = protocol.ATTITUDE_FRAME_SIZE
    frames = [good[i : i + FS] for i in range(0, 161 * FS, FS)]  # first 161 attitude frames
    out = bytearray()
    for k, f in enumerate(frames):
        if k in (50, 51, 90):
            rec = np.frombuffer(f[4:56], dtype=protocol.ATTITUDE_DTYPE).copy()
            rec["acc_mg"][0, 0] = np.nan if k != 90 else np.inf
            f = protocol.encode_frame(protocol.TYPE_ATTITUDE, rec.tobytes())
        out += f
    out += good[161 * FS :]
    log = BatchLog()
    pipe = LivePipeline(["st-mahony", "accel"], log)
    feed_in_chunks(pipe, bytes(out))
    # protocol v2: CRC-32-valid frames that continue the sequence are kept and flagged, whatever their values (#24)
    assert pipe.decoder.stats.implausible == 0 and pipe.decoder.stats.values_bad == 3 and pipe.health.nonfinite == 3
    assert pipe.health.values_bad == 3 and pipe.health.first_bad_step == 50
    steps = log.column("step")
    assert np.isin([50, 51, 90], steps).all() and len(steps) == 400
    finite = log.column("finite").astype(bool)
    assert (~finite).sum() == 3 and not finite[np.isin(steps, [50, 51, 90])].any()
    accel = log.rows("accel")
    assert np.isfinite(accel[finite]).all()
    replica = log.rows("st-mahony")
    before = steps < 50
    assert np.isfinite(replica[before]).all()  # from power-up
    assert np.isnan(replica[(steps > 51) & (steps <= 160)]).all()  # no state to follow until the snapshot of 160
    assert np.isfinite(replica[steps > 160]).all()
    assert pipe.mahony.rows_mismatch == 0


def test_step_unwrapper_crosses_the_seq_wrap():
    class F:
        def __init__(self, seq, step=None):
            self.seq, self.step = seq, step

    u = StepUnwrapper()
    u.status(65533 + 65536)  # a status frame tells the full step
    got, restart = u.frames([F(65534), F(65535), F(0), F(2)])
    assert list(got) == [65534 + 65536, 65535 + 65536, 131072, 131074]
    assert not restart.any()


def test_inbox_drops_oldest_from_the_live_view_only_and_counts_it():
    box = Inbox(max_bytes=1000)
    for i in range(30):
        box.put(bytes([i]) * 100, float(i))
    got = box.get_all(0)
    assert sum(len(c) for c, _ in got) <= 1000 and got[-1][1] == 29.0
    assert box.dropped_bytes == 3000 - sum(len(c) for c, _ in got)
    assert box.get_all(0.01) == []


def test_health_line_rewrites_in_place_on_a_terminal_and_prints_lines_otherwise():
    tty = io.StringIO()
    d = HealthDisplay(tty, tty=True)
    d.show("a 161.5 Hz", 10.0)
    d.show("b", 10.01)  # too soon: not drawn
    d.show("c 160.9 Hz", 10.5)
    d.note("disconnected")
    d.close()
    assert tty.getvalue() == "\r\x1b[2Ka 161.5 Hz\r\x1b[2Kc 160.9 Hz\r\x1b[2Ksteval: disconnected\n"
    plain = io.StringIO()
    d = HealthDisplay(plain, tty=False)
    for k in range(100):
        d.show(f"line {k}", k * 0.1)
    assert plain.getvalue().count("\n") == 2 and "\r" not in plain.getvalue()


def test_default_capture_name_is_utc_and_unique(tmp_path):
    from datetime import datetime, timezone

    now = datetime(2026, 3, 1, 14, 5, 9, tzinfo=timezone.utc)
    p = default_capture_path(tmp_path / "recordings", now)
    assert p.name == "steval-20260301T140509Z.stv"
    p.parent.mkdir()
    p.write_bytes(b"")
    assert default_capture_path(tmp_path / "recordings", now).name == "steval-20260301T140509Z-2.stv"


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.slow
def test_endless_garbage_keeps_memory_bounded_and_records_every_byte(tmp_path):
    rng = np.random.default_rng(5)
    garbage = rng.integers(0, 256, 1 << 20, dtype=np.uint8).tobytes()
    # no sync pair, no line ending, no "$": nothing that could ever complete a frame or a text line
    garbage = garbage.replace(b"\xa5\x5a", b"\xa5\x00").replace(b"\n", b"\x0b").replace(b"$", b"%")
    out = tmp_path / "g.stv"
    err = io.StringIO()
    # 3 MB/s (26x the real link) for 4 s: 12 MB that can never decode
    with PtyFeeder(garbage, tmp_path / "ttyUSB0", bytes_per_s=3e6, loop=True) as feeder:
        source = source_for(str(feeder.link), wait=True)
        session = LiveSession(LiveOptions(out=out, estimators=[]), source, stream=err, tty=False)
        rss = []

        def drive():
            time.sleep(0.5)
            feeder.start()
            for _ in range(16):
                time.sleep(0.25)
                rss.append(_rss_bytes())
            session.request_stop("test")

        t = threading.Thread(target=drive)
        t.start()
        summary = session.run()
        t.join()
    from steval_link.link.capture import read_capture

    cap = read_capture(out)
    assert summary.attitude == 0 and summary.bytes_total == len(cap.data) > 5_000_000
    assert cap.data[:4096] == garbage[:4096]
    assert "no valid frames at 115200 baud" in err.getvalue() and "still waiting" in err.getvalue()
    pipe = session.pipeline
    assert pipe.decoder.pending_bytes < 64 * 1024 and len(pipe.sample) <= 4096
    # several MB went through; resident memory did not follow them
    assert max(rss) - rss[0] < 40 * 1024 * 1024


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_viewer_and_rrd_get_two_streams_of_one_recording_and_the_rrd_is_complete(tmp_path):
    # a live viewer (an in-process Rerun gRPC server, reached with --connect) and --rrd at once: the viewer gets every
    # processing round at once, the .rrd its own stream of the same recording with merged batches; stopping the
    # session (what Ctrl-C does) leaves a complete .rrd with every frame exactly once
    import socket

    import rerun as rr
    from rerun.chunk import RrdReader

    from steval_viewer import entities as ent
    from steval_viewer import live_adapter
    from steval_viewer.rrd_check import read_rrd
    from steval_viewer.sink_options import SinkOptions

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        grpc_port = s.getsockname()[1]
    server = rr.RecordingStream("test-viewer-server", make_default=False, make_thread_default=False)
    url = rr.serve_grpc(grpc_port=grpc_port, recording=server, server_memory_limit="64MB")

    n_frames = 1200
    data = flight_stream(n_frames, text_lines=("STEVAL boot",))
    n_status = len(decode_bytes(data).status)
    rrd = tmp_path / "live.rrd"
    made = []
    received: dict[str, list[int]] = {"live": [], "file": []}

    def factory(options, name):
        viewer = live_adapter.ViewerLogger(options, name)
        for key, logger in (("live", viewer.logger), ("file", viewer.file)):
            orig = logger.log_batch
            logger.log_batch = lambda batch, orig=orig, key=key: (received[key].append(len(batch)), orig(batch))
        made.append(viewer)
        return viewer

    sinks = SinkOptions(rrd=rrd, connect=url)
    opts = LiveOptions(out=tmp_path / "cap.stv", sinks=sinks, estimators=["st-mahony", "accel"])
    err = io.StringIO()
    with PtyFeeder(data, tmp_path / "ttyUSB0", bytes_per_s=8 * REAL_BYTES_PER_S) as feeder:
        source = source_for(str(feeder.link), wait=True)
        session = LiveSession(opts, source, stream=err, tty=False, viewer_factory=factory)

        def drive():
            deadline = time.monotonic() + 30
            while not made and time.monotonic() < deadline:
                time.sleep(0.05)
            feeder.start()
            while time.monotonic() < deadline:
                pipe = getattr(session, "pipeline", None)
                if pipe is not None and pipe.health.attitude >= n_frames:
                    break
                time.sleep(0.05)
            session.request_stop("interrupted")

        t = threading.Thread(target=drive)
        t.start()
        summary = session.run()
        t.join()

    assert summary.attitude == n_frames, err.getvalue()
    viewer = made[0]
    # two streams, one recording: the viewer's has no file sink, the file's is its own
    assert viewer.file is not None and viewer.session.file_rec is not viewer.session.rec
    assert viewer.session.file_rec.get_recording_id() == viewer.session.rec.get_recording_id()
    # the viewer got the frames round by round; the file the same frames in few merged batches
    assert sum(received["live"]) == n_frames and len(received["live"]) > 5
    assert sum(received["file"]) == n_frames and len(received["file"]) <= 2
    entry = RrdReader(str(rrd)).recordings()[0]
    assert entry.recording_id == viewer.session.rec.get_recording_id()
    info = read_rrd(rrd)
    assert info.has_blueprint and info.application_id == "steval-link"
    for path in (
        ent.pitch_path("firmware"),
        ent.roll_path("firmware"),
        ent.PLOT_ACC,
        ent.PLOT_GYRO,
        ent.pitch_path("accel"),
        ent.pitch_path(ent.SOURCE_REPLICA),
        ent.DIFF_THX,
    ):
        assert info.samples[path] == n_frames, path  # every frame once (nothing logged twice into the file)
    assert info.samples[ent.DRONE_FIRMWARE] >= 1
    assert info.samples[ent.LINK_CYCLES] == n_status
    assert info.samples[ent.LOG_FIRMWARE] == 1


def test_a_settings_change_is_noted_at_its_status_frames_time():
    """A status frame sent because of a command (FLAG_EVENT) reaches the loggers as a note at that frame's firmware
    and host time (the viewer places it on both timelines)."""

    class EventLog(BatchLog):
        def __init__(self) -> None:
            super().__init__()
            self.events = []

        def log_event(self, text, at, level="INFO") -> None:
            self.events.append((text, at.t_fw_s, at.t_host_s, level))

    log = EventLog()
    pipe = LivePipeline(["st-mahony"], log, view_interval_s=3600.0)
    t_us = 1_234_567 + round(299 * C.AHRS_PERIOD_S * 1e6)  # flight_stream's clock at step 299
    event = protocol.encode_status(
        step=299, t_us=t_us, q_wxyz=(1, 0, 0, 0), int_xyz=(0, 0, 0), ki=1.0, flags=protocol.FLAG_EVENT
    )
    pipe.feed([(flight_stream(300) + event + protocol.encode_text("ok"), 1.7e9 + 5.0)])
    pipe.flush_view()
    notes = [e for e in log.events if e[0].startswith("drone:")]
    assert len(notes) == 1 and "ki 1, " in notes[0][0] and "from step 300" in notes[0][0]
    assert notes[0][1] == pytest.approx(t_us / 1e6, abs=1e-6) and np.isfinite(notes[0][2])

"""The Rerun side: recordings written headlessly read back with the expected entities, samples, gaps and blueprint."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from steval_link import constants as C
from steval_link.cli.checks import user_message
from steval_link.errors import UserError
from steval_link.estimators.st_mahony import quaternion_to_euler
from steval_link.link import protocol as P
from steval_link.link.decoder import StreamDecoder, decode_bytes
from steval_link.link.frames import AttitudeFrame, StatusFrame, TextFrame
from steval_link.link.telemetry import AttitudeArrays, TelemetryParts, TimeUnwrapper
from steval_link.live.pipeline import EventTime, LiveRows
from steval_viewer import blueprint, drone_model
from steval_viewer import entities as ent
from steval_viewer.live_log import LiveLogger
from steval_viewer.replay_log import log_replay
from steval_viewer.rrd_check import read_rrd
from steval_viewer.sink_options import SinkOptions, resolve_sinks
from steval_viewer.sinks import open_session

RATE = C.AHRS_RATE_HZ


def _pitch_q(angle_rad: np.ndarray) -> np.ndarray:
    """Unit quaternions (wxyz) of a rotation about x (thx = pitch) by ``angle_rad``."""
    return np.stack(
        [np.cos(angle_rad / 2), np.sin(angle_rad / 2), np.zeros_like(angle_rad), np.zeros_like(angle_rad)], axis=1
    ).astype(np.float32)


def make_stream(n: int = 900, *, nan_rows=(), first_step: int = 1000, drop=()) -> tuple[bytes, np.ndarray]:
    """Bytes of a binary stream: n attitude frames (pitch sweep), a status frame every 162 steps, two text lines.

    ``nan_rows``: rows whose q makes thy = asin(>1) = NaN (as the firmware yields). ``drop``: rows not sent.
    Returns (bytes, chunk offsets for host times).
    """
    t = np.arange(n) / RATE
    q = _pitch_q(0.6 * np.sin(2 * np.pi * 0.5 * t))
    for r in nan_rows:
        q[r] = (0.8, 0.0, 0.8, 0.0)  # 2(q0q2 - q1q3) = 1.28: asin out of range
    out = bytearray(P.encode_text("STEVAL-FCU001V1 steval-link 1.0.0"))
    for i in range(n):
        if i == n // 3:
            out += P.encode_text("calibration done")
        if i in drop:
            continue
        step = first_step + i
        out += P.encode_attitude(
            t_us=int(2_000_000 + step * 1e6 / RATE),
            acc_mg=(0.0, 1000 * math.sin(0.1 * i), 1000.0),
            gyro_mdps=(10.0 * i, -5.0, 0.0),
            q_wxyz=q[i],
            thz_rad=0.001 * i,
            seq=step,
            thr=0 if i < n // 2 else 300,
        )
        if i % 162 == 161:
            out += P.encode_status(
                step=step,
                t_us=int(2_000_000 + step * 1e6 / RATE),
                q_wxyz=q[i],
                int_xyz=(0, 0, 0),
                cyc_min=9000,
                cyc_mean=9400,
                cyc_max=12000,
                cyc_n=162,
                tx_dropped=i // 400,
                queue_peak=116,
            )
    return bytes(out), q


def make_telemetry(n: int = 900, **kw):
    data, _ = make_stream(n, **kw)
    # host times: the stream arrives in 580-byte chunks, 10 ms apart
    offsets = np.arange(0, len(data), 580, dtype=np.int64)
    return decode_bytes(data, (offsets, 0.01 * np.arange(len(offsets))))


def test_replay_rrd_reads_back_with_entities_counts_gaps_and_blueprint(tmp_path):
    nan_rows = (100, 101, 102, 500)
    tel = make_telemetry(900, nan_rows=nan_rows, drop=(300, 301, 302))
    n = len(tel.attitude.t_fw_s)
    assert n == 897
    assert np.isnan(tel.attitude.thy_rad).sum() == len(nan_rows)

    from steval_link.estimators import registry
    from steval_link.estimators.firmware_replay import replay_firmware

    att = tel.attitude
    accel = registry.create("accel").run(att.acc_mg, att.gyro_mdps, att.thr)
    replica = replay_firmware(tel)
    out = tmp_path / "replay.rrd"
    session = open_session(SinkOptions(rrd=out), recording_name="test")
    summary = log_replay(session.rec, tel, {"accel": accel}, replica=replica)
    session.close()

    info = read_rrd(out)
    assert info.has_blueprint
    assert info.application_id == "steval-link"
    assert {ent.TIMELINE_FW, ent.TIMELINE_HOST, ent.TIMELINE_STEP} <= info.timelines
    fw_thy_ok = int(np.isfinite(att.thy_rad).sum())
    assert info.samples[ent.pitch_path("firmware")] == n
    assert info.samples[ent.roll_path("firmware")] == fw_thy_ok == n - len(nan_rows)
    # one Clear (a gap in the plot) per run of NaN: rows 100..102 and 500
    assert info.clears[ent.roll_path("firmware")] == 2
    assert info.samples[ent.DRONE_FIRMWARE] == n
    for path in (ent.PLOT_ACC, ent.PLOT_GYRO, ent.PLOT_THROTTLE, ent.yaw_path("firmware"), ent.ACC_GRAVITY):
        assert info.samples[path] == n, path
    assert info.samples[ent.pitch_path("accel")] == int(np.asarray(accel.valid).sum())
    assert (
        info.samples[ent.estimate_path("st_mahony_replica")] == summary.samples[ent.estimate_path("st_mahony_replica")]
    )
    assert ent.estimate_model_path("st_mahony_replica") in info.static
    assert ent.DRONE_FIRMWARE_MODEL in info.static
    assert info.samples[ent.LINK_CYCLES] == len(tel.status.step)
    assert info.samples[ent.LOG_FIRMWARE] == 2
    assert info.samples == summary.samples


def test_port_difference_is_zero_where_bit_exact(tmp_path):
    """firmware − replica is logged in degrees; on a real replica replay it is exactly 0 where bit-exact."""
    from steval_link.estimators.st_mahony import MahonyState, run

    n = 400
    acc = np.tile(np.float32([100.0, -50.0, 990.0]), (n, 1))
    gyro = np.tile(np.float32([300.0, 0.0, 0.0]), (n, 1))
    thr = np.zeros(n, dtype=np.int64)
    q, _, _, _ = run(acc, gyro, thr, state=MahonyState(), euler=False)
    data = b"".join(
        P.encode_attitude(t_us=i * 6192, acc_mg=acc[i], gyro_mdps=gyro[i], q_wxyz=q[i], thz_rad=0.0, seq=i, thr=0)
        for i in range(n)
    )
    tel = decode_bytes(data)
    from steval_link.estimators.firmware_replay import replay_firmware

    replica = replay_firmware(tel)
    assert replica.n_bit_exact == n
    out = tmp_path / "diff.rrd"
    session = open_session(SinkOptions(rrd=out))
    log_replay(session.rec, tel, {}, replica=replica)
    session.close()
    from rerun.chunk import RrdReader

    values = []
    for chunk in RrdReader(str(out)).stream():
        if chunk.entity_path == "/" + ent.DIFF_THX and not chunk.is_static:
            rb = chunk.to_record_batch()
            values += [v for row in rb.column("Scalars:scalars").to_pylist() if row for v in row]
    assert len(values) == n and set(values) == {0.0}


def test_replay_without_host_times_and_text_without_time(tmp_path):
    data, _ = make_stream(300)
    tel = decode_bytes(data)  # no chunk times: host times NaN
    assert np.isnan(tel.attitude.t_host_s).all()
    out = tmp_path / "nohost.rrd"
    session = open_session(SinkOptions(rrd=out))
    log_replay(session.rec, tel)
    session.close()
    info = read_rrd(out)
    assert ent.TIMELINE_HOST not in info.timelines
    assert info.samples[ent.pitch_path("firmware")] == 300
    assert info.samples[ent.LOG_FIRMWARE] == 2


def test_replay_rejects_mismatched_estimate_length(tmp_path):
    tel = make_telemetry(200)
    bad = SimpleNamespace(q_wxyz=np.zeros((10, 4)), thx_rad=np.zeros(10), thy_rad=np.zeros(10))
    session = open_session(SinkOptions(rrd=tmp_path / "x.rrd"))
    with pytest.raises(ValueError, match="rows"):
        log_replay(session.rec, tel, {"ekf3": bad})
    session.close()


def _batches_from_stream(data: bytes, chunk: int):
    """Feed the stream to a StreamDecoder in ``chunk``-byte pieces; yield what a live session hands the logger
    (host times in s since capture start)."""
    dec = StreamDecoder()
    for k, off in enumerate(range(0, len(data), chunk)):
        t_host = 0.026 * k  # 300 bytes at 115200 baud take 26 ms
        att, events = [], []
        for f in dec.feed(data[off : off + chunk]):
            (att if isinstance(f, AttitudeFrame) else events).append(f)
        yield t_host, att, events


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_live_logger_logs_every_frame_with_gaps_and_link(tmp_path):
    data, q = make_stream(700, nan_rows=(50, 51), first_step=65_500)  # seq wraps at 65 536
    out = tmp_path / "live.rrd"
    session = open_session(SinkOptions(rrd=out))
    logger = LiveLogger(session.rec, ["st-mahony", "accel"])
    n_frames = n_batches = 0
    fw = TimeUnwrapper()  # the pipeline's times (steval_link.live.pipeline)
    for t_host, att, events in _batches_from_stream(data, 300):
        if att:
            n_batches += 1
            n = len(att)
            est_q = np.array([f.q_wxyz for f in att], dtype=np.float32)
            est_q[: n // 2] = np.nan  # e.g. the replica waiting for its first snapshot
            parts = TelemetryParts()
            for f in att:
                parts.add_frame(f)
            rows = AttitudeArrays.from_records(
                parts.attitude_records(),
                step=np.array([65_500 + n_frames + i for i in range(n)]),
                t_fw_s=fw.seconds([f.t_us for f in att]),
                t_host_s=np.full(n, t_host),
            )
            batch = LiveRows(rows, {"st-mahony": est_q, "accel": np.array([f.q_wxyz for f in att], dtype=np.float64)})
            logger.log_batch(batch)
            n_frames += n
        for f in events:
            if isinstance(f, StatusFrame):
                logger.log_status(f, EventTime(fw.nearest(f.t_us), t_host))
            elif isinstance(f, TextFrame):
                logger.log_text(f, EventTime(math.nan, t_host))
        logger.log_link(SimpleNamespace(crc_failures=0), t_host)
    logger.close()
    session.close()

    assert n_frames == 700
    info = read_rrd(out)
    assert info.has_blueprint
    assert info.samples[ent.pitch_path("firmware")] == 700
    assert info.samples[ent.roll_path("firmware")] == 698
    assert info.clears[ent.roll_path("firmware")] == 1
    # the 3D view is updated with the newest frame of a batch, at most LIVE_3D_MAX_HZ
    from steval_viewer.live_log import LIVE_3D_MAX_HZ

    n3d = info.samples[ent.DRONE_FIRMWARE]
    assert 0.8 * n_batches <= n3d <= min(n_batches, 700 / RATE * LIVE_3D_MAX_HZ + 1)
    assert info.samples[ent.ACC_GRAVITY] == n3d
    assert info.samples[ent.pitch_path("accel")] == 700
    port_rows = info.samples[ent.pitch_path("st_mahony_replica")]
    assert 0 < port_rows < 700
    assert info.samples[ent.LINK_CYCLES] == 4
    assert info.samples[ent.LOG_FIRMWARE] == 2
    assert info.samples[ent.LINK_RATE] >= 3
    assert info.samples[ent.LINK_CRC] >= 1


def test_time_unwrapper_crosses_the_u32_wrap():
    u = TimeUnwrapper()
    a = u.seconds(np.array([P.T_US_MODULUS - 2000, P.T_US_MODULUS - 1000]))
    b = u.seconds(np.array([500, 1500]))
    assert np.all(np.diff(np.concatenate([a, b])) > 0)
    assert b[0] - a[1] == pytest.approx(1500e-6)


def test_time_unwrapper_nearest_places_a_status_time_next_to_the_attitude_rows():
    u = TimeUnwrapper()
    u.seconds(np.array([P.T_US_MODULUS - 1000, 500]))  # crossed the wrap
    assert u.nearest(500) == pytest.approx((P.T_US_MODULUS + 500) / 1e6)
    assert u.nearest(P.T_US_MODULUS - 1000) == pytest.approx((P.T_US_MODULUS - 1000) / 1e6)  # from before it
    v = TimeUnwrapper()
    v.seconds(np.array([P.T_US_MODULUS - 1000]))
    assert v.nearest(200) == pytest.approx((P.T_US_MODULUS + 200) / 1e6)  # already past the next wrap
    assert v.wraps == 0 and v.last == P.T_US_MODULUS - 1000  # nearest() changes nothing


def _views(container):
    """Every view of a blueprint container, depth first."""
    for child in container.contents:
        if hasattr(child, "class_identifier"):
            yield child
        else:
            yield from _views(child)


def test_blueprint_live_scrolls_and_hides_other_ghosts():
    live = list(_views(blueprint.make_blueprint(live=True, ghost_sources=["st_mahony_replica", "ekf3"]).root_container))
    replay = list(_views(blueprint.make_blueprint(live=False, ghost_sources=["ekf3"]).root_container))
    for views, scrolling in ((live, True), (replay, False)):
        ts = [v for v in views if v.class_identifier == "TimeSeries"]
        assert len(ts) >= 10
        assert all(("VisibleTimeRanges" in v.properties) == scrolling for v in ts)
        origins = {str(v.origin) for v in ts}
        assert {ent.PLOT_PITCH, ent.PLOT_ROLL, ent.PLOT_ACC, ent.PLOT_GYRO, ent.LINK_CYCLES} <= origins
        assert sum(v.class_identifier == "TextLog" for v in views) == 1
    v3d = [v for v in live if v.class_identifier == "3D"][0]
    assert list(v3d.visualizer_overrides) == [ent.estimate_path("ekf3")]  # the replica is the ghost shown
    v3d = [v for v in replay if v.class_identifier == "3D"][0]
    assert not v3d.visualizer_overrides


def test_default_sink_without_display_is_a_clear_user_error(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    with pytest.raises(UserError, match="rrd= FILE") as exc:
        resolve_sinks(SinkOptions())
    assert "--rrd FILE" in user_message(exc.value) and "--no-view to record only" in user_message(exc.value)
    opts = resolve_sinks(SinkOptions(rrd=Path("x.rrd")))
    assert not opts.spawn  # headless: the file alone
    monkeypatch.setenv("DISPLAY", ":0")
    assert resolve_sinks(SinkOptions(rrd=Path("x.rrd"))).spawn  # a display: watch it too
    assert not resolve_sinks(SinkOptions(serve=True)).spawn


def test_rrd_into_missing_folder_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="does not exist"):
        open_session(SinkOptions(rrd=tmp_path / "nope" / "x.rrd"))


def test_drone_model_nose_and_front_props_point_along_plus_y():
    mesh = drone_model.quadcopter_mesh()
    nose = (mesh.colors[:, :3] == drone_model.NOSE_COLOR[:3]).all(axis=1)
    front = (mesh.colors[:, :3] == drone_model.PROP_FRONT_COLOR[:3]).all(axis=1)
    assert mesh.positions[nose, 1].min() > 0 and mesh.positions[nose, 1].max() > drone_model.BODY_HALF[1]
    assert mesh.positions[front, 1].min() > 0
    assert abs(mesh.positions[nose, 0].mean()) < 1e-6
    assert len(mesh.triangles) * 3 == len(mesh.positions)


def test_firmware_quaternion_is_body_to_earth_so_nose_up_is_up():
    """A positive thx (pitch, nose up) from the firmware's QuaternionToEuler must lift the nose (+y) to +z when the
    quaternion is applied as the body -> world rotation (as Rerun's Transform3D does)."""
    q = _pitch_q(np.array([0.3]))
    thx, thy = quaternion_to_euler(q)
    assert thx[0] == pytest.approx(0.3, abs=1e-6) and thy[0] == pytest.approx(0.0, abs=1e-6)
    w, x, y, z = q[0].astype(float)
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    nose_world = r @ np.array([0.0, 1.0, 0.0])
    assert nose_world[2] > 0.25
    # Mahony's gravity estimate (vx, vy, vz) is the third row of this matrix: the earth z axis seen in the body
    vx, vy, vz = 2 * (x * z - w * y), 2 * (w * x + y * z), w * w - x * x - y * y + z * z
    assert np.allclose(r[2], [vx, vy, vz], atol=1e-6)


def test_simulation_logs_to_rrd(tmp_path):
    from steval_link.emulation.lab5 import BASELINE_ACC_MG, BASELINE_GYRO_MDPS, run_simulation
    from steval_viewer.simulate_log import log_simulation

    res = run_simulation(
        gyro_mdps=BASELINE_GYRO_MDPS,
        acc_mg=BASELINE_ACC_MG,
        iterations=500,
        gyro_noise_mdps=0,
        acc_noise_mg=0,
        seed=None,
        throttle=0,
        estimator="st-mahony",
        estimator_options={},
    )
    out = tmp_path / "sim.rrd"
    log_simulation(res, out)
    info = read_rrd(out)
    assert info.has_blueprint
    assert info.samples[ent.pitch_path("firmware")] == int(np.isfinite(res.eax_rad).sum())
    assert ent.LINK_RATE not in info.samples


def _steval_here(monkeypatch, capsys, *args: str):
    """``steval ARGS`` in this process, with no display (no interpreter start-up): returncode, stdout, stderr."""
    from support.cli import run_cli

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    code, out, err = run_cli(monkeypatch, capsys, *args)
    return SimpleNamespace(returncode=code, stdout=out, stderr=err)


def test_cli_replay_to_rrd_headless(tmp_path, monkeypatch, capsys):
    data, _ = make_stream(1200, nan_rows=(10, 11, 12))
    cap = tmp_path / "dump.bin"
    cap.write_bytes(data)
    out = tmp_path / "out.rrd"
    r = _steval_here(monkeypatch, capsys, "replay", str(cap), "--rrd", str(out))
    assert r.returncode == 0, r.stderr
    info = read_rrd(out)
    assert info.has_blueprint
    assert info.samples[ent.pitch_path("firmware")] == 1200
    assert info.samples[ent.roll_path("firmware")] == 1197
    assert info.samples[ent.pitch_path("accel")] == 1200
    assert ent.pitch_path("st_mahony_replica") in info.samples
    assert ent.pitch_path("st_mahony") not in info.samples  # replaced by the seeded replica

    r = _steval_here(monkeypatch, capsys, "replay", str(cap), "--rrd", str(tmp_path / "missing" / "x.rrd"))
    assert r.returncode == 2 and "does not exist" in r.stderr and "Traceback" not in r.stderr
    r = _steval_here(monkeypatch, capsys, "replay", str(cap), "--connect", "http://localhost:1")
    assert r.returncode == 2 and "rerun+http" in r.stderr


def _serial_recording(p: Path) -> bool:
    """A bundled serial capture or log (BLE captures have their own layout: tests/test_ble_replay.py)."""
    from steval_link.link.ble_payloads import is_ble_source
    from steval_link.link.load import read_recording

    return p.suffix in (".stv", ".log", ".bin", ".raw") and not is_ble_source(read_recording(p))


BUNDLED = sorted(p for p in (Path(__file__).resolve().parents[1] / "recordings").iterdir() if _serial_recording(p))


@pytest.mark.skipif(not BUNDLED, reason="no bundled recordings in recordings/")
@pytest.mark.parametrize("capture", BUNDLED, ids=[p.name for p in BUNDLED])
def test_every_bundled_recording_replays_to_rrd(capture, tmp_path, monkeypatch, capsys):
    """CI: each bundled capture replays headlessly to an .rrd that reads back with every entity and all samples."""
    from steval_link.link.load import load_telemetry

    tel = load_telemetry(capture)
    out = tmp_path / (capture.stem + ".rrd")
    r = _steval_here(monkeypatch, capsys, "replay", str(capture), "--rrd", str(out))
    assert r.returncode == 0, r.stderr
    info = read_rrd(out)
    assert info.has_blueprint
    att = tel.attitude
    n = len(att.t_fw_s)
    assert n > 0
    assert info.samples[ent.pitch_path("firmware")] == int(np.isfinite(att.thx_rad).sum())
    assert info.samples.get(ent.roll_path("firmware"), 0) == int(np.isfinite(att.thy_rad).sum())
    assert info.samples[ent.PLOT_ACC] == n
    # text-mode rows have no q: the 3D drone follows their thx/thy instead
    shown = np.isfinite(att.q_wxyz).all(axis=1) | (np.isfinite(att.thx_rad) & np.isfinite(att.thy_rad))
    assert info.samples.get(ent.DRONE_FIRMWARE, 0) == int(shown.sum())
    for path in (ent.pitch_path("accel"), ent.roll_path("accel"), ent.LINK_RATE):
        assert info.samples.get(path, 0) > 0, path
    if np.asarray(att.exact).any():
        assert info.samples.get(ent.pitch_path("st_mahony_replica"), 0) > 0
    if len(tel.status.step):
        assert info.samples.get(ent.LINK_CYCLES, 0) > 0


def test_quaternion_from_text_mode_angles_round_trips_through_the_firmware_euler():
    from steval_link.quat import quaternion_from_euler

    rng = np.random.default_rng(0)
    thx = rng.uniform(-3.0, 3.0, 200)
    thy = rng.uniform(-1.4, 1.4, 200)
    thz = rng.uniform(-3.0, 3.0, 200)
    q = quaternion_from_euler(thx, thy, thz)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    bx, by = quaternion_to_euler(q.astype(np.float32))
    assert np.allclose(bx, thx, atol=1e-5) and np.allclose(by, thy, atol=1e-5)


def test_serve_starts_a_web_viewer_on_loopback_only_and_stops_it(tmp_path):
    import socket
    import urllib.request

    from steval_viewer.replay_log import log_telemetry
    from steval_viewer.sink_options import free_port as _free_port

    web, grpc = _free_port(), _free_port()
    session = open_session(SinkOptions(serve=True, web_port=web, grpc_port=grpc, rrd=tmp_path / "s.rrd"))
    try:
        log_telemetry(session.rec, make_telemetry(300), {})
        session.flush()
        assert session.web_url.startswith(f"http://127.0.0.1:{web}/?url=rerun%2Bhttp")
        assert urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10).status == 200
        # bound to the loopback interface only: not reachable on another local address
        others = set()
        try:  # the address of the interface with the default route (a UDP connect sends nothing)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
                u.connect(("192.0.2.1", 9))
                others.add(u.getsockname()[0])
        except OSError:
            pass
        for addr in others - {"127.0.0.1", "0.0.0.0"}:
            with socket.socket() as s:
                s.settimeout(1)
                assert s.connect_ex((addr, web)) != 0
        child = session.children[0]
    finally:
        session.close()
    assert child.poll() is not None
    with socket.socket() as s:
        assert s.connect_ex(("127.0.0.1", grpc)) != 0
    assert read_rrd(tmp_path / "s.rrd").samples[ent.pitch_path("firmware")] == 300

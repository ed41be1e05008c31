"""The BLE transport's logic (steval_link.link.ble_transport) and ``steval live --ble``'s session, without a radio:
a fake backend (tests/support/ble.py FakeBleBackend) plays the notifications the emulated stock firmware
sent (recordings/ble_demo.stv), and can refuse connections, lose the link and fail like a platform without an
adapter or permission."""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

import numpy as np
import pytest
from support.ble import FakeBleBackend, RecordingViewer, run_until_played

from steval_link.errors import UserError
from steval_link.link import ble_payloads as B
from steval_link.link import ble_telemetry as BC
from steval_link.link.ble_transport import BleDevice, BleLink, explain_ble_error, is_address, pick_device
from steval_link.link.capture import read_capture
from steval_link.link.load import read_recording

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "recordings" / "ble_demo.stv"


@pytest.fixture(scope="module")
def firmware_notifications() -> list[tuple[int, bytes]]:
    """(char id, payload) of the first 3000 notifications the emulated stock firmware sent (ble_demo.stv)."""
    recs = B.ble_records(read_recording(DEMO).chunks)
    assert len(recs) > 3000
    return [(cid, p) for _, cid, p in recs[:3000]]


def run_link(backend, target=None, *, stop_when=None, timeout_s=10.0, **kw):
    got, events = [], []

    async def main():
        stop = asyncio.Event()
        link = BleLink(
            backend,
            target,
            lambda cid, data, t: got.append((cid, data)),
            on_event=lambda k, t: events.append((k, t)),
            retry_max_s=0.01,
            **kw,
        )
        task = asyncio.ensure_future(link.run(stop))

        async def watch():
            while not task.done():
                if (stop_when or (lambda: backend.finished is not None and backend.finished.is_set()))():
                    stop.set()
                await asyncio.sleep(0.001)

        await asyncio.wait_for(asyncio.gather(task, watch()), timeout_s)
        return link

    link = asyncio.run(main())
    return link, got, events


def test_pick_device_by_name_address_or_default():
    devs = [
        BleDevice("Phone", "AA:AA:AA:AA:AA:AA", -40.0),
        BleDevice("DRN1110", "C0:00:00:00:00:01", -80.0),
        BleDevice("DRN1120", "C0:00:00:00:00:02", -60.0),
        BleDevice(None, "C0:00:00:00:00:03", -30.0),
    ]
    assert pick_device(devs, None).address.endswith("02")  # strongest DRN1…
    assert pick_device(devs, "DRN1110").address.endswith("01")
    assert pick_device(devs, "c0:00:00:00:00:03").name is None
    assert pick_device(devs, "phone").name == "Phone"  # name prefix, any case
    assert pick_device(devs, "nothing") is None
    assert is_address("C0:28:38:35:21:34") and is_address("6A7B2F1E-0000-4C5B-9D1E-123456789ABC")
    assert not is_address("DRN1110")


def test_link_delivers_every_firmware_notification_in_order(firmware_notifications):
    fake = FakeBleBackend(firmware_notifications)
    link, got, events = run_link(fake)
    assert got == firmware_notifications
    assert [k for k, _ in events] == ["connect"]
    assert link.connections == 1 and link.losses == 0
    # subscribed to motion, environment, arming and both console characteristics
    assert set(fake.subscribed) == set(B.CHAR_UUIDS.values())


def test_link_reconnects_after_losses_and_refused_connections(firmware_notifications):
    fake = FakeBleBackend(firmware_notifications, drop_after=[700, 400], fail_connects=0)
    link, got, events = run_link(fake)
    kinds = [k for k, _ in events]
    assert kinds == ["connect", "disconnect", "reconnect", "disconnect", "reconnect"]
    assert link.losses == 2 and link.connections == 3
    # nothing is lost or duplicated by the reconnections (the fake drone keeps its place in the stream)
    assert got == firmware_notifications
    # a reconnection that is refused a few times first: retried with back-off
    fake = FakeBleBackend(firmware_notifications[:900], drop_after=[300])
    orig = fake.connect

    async def flaky(address, on_disconnect, _n=[0]):
        _n[0] += 1
        if _n[0] in (2, 3):
            from steval_link.link.ble_transport import BleError

            raise BleError("connection refused (fake)")
        await orig(address, on_disconnect)

    fake.connect = flaky
    link, got, events = run_link(fake)
    assert [k for k, _ in events] == ["connect", "disconnect", "reconnect"] and len(got) == 900


def test_link_errors_are_one_sentence(firmware_notifications):
    with pytest.raises(UserError, match="no BLE device matching 'DRN9999'"):
        run_link(FakeBleBackend(firmware_notifications), "DRN9999")
    with pytest.raises(UserError, match="no BLE device matching a DRN1… drone"):
        run_link(FakeBleBackend(firmware_notifications, devices=[BleDevice("Phone", "AA:AA:AA:AA:AA:AA", -40)]))
    with pytest.raises(UserError, match="cannot connect"):
        run_link(FakeBleBackend(firmware_notifications, fail_connects=1))
    for exc, words in (
        (FileNotFoundError(2, "No such file or directory"), "BlueZ"),
        (PermissionError("Operation not permitted"), "permission"),
        (Exception("org.freedesktop.DBus.Error.AccessDenied: not allowed"), "permission"),
        (Exception("No Bluetooth adapters found."), "no Bluetooth LE adapter"),
        (Exception("[org.bluez.Error.NotReady] Resource Not Ready"), "switched off"),
    ):
        assert words in explain_ble_error(exc)
        with pytest.raises(UserError, match=words):
            run_link(FakeBleBackend(firmware_notifications, scan_error=exc))
    assert explain_ble_error(TimeoutError("connection timed out")) is None  # retried, not a platform failure
    # a platform failure while connecting (first or again) is one sentence too, never a traceback
    fake = FakeBleBackend(firmware_notifications[:600], drop_after=[200])
    orig = fake.connect

    async def refused(address, on_disconnect, _n=[0]):
        _n[0] += 1
        if _n[0] == 2:
            raise Exception("[org.bluez.Error.NotPermitted] Not permitted")
        await orig(address, on_disconnect)

    fake.connect = refused
    with pytest.raises(UserError, match="permission"):
        run_link(fake)


@pytest.mark.slow  # real time: a paced BLE link with reconnects through a live session: ≈ 2.5 s
def test_live_session_records_reconnects_and_estimates(tmp_path, firmware_notifications):
    from steval_link.live.session import LiveOptions, LiveSession, source_for
    from steval_viewer.sink_options import SinkOptions

    viewer = RecordingViewer()

    # at a drone's pace (1 ms a notification): several rounds of the session, two link losses, and the 8 ms tick's
    # wrap (ble_demo's tick wraps 30 s after power-up: notifications 12500.. hold it)
    recs = B.ble_records(read_recording(DEMO).chunks)[12500:14000]
    firmware_notifications = [(c, p) for _, c, p in recs]
    fake = FakeBleBackend(firmware_notifications, drop_after=[500, 400], pace_s=0.001)
    out = tmp_path / "ble.stv"
    opts = LiveOptions(out=out, sinks=SinkOptions(rrd=tmp_path / "x.rrd"), estimators=["st-mahony", "accel"])
    source = source_for("ble:auto", backend=fake)
    session = LiveSession(opts, source, viewer_factory=lambda o, name: viewer, stream=sys.stderr)

    summary = run_until_played(session, fake)
    assert summary.disconnects == 2 and summary.connections == 3 and summary.stopped_by == "test"
    # the capture holds every notification, in order, as B chunks, with the link's events
    cap = read_capture(out)
    assert [(c, p) for _, c, p in B.ble_records(cap.chunks)] == firmware_notifications
    kinds = [e.kind for e in cap.events]
    assert kinds == ["connect", "disconnect", "reconnect", "disconnect", "reconnect", "stop"]
    assert cap.header["extra"]["link"] == "ble" and cap.header["format_version"] == 2
    # the one logger got the rows of the sender's samples on one grid and the estimators' attitude, then was closed
    assert viewer.closed
    rows = viewer.batches
    n_motion = sum(1 for c, _ in firmware_notifications if c == B.CHAR_MOTION)
    assert n_motion == summary.counts["motion"]
    n_grid = sum(len(r) for r in rows)
    assert n_grid == n_motion + summary.rows_held and summary.rows_held == 0  # no notification was missing
    t_grid = np.concatenate([r.attitude.t_fw_s for r in rows])
    wrap_s = (1 << 16) * B.TICK_S
    assert (np.diff(t_grid) > 0).all() and t_grid[0] < wrap_s <= t_grid[-1]  # one clock across the wrap
    assert np.allclose(np.diff(t_grid), BC.STEP_PERIOD_S)
    env = np.array([at.t_fw_s for _, at in viewer.env])
    assert len(env) == summary.counts["environment"]
    assert (np.diff(env) >= 0).all() and abs(env[-1] - t_grid[-1]) < 0.05
    q = rows[-1].estimates["st-mahony"]
    assert q.shape == (len(rows[-1]), 4) and np.isfinite(q).all()
    # BLE carries no firmware attitude: its rows say so (NaN, not bit-exact), and the note says why
    a = rows[-1].attitude
    assert np.isnan(a.thx_rad).all() and not a.exact.any() and np.isfinite(a.acc_mg).all()
    assert rows[-1].mag_mgauss.shape == (len(a), 3)
    assert any("not sent over BLE" in n for n in viewer.notes)
    assert "3 connection(s), 2 lost" in summary.line()


def test_cli_without_bleak_or_radio_is_one_line(monkeypatch, capsys, tmp_path):
    from support.cli import run_cli

    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, "bleak", None)  # not installed
    for args in (["ble", "scan"], ["live", "--ble", "--no-view"], ["live", "--ble", "DRN1110", "--no-view"]):
        code, out, err = run_cli(monkeypatch, capsys, *args)
        assert code == 2 and "Traceback" not in err
        assert err.strip() == 'steval: error: BLE needs bleak: pip install "steval-link[ble]" (or pip install bleak).'
    code, out, err = run_cli(monkeypatch, capsys, "live", "DRN1110")
    assert code == 2 and "goes with --ble" in err
    assert not (tmp_path / "recordings").exists() or not list((tmp_path / "recordings").iterdir())


def test_cli_platform_failures_are_one_line(monkeypatch, capsys, tmp_path):
    """A platform without BlueZ / an adapter / permission (bleak's own exceptions, as on this CI machine or a
    laptop with Bluetooth off): one line, exit 2, and no capture file left behind."""
    from support.cli import run_cli

    from steval_link.link import ble_transport as T

    monkeypatch.chdir(tmp_path)
    for exc, words in (
        (FileNotFoundError(2, "No such file or directory"), "BlueZ"),
        (PermissionError(1, "Operation not permitted"), "permission"),
    ):
        monkeypatch.setattr(T, "bleak_backend", lambda exc=exc: FakeBleBackend([], scan_error=exc))
        monkeypatch.setattr("steval_link.cli.ble.bleak_backend", T.bleak_backend)
        monkeypatch.setattr("steval_link.cli.live.bleak_backend", T.bleak_backend)
        for args in (["ble", "scan"], ["live", "--ble", "--no-view"]):
            code, out, err = run_cli(monkeypatch, capsys, *args)
            assert code == 2 and err.count("\n") == 1 and words in err and "Traceback" not in err, err
    assert not list(tmp_path.rglob("*.stv"))


def test_ble_scan_lists_drones_first(monkeypatch, capsys):
    from support.cli import run_cli

    devs = [BleDevice("Phone", "AA:AA:AA:AA:AA:AA", -40.0), BleDevice("DRN1110", "C0:28:38:35:21:34", -70.0)]
    monkeypatch.setattr("steval_link.cli.ble.bleak_backend", lambda: FakeBleBackend([], devices=devs))
    code, out, err = run_cli(monkeypatch, capsys, "ble", "scan", "--timeout", "0.1")
    assert code == 0 and out.splitlines()[0].startswith("DRN1110") and "Phone" not in out
    code, out, err = run_cli(monkeypatch, capsys, "ble", "scan", "--all")
    assert code == 0 and [ln.split()[0] for ln in out.splitlines()] == ["DRN1110", "Phone"]
    monkeypatch.setattr("steval_link.cli.ble.bleak_backend", lambda: FakeBleBackend([], devices=devs[:1][:0]))
    code, out, err = run_cli(monkeypatch, capsys, "ble", "scan")
    assert code == 1 and "no drone advertising DRN1" in err


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_live_session_to_rrd_with_the_ble_layout(tmp_path):
    """steval live --ble --rrd FILE --no-view: the one live logger writes the BLE stream's rows and values."""
    from steval_link.live.session import LiveOptions, LiveSession, source_for
    from steval_viewer.live_adapter import ViewerLogger
    from steval_viewer.rrd_check import blueprint_views, read_rrd
    from steval_viewer.sink_options import SinkOptions

    recs = B.ble_records(read_recording(DEMO).chunks)[:900]
    fake = FakeBleBackend([(c, p) for _, c, p in recs], pace_s=0.0005)
    rrd = tmp_path / "live.rrd"
    opts = LiveOptions(out=tmp_path / "c.stv", sinks=SinkOptions(rrd=rrd), estimators=["st-mahony", "ekf3"])
    source = source_for("ble:DRN1110", backend=fake)
    session = LiveSession(opts, source, viewer_factory=ViewerLogger, stream=sys.stderr)

    summary = run_until_played(session, fake)
    n = summary.counts["motion"]
    assert n == 300
    info = read_rrd(rrd)
    assert info.samples["plots/acc_mg"] == n and info.samples["ble/pressure_hpa"] == n
    assert info.samples["ble/mag_mgauss"] == n and info.samples["ble/armed"] == n
    assert info.samples["plots/pitch_thx_deg/ekf3"] == n and info.samples["plots/roll_thy_deg/st_mahony_replica"] == n
    assert info.samples.get("world/drone/estimate/ekf3", 0) >= 1
    assert {"fw_time", "host_time"} <= info.timelines and "ble/note" in info.static
    names = " ".join(blueprint_views(rrd))
    assert "magnetometer" in names and "battery" in names and "RSSI" in names and "Note" in names


def test_live_session_finds_the_drone_before_any_output(tmp_path):
    """The input first: a platform failure or a drone not found is said before the capture or the viewer exist."""
    from steval_link.live.session import LiveOptions, LiveSession, source_for
    from steval_viewer.sink_options import SinkOptions

    opened = []
    for fake, words in (
        (FakeBleBackend([], scan_error=FileNotFoundError(2, "No such file or directory")), "BlueZ"),
        (FakeBleBackend([], devices=[]), "no BLE device matching"),
    ):
        out = tmp_path / "ble.stv"
        opts = LiveOptions(out=out, sinks=SinkOptions(rrd=tmp_path / "x.rrd"), estimators=["accel"])
        session = LiveSession(
            opts, source_for("ble:auto", backend=fake), viewer_factory=lambda o, n: opened.append(n), stream=sys.stderr
        )
        with pytest.raises(UserError, match=words):
            session.run()
        assert not opened and not out.exists() and fake.connects == 0

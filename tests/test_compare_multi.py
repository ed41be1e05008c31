"""``steval compare A.stv B.stv ...``: flights side by side (analysis/side_by_side.py, its figure, its Rerun
recording), on captures made by ``steval synth`` (the bit-exact replica of the firmware behind the sensor model) and the
bundled recordings; the end-to-end check on the reference firmware under emulation is slow and needs the firmware.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.cli import run_cli

from steval_link import constants as C
from steval_link.analysis.side_by_side import (
    flight_of_telemetry,
    labels_by_difference,
    motion_lag_s,
    side_by_side,
    still_mask,
)
from steval_link.link.load import load_telemetry

ROOT = Path(__file__).resolve().parents[1]
REC = ROOT / "recordings"


def synth(monkeypatch, capsys, out: Path, *args) -> Path:
    code, _, err = run_cli(
        monkeypatch, capsys, "synth", "--scenario", "hand-tilts", "--duration", "14", "--seed", "1", "--out", out, *args
    )
    assert code == 0, err
    return out


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Stock (ki 0.1) and lab exercises 4 + 5 (ki 1, no correction): the same motion, the same seed. Made once for
    the module by ``steval synth`` (the tests only read them)."""
    import contextlib
    import io
    import sys

    from steval_link.cli import main

    d = tmp_path_factory.mktemp("pair")
    out = []
    for name, extra in (("stock.stv", ()), ("lab.stv", ("--ki", "1", "--no-correction"))):
        args = ["synth", "--scenario", "hand-tilts", "--duration", "14", "--seed", "1", "--out", str(d / name), *extra]
        err = io.StringIO()
        with (
            pytest.MonkeyPatch.context() as mp,
            contextlib.redirect_stdout(io.StringIO()),
            contextlib.redirect_stderr(err),
        ):
            mp.setattr(sys, "argv", ["steval", *args])
            try:
                main()
                code = 0
            except SystemExit as exc:
                code = exc.code
        assert code in (0, None), err.getvalue()
        out.append(d / name)
    return out


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_two_flights_labelled_by_settings_and_measured(pair, monkeypatch, capsys, tmp_path):
    a, b = pair
    png = tmp_path / "sbs.png"
    code, out, err = run_cli(monkeypatch, capsys, "compare", a, b, "--json", "--plot", png)
    assert code == 0, err
    d = json.loads(out)
    f0, f1 = d["flights"]
    assert [f0["label"], f1["label"]] == ["ki 0.1", "ki 1, correction off"]
    assert f0["settings"]["ki"] == 0.1 and f1["settings"]["ki"] == 1.0
    assert f0["settings"]["correction"] is True and f1["settings"]["correction"] is False
    assert f0["rows"] == len(load_telemetry(a).attitude)
    # the stock filter follows the accelerometer when still; without correction the gyro alone drifts away
    r0 = f0["figures"]["pitch_thx"]["rms_still_deg"]
    r1 = f1["figures"]["pitch_thx"]["rms_still_deg"]
    assert r0 < 0.5 and r1 > 4 * r0
    assert abs(f0["figures"]["pitch_thx"]["drift_deg"]) < 0.5 < abs(f1["figures"]["pitch_thx"]["drift_deg"])
    diff = d["differences"][0]
    assert diff["label"] == "ki 1, correction off" and diff["against"] == "ki 0.1"
    assert diff["pitch_thx"]["max_abs_deg"] > 1.0
    assert d["align"]["method"] == "time" and d["align"]["lags_s"] == [0.0, 0.0]
    assert d["notes"] == []  # same duration, same link, no drops: nothing to say
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and d["plot"] == str(png)


def test_text_output_and_label_override(pair, monkeypatch, capsys):
    a, b = pair
    code, out, _ = run_cli(monkeypatch, capsys, "compare", a, b)
    assert code == 0
    assert "ki 0.1 " in out and "ki 1, correction off" in out and "pitch = thx (about x, nose up +)" in out
    code, out, _ = run_cli(monkeypatch, capsys, "compare", a, b, "--label", "stock", "--label", "lab", "--json")
    assert [f["label"] for f in json.loads(out)["flights"]] == ["stock", "lab"]
    code, _, err = run_cli(monkeypatch, capsys, "compare", a, b, "--label", "only one")
    assert code == 2 and err.count("\n") == 1 and "1 --label for 2 captures" in err


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_rerun_recording_one_subtree_per_flight(pair, monkeypatch, capsys, tmp_path):
    from steval_viewer.rrd_check import blueprint_views, read_rrd

    a, b = pair
    rrd = tmp_path / "sbs.rrd"
    code, _, err = run_cli(monkeypatch, capsys, "compare", a, b, "--rrd", rrd)
    assert code == 0, err
    info = read_rrd(rrd)
    n = len(load_telemetry(a).attitude)
    for k in "ab":
        assert info.samples[f"flights/{k}/pitch_thx_deg"] == n
        assert info.samples[f"flights/{k}/roll_thy_deg"] == n
        assert info.samples[f"flights/{k}/accel_pitch_thx_deg"] == n
        assert info.samples[f"flights/{k}/world/drone"] == n
    assert info.samples["flights/b/diff_pitch_thx_deg"] == n and "flights/a/diff_pitch_thx_deg" not in info.samples
    assert "aligned_time" in info.timelines and info.has_blueprint
    views = blueprint_views(rrd)
    assert any(name.startswith("pitch thx") for name in views)  # one view overlays the flights' pitch
    assert not (tmp_path / "sbs.rrd.partial").exists()


def test_motion_alignment_finds_a_late_start(monkeypatch, capsys, tmp_path):
    a = synth(monkeypatch, capsys, tmp_path / "a.stv")
    b = synth(monkeypatch, capsys, tmp_path / "b.stv", "--join-at", "4.5")  # the capture starts 1.5 s later
    ta, tb = load_telemetry(a).attitude, load_telemetry(b).attitude
    expected = -(tb.t_fw_s[0] - ta.t_fw_s[0])  # b's motion comes that much earlier in its own time
    assert expected < -1.0
    code, out, _ = run_cli(monkeypatch, capsys, "compare", a, b, "--align", "motion", "--json")
    d = json.loads(out)
    lag = d["align"]["lags_s"][1]
    assert abs(lag - expected) < 2.5 / 161.5
    assert any(f"by {lag:+.3f} s" in n for n in d["notes"])
    # aligned, the same motion through the same filter agrees closely once b's filter has converged
    assert d["differences"][0]["overlap_s"] > 8
    code, _, err = run_cli(monkeypatch, capsys, "compare", a, b, "--align", "sideways")
    assert code == 2 and "--align must be time or motion" in err


def test_motion_lag_of_a_shifted_signal():
    rng = np.random.default_rng(3)
    t = np.arange(3000) / C.AHRS_RATE_HZ
    g = np.cumsum(rng.normal(0, 300, (3000, 3)), axis=0).astype(np.float32)
    lag, r = motion_lag_s(t, g, t[:2500], g[200:2700])  # the second starts 200 rows into the first
    assert abs(lag - (-200 / C.AHRS_RATE_HZ)) < 1e-9 and r > 0.9


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_mismatches_are_said_plainly(monkeypatch, capsys, tmp_path):
    a = synth(monkeypatch, capsys, tmp_path / "a.stv")
    cut = tmp_path / "cut.stv"
    data = a.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    code, out, err = run_cli(
        monkeypatch, capsys, "compare", a, cut, REC / "midflight_drops.stv", REC / "ble_demo.stv", "--json"
    )
    assert code == 0, err
    notes = json.loads(out)["notes"]
    assert any(n.startswith("durations differ") for n in notes)
    assert any("is a BLE capture and" in n for n in notes)
    assert any("14 frames lost on the link" in n for n in notes)
    assert any("capture cut short" in n for n in notes)
    assert all("\n" not in n for n in notes)


def test_same_settings_labelled_by_header_or_file(monkeypatch, capsys):
    code, out, _ = run_cli(monkeypatch, capsys, "compare", REC / "demo.stv", REC / "flight.stv", "--json")
    assert [f["label"] for f in json.loads(out)["flights"]] == ["scenario demo", "scenario flight"]
    code, out, _ = run_cli(monkeypatch, capsys, "compare", REC / "demo.stv", REC / "demo.stv", "--json")
    d = json.loads(out)
    assert [f["label"] for f in d["flights"]] == ["demo.stv #1", "demo.stv #2"]
    assert d["differences"][0]["pitch_thx"]["max_abs_deg"] == 0.0


def test_in_flight_changes_are_named(monkeypatch, capsys):
    tels = [load_telemetry(REC / "live_params.stv"), load_telemetry(REC / "demo.stv")]
    flights = [flight_of_telemetry(REC / n, t) for n, t in zip(("live_params.stv", "demo.stv"), tels)]
    labels = labels_by_difference(flights)
    assert "changes in flight" in labels[0] and "changes in flight" not in labels[1]


def test_still_mask_needs_quiet_sensors_for_long_enough():
    n = 400
    t = np.arange(n) / 161.5
    acc = np.tile(np.float32([0, 0, 1000]), (n, 1))
    gyro = np.zeros((n, 3), np.float32)
    gyro[100:110, 0] = 20000  # a 60 ms move splits the still run
    gyro[300:, 1] = 5000  # turning from row 300 on
    m = still_mask(acc, gyro, t)
    assert m[:100].all() and not m[100:110].any() and m[110:300].all() and not m[300:].any()
    short = still_mask(acc[:30], gyro[:30], t[:30])  # 0.18 s: too short to count
    assert not short.any()


def test_one_capture_is_the_single_report(monkeypatch, capsys, tmp_path):
    demo = REC / "demo.stv"
    code, out, _ = run_cli(monkeypatch, capsys, "compare", demo, "--json")
    d = json.loads(out)
    assert code == 0 and "replica" in d and "traces" in d and "flights" not in d
    code, _, err = run_cli(monkeypatch, capsys, "compare", demo, "--rrd", tmp_path / "x.rrd")
    assert code == 2 and "for two or more captures" in err and not (tmp_path / "x.rrd").exists()


def test_port_options_are_for_one_capture(pair, monkeypatch, capsys):
    code, out, err = run_cli(monkeypatch, capsys, "compare", *pair, "--ki", "1")
    assert code == 2 and err.startswith("steval: error: --ki applies to one capture") and out == ""


def test_side_by_side_api_keeps_the_rows():
    tel = load_telemetry(REC / "flight.stv")
    f = flight_of_telemetry(REC / "flight.stv", tel)
    r = side_by_side([f, flight_of_telemetry(REC / "flight.stv", tel)], labels=["x", "y"])
    assert [g.label for g in r.flights] == ["x", "y"]
    assert np.array_equal(r.flights[0].thx_rad, np.asarray(tel.attitude.thx_rad, np.float64))
    with pytest.raises(ValueError):
        side_by_side([f, f], align="nope")


@pytest.mark.slow
def test_reference_firmware_stock_against_exercises_4_and_5(tmp_path, monkeypatch, capsys):
    """Acceptance (issue 26): the reference firmware, stock and AHRS_KI=1.0f NO_CORRECTION=1, emulated with the
    same scenario and seed, compared in one command: the plot is written, the JSON names ki per flight, the Rerun
    recording holds both flights."""
    from support import firmware as S

    why = S.missing()
    if why:
        pytest.skip(why)
    if not hasattr(S, "build_reference"):
        pytest.skip("tests/support/firmware.py has no build_reference (the reference firmware's branch)")
    captures = []
    for name, options in (("stock", ()), ("lab", ("AHRS_KI=1.0f", "NO_CORRECTION=1"))):
        elf = S.build_reference(tmp_path / name, *options)
        out = tmp_path / f"{name}.stv"
        code, _, err = run_cli(
            monkeypatch,
            capsys,
            "emulate",
            elf,
            "--scenario",
            "hand-tilts",
            "--duration",
            "20",
            "--seed",
            "1",
            "--out",
            out,
            "--no-view",
        )
        assert code == 0, err
        captures.append(out)
    png, rrd = tmp_path / "ex45.png", tmp_path / "ex45.rrd"
    code, out, err = run_cli(monkeypatch, capsys, "compare", *captures, "--plot", png, "--json", "--rrd", rrd)
    assert code == 0, err
    d = json.loads(out)
    assert [f["settings"]["ki"] for f in d["flights"]] == [0.1, 1.0]
    assert [f["label"] for f in d["flights"]] == ["ki 0.1", "ki 1, correction off"]
    assert png.stat().st_size > 10_000
    from steval_viewer.rrd_check import read_rrd

    info = read_rrd(rrd)
    assert info.samples["flights/a/pitch_thx_deg"] == d["flights"][0]["rows"]
    assert info.samples["flights/b/pitch_thx_deg"] == d["flights"][1]["rows"]


@pytest.mark.slow
def test_spawn_shows_both_flights_in_the_viewer(pair, tmp_path):
    """`steval compare stock.stv lab.stv --spawn` on a virtual display: the desktop viewer holds both flights'
    subtrees on the aligned timeline (a screenshot is kept under the test's tmp path)."""
    from support.cli import run_steval
    from support.xdisplay import screenshot, viewer_port, viewer_recording, virtual_display

    with virtual_display() as display, viewer_port() as port:
        r = run_steval(["compare", *pair, "--spawn", "--grpc-port", port], env=display.env, timeout=180)
        assert r.returncode == 0, r.stderr
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        held = viewer_recording(url, timeline="aligned_time", end=1)
        for k in "ab":
            assert {
                f"/flights/{k}/pitch_thx_deg",
                f"/flights/{k}/roll_thy_deg",
                f"/flights/{k}/world/drone",
            } <= held.entities
        png = screenshot(url, tmp_path / "side_by_side.png")
        assert png[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_readme_example_word_for_word(monkeypatch, capsys, tmp_path):
    """The docs' side-by-side example (docs/howto/compare-flights.md), run as written: the output it shows is the
    output."""
    import re
    import shlex

    text = (ROOT / "docs" / "howto" / "compare-flights.md").read_text(encoding="utf-8")
    commands = re.search(r"```sh\n(.*?)```", text, re.S).group(1).strip().splitlines()
    shown = re.search(r"prints\n\n```text\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    out = ""
    for line in commands:
        argv = shlex.split(line)
        assert argv[0] == "steval"
        code, out, err = run_cli(monkeypatch, capsys, *argv[1:])
        assert code == 0, (line, err)
    assert out == shown
    assert (tmp_path / "ex45.png").is_file() and (tmp_path / "ex45.rrd").is_file()

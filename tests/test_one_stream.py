"""One stream of frames: ``steval live --ble`` (the fake BLE backend playing the emulated stock firmware's
notifications), ``steval replay`` of a BLE capture in Rerun, a serial capture and a text log played live
(``replay://``) all run through the same pipeline (``LivePipeline``) and the same Rerun logger (``LiveLogger``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support.ble import FakeBleBackend
from support.cli import run_cli

from steval_link.link import ble_payloads as B
from steval_link.link.load import read_recording
from steval_link.live.pipeline import LivePipeline

ROOT = Path(__file__).resolve().parents[1]
REC = ROOT / "recordings"


@pytest.fixture
def spy(monkeypatch):
    """Every pipeline and logger made, and the rows each logger was given."""
    from steval_viewer import live_log

    made: dict[str, list] = {"pipelines": [], "loggers": [], "rows": []}
    init_pipe, init_logger, log_batch = (
        LivePipeline.__init__,
        live_log.LiveLogger.__init__,
        live_log.LiveLogger.log_batch,
    )

    def pipe_init(self, *a, **k):
        made["pipelines"].append(type(self))
        init_pipe(self, *a, **k)

    def logger_init(self, *a, **k):
        made["loggers"].append(type(self))
        init_logger(self, *a, **k)

    def logged(self, batch):
        made["rows"].append((type(batch).__name__, len(batch)))
        log_batch(self, batch)

    monkeypatch.setattr(LivePipeline, "__init__", pipe_init)
    monkeypatch.setattr(live_log.LiveLogger, "__init__", logger_init)
    monkeypatch.setattr(live_log.LiveLogger, "log_batch", logged)
    return made


def _ran(made) -> tuple[set, set, int]:
    rows = sum(n for _, n in made["rows"])
    out = (set(made["pipelines"]), set(made["loggers"]), rows, {k for k, _ in made["rows"]})
    for v in made.values():
        v.clear()
    return out


@pytest.mark.slow  # real time: a 2 s BLE session and two captures played at their pace (≈ 20 s)
def test_ble_live_ble_replay_serial_and_text_share_the_pipeline_and_logger(monkeypatch, capsys, tmp_path, spy):
    from steval_viewer import live_log

    recs = B.ble_records(read_recording(REC / "ble_demo.stv").chunks)[:1500]
    fake = FakeBleBackend([(c, p) for _, c, p in recs], pace_s=0.0002)
    monkeypatch.setattr("steval_link.cli.live.bleak_backend", lambda: fake)
    runs = {
        "live --ble": ["live", "--ble", "--no-view", "--rrd", tmp_path / "a.rrd", "--out", tmp_path / "a.stv"]
        + ["--duration", "2", "--no-prompt"],
        "replay BLE": ["replay", REC / "ble_demo.stv", "--rrd", tmp_path / "b.rrd"],
        "serial": ["live", "--port", f"replay://{REC / 'demo.stv'}?speed=200", "--no-view", "--rrd", tmp_path / "c.rrd"]
        + ["--out", tmp_path / "c.stv", "--no-prompt"],
        "text log": ["live", "--port", f"replay://{REC / 'textmode.log'}?speed=200", "--no-view"]
        + ["--rrd", tmp_path / "d.rrd", "--out", tmp_path / "d.stv", "--no-prompt"],
    }
    seen = {}
    for name, args in runs.items():
        code, out, err = run_cli(monkeypatch, capsys, *args)
        assert code == 0, (name, err)
        seen[name] = _ran(spy)
    for name, (pipes, loggers, rows, kinds) in seen.items():
        assert pipes == {LivePipeline} and loggers == {live_log.LiveLogger}, name
        assert rows > 100 and kinds == {"LiveRows"}, (name, rows, kinds)
    # the BLE rows are the sender's samples: one per motion notification recorded (none held: nothing dropped)
    played = B.ble_records(read_recording(tmp_path / "a.stv").chunks)
    assert seen["live --ble"][2] == sum(1 for _, c, _ in played if c == B.CHAR_MOTION) > 100
    assert seen["replay BLE"][2] == 5976

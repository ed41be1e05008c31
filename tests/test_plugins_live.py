"""A broken estimator never costs data: ``steval live`` over the pty fake drone with a user's estimator that fails
mid-flight keeps recording and viewing, with one line naming the user's file and line."""

from __future__ import annotations

import signal
import textwrap
import time

import pytest
from support.ptyfeed import PtyFeeder, StevalProcess, flight_stream

from steval_link.link.capture import read_capture
from steval_link.link.decoder import StreamDecoder

pytestmark = pytest.mark.slow  # real time: a child process on a pseudo-terminal

START_TIMEOUT_S = 60.0

FAILS_AFTER_2_S = textwrap.dedent("""
    import numpy as np

    class Brittle:
        def __init__(self, after=323):
            self.after = after
            self.reset()

        def reset(self):
            self.n = 0

        def step(self, acc_mg, gyro_mdps, thr=0):
            self.n += 1
            if self.n > self.after:
                raise ZeroDivisionError("the student's bug")
            return np.array([1.0, 0.0, 0.0, 0.0])
""")


@pytest.mark.parametrize("flavour", ["raises", "nan"])
def test_live_goes_on_recording_and_viewing_when_a_users_estimator_fails(flavour, tmp_path):
    source = (
        FAILS_AFTER_2_S
        if flavour == "raises"
        else FAILS_AFTER_2_S.replace('raise ZeroDivisionError("the student\'s bug")', "return np.full(4, np.nan)")
    )
    (tmp_path / "brittle.py").write_text(source)
    data = flight_stream(1600)  # ~10 s at the real rate
    rrd = tmp_path / "live.rrd"
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        proc = StevalProcess(
            [
                "live",
                "--no-view",
                "--port",
                str(feeder.link),
                "--out",
                str(tmp_path / "cap.stv"),
                "--rrd",
                str(rrd),
                "-e",
                "brittle.py:Brittle,ekf3",
            ],
            cwd=tmp_path,
        )
        assert proc.wait_line("reading ", START_TIMEOUT_S) is not None, proc.stderr
        feeder.start()
        assert proc.wait_line("Brittle disabled", 30) is not None, proc.stderr
        assert feeder.wait_done(30)
        time.sleep(0.5)
        rc = proc.finish(sig=signal.SIGINT)
    assert rc == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    notes = [line for line in proc.stderr.splitlines() if "disabled" in line]
    assert len(notes) == 1, proc.stderr
    if flavour == "raises":
        assert (
            "estimator Brittle failed in brittle.py, line 15, in step: ZeroDivisionError: the student's bug; "
            "Brittle disabled, recording and viewing go on"
        ) in notes[0]
    else:
        assert (
            "estimator Brittle gave no estimate (NaN) for" in notes[0]
            and "brittle.py, line 12 (Brittle.step)" in notes[0]
        )
    # nothing lost: every byte the fake drone sent is in the capture, every frame reached the viewer's file
    cap = read_capture(tmp_path / "cap.stv")
    assert cap.data == feeder.sent_bytes()
    frames = [f for f in StreamDecoder().feed(cap.data) if hasattr(f, "seq")]
    assert len(frames) == 1600
    from steval_viewer.rrd_check import read_rrd

    info = read_rrd(rrd)
    assert info.samples["plots/pitch_thx_deg/firmware"] == 1600
    assert info.samples["plots/pitch_thx_deg/ekf3"] == 1600
    assert 300 <= info.samples["plots/pitch_thx_deg/Brittle"] < 1600  # its rows until it was switched off
    summary = proc.stdout.strip().splitlines()
    assert len(summary) == 1 and summary[0].startswith("recorded ") and "1600 attitude frames" in summary[0]

"""``replay -e X`` summarises each estimator (issue #31): valid rows, the first invalid step, the RMS difference
from the firmware, in the text and in ``--json``."""

from __future__ import annotations

import json
import textwrap

from support.cli import run_cli

from steval_link.link.capture import demo_capture_path

GIVES_UP = textwrap.dedent("""
    import numpy as np
    from steval_link.estimators.accel_tilt import AccelTilt

    class Quits:
        def __init__(self, after=2000):
            self.after, self.inner = after, AccelTilt()
            self.reset()

        def reset(self):
            self.inner.reset()
            self.k = 0

        def step(self, acc_mg, gyro_mdps, thr=0):
            self.k += 1
            return np.full(4, np.nan) if self.k > self.after else self.inner.step(acc_mg, gyro_mdps, thr)
""")


def test_replay_says_what_each_estimator_did(tmp_path, monkeypatch, capsys):
    f = tmp_path / "quits.py"
    f.write_text(GIVES_UP)
    demo = demo_capture_path()
    code, out, err = run_cli(
        monkeypatch, capsys, "replay", demo, "-e", "accel", "-e", f"{f}:Quits(after=2000)", "--json"
    )
    assert code == 0, err
    est = {e["name"]: e for e in json.loads(out)["estimators"]}
    assert list(est) == ["accel", "Quits(after=2000)"]
    q, a = est["Quits(after=2000)"], est["accel"]
    assert q["valid_rows"] == 2000 and q["rows"] > 5000 and q["first_invalid_step"] is not None
    assert a["valid_rows"] == a["rows"] and a["first_invalid_step"] is None
    assert 0 < a["rms_diff_pitch_deg"] < 10 and 0 < a["rms_diff_roll_deg"] < 10
    code, out, err = run_cli(monkeypatch, capsys, "replay", demo, "-e", f"accel,{f}:Quits(after=2000)")
    assert code == 0, err
    lines = [ln for ln in out.splitlines() if ln.startswith("estimator ")]
    assert lines[0].startswith(f"estimator accel: {a['rows']}/{a['rows']} valid rows; RMS difference from the firmware")
    assert lines[1].startswith(
        f"estimator Quits(after=2000): 2000/{q['rows']} valid rows (first invalid at step {q['first_invalid_step']})"
    )

"""Your own estimator wherever one is named: references (file, module, entry point, options), the guard around it,
one line for every way it can be wrong, and the live session that disables a failing one and goes on."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from support.ble import run_until_played
from support.cli import run_cli
from support.ptyfeed import flight_stream

from steval_link import constants as C
from steval_link.errors import UserError
from steval_link.estimators import plugins, registry
from steval_link.live import pipeline as live_est
from steval_link.live.pipeline import LivePipeline

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "recordings" / "demo.stv"

#: a tilt-from-gravity estimator written as a student might: no base class, numpy only, a gain option
TILT = """
import math
import numpy as np


class {cls}:
    def __init__(self, gain=1.0, label="x"):
        self.gain = gain
        self.reset()

    def reset(self):
        self.thx = self.thy = 0.0

    def step(self, acc_mg, gyro_mdps, thr=0):
        ax, ay, az = acc_mg
        self.thx += self.gain * (math.atan2(ay, az) - self.thx)
        self.thy += self.gain * (math.atan2(-ax, math.hypot(ay, az)) - self.thy)
        hx, hy = self.thx / 2, self.thy / 2
        return np.array([math.cos(hx) * math.cos(hy), math.sin(hx) * math.cos(hy), math.cos(hx) * math.sin(hy),
                         -math.sin(hx) * math.sin(hy)])
"""


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def error_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("steval: error:")]


# ---- references ---------------------------------------------------------------------------------------------------


def test_split_list_keeps_commas_inside_options_and_quotes():
    assert plugins.split_list("ekf3, a.py:A(q=1, r=(2, 3)),b:B(s='x,y'),accel") == [
        "ekf3",
        "a.py:A(q=1, r=(2, 3))",
        "b:B(s='x,y')",
        "accel",
    ]


@pytest.mark.parametrize(
    "text, kind, source, attr, options",
    [
        ("my_ekf.py:MyEkf", "file", "my_ekf.py", "MyEkf", {}),
        ("my_ekf.py:MyEkf(q_gyro=1e-4, r_acc=0.05)", "file", "my_ekf.py", "MyEkf", {"q_gyro": 1e-4, "r_acc": 0.05}),
        ("sub/dir/f.py", "file", "sub/dir/f.py", None, {}),
        (r"C:\course\f.py:Filt", "file", r"C:\course\f.py", "Filt", {}),
        (
            "mypkg.filters:MyEkf(mode='fast', axes=(1, 2), on=True)",
            "module",
            "mypkg.filters",
            "MyEkf",
            {"mode": "fast", "axes": (1, 2), "on": True},
        ),
        ("ekf3(acc_motion_mg=20)", "builtin", "ekf3", None, {"acc_motion_mg": 20}),
        ("some-plugin", "builtin", "some-plugin", None, {}),
    ],
)
def test_references_parse(text, kind, source, attr, options):
    ref = plugins.parse_reference(text)
    assert (ref.kind, ref.source, ref.attr, ref.options) == (kind, source, attr, options)


@pytest.mark.parametrize(
    "text", ["f.py:A(__import__('os').system('true'))", "f.py:A(q=1+x)", "f.py:A(1, 2)", "f.py:A(**d)", "f.py:A(q=)"]
)
def test_options_are_keyword_literals_only(text):
    with pytest.raises(UserError, match="keyword=value|not a literal"):
        plugins.parse_reference(text)


def test_a_file_estimator_runs_everywhere_an_estimator_is_named(tmp_path, monkeypatch, capsys):
    f = write(tmp_path / "tilt_filter.py", TILT.format(cls="TiltFilter"))
    names = registry.parse_names(f"ekf3,{f}:TiltFilter(gain=0.5)", ())
    assert names == ["ekf3", "TiltFilter(gain=0.5)"] and names[1].reference.options == {"gain": 0.5}
    est = registry.create(names[1])
    assert isinstance(est, plugins.Guarded) and est.inner.gain == 0.5
    code, out, err = run_cli(monkeypatch, capsys, "compare", str(DEMO), "-e", f"{f}:TiltFilter", "--json")
    assert code == 0, err
    rows = {t["name"]: t for t in json.loads(out)["traces"]}
    assert rows["TiltFilter"]["available"] and rows["TiltFilter"]["pitch_thx"]["n"] > 9000
    code, out, err = run_cli(monkeypatch, capsys, "replay", str(DEMO), "-e", f"{f}", "--json")
    assert code == 0, err
    code, out, err = run_cli(
        monkeypatch,
        capsys,
        "simulate",
        "-e",
        f"{f}:TiltFilter(gain=0.2)",
        "--gyro",
        "0",
        "0",
        "0",
        "--acc",
        "0",
        "342",
        "940",
        "-n",
        "200",
        "--json",
    )
    assert code == 0, err
    assert json.loads(out)["final"]["eax_deg"] == pytest.approx(20.0, abs=0.1)


def test_a_module_estimator_and_the_estimators_name_attribute(tmp_path, monkeypatch):
    pkg = tmp_path / "coursework"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    write(pkg / "filters.py", TILT.format(cls="Complementary") + "\n    name = 'compl'\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    sel = registry.resolve("coursework.filters:Complementary(gain=0.3)")
    assert str(sel) == "compl(gain=0.3)" and sel.reference.kind == "module"
    tel_q = registry.create(sel).run(np.float32([[0, 0, 1000]] * 5), np.zeros((5, 3), np.float32))
    assert tel_q.valid.all() and np.allclose(tel_q.thx_rad, 0)


def test_an_installed_entry_point(tmp_path, monkeypatch):
    write(tmp_path / "plugin_mod.py", TILT.format(cls="Plugged"))
    dist = tmp_path / "steval_plugin_demo-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: steval-plugin-demo\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[steval_link.estimators]\nplugged-tilt = plugin_mod:Plugged\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "plugged-tilt" in plugins.entry_point_names()
    names = registry.parse_names("plugged-tilt(gain=0.25),accel", ())
    assert names == ["Plugged(gain=0.25)", "accel"] and registry.create(names[0]).inner.gain == 0.25


def test_a_plugin_named_like_a_builtin_keeps_its_own_name(tmp_path):
    f = write(tmp_path / "t.py", TILT.format(cls="Mine") + "\n    name = 'st-mahony'\n")
    (sel,) = registry.parse_names(f"{f}:Mine", ())
    assert sel == "st-mahony (Mine)" and isinstance(registry.create(sel), plugins.Guarded)


def test_the_same_class_twice_gets_its_options_in_the_name(tmp_path):
    f = write(tmp_path / "t.py", TILT.format(cls="T"))
    names = registry.parse_names(f"{f}:T,{f}:T(gain=0.1),{f}:T(gain=0.2)", ())
    assert [str(n) for n in names] == ["T", "T(gain=0.1)", "T(gain=0.2)"]


def test_two_identical_labels_are_one_sentence_never_a_merge(tmp_path):
    f = write(tmp_path / "t.py", TILT.format(cls="T"))
    with pytest.raises(UserError, match=r"estimator T\(gain=0.1\) is chosen twice"):
        registry.parse_names(f"{f}:T(gain=0.1),{f}:T(gain=0.1)", ())


def test_builtins_take_options_the_same_way():
    names = registry.parse_names("ekf3(acc_motion_mg=20),ekf3", ())
    assert names == ["ekf3(acc_motion_mg=20)", "ekf3"]
    assert registry.create(names[0]).acc_var != registry.create("ekf3").acc_var
    with pytest.raises(UserError, match="does not take"):
        registry.parse_names("ekf3(nonsense=1)", ())


# ---- one line for every mistake -----------------------------------------------------------------------------------


BAD = {
    "missing file": (None, "nope.py:X", "estimator file nope.py not found"),
    "syntax error": ("class A:\n    def step(self, a, g, thr=0)\n        return a\n", "{f}:A", "line 2: syntax error"),
    "missing class": (TILT.format(cls="Real"), "{f}:Imagined", "has no class Imagined (estimator classes there: Real)"),
    "no step": ("class A:\n    def reset(self):\n        pass\n", "{f}:A", "it has no step() method"),
    "wrong option": (TILT.format(cls="A"), "{f}:A(gian=2)", "does not take the option gian (it takes: gain, label)"),
    "import fails": (
        "import a_package_nobody_has\n" + TILT.format(cls="A"),
        "{f}:A",
        "failed to load: ModuleNotFoundError: No module named 'a_package_nobody_has'",
    ),
    "constructor raises": (
        "class A:\n    def __init__(self):\n        raise RuntimeError('no calibration')\n"
        "    def reset(self): pass\n    def step(self, a, g, thr=0): return a\n",
        "{f}:A",
        "could not be constructed: RuntimeError: no calibration",
    ),
    "no module": (None, "coursework_missing.filters:A", "no module named coursework_missing.filters"),
    "not a literal": (TILT.format(cls="A"), "{f}:A(gain=g)", "is not a literal value"),
}


@pytest.mark.parametrize("case", sorted(BAD))
@pytest.mark.parametrize("command", ["compare", "replay", "simulate", "evaluate", "live", "emulate"])
def test_every_bad_reference_is_one_line_and_exit_2(case, command, tmp_path, monkeypatch, capsys):
    source, ref, message = BAD[case]
    f = tmp_path / "student_filter.py"
    if source is not None:
        write(f, source)
    monkeypatch.chdir(tmp_path)
    ref = ref.format(f=f.name)
    args = {
        "compare": [str(DEMO), "-e", ref],
        "replay": [str(DEMO), "-e", ref],
        "simulate": ["-e", ref],
        "evaluate": [str(DEMO), "-e", ref],
        # checked before the port is opened or the firmware loaded: no capture file is made
        "live": ["--port", str(tmp_path / "ttyUSB9"), "--no-view", "-e", ref],
        "emulate": [str(DEMO), "--no-view", "-e", ref],
    }[command]
    code, out, err = run_cli(monkeypatch, capsys, command, *args)
    assert code == 2, err
    assert not list(tmp_path.glob("**/*.stv"))
    assert len(error_lines(err)) == 1 and message in error_lines(err)[0], err
    assert "Traceback (most recent call last)" not in err
    other = [line for line in err.splitlines() if not line.startswith("steval: error:")]
    if case == "constructor raises":  # the user's own traceback, trimmed to their file
        assert other[0] == "Traceback (your code):" and all("student_filter.py" in line for line in other[1::3])
    else:
        assert not [line for line in other if line.strip()], err


RAISES_LATE = """
import numpy as np


class Fragile:
    def __init__(self):
        self.reset()

    def reset(self):
        self.k = 0

    def step(self, acc_mg, gyro_mdps, thr=0):
        self.k += 1
        return self.update(acc_mg)

    def update(self, acc_mg):
        if self.k > 700:
            return np.array([1.0, 0.0, 0.0]) / (acc_mg[0] - acc_mg[0])[None][0:0].sum()  # line 18: raises
        return np.array([1.0, 0.0, 0.0, 0.0])
"""


@pytest.mark.parametrize("command", ["compare", "replay", "evaluate", "simulate"])
def test_a_failing_step_in_a_batch_command_is_exit_2_with_the_users_trimmed_traceback(
    command, tmp_path, monkeypatch, capsys
):
    f = write(
        tmp_path / "fragile.py",
        RAISES_LATE.replace(
            "np.array([1.0, 0.0, 0.0]) / (acc_mg[0] - acc_mg[0])[None][0:0].sum()  # line 18: raises",
            "{}['no such key']",
        ),
    )
    ref = f"{f}:Fragile"
    args = {
        "compare": [str(DEMO), "-e", ref],
        "replay": [str(DEMO), "-e", ref],
        "simulate": ["-e", ref, "-n", "1000"],
        "evaluate": [str(DEMO), "-e", ref],
    }[command]
    if command == "evaluate":  # a capture needs ground truth to be scored against: a sidecar of zeros
        np.savez(tmp_path / "demo.stv.truth.npz", step=np.arange(20000), quat=np.tile([1.0, 0, 0, 0], (20000, 1)))
        args[0] = str(tmp_path / "demo.stv")
        (tmp_path / "demo.stv").write_bytes(DEMO.read_bytes())
    code, out, err = run_cli(monkeypatch, capsys, command, *args)
    assert code == 2
    lines = err.strip().splitlines()
    assert lines[-1] == (
        "steval: error: estimator Fragile failed in fragile.py, line 18, in update: KeyError: 'no such key'"
    ), err
    assert lines[0] == "Traceback (your code):"
    assert [line.split(",")[0] for line in lines if line.startswith("  File")] == [f'  File "{f}"'] * 2
    assert "steval_link" not in err


@pytest.mark.parametrize(
    "returned, message",
    [
        ("None", "step() returned None"),
        ("np.zeros(3)", "step() returned shape (3,)"),
        ("'q'", "not the (4,) quaternion"),
    ],
)
def test_a_wrong_return_value_is_named(returned, message, tmp_path, monkeypatch, capsys):
    f = write(
        tmp_path / "w.py",
        f"import numpy as np\nclass W:\n    def reset(self): pass\n"
        f"    def step(self, a, g, thr=0):\n        return {returned}\n",
    )
    code, out, err = run_cli(monkeypatch, capsys, "compare", str(DEMO), "-e", f"{f}:W")
    assert code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert "w.py, line 4 (W.step)" in err


def test_the_guard_skips_nonfinite_rows_and_reads_the_users_own_run(tmp_path):
    f = write(
        tmp_path / "own.py",
        """
        import numpy as np
        class Batch:
            def reset(self): pass
            def step(self, a, g, thr=0): raise AssertionError("run() is used")
            def run(self, acc_mg, gyro_mdps, thr=None):
                assert np.isfinite(acc_mg).all() and np.isfinite(gyro_mdps).all()
                q = np.zeros((len(acc_mg), 4)); q[:, 0] = 1
                return q
        """,
    )
    est = registry.create(f"{f}:Batch")
    acc = np.float32([[0, 0, 1000]] * 6)
    acc[2] = np.nan
    out = est.run(acc, np.zeros((6, 3), np.float32))
    assert out.valid.tolist() == [True, True, False, True, True, True]
    assert np.isnan(out.q_wxyz[2]).all() and (out.q_wxyz[[0, 5], 0] == 1).all()


# ---- live ---------------------------------------------------------------------------------------------------------


def live_pipeline(tmp_path, spec: str) -> LivePipeline:
    return LivePipeline(registry.parse_names(spec, ()) + ["st-mahony"])


def feed(pipe: LivePipeline, data: bytes, chunk: int = 997) -> None:
    for i in range(0, len(data), chunk):
        pipe.feed([(data[i : i + chunk], 1.7e9 + i / 1e4)])


def test_live_a_raising_estimator_is_disabled_with_one_line_and_the_rest_goes_on(tmp_path):
    f = write(
        tmp_path / "fragile.py",
        RAISES_LATE.replace(
            "np.array([1.0, 0.0, 0.0]) / (acc_mg[0] - acc_mg[0])[None][0:0].sum()  # line 18: raises",
            "{}['no such key']",
        ),
    )
    pipe = live_pipeline(tmp_path, f"{f}:Fragile,ekf3")
    data = flight_stream(2000)
    feed(pipe, data)
    notes = list(pipe.notes)
    assert notes == [
        "estimator Fragile failed in fragile.py, line 18, in update: KeyError: 'no such key'; "
        "Fragile disabled, recording and viewing go on"
    ]
    assert pipe.health.attitude == 2000 and pipe.mahony.describe() == "replica bit-exact"
    assert pipe.estimators.disabled.keys() == {"Fragile"}


def test_live_a_nan_flood_is_disabled_with_where_its_step_is(tmp_path):
    f = write(
        tmp_path / "nan_filter.py",
        """
        import numpy as np
        class Drifter:
            def reset(self): self.k = 0
            def __init__(self): self.reset()
            def step(self, a, g, thr=0):
                self.k += 1
                return np.full(4, np.nan) if self.k > 100 else np.array([1.0, 0, 0, 0])
        """,
    )
    pipe = live_pipeline(tmp_path, f"{f}:Drifter")
    feed(pipe, flight_stream(1200))
    flood = int(live_est.NAN_FLOOD_S * C.AHRS_RATE_HZ)
    (note,) = pipe.notes
    assert note.startswith("estimator Drifter gave no estimate (NaN) for ")
    assert "nan_filter.py, line 6 (Drifter.step)" in note and int(note.split("for ")[1].split()[0]) >= flood


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def slowed_pipeline(tmp_path, monkeypatch, cls: str, others: str, seconds_of_call):
    """A live pipeline whose estimator ``cls`` (TILT, in CLS.py; ``others``: more names) takes
    ``seconds_of_call(args)`` on the estimators' fake clock per ``run`` call. Returns (pipeline, estimators)."""
    f = write(tmp_path / f"{cls.lower()}.py", TILT.format(cls=cls))
    clock = FakeClock()
    ests = live_est.LiveEstimators(registry.parse_names(f"{f}:{cls}{others}", ()), clock=clock)
    inner = ests.others[cls]
    real_run = inner.run

    def run(*args):
        clock.t += seconds_of_call(args)
        return real_run(*args)

    monkeypatch.setattr(inner, "run", run)
    pipe = LivePipeline([])
    pipe.estimators = ests
    return pipe, ests


def test_live_a_slow_estimator_is_measured_and_disabled(tmp_path, monkeypatch):
    # 0.8 s of processing per second of stream: cannot keep up
    pipe, ests = slowed_pipeline(
        tmp_path, monkeypatch, "Slow", ",accel", lambda args: 0.8 * len(args[0]) / C.AHRS_RATE_HZ
    )
    feed(pipe, flight_stream(2000), chunk=1700)
    assert ests.disabled.keys() == {"Slow"} and "accel" not in ests.disabled
    (note,) = pipe.notes
    assert note.startswith("estimator Slow needed 800 ms per second of stream for ") and "at most 500 ms" in note


def test_live_one_call_that_stalls_disables_at_once(tmp_path, monkeypatch):
    pipe, _ = slowed_pipeline(tmp_path, monkeypatch, "Stall", "", lambda args: 3.0)
    feed(pipe, flight_stream(300), chunk=100_000)
    (note,) = pipe.notes
    assert note.startswith("estimator Stall took 3.0 s for ") and "too slow to run live" in note


def test_estimates_of_a_disabled_estimator_stay_nan_columns_so_batches_still_merge(tmp_path):
    f = write(
        tmp_path / "fragile.py",
        RAISES_LATE.replace(
            "np.array([1.0, 0.0, 0.0]) / (acc_mg[0] - acc_mg[0])[None][0:0].sum()  # line 18: raises", "1 / 0"
        ),
    )

    from support.viewers import NullViewer

    class Collect(NullViewer):
        def __init__(self):
            self.batches = []

        def log_batch(self, b):
            self.batches.append(b)

    sink = Collect()
    pipe = LivePipeline(registry.parse_names(f"{f}:Fragile", ()), None, file_logger=sink, file_interval_s=1e9)
    feed(pipe, flight_stream(1500))
    pipe.flush_view()
    (batch,) = sink.batches
    q = batch.estimates["Fragile"]
    assert len(batch) == 1500 and np.isfinite(q[:600]).all() and np.isnan(q[-500:]).all()


@pytest.mark.slow  # real time: 3000 BLE notifications paced at 0.5 ms through a live session: ≈ 3 s
def test_ble_live_a_raising_estimator_without_rate_hz_is_disabled_and_every_notification_recorded(tmp_path):
    import io

    from support.ble import FakeBleBackend

    from steval_link.link import ble_payloads as B
    from steval_link.link.capture import read_capture
    from steval_link.link.load import read_recording
    from steval_link.live.session import LiveOptions, LiveSession, source_for

    f = write(
        tmp_path / "fragile.py",
        RAISES_LATE.replace(
            "np.array([1.0, 0.0, 0.0]) / (acc_mg[0] - acc_mg[0])[None][0:0].sum()  # line 18: raises",
            "{}['no such key']",
        ),
    )
    recs = [(c, p) for _, c, p in B.ble_records(read_recording(ROOT / "recordings" / "ble_demo.stv").chunks)[:3000]]
    fake = FakeBleBackend(recs, pace_s=0.0005)
    out = tmp_path / "ble.stv"
    stream = io.StringIO()
    opts = LiveOptions(out=out, estimators=registry.parse_names(f"{f}:Fragile,accel", ()))
    session = LiveSession(opts, source_for("ble:auto", backend=fake), stream=stream)

    run_until_played(session, fake)
    notes = [line for line in stream.getvalue().splitlines() if "disabled" in line]
    assert (
        len(notes) == 1
        and (
            "estimator Fragile failed in fragile.py, line 18, in update: KeyError: 'no such key'; "
            "Fragile disabled, recording and viewing go on"
        )
        in notes[0]
    )
    assert [(c, p) for _, c, p in B.ble_records(read_capture(out).chunks)] == recs
    est = session.pipeline.estimators
    assert [n for n in est.others if n not in est.disabled] == ["accel"]

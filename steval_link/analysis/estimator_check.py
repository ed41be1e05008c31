"""``steval estimator check``: an estimator's interface checks, then its scores next to ST-Mahony and VQF.

The checks run on inputs in the firmware's units (acc mg, gyro mdps, x right, y forward, z up, 161.5 Hz, seeded
noise): shapes, level at rest, the pitch sign (20° nose up → thx ≈ +20°) and roll sign, a +20 dps turn about x, NaN,
free fall and saturation, determinism across instances and ``reset()``, and speed (live needs 2 × 161.5 steps/s).
Scores: RMS tilt difference (deg) from the firmware and from accel-only tilt on the bundled captures, and the
inclination RMSE on BROAD trials (:mod:`~steval_link.analysis.evaluate`)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.analysis import evaluate as ev
from steval_link.emulation import broad
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.estimators.accel_tilt import accel_tilt, tilt_quaternion
from steval_link.estimators.plugins import PluginError
from steval_link.link.ble_payloads import is_ble_source
from steval_link.link.capture import demo_capture_path
from steval_link.link.load import read_recording, telemetry_of_recording

#: steps per second an estimator needs to run live (the stream's rate, twice over)
LIVE_MIN_STEPS_PER_S = 2.0 * C.AHRS_RATE_HZ
#: estimators scored next to the one checked (those installed)
COMPANIONS = ("st-mahony", "ekf3", "vqf")
#: BROAD labels of the companions (evaluate's table)
BROAD_COMPANIONS = ("st-mahony-flight", "ekf3", "vqf")


@dataclass
class Check:
    """One interface check: its name, passed or not, and what was seen (one sentence)."""

    name: str
    ok: bool
    detail: str


@dataclass
class CheckReport:
    """Everything ``steval estimator check`` found."""

    name: str
    reference: str
    label: str
    checks: list[Check] = field(default_factory=list)
    steps_per_s: float = math.nan
    traceback: str = ""  # the user's traceback of the first failure, trimmed to their code
    captures: list[dict] = field(default_factory=list)
    broad: list = field(default_factory=list)  # evaluate.TrialResult
    broad_note: str = ""

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.checks)

    def as_dict(self) -> dict:
        d = {
            "estimator": self.name,
            "reference": self.reference,
            "ok": self.ok,
            "checks": [{"name": c.name, "ok": c.ok, "detail": c.detail} for c in self.checks],
            "steps_per_s": ev.rounded(self.steps_per_s),
            "live_min_steps_per_s": round(LIVE_MIN_STEPS_PER_S, 1),
            "captures": self.captures,
            "broad": ev.summary(self.broad) if self.broad else None,
        }
        if self.broad_note:
            d["broad_note"] = self.broad_note
        return d


def _gravity_mg(thx_rad, thy_rad) -> np.ndarray:
    """(N, 3) accelerometer at rest for attitudes (thx, thy), mg: R(thx, thy)ᵀ·(0, 0, 1 g)."""
    thx = np.asarray(thx_rad, dtype=np.float64)
    thy = np.asarray(thy_rad, dtype=np.float64)
    return 1000.0 * np.stack([-np.sin(thy), np.sin(thx) * np.cos(thy), np.cos(thx) * np.cos(thy)], axis=-1)


def _noisy(acc_mg, gyro_mdps, seed: int = 7):
    rng = np.random.default_rng(seed)
    acc = np.asarray(acc_mg, dtype=np.float64) + rng.normal(0.0, 2.0, np.shape(acc_mg))
    gyro = np.asarray(gyro_mdps, dtype=np.float64) + rng.normal(0.0, 75.0, np.shape(gyro_mdps))
    return acc.astype(np.float32), gyro.astype(np.float32)


def _held(thx_deg: float, thy_deg: float, seconds: float, seed: int):
    n = int(round(seconds * C.AHRS_RATE_HZ))
    acc = np.repeat(_gravity_mg(math.radians(thx_deg), math.radians(thy_deg))[None], n, axis=0)
    return _noisy(acc, np.zeros((n, 3)), seed)


def _turn(seed: int):
    """1 s level, then +20 dps about x for 0.5 s (gravity turning along): ends at thx = +10°."""
    n0, n1 = int(C.AHRS_RATE_HZ), int(round(0.5 * C.AHRS_RATE_HZ))
    rate = 20.0  # dps
    thx = np.concatenate([np.zeros(n0), np.radians(rate) * np.arange(1, n1 + 1) / C.AHRS_RATE_HZ])
    gyro = np.zeros((n0 + n1, 3))
    gyro[n0:, 0] = rate * 1000.0
    acc = _gravity_mg(thx, np.zeros_like(thx))
    return _noisy(acc, gyro, seed), math.degrees(thx[-1])


def _invalid_input(seed: int):
    rest_a, rest_g = _held(0.0, 0.0, 2.0, seed)
    nan_a = np.full((10, 3), np.nan, np.float32)
    nan_g = rest_g[:10].copy()
    nan_g[::2] = np.nan
    nan_a[1::2] = rest_a[:5]
    fall = np.zeros((int(0.5 * C.AHRS_RATE_HZ), 3), np.float32), np.zeros((int(0.5 * C.AHRS_RATE_HZ), 3), np.float32)
    k = int(0.1 * C.AHRS_RATE_HZ)
    sat = np.tile(np.float32([16000.0, -16000.0, 16000.0]), (k, 1)), np.tile(np.float32([2e6, -2e6, 2e6]), (k, 1))
    after_a, after_g = _held(0.0, 0.0, 5.0, seed + 1)
    acc = np.concatenate([rest_a, nan_a, fall[0], sat[0], after_a])
    gyro = np.concatenate([rest_g, nan_g, fall[1], sat[1], after_g])
    return acc, gyro


def _last_deg(est) -> tuple[float, float]:
    return math.degrees(float(est.thx_rad[-1])), math.degrees(float(est.thy_rad[-1]))


def interface_checks(name, demo_inputs=None) -> tuple[list[Check], float, str]:
    """Every interface check of estimator ``name``: (checks, steps/s, the first failure's trimmed traceback or "")."""
    rate = [math.nan]

    def speed():
        ok, detail, rate[0] = _check_speed(name, demo_inputs)
        return ok, detail

    checks, first_trace = [], ""
    for check_name, fn in (
        ("shapes", partial(_check_shapes, name)),
        ("at rest", partial(_check_at_rest, name)),
        ("pitch sign", partial(_check_held, name, "pitch")),
        ("roll sign", partial(_check_held, name, "roll")),
        ("turn", partial(_check_turn, name)),
        ("invalid input", partial(_check_invalid, name)),
        ("determinism", partial(_check_determinism, name)),
        ("speed", speed),
    ):
        check, trace = _attempt(check_name, fn)
        checks.append(check)
        first_trace = first_trace or trace
    return checks, rate[0], first_trace


def _attempt(check_name: str, fn) -> tuple[Check, str]:
    """Run one check; an exception fails it. Returns the check and the plug-in's traceback (or "")."""
    try:
        ok, detail = fn()
    except PluginError as exc:
        return Check(check_name, False, str(exc)), exc.details or ""
    except Exception as exc:  # noqa: BLE001 - a built-in's failure is a failed check too
        return Check(check_name, False, f"{type(exc).__name__}: {exc}"), ""
    return Check(check_name, bool(ok), detail), ""


def _check_shapes(name):
    acc, gyro = _held(0.0, 0.0, 0.5, 1)
    q1 = np.asarray(registry.create(name).step(acc[0], gyro[0], 0), dtype=np.float64)
    if q1.shape != (4,):
        return False, f"step() returned shape {q1.shape}, not (4,)"
    res = registry.create(name).run(acc, gyro, np.zeros(len(acc), np.int64))
    q = np.asarray(res.q_wxyz, dtype=np.float64)
    if q.shape != (len(acc), 4) or np.shape(res.valid) != (len(acc),):
        return False, f"run() of {len(acc)} rows gave q of shape {q.shape}, valid {np.shape(res.valid)}"
    norm = np.linalg.norm(q[np.asarray(res.valid, bool)], axis=1)
    if norm.size == 0:
        return False, "no valid estimate in 0.5 s at rest (every row NaN or flagged invalid)"
    worst = float(np.max(np.abs(norm - 1.0)))
    if worst > 0.01:
        return False, f"not a unit quaternion: |q| differs from 1 by up to {worst:.3g} (angles come out wrong)"
    return True, f"step() gives a (4,) quaternion, run() one row per input; |q| within {max(worst, 1e-9):.1g} of 1"


def _check_at_rest(name):
    acc, gyro = _held(0.0, 0.0, 10.0, 2)
    thx, thy = _last_deg(registry.create(name).run(acc, gyro))
    return abs(thx) < 1.0 and abs(thy) < 1.0, f"level and still for 10 s: thx {thx:+.2f}°, thy {thy:+.2f}°"


def _check_held(name, axis: str):
    want_x, want_y = (20.0, 0.0) if axis == "pitch" else (0.0, 20.0)
    acc, gyro = _held(want_x, want_y, 10.0, 3)
    thx, thy = _last_deg(registry.create(name).run(acc, gyro))
    ok = abs(thx - want_x) < 2.0 and abs(thy - want_y) < 2.0
    what = "20° nose up (about x)" if axis == "pitch" else "20° roll (about y)"
    return ok, (
        f"held {what}, acc ({acc[0][0]:+.0f}, {acc[0][1]:+.0f}, {acc[0][2]:+.0f}) mg: "
        f"thx {thx:+.2f}°, thy {thy:+.2f}° (expected {want_x:+.0f}°, {want_y:+.0f}°)"
    )


def _check_turn(name):
    (acc, gyro), want = _turn(4)
    thx, thy = _last_deg(registry.create(name).run(acc, gyro))
    return (
        abs(thx - want) < 2.0 and abs(thy) < 2.0,
        f"+20 dps about x for 0.5 s: thx {thx:+.2f}° (expected {want:+.1f}°), thy {thy:+.2f}°",
    )


def _check_invalid(name):
    acc, gyro = _invalid_input(5)
    res = registry.create(name).run(acc, gyro)
    bad_rows = ~(np.isfinite(acc).all(axis=1) & np.isfinite(gyro).all(axis=1))
    q_bad = np.asarray(res.q_wxyz, np.float64)[bad_rows]
    valid_bad = np.asarray(res.valid, bool)[bad_rows]
    # a NaN row is either flagged invalid (the guard of your estimator does it) or holds a finite estimate
    flagged = bool(np.isfinite(q_bad[valid_bad]).all())
    how = "flagged invalid" if not valid_bad.any() else "held (finite)" if flagged else "NOT flagged invalid"
    tail = slice(len(acc) - int(C.AHRS_RATE_HZ), len(acc))
    finite = bool(np.isfinite(np.asarray(res.q_wxyz, np.float64)[tail]).all() and np.asarray(res.valid)[tail].all())
    thx, thy = _last_deg(res)
    detail = f"NaN rows {how}; after free fall and saturation, 5 s at rest ends at thx {thx:+.2f}°, thy {thy:+.2f}°" + (
        "" if finite else ": NO finite estimate in the last second (a NaN got into the state?)"
    )
    return flagged and finite, detail


def _check_determinism(name):
    acc, gyro = _held(5.0, -8.0, 3.0, 6)
    (acc2, gyro2), _ = _turn(6)
    acc, gyro = np.concatenate([acc, acc2]), np.concatenate([gyro, gyro2])
    a = registry.create(name).run(acc, gyro)
    b = registry.create(name).run(acc, gyro)
    est = registry.create(name)
    est.run(acc[:100] + 30.0, gyro[:100] + 500.0)
    est.reset()
    c = est.run(acc, gyro)
    qa, qb, qc = (np.asarray(x.q_wxyz, np.float64) for x in (a, b, c))
    if not np.array_equal(qa, qb, equal_nan=True):
        return False, "two fresh instances on the same inputs differ (random numbers? state shared between them?)"
    if not np.array_equal(qa, qc, equal_nan=True):
        return False, "after reset() the output differs from a fresh instance's (reset() misses some state)"
    return True, "two fresh instances and one after reset() agree bit for bit"


def _check_speed(name, demo_inputs):
    """Steps per second of ``run()`` on the demo capture's inputs: (ok, detail, rate)."""
    acc, gyro, thr = demo_inputs if demo_inputs is not None else _demo_inputs()
    est = registry.create(name)
    t0 = time.perf_counter()
    est.run(acc, gyro, thr)
    elapsed = time.perf_counter() - t0
    rate = len(acc) / elapsed if elapsed > 0 else math.inf
    detail = (
        f"{rate:,.0f} steps/s on {len(acc)} steps of recordings/demo.stv (live needs ≥ "
        f"{LIVE_MIN_STEPS_PER_S:.0f}: twice the stream's {C.AHRS_RATE_HZ:.1f} Hz)"
    )
    return rate >= LIVE_MIN_STEPS_PER_S, detail, rate


def _demo_inputs():
    a = telemetry_of_recording(read_recording(demo_capture_path())).attitude
    return a.acc_mg, a.gyro_mdps, a.thr


#: the recordings the repository ships (``recordings/make_recordings.sh`` makes them); a user's own captures in the
#: same folder (``steval live`` writes ``recordings/steval-<UTC>.stv``) are not among them
BUNDLED_CAPTURES = tuple(
    "ble_demo.stv broad_07.stv demo.stv flight.stv freefall.stv live_params.stv midflight_drops.stv preflight_ok.stv "
    "preflight_swapped_motors.stv".split()
)


def bundled_captures() -> list[Path]:
    """The bundled recordings (:data:`BUNDLED_CAPTURES` next to the demo, those present)."""
    folder = demo_capture_path().parent
    return [folder / name for name in BUNDLED_CAPTURES if (folder / name).is_file()]


def _tilt_rms_deg(q_a, q_b) -> float:
    err = broad.inclination_error_rad(np.asarray(q_a, np.float64), np.asarray(q_b, np.float64))
    ok = np.isfinite(err)
    return float(np.degrees(np.sqrt(np.mean(err[ok] ** 2)))) if ok.any() else math.nan


def capture_scores(names: list, paths: list[Path] | None = None) -> list[dict]:
    """Per capture with binary frames: RMS tilt difference (deg) of each of ``names`` from firmware and accel tilt."""
    out = []
    for p in bundled_captures() if paths is None else paths:
        src = read_recording(p)
        if is_ble_source(src):
            continue
        tel = telemetry_of_recording(src)
        a = tel.attitude
        rows = np.asarray(a.exact, bool)
        if rows.sum() < C.AHRS_RATE_HZ:  # text-mode or almost empty: no firmware quaternion to compare with
            continue
        acc, gyro, thr = (np.asarray(v)[rows] for v in (a.acc_mg, a.gyro_mdps, a.thr))
        q_fw = np.asarray(a.q_wxyz, np.float64)[rows]
        tx, ty, tv = accel_tilt(acc)
        q_acc = tilt_quaternion(tx, ty)
        q_acc[~tv] = np.nan
        vs_fw, vs_acc = {}, {}
        for label, name in names:
            est = registry.create(name).run(acc, gyro, thr)
            q = np.asarray(est.q_wxyz, np.float64).copy()
            q[~np.asarray(est.valid, bool)] = np.nan
            vs_fw[label] = ev.rounded(_tilt_rms_deg(q, q_fw))
            vs_acc[label] = ev.rounded(_tilt_rms_deg(q, q_acc))
        out.append({"capture": p.name, "frames": int(rows.sum()), "vs_firmware_deg": vs_fw, "vs_accel_deg": vs_acc})
    return out


def broad_scores(reference: str, paths: list[Path], progress=None) -> list:
    """Inclination RMSE on each BROAD trial (STEVAL pipeline) of ``reference`` and :data:`BROAD_COMPANIONS`."""
    only = [reference] + [c for c in BROAD_COMPANIONS if c != "vqf" or registry.is_available("vqf")]
    results = []
    for p in paths:
        view = broad.steval_view(broad.load_trial(p))
        specs = ev.default_specs(view.rate_hz, only=only)
        results.append(ev.evaluate_view(view, specs, p.stem, progress))
    return results


def run_check(
    reference: str, *, broad_paths: list[Path] | None = None, captures: bool = True, progress=None
) -> CheckReport:
    """The whole check of the estimator ``reference`` names (see the module doc), scored on ``broad_paths``."""
    progress = progress or (lambda f, s: None)
    sel = registry.resolve(reference)
    try:
        registry.create(sel)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    report = CheckReport(str(sel), sel.reference.text, sel.label)
    progress(0.0, "interface checks")
    report.checks, report.steps_per_s, report.traceback = interface_checks(sel)
    if not report.ok and any(not c.ok and "failed in" in c.detail for c in report.checks):
        report.broad_note = "not scored: the estimator raised in the checks"
        return report
    names = [(str(sel), sel)] + [(c, c) for c in COMPANIONS if registry.is_available(c)]
    if captures:
        progress(0.3, "bundled captures")
        report.captures = capture_scores(names)
    if broad_paths:
        n = len(broad_paths)
        done = [0]

        def each(trial: str, label: str) -> None:
            progress(0.5 + 0.5 * done[0] / (n * (len(BROAD_COMPANIONS) + 1)), f"{trial[:28]}: {label}")
            done[0] += 1

        report.broad = broad_scores(sel.reference.text, broad_paths, each)
    return report


def format_check(report: CheckReport) -> list[str]:
    """The report as plain lines (a table per part)."""
    lines = [f"{report.label}: interface checks"]
    w = max((len(c.name) for c in report.checks), default=5)
    lines += [f"  {'PASS' if c.ok else 'FAIL'}  {c.name.ljust(w)}  {c.detail}" for c in report.checks]
    if report.captures:
        labels = list(report.captures[0]["vs_firmware_deg"])
        width = [max(9, len(k)) for k in labels]
        w0 = max(len("capture"), *(len(c["capture"]) for c in report.captures))
        heads = [k.rjust(x) for k, x in zip(labels, width)]
        lines += [
            "",
            "bundled captures: RMS tilt difference in degrees, from the firmware's attitude | from "
            "accelerometer-only tilt",
            "  ".join(["capture".ljust(w0), "frames".rjust(7)] + heads + ["|"] + heads),
        ]
        for c in report.captures:
            fw, acc = (
                [("—" if c[key][k] is None else f"{c[key][k]:.3f}").rjust(x) for k, x in zip(labels, width)]
                for key in ("vs_firmware_deg", "vs_accel_deg")
            )
            lines.append("  ".join([c["capture"].ljust(w0), str(c["frames"]).rjust(7)] + fw + ["|"] + acc))
    if report.broad:
        lines += ["", "BROAD trials against ground truth (the STEVAL sensor pipeline, 161.5 Hz):"]
        lines += ev.format_table(report.broad).splitlines()
    if report.broad_note:
        lines += ["", report.broad_note]
    return lines

"""``steval simulate``: the UMaine Lab 5 AHRS simulator (constant inputs, optional noise) on any estimator."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from steval_link.analysis.report import json_number
from steval_link.cli import checks
from steval_link.cli.app import app, option
from steval_link.cli.outputs import ForceOption, atomic_output, check_outputs, write_atomic
from steval_link.emulation import lab5
from steval_link.errors import UserError
from steval_link.estimators import registry
from steval_link.estimators.plugins import split_list

CSV_COLUMNS = tuple(
    "iteration acc_x_mg acc_y_mg acc_z_mg gyro_x_mdps gyro_y_mdps gyro_z_mdps thr q0 q1 q2 q3 eax_rad eay_rad eaz_rad "
    "eax_deg eay_deg eaz_deg valid".split()
)

#: Most AHRS steps one run takes (≈ 17 h of firmware time; every iteration is kept in memory).
MAX_ITERATIONS = 10_000_000

_ON_WORDS = {"on", "typical", "yes", "true"}
_OFF_WORDS = {"off", "no", "false", "none"}


def _noise(text: str | None, typical: float, what: str, unit: str, on: bool = False) -> float:
    """The noise σ of ``--{what}-noise`` (``on`` or a number); ``on`` (``--noise``): the typical one when not given."""
    word = ("on" if on else "off") if text is None else text.strip().lower()
    if word in _ON_WORDS | _OFF_WORDS:
        return typical if word in _ON_WORDS else 0.0
    try:
        value = float(word)
    except ValueError:
        raise UserError(
            f"--{what}-noise takes a standard deviation in {unit} or 'on' (typical {typical:g}), got {text!r}"
        ) from None
    if not (math.isfinite(value) and value >= 0):
        raise UserError(f"--{what}-noise must be a standard deviation ≥ 0 {unit}, got {text!r}")
    return value


def write_csv(res: lab5.SimulationResult, stream) -> None:
    """Every iteration as CSV (header :data:`CSV_COLUMNS`); each float as the shortest decimal that reads back."""
    writer = csv.writer(stream, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    rad = np.column_stack([res.eax_rad, res.eay_rad, res.eaz_rad]).astype(np.float64)
    for k in range(res.iterations):
        acc_gyro = [repr(float(v)) for v in [*res.acc_mg[k], *res.gyro_mdps[k]]]
        floats = [repr(float(v)) for v in [*res.q_wxyz[k], *rad[k], *np.degrees(rad[k])]]
        writer.writerow([str(int(res.step[k])), *acc_gyro, str(int(res.thr[k])), *floats, "1" if res.valid[k] else "0"])


#: the run's fields in ``--json``, before its final angles and rows
_JSON_FIELDS = "estimator options settings dt_s estimator_dt_s iterations seed gyro_noise_mdps acc_noise_mg".split()


def to_json(res: lab5.SimulationResult) -> dict:
    """The run as a JSON-ready dict; float32 values are exact (``np.float32(value)`` restores the bits)."""
    final = dict(zip(("eax", "eay", "eaz"), res.final_angles_rad()))
    if not (res.iterations and res.valid[-1]):  # no valid last step: null, as the text says n/a
        final = dict.fromkeys(final, math.nan)
    return {
        **{key: getattr(res, key) for key in _JSON_FIELDS},
        "final": {
            **{f"{n}_rad": json_number(v) for n, v in final.items()},
            **{f"{n}_deg": json_number(math.degrees(v)) for n, v in final.items()},
        },
        "rows": [
            {
                "iteration": int(res.step[k]),
                "acc_mg": [json_number(v) for v in res.acc_mg[k]],
                "gyro_mdps": [json_number(v) for v in res.gyro_mdps[k]],
                "thr": int(res.thr[k]),
                "q_wxyz": [json_number(v) for v in res.q_wxyz[k]],
                **{f"{ea}_rad": json_number(getattr(res, f"{ea}_rad")[k]) for ea in ("eax", "eay", "eaz")},
                "valid": bool(res.valid[k]),
            }
            for k in range(res.iterations)
        ],
    }


def _fmt_vec(v) -> str:
    return "[" + ", ".join(f"{float(x):g}" for x in v) + "]"


def summary(res: lab5.SimulationResult, gyro, acc, throttle: int) -> str:
    """Human-readable inputs and final angles, labelled pitch/roll/yaw with the handout's eax/eay/eaz names."""
    own = res.estimator_dt_s
    integrates = (
        f"{res.estimator} does not integrate (no dt)"
        if own is None
        else f"{res.estimator} integrates at {own * 1e3:.4g} ms"
        + ("" if abs(own - res.dt_s) <= 1e-12 else " (its own period, not the simulation's)")
    )
    lines = [f"steval simulate: {res.estimator}, {res.iterations} iterations of {res.dt_s * 1e3:g} ms; {integrates}"]
    noise = "no noise"
    if res.seed is not None:
        noise = f"noise σ gyro {res.gyro_noise_mdps:g} mdps, acc {res.acc_noise_mg:g} mg (seed {res.seed})"
    lines.append(f"  inputs: gyro {_fmt_vec(gyro)} mdps, acc {_fmt_vec(acc)} mg, throttle {throttle}, {noise}")
    if res.settings:
        s = res.settings
        kp = s["kp_ground"] if throttle < s["min_thr"] else s["kp_flight"]
        extra = ("" if s["correction"] else ", no correction (g* = g)") + f", filter {s['variant']}"
        lines.append(
            f"  filter: kp {kp:g} (throttle {'<' if throttle < s['min_thr'] else '≥'} MIN_THR {s['min_thr']}), "
            f"KI {s['ki']:g}, dt {s['dt_s']:g} s{extra}"
        )
    elif res.options:
        lines.append("  options: " + ", ".join(f"{k}={v}" for k, v in res.options.items()))
    lines.append("final angles (firmware axes: x right, y forward, z up)")
    final_valid = bool(res.iterations and res.valid[-1])
    names = (("eax", "thx", "pitch", "x"), ("eay", "thy", "roll ", "y"), ("eaz", "thz", "yaw  ", "z"))
    for (ea, th, label, axis), rad in zip(names, res.final_angles_rad()):
        rad += 0.0  # print -0 as 0
        if math.isnan(rad) or not final_valid:
            lines.append(f"  {ea} = {th}  {label} (about {axis}):          n/a")
        else:
            lines.append(f"  {ea} = {th}  {label} (about {axis}): {math.degrees(rad):+14.6f} deg  {rad:+.9g} rad")
    lines.extend(_zero_acc_notes(res))
    if res.iterations and not res.valid.all():
        lines.append(
            f"  note: {int((~res.valid).sum())} of {res.iterations} iterations flagged invalid "
            "(valid = 0 in --csv and --json)"
        )
    return "\n".join(lines)


def _zero_acc_notes(res: lab5.SimulationResult) -> list[str]:
    """What a zero accelerometer input (the Lab 5 baseline) does to the estimator, as notes."""
    zero = ~np.asarray(res.acc_mg, dtype=np.float64).any(axis=1)
    if not zero.any():
        return []
    where = "" if zero.all() else f" in {int(zero.sum())} of {res.iterations} iterations"
    if res.settings:
        return [
            f"  acc is 0{where}: correction and KI inactive (the firmware's error term is 0, so --ki and "
            "--no-correction print the same angles; try --acc 0 0 1000 --throttle 500 -n 1000)"
        ]
    if res.estimator in ("ekf3", "mekf") and not res.valid[zero].any():
        return [
            f"  acc is 0{where}: {res.estimator} takes its initial tilt from the first non-zero accelerometer "
            "sample and does not integrate the gyro before it: those iterations are flagged invalid"
        ]
    if not res.valid[zero].any():
        return [
            f"  acc is 0{where}: {res.estimator} has no tilt from a zero accelerometer vector: those iterations "
            "are flagged invalid"
        ]
    return [f"  acc is 0{where}: no accelerometer correction in those iterations"]


_GyroNoise = option(
    str | None, "--gyro-noise", metavar="MDPS|on", help="Gyro noise standard deviation in mdps, or 'on' for 75 mdps."
)


@app.command("simulate")
def simulate_command(
    gyro: option(
        tuple[float, float, float], metavar="X Y Z", help="Gyro rate, mdps (Lab 5 baseline: 1000 2000 4000)."
    ) = lab5.BASELINE_GYRO_MDPS,
    acc: option(
        tuple[float, float, float], metavar="X Y Z", help="Acceleration, mg (Lab 5 baseline: 0 0 0; at rest 0 0 1000)."
    ) = lab5.BASELINE_ACC_MG,
    iterations: option(int, "--iterations", "-n", help="Number of AHRS steps (≥ 0).") = 100,
    noise: option(
        bool, "--noise", help="Add typical LSM6DSL noise to both sensors (gyro 75 mdps, acc 2 mg; Lab 5 part 3)."
    ) = False,
    gyro_noise: _GyroNoise = None,
    acc_noise: option(
        str | None, metavar="MG|on", help="Accelerometer noise standard deviation in mg, or 'on' for 2 mg."
    ) = None,
    seed: option(int | None, help="Noise seed (default: random, printed).") = None,
    throttle: option(int, help="gTHR for every step: below MIN_THR (200) kp = 10, otherwise 0.4.") = 0,
    ki: checks.KiOption = None,
    kp: option(float | None, help="Proportional gain, replacing both 10 and 0.4.") = None,
    correction: checks.CorrectionOption = None,
    variant: checks.VariantOption = None,
    dt: checks.DtOption = None,
    estimators: option(
        list[str] | None,
        "--estimator",
        "-e",
        help="Estimator (one; default st-mahony): a registry name or your own (FILE.py:CLASS, module:CLASS, options in "
        "parentheses: docs/ESTIMATORS.md).",
    ) = None,
    csv_out: option(
        str | None, "--csv", metavar="FILE|-", help="Write every iteration as CSV to FILE, or to stdout with '-'."
    ) = None,
    json_out: option(bool, "--json", help="Print the run (every iteration, exact values) as JSON.") = False,
    rrd: option(Path | None, help="Log the run to a Rerun .rrd file for the viewer.") = None,
    plot: option(
        Path | None,
        metavar="OUT.png",
        help='Write a PNG of eax/eay/eaz over the iterations; needs matplotlib: pip install "steval-link\\[plot]".',
    ) = None,
    compare_with: option(
        list[str] | None,
        metavar="NAME=VALUE,...",
        help="Also run with these settings changed, on the same inputs and noise, and overlay the runs in --plot "
        "(repeatable): ki, kp, dt, throttle, correction=on|off, variant=170120|221117, estimator; e.g. --compare-with "
        "ki=1 --compare-with correction=off.",
    ) = None,
    force: ForceOption = False,
) -> None:
    """Run the filter alone: constant gyro/acc inputs through the firmware's Mahony filter (or any estimator).

    The UMaine Lab 5 AHRS simulator; prints the final eax (pitch), eay (roll), eaz (yaw)."""
    checks.check_count("--iterations", iterations, MAX_ITERATIONS)
    checks.check_vector("--gyro", gyro, "mdps")
    checks.check_vector("--acc", acc, "mg")
    checks.check_gain("--ki", ki)
    checks.check_gain("--kp", kp)
    checks.check_throttle("--throttle", throttle)
    checks.check_period("--dt", dt)
    estimator = _estimator(estimators)
    if json_out and csv_out == "-":
        raise UserError("--json and --csv - both write to stdout; give --csv a file name")
    check_outputs({"--csv": None if csv_out == "-" else csv_out, "--rrd": rrd, "--plot": plot}, force=force)
    gyro_sigma = _noise(gyro_noise, lab5.TYPICAL_GYRO_NOISE_MDPS, "gyro", "mdps", noise)
    acc_sigma = _noise(acc_noise, lab5.TYPICAL_ACC_NOISE_MG, "acc", "mg", noise)
    given = dict(ki=ki, kp=kp, correction=correction, variant=checks.check_variant(variant))
    options = {k: v for k, v in given.items() if v is not None}
    inputs = dict(gyro_mdps=gyro, acc_mg=acc, iterations=iterations, gyro_noise_mdps=gyro_sigma, acc_noise_mg=acc_sigma)
    res = _run("", **inputs, seed=seed, throttle=throttle, estimator=estimator, estimator_options=options, dt_s=dt)
    if rrd is not None:
        from steval_viewer.simulate_log import log_simulation  # Rerun loads only for --rrd (start-up time)

        with atomic_output(rrd, option="--rrd") as part:
            log_simulation(res, part)
    others = _compare_runs(compare_with or [], dict(inputs, seed=res.seed), options, throttle, estimator)
    if plot is not None:
        from steval_link.analysis.plots import plot_simulation  # matplotlib loads only for --plot (start-up time)

        with atomic_output(plot, option="--plot", keep_suffix=True) as part:
            plot_simulation(res, part, compare=others)
    if csv_out is not None and csv_out != "-":
        write_atomic(csv_out, "--csv", lambda fh: write_csv(res, fh), text=True)
    text = summary(res, gyro, acc, throttle) + "".join(f"\n{_final_line(label, r)}" for label, r in others)
    if rrd is not None:
        text += f"\nRerun recording written to {rrd} (open it with: rerun {rrd})"
    if json_out:
        print(json.dumps(to_json(res), allow_nan=False))
    elif csv_out == "-":
        write_csv(res, sys.stdout)
        print(text, file=sys.stderr)
    else:
        print(text + (f"\nplot: {plot}" if plot is not None else ""))


def _estimator(estimators: list[str] | None):
    """The one estimator of ``-e`` (default st-mahony): a registry name, or your own resolved."""
    chosen = split_list(",".join(estimators)) if estimators else ["st-mahony"]
    if len(chosen) != 1:  # never one of them silently
        raise UserError(f"simulate runs one estimator at a time; -e gave {len(chosen)}: {', '.join(chosen)}")
    estimator = chosen[0]
    if estimator in registry.ESTIMATORS:
        return estimator
    if not registry.is_known(estimator):
        raise UserError(
            f"unknown estimator {estimator!r}; choose one of: {', '.join(registry.names())}, "
            "FILE.py:CLASS or module:CLASS"
        )
    return registry.resolve(estimator)  # your own: FILE.py:CLASS, module:CLASS, a plug-in, options


def _run(what: str, **kwargs) -> lab5.SimulationResult:
    """:func:`lab5.run_simulation`, its errors as one sentence (after ``what``: a --compare-with run)."""
    try:
        return lab5.run_simulation(**kwargs)
    except (ImportError, ValueError) as exc:
        if what:
            raise UserError(f"{what}: {exc}") from None
        if isinstance(exc, ImportError):
            raise UserError(
                f"estimator {kwargs['estimator']!r} needs a package that is not installed ({exc})"
            ) from None
        raise UserError(str(exc)) from None


#: ``--compare-with`` names → value type (each an estimator option, ``dt`` as ``dt_s``, or a run setting)
_COMPARE_NAMES = dict(ki=float, kp=float, dt=float, correction=bool, variant=str, throttle=int, estimator=str)


def _compare_value(name: str, text: str, kind: type):
    """One ``--compare-with`` value as its type; UserError naming the option when it is not one."""
    if kind is bool:
        if text.lower() not in ("on", "off", "true", "false", "1", "0"):
            raise UserError(f"--compare-with {name}={text}: give on or off")
        return text.lower() in ("on", "true", "1")
    try:
        v = kind(text)
    except ValueError:
        raise UserError(f"--compare-with {name}={text}: not a {kind.__name__}") from None
    if kind is float and not math.isfinite(v):
        raise UserError(f"--compare-with {name}={text}: must be a finite number")
    if name == "dt" and v <= 0:
        raise UserError(f"--compare-with dt={text}: must be a period > 0 s")
    return v


def _compare_runs(specs: list[str], inputs: dict, options: dict, throttle: int, estimator: str):
    """Each ``--compare-with NAME=VALUE,...``: a run on the same inputs and noise with those settings changed."""
    out = []
    for spec in specs:
        opts, thr, est = dict(options), throttle, estimator
        for item in filter(None, (p.strip() for p in spec.split(","))):
            name, sep, text = item.partition("=")
            name = name.strip().lower().replace("_", "-")
            if not sep or name not in _COMPARE_NAMES:
                raise UserError(
                    f"--compare-with {spec!r}: give NAME=VALUE pairs, NAME one of {', '.join(_COMPARE_NAMES)}"
                )
            v = _compare_value(name, text.strip(), _COMPARE_NAMES[name])
            if name == "throttle":
                checks.check_throttle("--compare-with throttle", v)
                thr = v
            elif name == "variant":
                opts[name] = checks.check_variant(v)
            elif name == "estimator":
                if not registry.is_known(v):
                    raise UserError(f"--compare-with estimator={v}: unknown estimator")
                est = v if v in registry.ESTIMATORS else registry.resolve(v)
            else:
                opts["dt_s" if name == "dt" else name] = v
        if est != "st-mahony" and est != estimator:
            opts = {}  # another estimator: its own defaults (the filter options are the firmware filter's)
        r = _run(f"--compare-with {spec}", **inputs, throttle=thr, estimator=est, estimator_options=opts)
        out.append((spec, r))
    return out


def _final_line(label: str, r: lab5.SimulationResult) -> str:
    """The final angles of a ``--compare-with`` run, in degrees."""
    if not r.iterations:
        return f"with {label}: no iterations"
    ang = ", ".join(f"{n} {math.degrees(v):+.6f}°" for n, v in zip(("eax", "eay", "eaz"), r.final_angles_rad()))
    return f"with {label}: final {ang}"

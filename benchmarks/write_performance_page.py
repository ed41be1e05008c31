"""Write the documentation's performance page (docs/performance.md): run the benchmarks, one process each, and
put what each printed on the page under its goal, with the date, the machine and its load.

    python benchmarks/write_performance_page.py [--quick] [--only NAME ...] [--out docs/performance.md]

``--quick`` runs every benchmark on a shorter input (its arguments are on the page), for a first look; without it
the benchmarks run as their own defaults (a one-hour flight: several minutes each). Run it on a quiet machine: the
page records the load average before and after, and each benchmark's wall and CPU time, so a reader can tell.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (script, what it measures and its goal, arguments of the full run, arguments of --quick)
BENCHMARKS = (
    ("bench_decode.py", "decode a clean 1-hour capture; goal ≤ 3 s", [], ["--seconds", "600"]),
    (
        "bench_estimators.py",
        "the estimators' steps per second; ST-Mahony ≥ 1 M steps/s, bit-exact",
        [],
        ["--steps", "200000", "--budget", "5"],
    ),
    ("bench_viewer_replay.py", "a 1-hour replay to .rrd with every series; goal ≤ 15 s", [], ["--frames", "100000"]),
    ("bench_export.py", "a 1-hour capture to .mat and .mcap; goal ≤ 10 s each", [], ["--seconds", "600"]),
    ("bench_fuzz.py", "loose-wire fuzz; goal 0 fake frames in ≥ 10⁷, ≥ 93 % recovered", [], ["--frames", "1000000"]),
    ("bench_firmware.py", "instructions per frame on the Cortex-M4 (-O2); goal ≤ 400", [], []),
    ("bench_flight_frame.py", "the flight-control frame's cost on the emulated firmware", [], []),
    ("bench_commands.py", "the two-way link's cost per AHRS step; never waits on the host", [], []),
    (
        "bench_emulate.py",
        "the firmware in the loop on the emulated board; goal ≥ 5× real time",
        [],
        ["--duration", "5"],
    ),
    ("bench_plugin.py", "your estimator's plug-in path: the guard's overhead per step", [], ["--steps", "10000"]),
    (
        "bench_live_latency.py",
        "live latency, last byte of a frame → logged; goal p99 ≤ 5 ms",
        [],
        ["--seconds", "5", "--reader", "transport"],
    ),
    ("bench_soak.py", "live soak: memory growth; goal < 10 MB/h", [], ["--minutes", "2"]),
    ("bench_accuracy.py", "every estimator on the BROAD trials (TRIALS_DIR: `steval data broad`'s)", [], []),
)


def machine() -> str:
    """One line about this machine: CPU model, cores, memory, OS, Python."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(
            next(ln for ln in Path("/proc/meminfo").read_text().splitlines() if ln.startswith("MemTotal")).split()[1]
        )
        mem = f", {kb / 1024**2:.0f} GB RAM"
    except (OSError, StopIteration, ValueError):
        pass
    system = f"{platform.system()} {platform.release()}"
    return f"{cpu}, {os.cpu_count()} cores{mem}; {system}; Python {platform.python_version()}"


def load() -> str:
    try:
        return " / ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def run(script: str, args: list[str], timeout_s: float) -> tuple[str, int, float, float]:
    """(what it printed, exit code, wall s, CPU s of the process and its children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    try:
        done = subprocess.run(
            [sys.executable, str(ROOT / "benchmarks" / script), *args],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
        text, code = (done.stdout + done.stderr).strip(), done.returncode
    except subprocess.TimeoutExpired as exc:
        text, code = f"(stopped after {timeout_s:.0f} s)\n{exc.stdout or ''}", -1
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return text, code, wall, cpu


def page(results: list, quick: bool, load_before: str, load_after: str) -> str:
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# Performance",
        "",
        "Written by `python benchmarks/write_performance_page.py"
        + (" --quick" if quick else "")
        + "`, which runs each benchmark in `benchmarks/` and copies what it printed; do not edit by hand.",
        "",
        f"- **When**: {now}",
        f"- **Machine**: {machine()}",
        f"- **Load average** (1, 5, 15 min): {load_before} before, {load_after} after. On a shared or loaded machine "
        "wall times are longer than CPU times; compare CPU times, or run it again on a quiet machine.",
        "- **Inputs**: "
        + (
            "shortened (`--quick`: the arguments after each script name); the goals are for the full inputs."
            if quick
            else "each benchmark's defaults (a one-hour flight where it applies)."
        ),
        "",
    ]
    for script, goal, args, code, wall, cpu, text in results:
        lines += [f"## {script}", "", f"{goal}.", "", f"`python benchmarks/{' '.join([script, *args])}`: "]
        lines[-1] += f"exit {code}, {wall:.1f} s wall, {cpu:.1f} s CPU." if code >= 0 else f"{text.splitlines()[0]}"
        lines += ["", "```text", text or "(nothing printed)", "```", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter inputs, for a first look")
    ap.add_argument("--only", nargs="*", default=None, help="only these scripts (e.g. bench_decode.py)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "performance.md")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds allowed per benchmark")
    args = ap.parse_args(argv)
    chosen = [b for b in BENCHMARKS if args.only is None or b[0] in args.only]
    if not chosen:
        print(f"no benchmark named {args.only}", file=sys.stderr)
        return 2
    load_before = load()
    results = []
    for script, goal, full, quick in chosen:
        bench_args = quick if args.quick else full
        if script == "bench_accuracy.py":  # the trials of steval data broad (or ../shared beside the project)
            from steval_link.cli.data import find_broad_data

            data = find_broad_data()
            if data is None:
                results.append((script, goal, bench_args, -1, 0.0, 0.0, "skipped: no BROAD trials (steval data broad)"))
                continue
            bench_args = [str(data), *bench_args]
        shown = ["TRIALS_DIR" if a == str(data) else a for a in bench_args] if script == "bench_accuracy.py" else None
        print(f"running {script} {' '.join(bench_args)}", file=sys.stderr, flush=True)
        text, code, wall, cpu = run(script, bench_args, args.timeout)
        results.append((script, goal, shown or bench_args, code, wall, cpu, text))
    partial = args.out.with_name(args.out.name + ".partial")
    partial.write_text(page(results, args.quick, load_before, load()), encoding="utf-8")
    partial.replace(args.out)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Soak benchmark: ``steval live`` on one hour of stream, fed as fast as the link consumes it; memory must stay flat.

Default (``--source replay``): the bundled ``recordings/demo.stv`` replayed in a loop, ``steval live --no-view --port
"replay://recordings/demo.stv?loop=1&speed=40" --duration 90 --rrd ...``: one hour of stream in 90 s, the whole
live path (capture, decoder, estimators, the ``.rrd`` written as the data arrives), and the child's RSS sampled once
a second; printed: the least-squares slope of RSS from a quarter of the stream to its end, per hour of stream (goal
< 10 MB/h), and whether the live side kept up (on a busy machine, a lower ``--speed``). ``--source pty``: the fake
drone below instead.

A fake drone (``tests/support/ptyfeed.py``) replays a synthetic flight (bit-exact firmware filter outputs, a status
frame
every 161 steps; the 16-bit ``seq`` wraps 8 times an hour) into a pseudo-terminal. The real CLI runs on it as a
child process, ``steval live --no-view --rrd ... --port <pty>`` with the default estimators (ST replica, accel, EKF),
and the child's resident memory (VmRSS, and the peak VmHWM) is sampled once a second.

With ``--default-view`` the child runs as a user on a machine without a display types it, ``steval live --rrd
...`` (neither ``--no-view`` nor a viewer flag): the default view resolves to the ``.rrd`` alone, which must be
written as with ``--no-view`` (merged batches), not one chunk per processing round.

With ``--viewer`` the child also streams to a live viewer: ``steval live --connect URL --rrd ...`` where URL is a
real Rerun gRPC server (``rr.serve_grpc``, the message proxy a viewer reads from) run headless in this benchmark's
process with a 64 MB buffer limit; only the child's memory is measured. The viewer stream gets every processing
round at once and the ``.rrd`` its own stream of the same recording, merged every 30 s. Faster than real time the
viewer gets fewer, larger rounds per hour of stream than a real session (~30 per s): ``--speed 1`` measures it at the
real cadence.

Printed: a table of stream time fed / wall time / RSS, the peak RSS, and the growth of RSS from 10 % of the stream
to its end scaled to one hour of stream. Goal: flat memory, growth < 10 MB per hour of stream.

    python benchmarks/bench_soak.py                   # 60 min of demo.stv in a loop at 40x, with --rrd
    python benchmarks/bench_soak.py --source pty      # 60 min of a synthetic flight on a pty at 40x
    python benchmarks/bench_soak.py --minutes 10 --no-rrd --speed 50   # 50x the real rate, no Rerun at all
    python benchmarks/bench_soak.py --viewer          # live viewer (headless gRPC server) and --rrd
    python benchmarks/bench_soak.py --default-view --minutes 2 --speed 1   # `steval live --rrd X`, no display

The ``.rrd``'s size is printed as MB per hour of stream: compare the modes at ``--speed 1`` (the real cadence of
processing rounds), where the number of chunks per hour is what a real session makes.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from support.ptyfeed import REAL_BYTES_PER_S, PtyFeeder, StevalProcess, flight_stream  # noqa: E402

from steval_link import constants as C  # noqa: E402


def proc_mem_mb(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of ``pid`` in MB (NaN when the process is gone)."""
    rss = hwm = float("nan")
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    rss = int(line.split()[1]) / 1024
                elif line.startswith("VmHWM:"):
                    hwm = int(line.split()[1]) / 1024
    except OSError:
        pass
    return rss, hwm


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="stream time to feed (default 60)")
    ap.add_argument(
        "--speed",
        default="40",
        help="multiple of the real rate (default 40: one hour in 90 s, within what the live pipeline processes on "
        "one core), or 'max': as fast as the serial reader consumes it (the pipeline then falls behind and drops "
        "frames from the live view only; the capture keeps everything)",
    )
    ap.add_argument("--no-rrd", action="store_true", help="no --rrd (then no Rerun at all, unless --viewer)")
    ap.add_argument(
        "--viewer",
        action="store_true",
        help="also stream to a live viewer: --connect to a headless Rerun gRPC server in this process",
    )
    ap.add_argument(
        "--default-view",
        action="store_true",
        help="no --no-view and no viewer flag, and no display: what `steval live --rrd X` does headless",
    )
    ap.add_argument("--estimators", default=None, help="passed to --estimators (default: the CLI's default)")
    ap.add_argument("--keep", action="store_true", help="keep the capture and .rrd (prints the folder)")
    ap.add_argument(
        "--source",
        choices=("replay", "pty"),
        default="replay",
        help="replay: recordings/demo.stv in a loop (replay://...?loop=1&speed=S); pty: a synthetic flight on a "
        "pseudo-terminal",
    )
    args = ap.parse_args()
    if args.source == "replay":
        soak_replay(args)
        return

    n_steps = int(args.minutes * 60 * C.AHRS_RATE_HZ)
    t0 = time.perf_counter()
    data = flight_stream(n_steps, seed=11)
    print(
        f"stream: {args.minutes:.0f} min = {n_steps} attitude frames, {len(data) / 1e6:.1f} MB "
        f"(made in {time.perf_counter() - t0:.1f} s)"
    )
    tmp = Path(tempfile.mkdtemp(prefix="steval-soak-"))
    cmd = ["live", "--port", str(tmp / "ttyUSB0"), "--out", str(tmp / "soak.stv")]
    if args.viewer:
        import socket

        import rerun as rr

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            grpc_port = s.getsockname()[1]
        server = rr.RecordingStream("bench-soak-viewer-server", make_default=False, make_thread_default=False)
        url = rr.serve_grpc(grpc_port=grpc_port, recording=server, server_memory_limit="64MB")
        cmd += ["--connect", url]
    elif not args.default_view:
        cmd.insert(1, "--no-view")
    if not args.no_rrd:
        cmd += ["--rrd", str(tmp / "soak.rrd")]
    if args.estimators:
        cmd += ["--estimators", args.estimators]
    speed = None if args.speed == "max" else float(args.speed) * REAL_BYTES_PER_S

    with PtyFeeder(data, tmp / "ttyUSB0", bytes_per_s=speed, blocking=True) as feeder:
        proc = StevalProcess(cmd, cwd=tmp)
        if proc.wait_line("reading ", 120) is None:
            print(proc.stderr)
            raise SystemExit("steval live did not start")
        pid = proc.proc.pid
        rss0, _ = proc_mem_mb(pid)
        print(f"steval live {' '.join(cmd[1:])}\nRSS at start (port open, nothing received): {rss0:.1f} MB")
        print(f"{'stream min':>10} {'wall s':>8} {'RSS MB':>8} {'peak MB':>8}")
        samples: list[tuple[float, float]] = []  # (stream fraction, rss)
        t_start = time.monotonic()
        feeder.start()
        next_report = 0.0
        cap_path = tmp / "soak.stv"
        last_size, last_change = -1, time.monotonic()
        while True:
            time.sleep(1.0)
            rss, hwm = proc_mem_mb(pid)
            frac = feeder.pos / len(data)
            samples.append((frac, rss))
            stream_min = frac * args.minutes
            if stream_min >= next_report or feeder.done.is_set():
                print(f"{stream_min:10.1f} {time.monotonic() - t_start:8.1f} {rss:8.1f} {hwm:8.1f}", flush=True)
                next_report += max(1.0, args.minutes / 12)
            if proc.proc.poll() is not None:
                print(proc.stderr)
                raise SystemExit(f"steval live ended early (exit {proc.proc.returncode})")
            size = cap_path.stat().st_size if cap_path.exists() else 0
            if size != last_size:
                last_size, last_change = size, time.monotonic()
            if feeder.done.is_set() and time.monotonic() - last_change > 3.0:
                break  # everything fed and nothing more arriving: the child has caught up
        wall = time.monotonic() - t_start
        rss_end, hwm_end = proc_mem_mb(pid)
        rc = proc.finish(timeout_s=600, sig=signal.SIGINT)
    tenth = [r for f, r in samples if f >= 0.1]
    rss_10 = tenth[0] if tenth else samples[0][1]
    growth_per_h = (rss_end - rss_10) / max(0.9 * args.minutes / 60.0, 1e-9)
    print(proc.stdout.strip())
    print(
        f"fed {feeder.sent / 1e6:.1f} MB in {wall:.0f} s ({args.minutes * 60 / wall:.0f}x real time); exit {rc}\n"
        f"peak RSS {hwm_end:.1f} MB; RSS {rss0:.1f} MB at start, {rss_10:.1f} MB at 10 % of the stream, "
        f"{rss_end:.1f} MB at the end\n"
        f"growth from 10 % to the end: {rss_end - rss_10:+.1f} MB = {growth_per_h:+.1f} MB per hour of stream "
        f"(goal < 10 MB/h): {'OK' if growth_per_h < 10 else 'TOO MUCH'}"
    )
    rrd = tmp / "soak.rrd"
    if rrd.exists():
        from steval_viewer import entities as ent
        from steval_viewer.rrd_check import read_rrd

        rows = read_rrd(rrd).samples.get(ent.pitch_path(ent.SOURCE_FIRMWARE), 0)
        size_mb = rrd.stat().st_size / 1e6
        print(
            f".rrd {size_mb:.1f} MB = {size_mb * 60 / args.minutes:.1f} MB per hour of stream; reads back with "
            f"{rows} of {n_steps} frames: {'complete' if rows == n_steps else 'INCOMPLETE'}"
        )
    if args.keep:
        print(f"files kept in {tmp}")
    else:
        for p in tmp.iterdir():
            p.unlink()
        os.rmdir(tmp)


def soak_replay(args) -> None:
    """``steval live`` on ``replay://recordings/demo.stv?loop=1&speed=S`` for ``minutes`` of stream."""
    speed = 40.0 if args.speed == "max" else float(args.speed)
    wall_s = args.minutes * 60 / speed
    tmp = Path(tempfile.mkdtemp(prefix="steval-soak-"))
    url = f"replay://{ROOT / 'recordings' / 'demo.stv'}?loop=1&speed={speed:g}"
    cmd = ["live", "--no-view", "--no-prompt", "--port", url, "--duration", f"{wall_s:g}", "--out", str(tmp / "x.stv")]
    if not args.no_rrd:
        cmd += ["--rrd", str(tmp / "soak.rrd")]
    if args.estimators:
        cmd += ["--estimators", args.estimators]
    proc = StevalProcess(cmd, cwd=tmp)
    if proc.wait_line("reading ", 120) is None:
        print(proc.stderr)
        raise SystemExit("steval live did not start")
    pid = proc.proc.pid
    print(f"steval {' '.join(cmd)}\n{'stream min':>10} {'wall s':>8} {'RSS MB':>8} {'peak MB':>8}")
    t0 = time.monotonic()
    samples: list[tuple[float, float]] = []  # (stream minutes, RSS MB)
    hwm_end = float("nan")
    next_report = 0.0
    while proc.proc.poll() is None:
        time.sleep(1.0)
        rss, hwm = proc_mem_mb(pid)
        if rss == rss:  # not NaN: still running
            hwm_end = hwm
            stream_min = (time.monotonic() - t0) * speed / 60
            samples.append((stream_min, rss))
            if stream_min >= next_report:
                print(f"{stream_min:10.1f} {time.monotonic() - t0:8.1f} {rss:8.1f} {hwm:8.1f}", flush=True)
                next_report += max(1.0, args.minutes / 12)
    rc = proc.finish(timeout_s=600)
    # the steady state: from a quarter of the stream (start-up and Rerun's warm-up done) to its end (not the close)
    late = [(m, r) for m, r in samples if 0.25 * args.minutes <= m <= args.minutes]
    (m25, r25), (m_end, r_end) = late[0], late[-1]
    slope_per_h = float(np.polyfit([m for m, _ in late], [r for _, r in late], 1)[0]) * 60 if len(late) > 2 else 0.0
    print(proc.stdout.strip())
    behind = "not shown live" in proc.stdout
    print(
        f"exit {rc}; peak RSS {hwm_end:.1f} MB; RSS {r25:.1f} MB at {m25:.1f} min of stream, {r_end:.1f} MB at "
        f"{m_end:.1f} min\ngrowth: {r_end - r25:+.1f} MB, least-squares slope {slope_per_h:+.1f} MB per hour of stream "
        f"(goal < 10 MB/h): {'OK' if slope_per_h < 10 else 'TOO MUCH'}"
        + (
            "\nthe live side fell behind the replay (frames not shown live): use a lower --speed on a busy machine"
            if behind
            else ""
        )
    )
    rrd = tmp / "soak.rrd"
    if rrd.exists():
        size_mb = rrd.stat().st_size / 1e6
        print(f".rrd {size_mb:.1f} MB ({size_mb * 60 / max(m_end, 1e-9):.0f} MB per hour of stream at {speed:g}x)")
    if args.keep:
        print(f"files kept in {tmp}")
    else:
        for p in tmp.iterdir():
            p.unlink()
        os.rmdir(tmp)


if __name__ == "__main__":
    main()

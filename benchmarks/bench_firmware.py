"""Firmware-patch benchmark: cost of the telemetry on the Cortex-M4 and the UART load it makes.

Prints (asserts nothing):
- Cortex-M4 instructions per attitude frame (``stv_send_attitude``: encode + CRC + enqueue), per status frame,
  and per AHRS step on the main-loop side (``stv_link_step_begin`` + ``stv_link_step_end``), counted under
  unicorn on the -O2 hard-float build. Goal: <= 400 per attitude frame.
- UART utilisation of the binary stream (from the bytes the target code emitted) at 115200 and 921600 baud and
  161.5 Hz. Goal: <= 85 % at 115200.
- The USART1 TX interrupt's instruction count (static, from the cross-compiled stv_fw.o) and the CPU share it takes.
- Host ``stv_encode`` throughput (the tool that makes the bundled recordings).

Run: ``python benchmarks/bench_firmware.py`` (needs arm-none-eabi-gcc, make, gcc and unicorn).
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FW = ROOT / "firmware_patch"
sys.path.insert(0, str(FW / "tools"))
import stv_emu  # noqa: E402

from steval_link import constants as C  # noqa: E402
from steval_link.link.decoder import StreamDecoder  # noqa: E402


def stats(xs: list[int]) -> str:
    return f"min {min(xs)}  mean {np.mean(xs):.1f}  max {max(xs)}  (n={len(xs)})"


def main() -> None:
    why = stv_emu.missing_tools()
    if why:
        print(f"skipped: {why}")
        return
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        target = stv_emu.TargetEncoder(stv_emu.build_emu(tmp))
        rng = np.random.default_rng(0)

        # encode + enqueue, per frame
        n = 250
        req = b"".join(bytes([1, 52]) + rng.integers(0, 256, 52, dtype=np.uint8).tobytes() for _ in range(n))
        req += b"".join(bytes([2, 88]) + rng.integers(0, 256, 88, dtype=np.uint8).tobytes() for _ in range(20))
        res = target.run(req)
        att = res.calls["stv_send_attitude"]
        print("Cortex-M4 (-O2, Thumb-2, hard float), instructions under unicorn")
        print(f"  attitude frame, encode + enqueue (stv_send_attitude): {stats(att)}   goal <= 400")
        print(f"  status frame (stv_send_status):                       {stats(res.calls['stv_send_status'])}")

        # the main loop's side of one AHRS step, binary mode, status every 162 steps
        steps = 162 * 2
        v = rng.normal(0, 500, (steps, 10)).astype(np.float32)
        link = target.run(v.tobytes(), count=("stv_link_step_begin", "stv_link_step_end"), entry="emu_run_link")
        per_step = [a + b for a, b in zip(link.calls["stv_link_step_begin"], link.calls["stv_link_step_end"])]
        print(f"  per AHRS step in the main loop (step_begin + step_end): {stats(per_step)}")
        mean_step = float(np.mean(per_step))
        print(
            f"    = {mean_step / 84:.2f} µs at 84 MHz (~1 cycle/instruction), "
            f"{100 * mean_step * C.AHRS_RATE_HZ / 84e6:.3f} % CPU at 161.5 Hz"
        )

        dec = StreamDecoder(plausibility=False)  # the harness feeds made-up values and cycle counts
        dec.feed(link.output)
        dec.finish()
        assert dec.stats.bytes_skipped == 0 and dec.stats.attitude == steps
        bytes_per_s = len(link.output) / steps * C.AHRS_RATE_HZ
        print("\nUART load of the binary stream (bytes the target code emitted, 161.5 Hz, status every 162 steps)")
        print(f"  {bytes_per_s:.0f} bytes/s")
        for baud in (115200, 230400, 460800, 921600):
            print(
                f"  {baud:>7} baud 8N1: {100 * bytes_per_s / (baud / 10):5.1f} %"
                + ("   goal <= 85 %" if baud == 115200 else "")
            )

        # TX interrupt (static count of stv_fw_usart1_irq in the cross-compiled port)
        subprocess.run(["make", "-s", "-C", str(FW), "cross", f"BUILD_DIR={tmp}"], check=True, capture_output=True)
        dis = subprocess.run(
            ["arm-none-eabi-objdump", "-d", str(tmp / "arm" / "stv_fw.o")], check=True, capture_output=True, text=True
        ).stdout
        body = dis.split("<stv_fw_usart1_irq>:")[1].split("\n\n")[0]
        n_irq = len(re.findall(r"^\s+[0-9a-f]+:\s", body, flags=re.M))
        print(f"\nUSART1 TXE interrupt: {n_irq} instructions (static, all paths) + ~12 cycles entry/exit per byte")
        for baud in (115200, 921600):
            cyc = (n_irq + 12) * bytes_per_s
            print(f"  at {baud} baud: <= {100 * cyc / 84e6:.2f} % CPU for {bytes_per_s:.0f} bytes/s")

        # host tool throughput
        subprocess.run(
            ["make", "-s", "-C", str(FW), f"BUILD_DIR={tmp}", f"{tmp}/host/stv_encode"], check=True, capture_output=True
        )
        big = req[: 54 * n] * 400  # 100 000 attitude requests
        t0 = time.perf_counter()
        out = subprocess.run([tmp / "host" / "stv_encode"], input=big, capture_output=True, check=True).stdout
        dt = time.perf_counter() - t0
        print(f"\nhost stv_encode: {len(big) // 54 / dt:,.0f} attitude frames/s ({len(out) / dt / 1e6:.1f} MB/s out)")


if __name__ == "__main__":
    main()

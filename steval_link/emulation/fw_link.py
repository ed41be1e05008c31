"""The firmware patch's link (``stv_link.c``, ``stv_txq.c``) step by step for ``steval synth``: AHRS step timing, an
attitude frame per step (text mode: a ``$ATT`` line every 16th), a status frame every 162nd step, the boot log as
text frames, and the 2048-byte TX queue drained by USART1 (a frame that does not fit is dropped and counted;
attitude and text frames leave room for a status frame). Then the bytes, by the Python or the firmware's C encoder.
Timings are the real firmware's under ``steval emulate`` where measurable, else models.
"""

from __future__ import annotations

import math
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.errors import UserError
from steval_link.estimators.st_mahony import MahonySettings, MahonyState
from steval_link.link import protocol as P
from steval_link.link.textmode import format_att, format_sta

#: DWT window of ``ahrs_fusion_ag`` + ``QuaternionToEuler``: the real firmware's median at rest under ``steval
#: emulate``, where CYCCNT counts instructions (4050-6600 when tilted or flying; a real M4 needs somewhat more).
AHRS_CYCLES = 4420
#: USART1 TXE interrupt (stv_fw_usart1_irq, -O2) including entry and exit, cycles.
TXE_IRQ_CYCLES = 62
#: ``STV_STATUS_EVERY_STEPS``, ``STV_TEXT_DECIMATION``, ``STV_TXQ_SIZE``, ``STV_TEXT_LINE_MAX`` of the patch.
STATUS_EVERY_STEPS = 162
TEXT_DECIMATION = 16
TXQ_SIZE = 2048
TEXT_LINE_MAX = 192
FW_VERSION = (2, 0)
#: TIM9's tick 0 comes this long after the link starts (≈ power-up) less one tick period (measured under ``steval
#: emulate``: main()'s sensor set-up includes ST's ``HAL_Delay(1000)``); the first attitude frame is at ≈ 2.985 s.
TIM9_START_CYCLES = 84_007_128 - C.TICK_CYCLES
_RAD_TO_MDEG_F32 = np.float32(57295.78)


#: a frame in transmit order: (kind att/status/text/raw, attitude row or payload, first byte's cycle time, bytes)
Frame = tuple[str, object, float, int]


def boot_lines(rng: np.random.Generator) -> list[tuple[int, str]]:
    """The 170120 firmware's non-empty PRINTF lines from power-up with their cycle counts; BLE address from rng."""
    mac = [0xC0, 0x8C, *(int(v) for v in rng.integers(0, 256, 4))]
    # ms after the link starts, as under emulation (after ST's HAL_Delay(1000)); the BLE lines' spacing is a guess
    ms = [
        (0.02, "STEVAL-FCU001V1 FW rev.1.0 - Sep 2017"),
        (999.95, "LSM6DSL MEMS Accelerometer initialized and enabled"),
        (999.97, "LSM6DSL MEMS Gyroscope initialized and enabled"),
        (1000.0, "LIS2MDL Magnetometer initialized and enabled"),
        (1000.02, "LPS22HB Pressure sensor initialized and enabled"),
        (1000.04, "LPS22HB Temperature sensor initialized and enabled"),
        (1000.09, "BLE communication initialization..."),
        (1000.11, "****** START BLE TESTS ******"),
        (1009.9, "Reading BlueNRG version ..."),
        (1019.9, "GATT Initializzation..."),
        (1020.5, "GAP setting Authentication ...."),
        (1021.0, "SERVER: BLE Stack Initialized "),
        (1021.1, "Board HWver=49, FWver=7.2.c"),
        (1021.2, "BoardMAC = " + ":".join(f"{b:x}" for b in mac)),
        (1022.0, "Console Service W2ST added successfully"),
        (1023.0, "Config  Service W2ST added successfully"),
        (1023.1, "All test passed!"),
        (1023.2, "****** END BLE TESTS ******"),
        (1024.0, "HW      Service W2ST added successfully"),
        (1025.0, "Console Service W2ST added successfully"),
        (1026.0, "Config  Service W2ST added successfully"),
    ]
    return [(int((t + j) * C.CPU_HZ / 1000), text) for (t, text), j in zip(ms, rng.uniform(0.0, 0.03, len(ms)))]


class TxQueue:
    """The patch's TX ring buffer drained by USART1 at ``baud`` (10 bit times per byte), in cycle time."""

    def __init__(self, baud: int) -> None:
        self.tau = 10.0 * C.CPU_HZ / baud  # cycles per byte
        self.busy_until = 0.0  # cycle time the last queued byte has been shifted out
        self.dropped = self.peak = 0

    def used(self, t: float) -> int:
        """Bytes still in the queue at ``t`` (one byte sits in the shift register, one in DR)."""
        return max(0, math.ceil((self.busy_until - t) / self.tau - 1e-9) - 2)

    def push(self, t: float, n: int, keep_free: int) -> float | None:
        """Enqueue n bytes at cycle time t; the cycle time their first byte starts, or None if dropped."""
        used = self.used(t)
        if n + keep_free > TXQ_SIZE - used:
            self.dropped += 1
            return None
        start = max(t, self.busy_until)
        self.busy_until = start + n * self.tau
        self.peak = max(self.peak, used + n)
        return start


def forced_drops(n_steps: int, rate: float, rng: np.random.Generator) -> np.ndarray:
    """(n,) bool: attitude frames refused on purpose: bursts (mean 3) at geometric gaps, ``rate`` in the long run."""
    out = np.zeros(n_steps, dtype=bool)
    if rate <= 0 or n_steps == 0:
        return out
    mean_gap = max(1.0, 3.0 * (1.0 - rate) / rate)
    mean_burst = rate * mean_gap / (1.0 - rate)
    i = int(rng.geometric(1.0 / mean_gap)) - 1
    while i < n_steps:
        burst = int(rng.geometric(min(1.0, 1.0 / mean_burst)))
        out[i : i + burst] = True
        i += burst + int(rng.geometric(1.0 / mean_gap))
    return out


def step_timing(step_tick: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(begin, cycle noise, TXE-interrupt draw)`` of each AHRS step, begin in CPU cycles since the link started:
    after its TIM9 tick's ISR (≈ 180 µs) and the main loop's latency (BLE traffic now and then)."""
    n_steps = len(step_tick)
    isr_cycles = 15_100 + rng.integers(-300, 300, n_steps)
    loop_latency = rng.integers(0, 700, n_steps) + np.where(
        rng.random(n_steps) < 0.08, rng.integers(0, 34_000, n_steps), 0
    )
    begin = TIM9_START_CYCLES + (np.asarray(step_tick, np.int64) + 1) * C.TICK_CYCLES + isr_cycles + loop_latency
    cyc_noise = np.rint(rng.normal(0.0, 14.0, n_steps)).astype(np.int64) + rng.integers(0, 24, n_steps)
    return begin, cyc_noise, rng.random(n_steps)


@dataclass
class LinkEmulation:
    """``stv_link.c`` of one run, fed the boot lines (:meth:`text`) and every AHRS step (:meth:`step`): ``att`` the
    payloads, ``thx``/``thy`` rad, ``snapshots`` the filter after each status step, ``drop`` frames refused on purpose.
    It keeps the transmit ``order``, which steps were ``sent`` and the ``status`` records."""

    att: np.ndarray
    thx: np.ndarray
    thy: np.ndarray
    settings: MahonySettings
    baud: int
    text_mode: bool
    snapshots: list[MahonyState]
    drop: np.ndarray
    order: list[Frame] = field(default_factory=list)
    status: list[np.ndarray] = field(default_factory=list)
    cycles: list[int] = field(default_factory=list)  #: DWT counts of the steps since the last status frame

    def __post_init__(self) -> None:
        self.txq = TxQueue(self.baud)
        self.sent = np.zeros(len(self.att), dtype=bool)
        self.flags = self.settings.flags | (P.FLAG_TEXT_MODE if self.text_mode else 0)
        self.ki_f32 = np.float32(self.settings.ki)

    def _push(self, kind: str, item, cyc: float, size: int, keep_free: int) -> bool:
        start = self.txq.push(cyc, size, keep_free)
        if start is not None:
            self.order.append((kind, item, start, size))
        return start is not None

    def text(self, cyc: float, line: str) -> None:
        """A ``PRINTF`` line at cycle time ``cyc``: text frames (binary mode) or a plain line (text mode)."""
        if self.text_mode:  # "$" starts only $ATT/$STA lines: a log line's becomes "#"
            data = ("#" + line[1:] if line.startswith("$") else line).encode("utf-8") + b"\r\n"
            self._push("raw", data, cyc, len(data), TEXT_LINE_MAX)
            return
        raw = line.encode("utf-8") or b" "
        for i in range(0, len(raw), P.TEXT_MAX_PAYLOAD):
            piece = raw[i : i + P.TEXT_MAX_PAYLOAD]
            self._push("text", piece, cyc, P.HEADER_SIZE + len(piece) + P.CRC_SIZE, P.STATUS_FRAME_SIZE)

    def step(self, k: int, c0: float, cyc_noise: int, txe_u: float) -> None:
        """AHRS step ``k`` from cycle ``c0``: its DWT count (with the TXE interrupts in it), its frame, status frame."""
        base = AHRS_CYCLES + int(cyc_noise)
        irqs = max(0.0, min(self.txq.busy_until, c0 + base) - c0) / self.txq.tau  # bytes the UART finishes in it
        n_irq = int(irqs) + (1 if txe_u < irqs - int(irqs) else 0)
        cyc = base + n_irq * TXE_IRQ_CYCLES
        c1 = c0 + cyc
        self.cycles.append(cyc)
        if not self.text_mode:
            self._attitude(k, c1, "att", k, P.ATTITUDE_FRAME_SIZE, P.STATUS_FRAME_SIZE)
        elif k % TEXT_DECIMATION == 0:
            line = self._att_line(k)
            self._attitude(k, c1, "raw", line, len(line), TEXT_LINE_MAX)
        if k % STATUS_EVERY_STEPS == STATUS_EVERY_STEPS - 1:
            self._status(k, c1)

    def _attitude(self, k: int, c1: float, kind: str, item, size: int, keep_free: int) -> None:
        """Step k's attitude frame or line into the queue, unless ``--drop-rate`` refuses it."""
        if self.drop[k]:
            self.txq.dropped += 1
        elif self._push(kind, item, c1, size, keep_free):
            self.sent[k] = True

    def _att_line(self, k: int) -> bytes:
        a = self.att[k]
        return format_att(
            step=k,
            t_ms=int(a["t_us"]) // 1000,
            thr=int(a["thr"]),
            thx_mdeg=f2i(self.thx[k] * _RAD_TO_MDEG_F32),
            thy_mdeg=f2i(self.thy[k] * _RAD_TO_MDEG_F32),
            thz_mdeg=f2i(np.float32(a["thz_rad"]) * _RAD_TO_MDEG_F32),
            acc_mg=[f2i(v) for v in a["acc_mg"]],
            gyro_mdps=[f2i(v) for v in a["gyro_mdps"]],
        )

    def _status(self, k: int, c1: float) -> None:
        snap = self.snapshots[len(self.status)]
        s = self.settings
        rec = np.zeros((), dtype=P.STATUS_DTYPE)
        rec["step"], rec["t_us"], rec["q_wxyz"], rec["int_xyz"] = k, self.att[k]["t_us"], snap.q_wxyz, snap.int_xyz
        rec["kp_ground"], rec["kp_flight"], rec["ki"], rec["dt_s"] = s.kp_ground, s.kp_flight, self.ki_f32, s.dt_s
        cyc = self.cycles
        rec["cyc_min"], rec["cyc_max"], rec["cyc_n"] = min(cyc), max(cyc), min(len(cyc), 0xFFFF)
        rec["cyc_mean"], rec["cpu_hz"], rec["tx_dropped"] = sum(cyc) // len(cyc), C.CPU_HZ, self.txq.dropped
        rec["baud"], rec["min_thr"], rec["flags"] = self.baud, s.min_thr, self.flags
        rec["queue_peak"], self.txq.peak = min(self.txq.peak, 0xFFFF), self.txq.used(c1)  # stv_txq_take_peak
        rec["fw_version"] = FW_VERSION
        self.status.append(rec)
        self.cycles = []
        if self.text_mode:
            counters = {name: int(rec[name]) for name in ("cyc_min", "cyc_mean", "cyc_max", "cyc_n", "tx_dropped")}
            t_ms = int(rec["t_us"]) // 1000
            line = format_sta(step=k, t_ms=t_ms, flags=self.flags, ki_micro=ki_micro(self.ki_f32), **counters)
            self._push("raw", line, c1, len(line), 0)
        else:
            self._push("status", rec, c1, P.STATUS_FRAME_SIZE, 0)

    def status_table(self) -> np.ndarray:
        """The status records sent or not, as one ``STATUS_DTYPE`` array."""
        return np.array(self.status, dtype=P.STATUS_DTYPE).reshape(-1)


def f2i(x) -> int:
    """The patch's ``stv_f2i_trunc``: float32 → int32 toward zero, NaN → 0, saturating."""
    x = np.float32(x)
    if x != x:
        return 0
    if x >= np.float32(2147483520.0):
        return 2**31 - 1
    if x <= np.float32(-2147483648.0):
        return -(2**31)
    return int(x)


def ki_micro(ki: np.float32) -> int:
    half = np.float32(0.5) if ki >= 0 else np.float32(-0.5)
    return f2i(np.float32(ki * np.float32(1e6)) + half)


def encode(order: list[Frame], att: np.ndarray) -> bytes:
    """The frames of ``order`` as bytes, by the Python encoder."""
    att_idx = [o[1] for o in order if o[0] == "att"]
    block = P.encode_attitude_block(att[att_idx]) if att_idx else b""
    out, j = [], 0
    for kind, item, _, size in order:
        if kind == "att":
            out.append(block[j : j + size])
            j += size
        elif kind == "status":
            out.append(P.encode_frame(P.TYPE_STATUS, item.tobytes()))
        elif kind == "text":
            out.append(P.encode_frame(P.TYPE_TEXT, item))
        else:
            out.append(item)
    return b"".join(out)


def encode_c(order: list[Frame], att: np.ndarray, exe: Path) -> bytes:
    """The frames of ``order`` through the firmware's own C encoder ``exe`` (the host build, fed frame requests)."""
    if not exe.is_file() or not os.access(exe, os.X_OK):
        raise UserError(f"C encoder {exe} not found or not executable; build it with: make -C firmware_patch host")
    req = []
    types = {"att": P.TYPE_ATTITUDE, "status": P.TYPE_STATUS, "text": P.TYPE_TEXT}
    for kind, item, _, _ in order:
        if kind in types:
            payload = att[item].tobytes() if kind == "att" else item if kind == "text" else item.tobytes()
            req.append(bytes((types[kind], len(payload))) + payload)
    try:
        proc = subprocess.run([str(exe)], input=b"".join(req), capture_output=True, check=False, timeout=120)
    except OSError as exc:
        raise UserError(f"cannot run the C encoder {exe}: {exc.strerror or exc}") from None
    if proc.returncode != 0:
        msg = proc.stderr.decode("utf-8", "replace").strip().splitlines()
        raise UserError(f"the C encoder {exe} failed (exit {proc.returncode}): {msg[-1] if msg else 'no message'}")
    expected = sum(o[3] for o in order)
    if len(proc.stdout) != expected:
        raise UserError(f"the C encoder {exe} wrote {len(proc.stdout)} bytes, {expected} were expected")
    return proc.stdout


def count_frames(order: list[Frame], offsets: tuple[int, int]) -> dict:
    """Frames of each kind whose bytes are entirely in the captured range."""
    counts = {"attitude": 0, "status": 0, "text": 0, "att_lines": 0, "sta_lines": 0, "log_lines": 0}
    pos = 0
    lo, hi = offsets
    for kind, item, _, size in order:
        if pos >= lo and pos + size <= hi:
            if kind == "raw":
                kind = {b"$ATT": "att_lines", b"$STA": "sta_lines"}.get(item[:4], "log_lines")
            counts["attitude" if kind == "att" else kind] += 1
        pos += size
    return counts

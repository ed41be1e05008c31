"""Emulated drone captures (``steval synth``): a motion profile through the whole STEVAL-FCU001V1 chain to a capture.

Until real drone captures exist, tests and the demo use these. The chain, one function per link:

1. motion (:mod:`steval_link.emulation.motion`): a built-in scenario or a BROAD trial, at every TIM9 tick (807.7 Hz);
2. LSM6DSL (:class:`steval_link.emulation.sensor_model.Lsm6dsl`): bias, white noise, ranges, ADC and driver
quantisation;
3. the firmware's ISR and main loop (:func:`steval_link.emulation.sensor_model.run_isr`): power-up offset calibration
(the
   AHRS starts ≈ 2 s after TIM9), gyro IIR, 5-sample boxcar; ``thz`` from
   :func:`~steval_link.emulation.sensor_model.isr_yaw_rad`
   (reset below MIN_THR);
4. ``ahrs_fusion_ag`` + ``QuaternionToEuler``: the bit-exact port (:func:`steval_link.estimators.st_mahony.run`),
   with the firmware variant's settings (``--ki``, ``--no-correction``);
5. the firmware patch's link (``firmware_patch/src/stv_link.c``), emulated step by step: step counter from 0 at
   the first AHRS step, ``t_us`` from the DWT cycle counter (84 MHz, µs since the link started at power-up, u32),
   an attitude frame per step, a status frame after every 162nd step with the filter-state snapshot after that
   step, boot log lines as text frames, text mode (``$ATT`` every 16th step, ``$STA``), and the 2048-byte TX
   queue drained by USART1 at the baud rate (frames that do not fit are dropped and counted in ``tx_dropped``;
   attitude and text frames leave room for a status frame);
6. frame bytes from the Python encoder (:mod:`steval_link.link.protocol`) or the firmware's own C encoder
   (``firmware_patch/host/stv_encode``, fed with frame requests);
7. the host: a USB-UART adapter delivering the bytes in packets, with receive times, into a ``.stv`` capture
   (or the plain bytes, like ``cat /dev/ttyUSB0 > file``).

What is emulated rather than measured (documented so nobody mistakes it for the drone's): the boot timing, the
main loop's latency after each tick, the DWT cycle counts of ``ahrs_fusion_ag`` + ``QuaternionToEuler`` (a noisy
constant of :data:`AHRS_CYCLES` at -O0 on the Cortex-M4 at 84 MHz plus the USART TXE interrupts that land in the
step), the slow drift of the gyro's zero-rate level after calibration, the BLE module's banner values, the adapter
(FTDI-like: 62 data bytes per USB packet, 16 ms latency timer,
1 ms USB frames). ``--drop-rate P`` makes the queue refuse about a fraction P of the attitude frames (bursts of
about 3, as when it is full); a baud rate too low for the stream overflows the emulated queue by itself.

Everything is deterministic for a given :class:`SynthOptions` (seeded numpy generators; capture start time
:data:`EPOCH_UNIX_S` + the join time): the same command gives the same bytes.
"""

from __future__ import annotations

import math
import os
import shlex
import subprocess
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.emulation import motion as M
from steval_link.emulation import sensor_model as sm
from steval_link.emulation.broad import load_trial
from steval_link.errors import UserError
from steval_link.estimators.st_mahony import MahonySettings, MahonyState
from steval_link.estimators.st_mahony import run as mahony_run
from steval_link.link import capture
from steval_link.link import protocol as P
from steval_link.link.textmode import format_att, format_sta

__all__ = [
    "EPOCH_UNIX_S",
    "AHRS_CYCLES",
    "STATUS_EVERY_STEPS",
    "TEXT_DECIMATION",
    "TXQ_SIZE",
    "SynthOptions",
    "SynthResult",
    "synthesize",
    "write_output",
    "default_c_encoder",
    "boot_lines",
]

#: Capture start time of emulated captures: 2026-01-01T00:00:00Z (+ ``--join-at``), never the wall clock.
EPOCH_UNIX_S = 1767225600.0
#: DWT window of ``ahrs_fusion_ag`` + ``QuaternionToEuler`` (-O0, hard float, software double atan2/asin): the
#: median the real firmware (gcc 12.2 build) shows under firmware-in-the-loop emulation at rest, where CYCCNT counts
#: instructions (``steval emulate``; 4050-6600 when tilted or flying). A real M4 needs somewhat more cycles.
AHRS_CYCLES = 4420
#: USART1 TXE interrupt (stv_fw_usart1_irq, -O2) including entry and exit, cycles.
TXE_IRQ_CYCLES = 62
#: ``STV_STATUS_EVERY_STEPS``, ``STV_TEXT_DECIMATION``, ``STV_TXQ_SIZE``, ``STV_TEXT_LINE_MAX`` of the patch.
STATUS_EVERY_STEPS = 162
TEXT_DECIMATION = 16
TXQ_SIZE = 2048
TEXT_LINE_MAX = 192
FW_VERSION = (1, 0, 0)
CPU_HZ = C.CPU_HZ
#: TIM9's tick 0 comes this long after the link starts (≈ power-up) less one tick period: the sensor set-up in main()
#: includes ST's ``HAL_Delay(1000)`` in the LPS22HB init, then HAL_TIM_Base_Start_IT's first interrupt comes at
#: once (the update flag HAL's UG left set) and then every 104000 cycles. Measured on the real firmware under
#: emulation (stv_fw_init → HAL_TIM_Base_Start_IT: 84 007 128 cycles); the first attitude frame then comes at
#: t_us ≈ 2.985 s, as the emulated firmware's does.
TIM9_START_CYCLES = 84_007_128 - 104_000
#: USB-UART adapter (FTDI FT232R-like): data bytes per USB packet, latency timer, USB frame.
ADAPTER_PACKET_BYTES = 62
ADAPTER_LATENCY_S = 0.016
USB_FRAME_S = 0.001
MAX_BAUD = 5_250_000  # USART1 at 84 MHz, oversampling by 16
MIN_BAUD = 1200
_RAD_TO_MDEG_F32 = np.float32(57295.78)


@dataclass(frozen=True)
class SynthOptions:
    """What to emulate (the ``steval synth`` options).

    Attributes:
        scenario: built-in scenario name (:data:`steval_link.emulation.motion.SCENARIOS`) or a BROAD trial ``.npz``
        path.
        duration_s: capture length, s (default: the scenario's; a BROAD trial: all of it after the join).
        seed: seeds every random choice (motion details, sensor bias and noise, latencies, drops).
        baud: USART1 baud rate (header, status frames, byte timing, queue drain).
        throttle: ``--throttle`` spec overriding the scenario's throttle (see
        :func:`steval_link.emulation.motion.parse_throttle`).
        ki: ``AHRS_KI`` of the emulated build (float32 like the firmware).
        correction: False: the build without accelerometer correction (lab exercise 5, status flag bit 0).
        text_mode: the text-mode build (``$ATT`` every 16th step, ``$STA``, plain log lines).
        join_at_s: the capture starts this long after power-up (mid-flight, mid-frame).
        drop_rate: fraction of attitude frames the TX queue refuses (0 ≤ P < 1).
        encoder: "python" or "c" (frames made by ``firmware_patch/host/stv_encode``).
        c_encoder: path of the host-built C encoder (default :func:`default_c_encoder`).
    """

    scenario: str = "bench"
    duration_s: float | None = None
    seed: int = 0
    baud: int = C.BAUD
    throttle: str | None = None
    ki: float = C.KI
    correction: bool = True
    text_mode: bool = False
    join_at_s: float = 0.0
    drop_rate: float = 0.0
    encoder: str = "python"
    c_encoder: str | None = None

    def command(self) -> str:
        """The ``steval synth`` options that determine the serial bytes (no output path, no encoder choice)."""
        parts = ["steval", "synth", "--scenario", self.scenario]
        if self.duration_s is not None:
            parts += ["--duration", f"{self.duration_s:g}"]
        parts += ["--seed", str(self.seed)]
        if self.baud != C.BAUD:
            parts += ["--baud", str(self.baud)]
        if self.throttle is not None:
            parts += ["--throttle", self.throttle]
        if self.ki != C.KI:
            parts += ["--ki", f"{self.ki:g}"]
        if not self.correction:
            parts.append("--no-correction")
        if self.text_mode:
            parts.append("--text-mode")
        if self.join_at_s:
            parts += ["--join-at", f"{self.join_at_s:g}"]
        if self.drop_rate:
            parts += ["--drop-rate", f"{self.drop_rate:g}"]
        return " ".join(shlex.quote(p) for p in parts)


@dataclass
class SynthResult:
    """An emulated capture and what the firmware did to make it.

    Attributes:
        data: the serial bytes the host received (what a capture holds).
        chunk_offsets: (K,) int64 stream offset of each received chunk (USB packet).
        chunk_times_s: (K,) float64 host receive time of each chunk, s since the capture started.
        header: the capture header (``port``, ``baud``, ``start_time_utc``, ``extra`` with the emulation's
            parameters).
        attitude: (M,) ``ATTITUDE_DTYPE`` records of every AHRS step the firmware made (sent or not).
        sent: (M,) bool, the step's attitude frame (or, in text mode, its decimated line) went into the queue.
        status: (S,) ``STATUS_DTYPE`` records of every status the firmware made.
        tx_dropped: frames the queue refused in the whole emulation.
        profile: the motion profile (truth) at every tick.
        step_t_s: (M,) firmware time of each step, s since power-up.
        counts: frames of each kind in ``data`` (``attitude``, ``status``, ``text``, ``att_lines``, ``sta_lines``).
    """

    data: bytes
    chunk_offsets: np.ndarray
    chunk_times_s: np.ndarray
    header: dict
    attitude: np.ndarray
    sent: np.ndarray
    status: np.ndarray
    tx_dropped: int
    profile: M.MotionProfile
    step_t_s: np.ndarray
    counts: dict = field(default_factory=dict)


# ---- validation --------------------------------------------------------------------------------------------------

def default_c_encoder() -> Path:
    """``firmware_patch/host/stv_encode`` of this source tree (``make -C firmware_patch host`` builds it)."""
    return Path(__file__).resolve().parents[2] / "firmware_patch" / "host" / "stv_encode"


def _is_path(scenario: str) -> bool:
    return scenario.endswith(".npz") or os.sep in scenario or "/" in scenario


def _check(opts: SynthOptions) -> None:
    def finite(v):
        return v is not None and math.isfinite(v)

    if opts.duration_s is not None and not (finite(opts.duration_s) and opts.duration_s > 0):
        raise UserError(f"--duration must be a positive number of seconds, got {opts.duration_s}")
    if not (finite(opts.join_at_s) and opts.join_at_s >= 0):
        raise UserError(f"--join-at must be ≥ 0 seconds, got {opts.join_at_s}")
    if not (finite(opts.drop_rate) and 0 <= opts.drop_rate < 1):
        raise UserError(f"--drop-rate must be a fraction in [0, 1), got {opts.drop_rate}")
    if not MIN_BAUD <= opts.baud <= MAX_BAUD:
        raise UserError(f"--baud must be between {MIN_BAUD} and {MAX_BAUD} (USART1 at 84 MHz), got {opts.baud}")
    if not finite(opts.ki) or not math.isfinite(float(np.float32(opts.ki))):
        raise UserError(f"--ki must be a finite number, got {opts.ki}")
    if not 0 <= opts.seed < 2**63:
        raise UserError(f"--seed must be a non-negative integer, got {opts.seed}")
    if opts.encoder not in ("python", "c"):
        raise UserError(f"--encoder must be 'python' or 'c', got {opts.encoder!r}")
    if opts.encoder == "c" and opts.text_mode:
        raise UserError("--text-mode lines are formatted in Python; the C host encoder (stv_encode) takes binary "
                        "frame requests only, so use --encoder python with --text-mode")


# ---- firmware timing ---------------------------------------------------------------------------------------------

def boot_lines(rng: np.random.Generator) -> list[tuple[int, str]]:
    """The 170120 firmware's PRINTF lines from power-up (empty lines dropped by the link), with the emulated cycle
    counts at which they are written. The BlueNRG version and the random BLE address come from ``rng``."""
    uid = rng.integers(0, 256, 4)
    mac = [0xC0, 0x8C, int(uid[0]), int(uid[1]), int(uid[2]), int(uid[3])]
    # ms after the link starts, as the real firmware writes them under emulation (the sensor lines come after ST's
    # HAL_Delay(1000); the BlueNRG's own reply times are not modelled there, so the BLE lines' spacing is a guess)
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
    jitter = rng.uniform(0.0, 0.03, len(ms))
    return [(int((t + j) * CPU_HZ / 1000), text) for (t, text), j in zip(ms, jitter)]


class _TxQueue:
    """The patch's TX ring buffer drained by USART1 at ``baud`` (10 bit times per byte), in cycle time."""

    def __init__(self, baud: int) -> None:
        self.tau = 10.0 * CPU_HZ / baud  # cycles per byte
        self.busy_until = 0.0  # cycle time the last queued byte has been shifted out
        self.dropped = 0
        self.peak = 0

    def used(self, t: float) -> int:
        """Bytes still in the queue at ``t`` (one byte sits in the shift register, one in DR)."""
        if self.busy_until <= t:
            return 0
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

    def take_peak(self, t: float) -> int:
        p = self.peak
        self.peak = self.used(t)
        return p

    def busy_overlap(self, t0: float, t1: float) -> float:
        """Bytes the UART finishes between t0 and t1 (for the TXE interrupts landing in an AHRS step)."""
        return max(0.0, min(self.busy_until, t1) - t0) / self.tau


def _forced_drops(n_steps: int, rate: float, rng: np.random.Generator) -> np.ndarray:
    """(n,) bool: attitude frames the queue refuses for ``--drop-rate``: bursts (mean 3 frames) separated by
    geometric gaps, so the long-run fraction is ``rate``."""
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


# ---- the emulation -----------------------------------------------------------------------------------------------

def _profile(opts: SynthOptions, rng_motion, n_ticks: int, first_tick_s: float, total_s: float,
             trial=None) -> M.MotionProfile:
    t = M.tick_times_s(n_ticks, first_tick_s)
    thr_fn = M.parse_throttle(opts.throttle) if opts.throttle is not None else None
    if trial is not None:
        return M.broad_profile(trial, t, first_tick_s, thr_fn)
    return M.build_profile(opts.scenario, t, rng_motion, throttle=thr_fn, total_s=total_s)


def _sensor(rng: np.random.Generator) -> sm.Lsm6dsl:
    """The LSM6DSL of this seed: zero-g and zero-rate offsets well inside the datasheet's ±40 mg / ±2 dps."""
    return sm.Lsm6dsl(
        acc_bias_mg=tuple(float(v) for v in rng.normal(0.0, 12.0, 3)),
        gyro_bias_mdps=tuple(float(v) for v in rng.normal(0.0, 600.0, 3)),
    )


def _gyro_drift_mdps(t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Slow zero-rate drift after the power-up calibration (warm-up), (T, 3) mdps: ≈ 40 mdps RMS per axis over
    minutes, so the calibrated offset is not perfect and the filter's integral terms have work to do."""
    out = np.empty((len(t_s), 3))
    for i in range(3):
        f = rng.uniform(0.002, 0.02, 3)
        a = rng.normal(0.0, 40.0 / np.sqrt(1.5), 3)
        ph = rng.uniform(0, 2 * np.pi, 3)
        out[:, i] = (np.sin(2 * np.pi * f * t_s[:, None] + ph) - np.sin(ph)) @ a
    return out


def _settings(opts: SynthOptions) -> MahonySettings:
    return MahonySettings(ki=float(np.float32(opts.ki)), correction=opts.correction)


def synthesize(opts: SynthOptions, progress: Callable[[float, str], None] | None = None) -> SynthResult:
    """Emulate the drone end to end for ``opts``; deterministic for given options (see the module docstring).
    ``progress(fraction, stage)`` is called as the stages advance (e.g. ``steval_link.cli.progress``)."""
    _check(opts)
    if progress is None:
        progress = lambda fraction, stage="": None  # noqa: E731
    root = np.random.SeedSequence([int(opts.seed), 0x5EA1])
    r_motion, r_sensor, r_noise, r_fw, r_drop, r_host, r_boot = (np.random.default_rng(s) for s in root.spawn(7))

    trial = None
    if _is_path(opts.scenario):

        trial = load_trial(opts.scenario)
        min_total = 3.0
        default_duration = None
    else:
        sc = M.SCENARIOS.get(opts.scenario)
        if sc is None:
            raise UserError(f"unknown scenario {opts.scenario!r}; built-in: {', '.join(M.SCENARIOS)} "
                            f"(or a BROAD trial .npz path; see steval synth --list)")
        min_total = sc.min_duration_s
        default_duration = sc.default_duration_s
    tim9_s = TIM9_START_CYCLES / CPU_HZ
    if opts.duration_s is not None:
        duration = float(opts.duration_s)
    elif trial is not None:
        duration = trial.t_s[-1] + tim9_s - opts.join_at_s - 1e-6
        if duration <= 0:
            raise UserError(f"--join-at {opts.join_at_s:g} s is after the end of BROAD trial {trial.name}")
    else:
        duration = default_duration
    total = opts.join_at_s + duration
    if total < min_total:
        raise UserError(f"scenario {opts.scenario} needs at least {min_total:g} s from power-up "
                        f"(the firmware calibrates for 2 s before the first AHRS step); got {total:g} s")

    # 1-2: motion and sensor at every tick, from TIM9's first tick to the end of the capture
    first_tick_s = (TIM9_START_CYCLES + M.TICK_CYCLES) / CPU_HZ
    n_ticks = int(math.floor((total - first_tick_s) * sm.TICK_HZ)) + 1
    progress(0.0, "motion profile")
    profile = _profile(opts, r_motion, n_ticks, first_tick_s, total, trial)
    gyro_true = profile.gyro_mdps
    if profile.measured:
        sensor = sm.Lsm6dsl(acc_noise_mg=0.0, gyro_noise_mdps=0.0)
    else:
        sensor = _sensor(r_sensor)
        gyro_true = gyro_true + _gyro_drift_mdps(profile.t_s, r_sensor)
    progress(0.55, "LSM6DSL model")
    acc_raw, gyro_raw = sensor.read(profile.acc_mg, gyro_true, rng=r_noise, t_tick_s=profile.t_s)

    # 3: ISR and main-loop averaging; ISR yaw
    progress(0.6, "ISR pipeline")
    isr = sm.run_isr(acc_raw, gyro_raw)
    thr_tick = profile.thr.astype(np.int64)
    yaw = sm.isr_yaw_rad(isr.gyro_fil_mdps[:, 2], thr_tick[isr.first_tick:])
    n_steps = len(isr.step_tick)
    thr_step = thr_tick[isr.step_tick]
    thz = yaw[isr.step_tick - isr.first_tick]

    # 4: the port, in runs between status snapshots
    progress(0.8, "filter port")
    settings = _settings(opts)
    q = np.empty((n_steps, 4), np.float32)
    thx = np.empty(n_steps, np.float32)
    thy = np.empty(n_steps, np.float32)
    status_steps = np.arange(STATUS_EVERY_STEPS - 1, n_steps, STATUS_EVERY_STEPS)
    snapshots = []
    state = MahonyState()
    a = 0
    for b in list(status_steps + 1) + [n_steps]:
        if b <= a:
            continue
        q[a:b], thx[a:b], thy[a:b], state = mahony_run(isr.acc_ahrs_mg[a:b], isr.gyro_ahrs_mdps[a:b], thr_step[a:b],
                                                       settings=settings, state=state)
        snapshots.append(state)
        a = b

    # 5: the link, step by step, with the TX queue
    tick_cycles = TIM9_START_CYCLES + (np.arange(n_ticks, dtype=np.int64) + 1) * M.TICK_CYCLES
    isr_cycles = 15_100 + r_fw.integers(-300, 300, n_steps)  # TIM9 ISR (SPI sensor reads, IIR, PID) ≈ 180 µs
    loop_latency = r_fw.integers(0, 700, n_steps) + np.where(r_fw.random(n_steps) < 0.08,
                                                             r_fw.integers(0, 34_000, n_steps), 0)  # BLE traffic
    begin = tick_cycles[isr.step_tick] + isr_cycles + loop_latency
    cyc_noise = np.rint(r_fw.normal(0.0, 14.0, n_steps)).astype(np.int64) + r_fw.integers(0, 24, n_steps)
    txe_u = r_fw.random(n_steps)
    forced = _forced_drops(n_steps, opts.drop_rate, r_drop)
    t_us = (begin // (CPU_HZ // 1_000_000)) % P.T_US_MODULUS

    att = np.zeros(n_steps, dtype=P.ATTITUDE_DTYPE)
    att["t_us"] = t_us
    att["acc_mg"] = isr.acc_ahrs_mg
    att["gyro_mdps"] = isr.gyro_ahrs_mdps
    att["q_wxyz"] = q
    att["thz_rad"] = thz
    att["seq"] = np.arange(n_steps) % P.SEQ_MODULUS
    att["thr"] = thr_step.astype(np.int16)

    txq = _TxQueue(opts.baud)
    flags = settings.flags | (P.FLAG_TEXT_MODE if opts.text_mode else 0)
    ki_f32 = np.float32(opts.ki)
    # the transmit order: (kind, index or payload, start cycle, size)
    order: list[tuple[str, object, float, int]] = []
    sent = np.zeros(n_steps, dtype=bool)
    status_recs = []

    def push_text(cyc: float, line: str) -> None:
        if opts.text_mode:
            data = line.encode("utf-8")
            if data.startswith(b"$"):
                data = b"#" + data[1:]
            data += b"\r\n"
            start = txq.push(cyc, len(data), TEXT_LINE_MAX)
            if start is not None:
                order.append(("raw", data, start, len(data)))
            return
        raw = line.encode("utf-8") or b" "
        for i in range(0, len(raw), P.TEXT_MAX_PAYLOAD):
            piece = raw[i : i + P.TEXT_MAX_PAYLOAD]
            size = P.HEADER_SIZE + len(piece) + P.CRC_SIZE
            start = txq.push(cyc, size, P.STATUS_FRAME_SIZE)
            if start is not None:
                order.append(("text", piece, start, size))

    for cyc, line in boot_lines(r_boot):
        push_text(cyc, line)

    cyc_min, cyc_max, cyc_sum, cyc_n = 2**32 - 1, 0, 0, 0
    snap_i = 0
    progress(0.85, "link and TX queue")
    for k in range(n_steps):
        if k % 8192 == 0:
            progress(0.85 + 0.1 * k / n_steps, "link and TX queue")
        c0 = float(begin[k])
        base = AHRS_CYCLES + int(cyc_noise[k])
        irqs = txq.busy_overlap(c0, c0 + base)
        n_irq = int(irqs) + (1 if txe_u[k] < irqs - int(irqs) else 0)
        cyc = base + n_irq * TXE_IRQ_CYCLES
        c1 = c0 + cyc
        cyc_min, cyc_max, cyc_sum, cyc_n = min(cyc_min, cyc), max(cyc_max, cyc), cyc_sum + cyc, cyc_n + 1
        if not opts.text_mode:
            if forced[k]:
                txq.dropped += 1
            else:
                start = txq.push(c1, P.ATTITUDE_FRAME_SIZE, P.STATUS_FRAME_SIZE)
                if start is not None:
                    sent[k] = True
                    order.append(("att", k, start, P.ATTITUDE_FRAME_SIZE))
        elif k % TEXT_DECIMATION == 0:
            line = format_att(
                step=k, t_ms=int(t_us[k]) // 1000, thr=int(thr_step[k]),
                thx_mdeg=_f2i(thx[k] * _RAD_TO_MDEG_F32), thy_mdeg=_f2i(thy[k] * _RAD_TO_MDEG_F32),
                thz_mdeg=_f2i(np.float32(thz[k]) * _RAD_TO_MDEG_F32),
                acc_mg=[_f2i(v) for v in isr.acc_ahrs_mg[k]], gyro_mdps=[_f2i(v) for v in isr.gyro_ahrs_mdps[k]],
            )
            if forced[k]:
                txq.dropped += 1
            else:
                start = txq.push(c1, len(line), TEXT_LINE_MAX)
                if start is not None:
                    sent[k] = True
                    order.append(("raw", line, start, len(line)))
        if k % STATUS_EVERY_STEPS == STATUS_EVERY_STEPS - 1:
            snap = snapshots[snap_i]
            snap_i += 1
            rec = np.zeros((), dtype=P.STATUS_DTYPE)
            rec["step"] = k
            rec["t_us"] = t_us[k]
            rec["q_wxyz"] = snap.q_wxyz
            rec["int_xyz"] = snap.int_xyz
            rec["kp_ground"] = settings.kp_ground
            rec["kp_flight"] = settings.kp_flight
            rec["ki"] = ki_f32
            rec["dt_s"] = settings.dt_s
            rec["cyc_min"] = cyc_min
            rec["cyc_mean"] = cyc_sum // cyc_n
            rec["cyc_max"] = cyc_max
            rec["cyc_n"] = min(cyc_n, 0xFFFF)
            rec["cpu_hz"] = CPU_HZ
            rec["tx_dropped"] = txq.dropped
            rec["baud"] = opts.baud
            rec["min_thr"] = settings.min_thr
            rec["flags"] = flags
            rec["queue_peak"] = min(txq.take_peak(c1), 0xFFFF)
            rec["fw_version"] = FW_VERSION
            status_recs.append(rec)
            cyc_min, cyc_max, cyc_sum, cyc_n = 2**32 - 1, 0, 0, 0
            if opts.text_mode:
                line = format_sta(step=k, t_ms=int(t_us[k]) // 1000, cyc_min=int(rec["cyc_min"]),
                                  cyc_mean=int(rec["cyc_mean"]), cyc_max=int(rec["cyc_max"]), cyc_n=int(rec["cyc_n"]),
                                  tx_dropped=int(rec["tx_dropped"]), flags=flags, ki_micro=_ki_micro(ki_f32))
                start = txq.push(c1, len(line), 0)
                if start is not None:
                    order.append(("raw", line, start, len(line)))
            else:
                start = txq.push(c1, P.STATUS_FRAME_SIZE, 0)
                if start is not None:
                    order.append(("status", rec, start, P.STATUS_FRAME_SIZE))
    status = np.array(status_recs, dtype=P.STATUS_DTYPE).reshape(-1)

    # 6: the bytes, in transmit order
    progress(0.95, "encoding frames")
    stream = _encode(order, att, opts)
    sizes = np.array([o[3] for o in order], dtype=np.int64)
    starts = np.array([o[2] for o in order], dtype=np.float64)

    # 7: the host
    offsets, chunk_offsets, chunk_times = _host_chunks(stream, sizes, starts, txq.tau, opts, r_host, total)
    data = stream[offsets[0] : offsets[1]]
    counts = _count(order, offsets)
    header = _header(opts, profile.name, duration, counts, txq.dropped)
    step_t_s = begin / CPU_HZ
    return SynthResult(data, chunk_offsets, chunk_times, header, att, sent, status, txq.dropped, profile, step_t_s,
                       counts)


def _f2i(x) -> int:
    """The patch's ``stv_f2i_trunc``: float32 → int32 toward zero, NaN → 0, saturating."""
    x = np.float32(x)
    if x != x:
        return 0
    if x >= np.float32(2147483520.0):
        return 2**31 - 1
    if x <= np.float32(-2147483648.0):
        return -(2**31)
    return int(x)


def _ki_micro(ki: np.float32) -> int:
    half = np.float32(0.5) if ki >= 0 else np.float32(-0.5)
    return _f2i(np.float32(ki * np.float32(1e6)) + half)


def _encode(order, att: np.ndarray, opts: SynthOptions) -> bytes:
    """The frames of ``order`` as bytes, by the Python encoder or the C host encoder."""
    if opts.encoder == "c":
        return _encode_c(order, att, opts)
    att_idx = [o[1] for o in order if o[0] == "att"]
    block = P.encode_attitude_block(att[att_idx]) if att_idx else b""
    out = []
    j = 0
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


def _encode_c(order, att: np.ndarray, opts: SynthOptions) -> bytes:
    exe = Path(opts.c_encoder) if opts.c_encoder else default_c_encoder()
    if not exe.is_file() or not os.access(exe, os.X_OK):
        raise UserError(f"C encoder {exe} not found or not executable; build it with: make -C firmware_patch host")
    req = []
    for kind, item, _, _ in order:
        if kind == "att":
            payload = att[item].tobytes()
            req.append(bytes((P.TYPE_ATTITUDE, len(payload))) + payload)
        elif kind == "status":
            payload = item.tobytes()
            req.append(bytes((P.TYPE_STATUS, len(payload))) + payload)
        elif kind == "text":
            req.append(bytes((P.TYPE_TEXT, len(item))) + item)
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


def _host_chunks(stream: bytes, sizes, starts, tau: float, opts: SynthOptions, rng, total_s: float):
    """Bytes the host receives in [join, join + duration] and their USB packets' receive times.

    Returns ``((first, end) stream offsets of the captured bytes, chunk offsets, chunk times s since start)``.
    """
    n = len(stream)
    if n == 0:
        return (0, 0), np.zeros(0, np.int64), np.zeros(0)
    frame_off = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    rep_start = np.repeat(starts, sizes)
    idx = np.arange(n, dtype=np.float64) - np.repeat(frame_off, sizes)
    end_s = (rep_start + (idx + 1) * tau) / CPU_HZ  # the stop bit of each byte is out
    join = float(opts.join_at_s)
    first = int(np.searchsorted(end_s, join, side="right")) if join > 0 else 0
    e = end_s[first:]
    # adapter: a packet when 62 bytes are in, or when the latency timer expires with data waiting
    sof_phase = rng.uniform(0.0, USB_FRAME_S)
    t_last = (e[0] if len(e) else 0.0) - rng.uniform(0.0, ADAPTER_LATENCY_S)
    flush_t, flush_end = [], []
    i, m = 0, len(e)
    while i < m:
        k = max(1, math.ceil((e[i] - t_last) / ADAPTER_LATENCY_S - 1e-12))
        expiry = t_last + k * ADAPTER_LATENCY_S
        j_full = i + ADAPTER_PACKET_BYTES - 1
        if j_full < m and e[j_full] <= expiry:
            t_f, j = e[j_full], j_full
        else:
            j = int(np.searchsorted(e, expiry, side="right")) - 1
            t_f = expiry
        flush_t.append(t_f)
        flush_end.append(j + 1)
        t_last = t_f
        i = j + 1
    flush_t = np.array(flush_t)
    # USB: the host controller picks the packet up at the next 1 ms frame; the OS hands it to the reader later
    arrive = sof_phase + np.ceil((flush_t - sof_phase) / USB_FRAME_S) * USB_FRAME_S
    arrive = arrive + rng.exponential(0.00015, len(arrive))
    arrive = np.maximum.accumulate(arrive)
    keep = arrive <= total_s
    flush_end = np.array(flush_end, dtype=np.int64)[keep]
    arrive = arrive[keep]
    n_cap = int(flush_end[-1]) if len(flush_end) else 0
    chunk_offsets = np.concatenate(([0], flush_end[:-1])) if len(flush_end) else np.zeros(0, np.int64)
    return (first, first + n_cap), chunk_offsets.astype(np.int64), arrive - join


def _count(order, offsets) -> dict:
    """Frames of each kind whose bytes are entirely in the captured range."""
    counts = {"attitude": 0, "status": 0, "text": 0, "att_lines": 0, "sta_lines": 0, "log_lines": 0}
    pos = 0
    lo, hi = offsets
    for kind, item, _, size in order:
        if pos >= lo and pos + size <= hi:
            if kind == "att":
                counts["attitude"] += 1
            elif kind in ("status", "text"):
                counts[kind] += 1
            elif item.startswith(b"$ATT"):
                counts["att_lines"] += 1
            elif item.startswith(b"$STA"):
                counts["sta_lines"] += 1
            else:
                counts["log_lines"] += 1
        pos += size
    return counts


def _header(opts: SynthOptions, name: str, duration: float, counts: dict, dropped: int) -> dict:

    start = EPOCH_UNIX_S + opts.join_at_s
    params = {k: v for k, v in asdict(opts).items() if k not in ("encoder", "c_encoder")}
    params["duration_s"] = duration
    return capture.capture_header(f"synth:{name}", opts.baud, start, {
        "emulated": True,
        "generator": "steval synth (steval_link.emulation.synth): motion → LSM6DSL model → ISR pipeline → bit-exact "
                     "ahrs_fusion_ag port → firmware link emulation → USB-UART adapter model",
        "command": opts.command(),
        "synth": params,
    })


def write_output(result: SynthResult, path, *, fmt: str = "auto", force: bool = False) -> str:
    """Write ``result`` to ``path``: a ``.stv`` capture (``fmt`` "stv", or "auto" with a .stv name) or the plain
    received bytes ("raw", or "auto" with any other name). Never overwrites unless ``force``. Returns the format."""
    path = Path(path)
    if fmt not in ("auto", "stv", "raw"):
        raise UserError(f"--format must be auto, stv or raw, got {fmt!r}")
    kind = ("stv" if path.suffix.lower() == ".stv" else "raw") if fmt == "auto" else fmt
    if path.is_dir():
        raise UserError(f"{path} is a directory; give a file name for --out")
    if path.exists() and not force:
        raise UserError(f"{path} exists; pass --force to replace it")
    if not path.parent.is_dir():
        raise UserError(f"{path.parent} does not exist")
    if kind == "raw":
        blob = result.data
    else:
        bounds = list(result.chunk_offsets) + [len(result.data)]
        blob = capture.encode_capture(
            result.header,
            ((result.data[bounds[i] : bounds[i + 1]], t) for i, t in enumerate(result.chunk_times_s)),
        )
    tmp = path.with_name(path.name + ".part")
    try:
        tmp.write_bytes(blob)
        os.replace(tmp, path)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None
    return kind

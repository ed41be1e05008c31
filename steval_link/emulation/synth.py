"""Emulated drone captures (``steval synth``): a motion profile through the whole STEVAL-FCU001V1 chain to a capture.

``steval emulate`` runs the real firmware; synth does what only it does: joining mid-frame, injected drops, the
adapter model, text-mode logs. Motion (a scenario or a BROAD trial) → LSM6DSL and ISR pipeline → the bit-exact
``ahrs_fusion_ag`` replica → the link and TX queue (:mod:`.fw_link`) → a USB-UART adapter (:func:`host_chunks`).

Modelled, not measured: the main loop's latency, the DWT counts' noise, the gyro's drift after calibration, the BLE
banner values, the adapter. The same :class:`SynthOptions` give the same bytes (capture start :data:`EPOCH_UNIX_S`).
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.emulation import fw_link as fwl
from steval_link.emulation import motion as M
from steval_link.emulation import sensor_model as sm
from steval_link.emulation.broad import load_trial
from steval_link.emulation.scenarios import random_streams, scenario
from steval_link.errors import ParamError, UserError
from steval_link.estimators.st_mahony import MahonySettings, MahonyState
from steval_link.estimators.st_mahony import run as mahony_run
from steval_link.link import capture
from steval_link.link import protocol as P

EPOCH_UNIX_S = 1767225600.0  #: capture start time: 2026-01-01T00:00:00Z (+ the join time), never the wall clock
MAX_BAUD = 5_250_000  # USART1 at 84 MHz, oversampling by 16
MIN_BAUD = 1200
_GENERATOR = (
    "steval synth (steval_link.emulation.synth): motion → LSM6DSL model → ISR pipeline → bit-exact ahrs_fusion_ag "
    "replica → firmware link emulation → USB-UART adapter model"
)


@dataclass(frozen=True)
class SynthOptions:
    """What to emulate (the ``steval synth`` options)."""

    scenario: str = "bench"  #: built-in scenario name or a BROAD trial ``.npz`` path
    duration_s: float | None = None  #: capture length, s (default: the scenario's; a BROAD trial: all of it)
    seed: int = 0  #: seeds every random choice (motion details, sensor bias and noise, latencies, drops)
    baud: int = C.BAUD  #: USART1 baud rate (header, status frames, byte timing, queue drain)
    throttle: str | None = None  #: ``--throttle`` spec (:func:`~steval_link.emulation.motion.parse_throttle`)
    ki: float = C.KI  #: ``AHRS_KI`` of the emulated build (float32 like the firmware)
    correction: bool = True  #: False: the build without accelerometer correction (lab exercise 5)
    text_mode: bool = False  #: the text-mode build (``$ATT`` every 16th step, ``$STA``, plain log lines)
    join_at_s: float = 0.0  #: the capture starts this long after power-up (mid-flight, mid-frame)
    drop_rate: float = 0.0  #: fraction of attitude frames the TX queue refuses (0 ≤ P < 1)
    encoder: str = "python"  #: "python" or "c" (frames made by ``firmware_patch/host/stv_encode``)
    c_encoder: str | None = None  #: path of the host-built C encoder (default :func:`default_c_encoder`)
    vibration: tuple[str, ...] = ()  #: ``SENSOR-AXIS:HZ:AMPLITUDE`` specs: pure sinusoids added to the motion
    command_line: str | None = None  #: the command line that made this capture, for its header (the CLI's)

    def settings(self) -> dict:
        """The settings that determine the serial bytes, by parameter name (no output path, no encoder choice)."""
        out = dict(scenario=self.scenario, duration_s=self.duration_s, seed=self.seed)
        out.update(baud=self.baud if self.baud != C.BAUD else None, throttle=self.throttle)
        out.update(ki=self.ki if self.ki != C.KI else None, correction=None if self.correction else False)
        out.update(text_mode=self.text_mode or None, join_at_s=self.join_at_s or None, drop_rate=self.drop_rate or None)
        out["vibration"] = [M.parse_vibration(spec).spec for spec in self.vibration] or None
        return {k: v for k, v in out.items() if v is not None}

    def command(self) -> str:
        """The capture header's command: :attr:`command_line`, else :meth:`settings`."""
        return self.command_line or "synth " + " ".join(f"{k}={v}" for k, v in self.settings().items())


@dataclass
class SynthResult:
    """An emulated capture and what the firmware did to make it."""

    data: bytes  #: the serial bytes the host received (what a capture holds)
    chunk_offsets: np.ndarray  #: (K,) int64 stream offset of each received chunk (USB packet)
    chunk_times_s: np.ndarray  #: (K,) host receive time of each chunk, s since the capture started
    header: dict  #: the capture header (``extra`` holds the emulation's parameters)
    attitude: np.ndarray  #: (M,) ``ATTITUDE_DTYPE`` records of every AHRS step the firmware made (sent or not)
    sent: np.ndarray  #: (M,) bool, the step's attitude frame (or text-mode line) went into the queue
    status: np.ndarray  #: (S,) ``STATUS_DTYPE`` records of every status the firmware made
    tx_dropped: int  #: frames the queue refused in the whole emulation
    profile: M.MotionProfile  #: the motion profile (truth) at every tick
    step_t_s: np.ndarray  #: (M,) firmware time of each step, s since power-up
    counts: dict = field(default_factory=dict)  #: frames of each kind in ``data``


def default_c_encoder() -> Path:
    """``firmware_patch/host/stv_encode`` of this source tree (``make -C firmware_patch host`` builds it)."""
    return Path(__file__).resolve().parents[2] / "firmware_patch" / "host" / "stv_encode"


def _finite(v) -> bool:
    return v is not None and math.isfinite(v)


#: the numeric options: (parameter, test, what it must be)
_LIMITS = (
    ("duration_s", lambda v: v is None or (_finite(v) and v > 0), "a positive number of seconds"),
    ("join_at_s", lambda v: _finite(v) and v >= 0, "≥ 0 seconds"),
    ("drop_rate", lambda v: _finite(v) and 0 <= v < 1, "a fraction in [0, 1)"),
    ("baud", lambda v: MIN_BAUD <= v <= MAX_BAUD, f"between {MIN_BAUD} and {MAX_BAUD} (USART1 at 84 MHz)"),
    ("ki", lambda v: _finite(v) and math.isfinite(float(np.float32(v))), "a finite number"),
    ("seed", lambda v: 0 <= v < 2**63, "a non-negative integer"),
)


def _check(opts: SynthOptions) -> None:
    for name, ok, what in _LIMITS:
        if not ok(getattr(opts, name)):
            raise ParamError(f"{{{name}}} must be {what}, got {getattr(opts, name)}", name)
    if opts.encoder not in ("python", "c"):
        raise ParamError(f"{{encoder}} must be 'python' or 'c', got {opts.encoder!r}", "encoder")
    for spec in opts.vibration:
        M.parse_vibration(spec)
    if opts.encoder == "c" and opts.text_mode:
        raise ParamError(
            "{text_mode} lines are formatted in Python; the C host encoder (stv_encode) takes binary "
            "frame requests only, so use {encoder} python with {text_mode}",
            "text_mode",
            "encoder",
        )


def _gyro_drift_mdps(t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Slow zero-rate drift after calibration (warm-up), (T, 3) mdps: ≈ 40 mdps RMS per axis over minutes."""
    out = np.empty((len(t_s), 3))
    for i in range(3):
        f = rng.uniform(0.002, 0.02, 3)
        a = rng.normal(0.0, 40.0 / np.sqrt(1.5), 3)
        ph = rng.uniform(0, 2 * np.pi, 3)
        out[:, i] = (np.sin(2 * np.pi * f * t_s[:, None] + ph) - np.sin(ph)) @ a
    return out


def _span(opts: SynthOptions):
    """(BROAD trial or None, scenario or None, capture duration s, s from power-up to the capture's end)."""
    is_path = opts.scenario.endswith(".npz") or os.sep in opts.scenario or "/" in opts.scenario
    trial = load_trial(opts.scenario) if is_path else None
    sc = None if trial is not None else scenario(opts.scenario, "or a BROAD trial .npz path")
    min_total = 3.0 if sc is None else sc.min_duration_s
    if opts.duration_s is not None:
        duration = float(opts.duration_s)
    elif sc is not None:
        duration = sc.default_duration_s
    else:
        duration = trial.t_s[-1] + fwl.TIM9_START_CYCLES / C.CPU_HZ - opts.join_at_s - 1e-6
        if duration <= 0:
            raise ParamError(
                f"{{join_at_s}} {opts.join_at_s:g} s is after the end of BROAD trial {trial.name}", "join_at_s"
            )
    total = opts.join_at_s + duration
    if total < min_total:
        raise UserError(
            f"scenario {opts.scenario} needs at least {min_total:g} s from power-up "
            f"(the firmware calibrates for 2 s before the first AHRS step); got {total:g} s"
        )
    return trial, sc, duration, total


def _replica_with_snapshots(isr, thr_step: np.ndarray, settings: MahonySettings):
    """The bit-exact replica over every AHRS step: (q, thx, thy, the filter state after each status step)."""
    n_steps = len(isr.step_tick)
    q = np.empty((n_steps, 4), np.float32)
    thx, thy = np.empty(n_steps, np.float32), np.empty(n_steps, np.float32)
    snapshots, state = [], MahonyState()
    for a, b in itertools.pairwise([*range(0, n_steps, fwl.STATUS_EVERY_STEPS), n_steps]):
        q[a:b], thx[a:b], thy[a:b], state = mahony_run(
            isr.acc_ahrs_mg[a:b], isr.gyro_ahrs_mdps[a:b], thr_step[a:b], settings=settings, state=state
        )
        snapshots.append(state)
    return q, thx, thy, snapshots


def synthesize(opts: SynthOptions, progress: Callable[[float, str], None] | None = None) -> SynthResult:
    """The modelled drone end to end for ``opts``; ``progress(fraction, stage)`` is called as the stages advance."""
    _check(opts)
    progress = progress or (lambda fraction, stage="": None)
    rs = random_streams(opts.seed)
    trial, sc, duration, total = _span(opts)
    # 1-3: the motion and the LSM6DSL at every TIM9 tick to the capture's end, then the ISR
    first_tick_s = (fwl.TIM9_START_CYCLES + C.TICK_CYCLES) / C.CPU_HZ
    n_ticks = int(math.floor((total - first_tick_s) * C.ISR_RATE_HZ)) + 1
    progress(0.0, "motion profile")
    t = first_tick_s + np.arange(n_ticks, dtype=np.float64) * C.TICK_PERIOD_S
    thr_fn = M.parse_throttle(opts.throttle) if opts.throttle is not None else None
    if trial is not None:
        profile = M.broad_profile(trial, t, first_tick_s, thr_fn)
    else:
        profile = M.render(sc.name, sc.build(total, rs.motion), t, rs.motion, thr_fn)
    profile = M.add_vibrations(profile, [M.parse_vibration(spec) for spec in opts.vibration])
    gyro_true = profile.gyro_mdps
    if profile.measured:
        sensor = sm.Lsm6dsl(acc_noise_mg=0.0, gyro_noise_mdps=0.0)
    else:
        sensor = sm.seeded_lsm6dsl(rs.sensor)
        gyro_true = gyro_true + _gyro_drift_mdps(profile.t_s, rs.sensor)
    progress(0.55, "LSM6DSL model")
    acc_raw, gyro_raw = sensor.read(profile.acc_mg, gyro_true, rng=rs.noise, t_tick_s=profile.t_s)
    progress(0.6, "ISR pipeline")
    isr = sm.run_isr(acc_raw, gyro_raw)
    thr_tick = profile.thr.astype(np.int64)
    yaw = sm.isr_yaw_rad(isr.gyro_fil_mdps[:, 2], thr_tick[isr.first_tick :])
    thr_step = thr_tick[isr.step_tick]

    # 4: the replica, in runs between status snapshots
    progress(0.8, "filter replica")
    settings = MahonySettings(ki=float(np.float32(opts.ki)), correction=opts.correction)
    q, thx, thy, snapshots = _replica_with_snapshots(isr, thr_step, settings)

    # 5: the link, step by step, with the TX queue
    begin, cyc_noise, txe_u = fwl.step_timing(isr.step_tick, rs.fw)
    att = _attitude_rows(isr, begin, q, yaw[isr.step_tick - isr.first_tick], thr_step)
    forced = fwl.forced_drops(len(att), opts.drop_rate, rs.drop)
    link = fwl.LinkEmulation(att, thx, thy, settings, opts.baud, opts.text_mode, snapshots, forced)
    for cyc, line in fwl.boot_lines(rs.boot):
        link.text(cyc, line)
    progress(0.85, "link and TX queue")
    for k in range(len(att)):
        if k % 8192 == 0:
            progress(0.85 + 0.1 * k / len(att), "link and TX queue")
        link.step(k, float(begin[k]), int(cyc_noise[k]), float(txe_u[k]))
    status = link.status_table()

    # 6-7: the bytes in transmit order, as the host receives them from the join time on
    progress(0.95, "encoding frames")
    if opts.encoder == "c":
        stream = fwl.encode_c(link.order, att, Path(opts.c_encoder) if opts.c_encoder else default_c_encoder())
    else:
        stream = fwl.encode(link.order, att)
    offsets, chunk_offsets, chunk_times = host_chunks(stream, link.order, link.txq.tau, opts.join_at_s, rs.host, total)
    data, counts = stream[offsets[0] : offsets[1]], fwl.count_frames(link.order, offsets)
    dropped = link.txq.dropped
    header = _header(opts, profile.name, duration)
    return SynthResult(
        data, chunk_offsets, chunk_times, header, att, link.sent, status, dropped, profile, begin / C.CPU_HZ, counts
    )


def _attitude_rows(isr, begin: np.ndarray, q: np.ndarray, thz: np.ndarray, thr_step: np.ndarray) -> np.ndarray:
    """The attitude frame of every AHRS step (``ATTITUDE_DTYPE``); ``begin``: each step's start, CPU cycles."""
    n_steps = len(isr.step_tick)
    att = np.zeros(n_steps, dtype=P.ATTITUDE_DTYPE)
    att["t_us"] = (begin // (C.CPU_HZ // 1_000_000)) % P.T_US_MODULUS
    att["acc_mg"] = isr.acc_ahrs_mg
    att["gyro_mdps"] = isr.gyro_ahrs_mdps
    att["q_wxyz"] = q
    att["thz_rad"] = thz
    att["seq"] = np.arange(n_steps) % P.SEQ_MODULUS
    att["thr"] = thr_step.astype(np.int16)
    return att


#: data bytes per USB packet, latency timer, USB frame
ADAPTER_PACKET_BYTES = 62
ADAPTER_LATENCY_S = 0.016
USB_FRAME_S = 0.001


def host_chunks(stream: bytes, order: list[fwl.Frame], tau: float, join_at_s: float, rng, total_s: float):
    """What the host receives of the frames ``order`` through a USB-UART adapter (FT232R-like) in [join, total_s]:
    ``((first, end) stream offsets of the captured bytes, USB packet offsets, their receive times s since join)``."""
    n = len(stream)
    if n == 0:
        return (0, 0), np.zeros(0, np.int64), np.zeros(0)
    sizes = np.array([o[3] for o in order], dtype=np.int64)
    starts = np.array([o[2] for o in order], dtype=np.float64)
    frame_off = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    idx = np.arange(n, dtype=np.float64) - np.repeat(frame_off, sizes)
    end_s = (np.repeat(starts, sizes) + (idx + 1) * tau) / C.CPU_HZ  # the stop bit of each byte is out
    join = float(join_at_s)
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
            t_f, j = expiry, int(np.searchsorted(e, expiry, side="right")) - 1
        flush_t.append(t_f)
        flush_end.append(j + 1)
        t_last, i = t_f, j + 1
    # USB: the host controller picks the packet up at the next 1 ms frame; the OS hands it to the reader later
    arrive = sof_phase + np.ceil((np.array(flush_t) - sof_phase) / USB_FRAME_S) * USB_FRAME_S
    arrive = np.maximum.accumulate(arrive + rng.exponential(0.00015, len(arrive)))
    keep = arrive <= total_s
    ends = np.array(flush_end, dtype=np.int64)[keep]
    n_cap = int(ends[-1]) if len(ends) else 0
    return (first, first + n_cap), np.concatenate(([0], ends[:-1]))[: len(ends)].astype(np.int64), arrive[keep] - join


def _header(opts: SynthOptions, name: str, duration: float) -> dict:
    params = {k: v for k, v in asdict(opts).items() if k not in ("encoder", "c_encoder")}
    params["duration_s"] = duration
    if not opts.vibration:  # headers of captures made without it stay as they were
        del params["vibration"]
    extra = {"emulated": True, "generator": _GENERATOR, "command": opts.command(), "synth": params}
    return capture.capture_header(f"synth:{name}", opts.baud, EPOCH_UNIX_S + opts.join_at_s, extra)


def write_output(result: SynthResult, path, *, fmt: str = "auto", force: bool = False) -> str:
    """Write ``result`` to ``path``: a ``.stv`` capture (``fmt`` "stv", or "auto" with a .stv name) or the plain
    received bytes ("raw", or "auto" with any other name). Never overwrites unless ``force``. Returns the format."""
    path = Path(path)
    if fmt not in ("auto", "stv", "raw"):
        raise ParamError(f"{{fmt}} must be auto, stv or raw, got {fmt!r}", "fmt")
    kind = ("stv" if path.suffix.lower() == ".stv" else "raw") if fmt == "auto" else fmt
    if path.is_dir():
        raise ParamError(f"{path} is a directory; give a file name for {{path}}", "path")
    if path.exists() and not force:
        raise ParamError(f"{path} exists; pass {{force}} to replace it", "force")
    if not path.parent.is_dir():
        raise UserError(f"{path.parent} does not exist")
    if kind == "raw":
        blob = result.data
    else:
        ends = [*result.chunk_offsets[1:], len(result.data)]
        chunks = (result.data[a:b] for a, b in zip(result.chunk_offsets, ends))
        blob = capture.encode_capture(result.header, zip(chunks, result.chunk_times_s))
    tmp = path.with_name(path.name + ".part")
    try:
        tmp.write_bytes(blob)
        os.replace(tmp, path)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None
    return kind

"""Run a firmware ELF on the emulated board with motion fed to its sensors; USART1 bytes out with emulated times.

:class:`Emulation` is what ``steval emulate`` and the tests use::

    emu = Emulation(EmulationOptions(elf="firmware_patch/build/reference/steval-reference.elf", scenario="hand-tilts"))
    for data, t_s in emu.chunks():      # bytes that left USART1 in the last slice, emulated time of the last one
        ...
    print(emu.report().lines())

Motion: a built-in scenario (rendered :data:`WINDOW_S` at a time, so memory stays bounded) or a BROAD trial (from
the first TIM9 tick on), through an LSM6DSL with this seed's offsets and noise (as ``steval synth``) into its ADC
registers. Throttle: the default build takes ``gTHR = joydata[3] * 13`` from the BLE remote while ``connected``.
The emulated remote writes ``joydata`` each TIM9 tick and connects at its first throttle or arming (a scenario with
sticks: at power-up; the firmware then also sends BLE notifications). Connected, it sends every stick as ST's app
does: ``joydata[2]`` rudder, ``[3]`` throttle, ``[4]`` aileron, ``[5]`` elevator (128 = centred; ``gRUD =
(j2-128)·(-13)``, ``gAIL = (j4-128)·(-13)``, ``gELE = (j5-128)·13``), ``[7]`` bit 2 the arming switch. Builds with
``REMOCON_PWM`` keep gTHR 0 (no RC receiver is modelled).

Sensor faults (``mount``): the board turned on the frame, as a wrong ``COORDINATE_SYSTEM`` in ST's
``config_drone.h``: ``turned-90`` (x and y swapped), ``turned-180`` (x and y reversed).

Host → drone bytes (:meth:`Emulation.send_at`, :meth:`Emulation.send`) reach USART1 RX at the baud rate's pace;
:meth:`Emulation.take_host_bytes` hands them back for ``H`` chunks.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import math
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.emulation import motion as M
from steval_link.emulation import sensor_model as sm
from steval_link.emulation.board import Board, EmulationError, FirmwareStuck
from steval_link.emulation.board.core import Mark
from steval_link.emulation.board.memory_map import in_ram
from steval_link.emulation.broad import BroadTrial, load_trial
from steval_link.emulation.elf import Elf
from steval_link.emulation.scenarios import random_streams, scenario
from steval_link.emulation.sensors import SensorBus, body_to_sensor_counts
from steval_link.errors import ParamError, UserError

__all__ = ["EmulationOptions", "Emulation", "EmulationReport", "WINDOW_S", "MOUNTS", "joydata_bytes"]

WINDOW_S = 10.0  #: motion is rendered this many seconds at a time
_WINDOW_TICKS = int(round(WINDOW_S / C.TICK_PERIOD_S))
WATCHDOG_S = 6.0  #: the watchdog: no USART1 byte or AHRS step for this long (emulated) → stop, saying where
#: the AHRS globals each step's marks copy (symbol, bytes): the filter's inputs and outputs (float mg, mdps, int16
#: gTHR, q0..q3, Euler angles in rad)
STEP_RAM = (("acc_ahrs", 12), ("gyro_ahrs", 12), ("gTHR", 2), ("ahrs", 16), ("euler_ahrs", 12))
_STEP_START, _STEP_END = 0, 1  # the marks' kinds


def _check_time_s(t_s: float) -> None:
    """ValueError unless ``t_s`` is an emulated time (finite, ≥ 0 s)."""
    if not math.isfinite(t_s) or t_s < 0:
        raise ValueError(f"emulated time must be finite and >= 0, got {t_s}")


@dataclass
class EmulationOptions:
    elf: Path | str
    scenario: str = "bench"
    broad: Path | str | BroadTrial | None = None  #: a BROAD trial: its .npz, or loaded
    duration_s: float | None = None
    seed: int = 0
    throttle: str | None = None
    skip_idle: bool = True
    log_samples: int = 0  #: keep this many LSM6DSL samples the firmware read (tests compare them with sensor_model)
    watchdog_s: float = WATCHDOG_S
    mount: str | None = None  #: the board turned on the frame (a sensor fault): None, or a MOUNTS key
    command_line: str | None = None  #: the command line that made this run, for the capture header (the CLI's)

    def settings(self) -> dict:
        """What determines the run (the parameters given), by parameter name."""
        out = {"broad": str(self.broad)} if self.broad is not None else {"scenario": self.scenario}
        out.update(duration_s=self.duration_s, seed=self.seed, throttle=self.throttle, mount=self.mount)
        return {k: v for k, v in out.items() if v is not None}

    def command(self) -> str:
        """The capture header's command: :attr:`command_line`, else the ELF and :meth:`settings`."""
        return self.command_line or " ".join([str(self.elf), *(f"{k}={v}" for k, v in self.settings().items())])


#: board mountings (sensor faults): the frame's body axes (x right, y forward, z up) → what the board reads
MOUNTS: dict[str, np.ndarray] = {
    "turned-90": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
    "turned-180": np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]),
}


class ScenarioMotion:
    """A built-in scenario's true motion + the LSM6DSL (bias, noise, ADC) → sensor-axis counts per tick."""

    def __init__(
        self, name: str, total_s: float, seed: int, throttle: str | None = None, trial=None, mount: str | None = None
    ) -> None:
        if mount is not None and mount not in MOUNTS:
            raise ParamError(f"unknown {{mount}} {mount!r}; one of: {', '.join(MOUNTS)}", "mount")
        self.name = name
        self._mount = None if mount is None else MOUNTS[mount]
        self.seed = seed
        self.trial = trial
        self._thr_fn = M.parse_throttle(throttle) if throttle is not None else None
        streams = random_streams(seed)  # as steval synth's for the same seed: the same moves and sensor offsets
        if trial is None:
            sc = scenario(name, "or {broad} TRIAL.npz")
            try:
                self._kin = sc.build(total_s, streams.motion)
            except ValueError:  # its moves do not fit in so short a run
                raise ParamError(
                    f"scenario {name!r} needs {{duration_s}} of at least {sc.min_duration_s:g} s (default "
                    f"{sc.default_duration_s:g} s), got {total_s:g}",
                    "duration_s",
                ) from None
        self.remote_from_start = trial is None and self._kin.sticks is not None  #: sticks: connected at power-up
        self.sensor = sm.seeded_lsm6dsl(streams.sensor)  #: this seed's LSM6DSL: offsets and noise
        self._window = -1
        self._total_s = total_s
        #: rendered windows by (window, first_tick_s): this one, the one before and the next
        self._windows: dict[tuple[int, float | None], tuple] = {}
        self._ahead: tuple[tuple[int, float | None], threading.Thread] | None = None  # the next one, rendering
        self.first_tick_s: float | None = None  # for BROAD: trial time 0 at the first TIM9 tick

    def _rendered(self, w: int) -> tuple:
        """Window ``w``, and the next one rendered in a thread meanwhile (numpy works there while the board runs)."""
        key = (w, self.first_tick_s)
        if self._ahead is not None and self._ahead[0] == key:
            self._ahead[1].join()
        got = self._windows.get(key)
        if got is None:
            got = self._windows[key] = self._render(*key)
        nxt, keep = (w + 1, self.first_tick_s), {(w - 1, self.first_tick_s), key, (w + 1, self.first_tick_s)}
        for old in list(self._windows):  # (the remote reads a tick ahead: a run crosses each edge back and forth)
            if old not in keep:
                self._windows.pop(old, None)
        self._start_ahead(nxt)
        return got

    def render_first(self) -> None:
        """Window 0 rendered in a thread from now on, while the firmware boots (before its first TIM9 tick)."""
        self._start_ahead((0, self.first_tick_s))

    def _start_ahead(self, key: tuple[int, float | None]) -> None:
        """Window ``key`` rendered in a thread, unless it is there, rendering, past the run or a trial's unknown."""
        rendering = self._ahead is not None and self._ahead[0] == key and self._ahead[1].is_alive()
        unknown = self.trial is not None and self.first_tick_s is None  # (a trial's windows wait for its first tick)
        if key not in self._windows and not rendering and not unknown and key[0] * WINDOW_S < self._total_s + 1.0:
            thread = threading.Thread(target=self._render_ahead, args=(key,), name="steval-motion", daemon=True)
            self._ahead = key, thread
            thread.start()

    def _render_ahead(self, key: tuple[int, float | None]) -> None:
        with contextlib.suppress(Exception):  # (rendered again, and raised, where it is needed)
            self._windows[key] = self._render(*key)

    def _render(self, w: int, first_tick_s: float | None) -> tuple:
        """Window ``w``: its first tick, the acc and gyro counts, the remote's thr, sticks, armed and joydata (BROAD:
        trial time 0 at ``first_tick_s``, else at 1 s)."""
        n = _WINDOW_TICKS
        k0 = w * n
        t = (k0 + np.arange(n)) * C.TICK_PERIOD_S
        rng = np.random.default_rng([self.seed, 3, w])
        if self.trial is not None:
            t0 = first_tick_s if first_tick_s is not None else 1.0
            prof = M.broad_profile(self.trial, t0 + np.clip(t - t0, 0.0, self.trial.t_s[-1]), t0, self._thr_fn)
            acc, gyro = prof.acc_mg, prof.gyro_mdps
        else:
            prof = M.render(self.name, self._kin, t, rng, self._thr_fn)
            s = self.sensor
            acc = prof.acc_mg + np.asarray(s.acc_bias_mg) + s.acc_noise_mg * rng.standard_normal((n, 3))
            u, inv = np.unique(sm.gyro_hold_index(t), return_inverse=True)  # noise held like the 416 Hz reading
            noise = rng.standard_normal((len(u), 3))[inv]
            gyro = prof.gyro_mdps + np.asarray(s.gyro_bias_mdps) + s.gyro_noise_mdps * noise
        if self._mount is not None:
            acc, gyro = acc @ self._mount.T, gyro @ self._mount.T
        acc, gyro = body_to_sensor_counts(acc, gyro)
        return k0, acc, gyro, prof.thr, prof.sticks, prof.armed, _joydata_table(prof.thr, prof.sticks, prof.armed)

    def _at(self, k: int) -> int:
        w = max(k, 0) // _WINDOW_TICKS
        if w != self._window:
            self._window = w
            self._k0, self._acc, self._gyro, self._thr, self._sticks, self._armed, self._joydata = self._rendered(w)
        return max(k, 0) - self._k0

    def counts(self, k: int):
        i = self._at(k)
        return self._acc[i], self._gyro[i]

    def remote(self, k: int) -> tuple[int, tuple[int, int, int], bool]:
        """gTHR, (gAIL, gELE, gRUD) and the arming switch the remote sets at tick ``k``."""
        i = self._at(k)
        sticks = (0, 0, 0) if self._sticks is None else tuple(int(v) for v in self._sticks[i])
        armed = False if self._armed is None else bool(self._armed[i])
        return int(self._thr[i]), sticks, armed

    def remote_bytes(self, k: int) -> tuple[int, bytes]:
        """At tick ``k``: 1 if the remote moves (throttle or arming) else 0, and its ``joydata[2..7]``."""
        j = 7 * self._at(k)
        return self._joydata[j + 6], self._joydata[j : j + 6]


@dataclass
class EmulationReport:
    """What the run measured (instruction counts of this emulator, not Cortex-M4 cycles)."""

    elf: str
    emulated_s: float
    instructions: int
    skipped_instructions: int
    interrupts: dict[str, int]
    usart_bytes: int
    first_attitude_s: float | None
    tim9_start_s: float | None
    ahrs_steps: int
    step_instructions: list[int] = field(default_factory=list)
    dwt_windows: list[int] = field(default_factory=list)
    wall_s: float = 0.0  #: wall seconds spent in :meth:`Emulation.chunks` (not the consumer)

    def lines(self) -> list[str]:
        out = [
            f"emulated {self.emulated_s:.3f} s of {Path(self.elf).name}: {self.usart_bytes} USART1 bytes, "
            f"{self.ahrs_steps} AHRS steps, {self.instructions:,} instructions executed "
            f"(+{self.skipped_instructions:,} idle skipped)"
        ]
        if self.tim9_start_s is not None:
            out.append(
                f"TIM9 started at {self.tim9_start_s:.4f} s; first attitude step at "
                + (f"{self.first_attitude_s:.4f} s" if self.first_attitude_s is not None else "-")
            )
        stats = {
            "instructions per AHRS step (ahrs_fusion_ag + QuaternionToEuler, interrupts excluded; instruction counts, "
            "not M4 cycles)": self.step_instructions,
            "firmware DWT window (CYCCNT delta, = emulated instructions incl. interrupts; "
            "status cyc_*)": self.dwt_windows,
        }
        for what, values in stats.items():
            if any(values):
                a = np.asarray(values)
                out.append(f"{what}: min {a.min()} median {int(np.median(a))} max {a.max()}")
        return [*out, "interrupts: " + ", ".join(f"{k} {v}" for k, v in sorted(self.interrupts.items()))]


_EXC_NAMES = {15: "SysTick", 40: "TIM9", 44: "TIM2", 53: "USART1", 26: "EXTI4"}


def joydata_bytes(thr: int, ail: int, ele: int, rud: int, armed: bool) -> bytes:
    """``joydata[2..7]`` of ST's BLE app for these stick values (the inverse of main.c's conversion, to the
    nearest step of 13): rudder, throttle, aileron, elevator, seek bar (0), buttons (bit 2 armed)."""
    return _joydata_table([thr], [[ail, ele, rud]], [armed])[:6]


def _joydata_table(thr, sticks, armed) -> bytes:
    """:func:`joydata_bytes` of each tick (values as int), 7 bytes a tick: the six, then 1 where the remote moves."""
    thr_i = np.trunc(np.asarray(thr, np.float64))
    rud = ail = ele = np.zeros(len(thr_i))
    if sticks is not None:
        ail, ele, rud = np.trunc(np.asarray(sticks, np.float64)).T
    on = np.zeros(len(thr_i), bool) if armed is None else np.asarray(armed, bool)
    out = np.zeros((len(thr_i), 7), np.uint8)
    out[:, :4] = np.clip(np.rint(np.stack([128 - rud / 13, thr_i / 13, 128 - ail / 13, 128 + ele / 13], 1)), 0, 255)
    out[:, 5] = np.where(on, 0x04, 0)
    out[:, 6] = (thr_i != 0) | on
    return out.tobytes()


class Emulation:
    """One firmware run (see the module docstring)."""

    def __init__(
        self, options: EmulationOptions, *, bluenrg=None, tick_start_ms: int = 0, ble_connect_s: float | None = None
    ) -> None:
        """``bluenrg``: an ``ble_capture.EmulatedBlueNrg`` answering HCI requests; ``tick_start_ms``: ``uwTick`` at
        ``main``; ``ble_connect_s``: a central (not the remote) connects at this emulated time."""
        self.options = options
        self._connect_at = None if ble_connect_s is None else int(ble_connect_s * C.CPU_HZ)
        if options.duration_s is not None and not (options.duration_s > 0 and math.isfinite(options.duration_s)):
            raise ParamError(
                f"{{duration_s}} must be a positive number of seconds, got {options.duration_s}", "duration_s"
            )
        self.elf = Elf(options.elf)
        trial = options.broad  # a path, or already loaded (e.g. cut short by steval evaluate)
        if trial is not None and not isinstance(trial, BroadTrial):
            trial = load_trial(trial)
        name = options.scenario if trial is None else trial.name
        default = scenario(name, "or {broad} TRIAL.npz").default_duration_s if trial is None else trial.t_s[-1] + 3.0
        self.duration_s = float(options.duration_s if options.duration_s is not None else default)
        self.motion = ScenarioMotion(name, self.duration_s, options.seed, options.throttle, trial, options.mount)
        self.bus = SensorBus(self.motion, log_limit=options.log_samples)
        try:
            import unicorn  # noqa: F401
        except ImportError:
            raise UserError("steval emulate needs unicorn: pip install unicorn (or steval-link[test])") from None
        self.board = Board(self.elf, self.bus, skip_idle=options.skip_idle)
        self._joy = self.elf.addr("joydata")
        self._connected = self.elf.by_name.get("connected")
        self._remote_connected = False
        self.board.tick_observers.append(self._on_tick)
        self.board.tick_planner = self.plan_ticks
        self._steps: list[int] = []
        #: called with a board ``Mark`` (the clock, the counters, the ``STEP_RAM`` globals) of each AHRS step's start
        #: (``ahrs_fusion_ag`` entry) and end (Euler angles computed), after the slice that ran it
        self.step_start_observers: list[Callable[[Mark], None]] = []
        self.step_end_observers: list[Callable[[Mark], None]] = []
        self._dwt: list[int] = []
        self._step_start = None  # (instructions, exception instructions, CYCCNT) at the step's start
        self._first_step_s: float | None = None
        self.n_steps = 0
        self._wall_s = 0.0
        self._bytes = 0
        self._live_tx: queue.SimpleQueue = queue.SimpleQueue()  # (bytes, emulated s or None) for the next slice
        self._host_sched: list[tuple[int, int, bytes]] = []  # heap of (instruction count, order, bytes) to send
        self._host_sent: list[tuple[bytes, float]] = []  # (bytes, emulated s) gone on the line, not yet taken
        self._host_order = itertools.count()
        self._hold: tuple[int, threading.Event] | None = None  # (instruction count, the event to wait for there)
        self._install_step_probes()
        self.board.hci_handler = bluenrg
        tick, main = self.elf.addr("uwTick"), self.elf.addr("main")
        if tick_start_ms and tick is not None and main is not None:  # after the startup code zeroed .bss
            start = int(tick_start_ms) & 0xFFFFFFFF
            self.board.probe(main, lambda board: board.ram_write(tick, start.to_bytes(4, "little")))

    def send_at(self, data: bytes, t_s: float) -> None:
        """Schedule ``data`` (host → drone) on the RX line at emulated time ``t_s`` (s), after what is before it."""
        if not data:
            return
        _check_time_s(t_s)
        t = max(int(round(t_s * C.CPU_HZ)), self.board.now)
        self.board.usart1.inject(bytes(data), t)
        heapq.heappush(self._host_sched, (t, next(self._host_order), bytes(data)))

    def send(self, data: bytes, at_s: float | None = None) -> None:
        """Queue ``data`` (host → drone) from any thread, for :meth:`send_at` at the start of the next slice: at
        emulated time ``at_s`` (s), or then."""
        if at_s is not None:
            _check_time_s(at_s)
        if data:
            self._live_tx.put((bytes(data), at_s))

    def hold(self, t_s: float, until: threading.Event) -> None:
        """Wait before the slice that passes emulated time ``t_s`` until ``until`` is set (another thread then has
        queued with :meth:`send` what is due from ``t_s`` on)."""
        self._hold = int(round(t_s * C.CPU_HZ)), until

    def take_host_bytes(self) -> list[tuple[bytes, float]]:
        """The host → drone blocks that went on the line since the last call, with their emulated start times (s)."""
        out, self._host_sent = self._host_sent, []
        return out

    def _host_progress(self) -> None:
        while not self._live_tx.empty():  # this thread is the one consumer
            data, at_s = self._live_tx.get_nowait()
            self.send_at(data, self.board.now / C.CPU_HZ if at_s is None else at_s)
        now = self.board.now
        while self._host_sched and self._host_sched[0][0] <= now:
            t, _, data = heapq.heappop(self._host_sched)
            self._host_sent.append((data, t / C.CPU_HZ))

    def _on_tick(self, board: Board) -> None:
        motion = self.motion
        if motion.trial is not None and motion.first_tick_s is None:
            motion.first_tick_s = board.now / C.CPU_HZ
            motion._window = -1  # render again with trial time 0 at this tick
        if self._joy is None:
            return
        moves, joy = motion.remote_bytes(self.bus.tick_index(board) + 1)
        if not self._remote_connected and self._connected is not None:
            central = self._connect_at is not None and board.now >= self._connect_at
            if moves or central or motion.remote_from_start:
                # ST's main loop takes gTHR from joydata only while `connected` (and then sends BLE notifications)
                board.ram_write(self._connected.addr, (1).to_bytes(max(self._connected.size, 1), "little"))
                self._remote_connected = True
        cols = slice(0, 6) if self._remote_connected else slice(1, 2)  # before: the throttle's byte only
        board.ram_write(self._joy + 2 + cols.start, joy[cols])

    def plan_ticks(self, board: Board) -> tuple | None:
        """The next TIM9 updates as tables (updates n, LSM6DSL outputs 0x22..0x2D (n, 12) uint8, RAM address, remote
        bytes (n, m) uint8, the instruction count it holds until or None); None: the next needs :meth:`_on_tick`."""
        m = self.motion
        k = self.bus.tick_index(board) + 1  # the next update's sensor row (the remote reads the one after)
        i = k - m._k0 if m._window >= 0 and k - m._k0 < _WINDOW_TICKS else -1
        n = _WINDOW_TICKS - 1 - i
        if i < 0 or n <= 0 or (self._joy is not None and not self._remote_connected and m.remote_from_start):
            return None
        rows, until = np.frombuffer(m._joydata, np.uint8).reshape(-1, 7)[i + 1 : i + 1 + n], None
        if self._joy is not None and not self._remote_connected and self._connected is not None:
            moves = np.flatnonzero(rows[:, 6])  # the remote connects at its first move, or a central at _connect_at
            n, until = (int(moves[0]) if len(moves) else n), self._connect_at
        if n <= 0:
            return None
        addr = 0 if self._joy is None else self._joy + (2 if self._remote_connected else 3)
        cols = slice(0, 0) if self._joy is None else slice(0, 6) if self._remote_connected else slice(1, 2)
        img = np.concatenate([m._gyro[i : i + n], m._acc[i : i + n]], 1).astype("<i2").view(np.uint8)
        return n, np.ascontiguousarray(img), addr, np.ascontiguousarray(rows[:n, cols]), until

    def _install_step_probes(self) -> None:
        b, e = self.board, self.elf
        # ST's filter; else the patch's hook right before it (a build whose filter function has another name)
        start = e.addr("ahrs_fusion_ag") or e.addr("stv_fw_step_begin")
        end = e.addr("stv_fw_step_end") or e.addr("GetTargetEulerAngle")
        if start is not None and end is not None:
            ram = [(e.addr(name), n) for name, n in STEP_RAM if e.addr(name) is not None]
            b.mark_ram([(a, n) for a, n in ram if in_ram(a, n)])
            b.mark(start, _STEP_START)
            b.mark(end, _STEP_END)

    def _take_steps(self) -> None:
        """The AHRS steps' marks of the last slice to the step observers, in order."""
        for m in self.board.take_marks():
            (self._on_step_start if m.kind == _STEP_START else self._on_step_end)(m)

    def _on_step_start(self, m: Mark) -> None:
        self._step_start = (m.instructions, m.exception_instructions, m.cyccnt)
        if self._first_step_s is None:
            self._first_step_s = m.now / C.CPU_HZ
        for ob in self.step_start_observers:
            ob(m)

    def _on_step_end(self, m: Mark) -> None:
        if self._step_start is None:
            return
        i0, x0, c0 = self._step_start
        n = m.instructions - i0 - (m.exception_instructions - x0)
        self.n_steps += 1
        if len(self._steps) < 100_000:
            self._steps.append(n)
            self._dwt.append(m.cyccnt - c0)
        self._step_start = None
        for ob in self.step_end_observers:
            ob(m)

    def tick_index(self, mark: Mark | None = None) -> int:
        """Motion tick index of the latest TIM9 update (the sample the ISR last read), now or at ``mark``."""
        if mark is None:
            return self.bus.tick_index(self.board)
        return self.bus.tick_index(self.board, updates=mark.tim9_updates, now=mark.now)

    def tick_time_s(self, k) -> np.ndarray | float:
        """Emulated time (s since power-up) of motion tick ``k``'s TIM9 update (after TIM9 started)."""
        first = self.board.tim9.first_update
        if first is None:
            raise ValueError("TIM9 has not started")
        return (first + (np.asarray(k) - (self.bus.tick_offset or 0)) * C.TICK_CYCLES) / C.CPU_HZ

    def trial_time_s(self, k) -> np.ndarray | float:
        """BROAD runs: trial time (s) of motion tick ``k``, not clipped (a caller tells the ticks outside the trial)."""
        if self.motion.first_tick_s is None:
            raise ValueError("TIM9 has not started")
        return np.asarray(k) * C.TICK_PERIOD_S - self.motion.first_tick_s

    def chunks(self, slice_s: float = 0.05, stop: threading.Event | None = None) -> Iterator[tuple[bytes, float]]:
        """Run to the end (or to the slice in which ``stop`` is set); yield (USART1 bytes, emulated time of the last
        byte, s) of every ``slice_s`` emulated that has some."""
        b = self.board
        end = int(round(self.duration_s * C.CPU_HZ))
        last_byte_t = last_steps = last_progress_t = 0
        slice_cycles = int(min(slice_s, self.options.watchdog_s / 4) * C.CPU_HZ)
        if b.now == 0:
            self.motion.render_first()
        while b.now < end and not (stop is not None and stop.is_set()):
            if self._hold is not None and b.now + slice_cycles >= self._hold[0]:
                self._hold[1].wait()
                self._hold = None
                if stop is not None and stop.is_set():  # (released by a stop, not by the commands)
                    break
            self._host_progress()
            t0 = time.perf_counter()
            try:
                b.run_until(min(end, b.now + slice_cycles))
            finally:  # (the steps before a fault too)
                self._take_steps()
            self._wall_s += time.perf_counter() - t0
            self._host_progress()
            data, _, last_t = b.take_output()
            if data:
                last_byte_t = last_t
                self._bytes += len(data)
                yield data, last_byte_t / C.CPU_HZ
            if self.n_steps != last_steps:
                last_steps, last_progress_t = self.n_steps, b.now
            if b.now - max(last_byte_t, last_progress_t) > self.options.watchdog_s * C.CPU_HZ:
                raise FirmwareStuck(
                    f"no USART1 output and no AHRS step for {self.options.watchdog_s:g} s of emulated time "
                    f"(t = {b.now / C.CPU_HZ:.3f} s); {b.describe_cpu()}"
                )

    def run(self) -> bytes:
        """Run to the end; all USART1 bytes."""
        return b"".join(d for d, _ in self.chunks())

    def motor_ccr(self) -> tuple[int, int, int, int]:
        """TIM4 CCR1..4: the motor outputs the firmware last wrote (``set_motor_pwm``: counts of the 2000-count
        period, clamped to 0..1900)."""
        regs = self.board.tim4.regs
        return tuple(int(regs.get(off, 0)) for off in (0x34, 0x38, 0x3C, 0x40))

    def report(self) -> EmulationReport:
        b = self.board
        return EmulationReport(
            elf=str(self.elf.path),
            emulated_s=b.now / C.CPU_HZ,
            instructions=b.stats.instructions,
            skipped_instructions=b.stats.skipped_instructions,
            interrupts={_EXC_NAMES.get(k, f"exception {k}"): v for k, v in b.stats.interrupts.items()},
            usart_bytes=self._bytes,
            first_attitude_s=self._first_step_s,
            tim9_start_s=None if b.tim9.first_update is None else b.tim9.first_update / C.CPU_HZ,
            ahrs_steps=self.n_steps,
            step_instructions=list(self._steps),
            dwt_windows=list(self._dwt),
            wall_s=self._wall_s,
        )


__all__ += ["EmulationError"]

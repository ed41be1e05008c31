"""A firmware ELF scored against ground truth (``steval evaluate --firmware``) on the emulated board fed with a BROAD
trial's motion: its own ``thx``/``thy`` (pitch about x, roll about y) per AHRS step, scored like the estimators.

Its output comes from its attitude frames (frame step ``i`` is AHRS step ``i``), else from its globals read by symbol:
``euler_ahrs`` and ``ahrs`` when a step ends, ``acc_ahrs``/``gyro_ahrs`` (mg/mdps) and ``gTHR`` when it starts.
Metric: the inclination error of ``quaternion_from_euler(thx, thy, 0)`` against the per-step truth, RMSE in degrees
over the movement steps; the replica runs on the firmware's own inputs. Cost: emulated instructions, not M4 cycles."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from steval_link import constants as C
from steval_link.analysis.report import Coverage, coverage_of, on_rows
from steval_link.emulation.broad import BroadTrial, StepTruth, TruthRows, score_euler
from steval_link.emulation.runner import Emulation, EmulationOptions
from steval_link.emulation.symbol_attitude import SymbolAttitude, elf_filter_variant
from steval_link.errors import ParamError, UserError
from steval_link.estimators import firmware_replay, st_mahony
from steval_link.estimators.st_mahony import MahonySettings
from steval_link.link.decoder import decode_bytes

_F32 = np.float32


def _on_rows(n: int, rows, values) -> np.ndarray:
    return on_rows(n, rows, values, dtype=_F32)


def firmware_labels(paths: Sequence[Path | str]) -> list[str]:
    """Table labels of firmware ELFs: ``fw:`` and the shortest path suffix that tells them apart (``fw:a.elf``, or
    ``fw:stock/steval-reference.elf`` next to ``fw:lab/steval-reference.elf``). The same file twice: UserError."""
    resolved = [Path(p).resolve() for p in paths]
    seen: dict[Path, str] = {}
    for p, given in zip(resolved, paths):
        if p in seen:
            raise ParamError(f"{{firmware}} {given} is given twice (as {seen[p]})", "firmware")
        seen[p] = str(given)
    parts = [p.parts for p in resolved]
    labels = []
    for i, ps in enumerate(parts):
        for n in range(1, len(ps) + 1):
            suffix = ps[-n:]
            if all(other[-n:] != suffix for j, other in enumerate(parts) if j != i):
                break
        labels.append("fw:" + "/".join(suffix))
    return labels


def cut_trial(trial: BroadTrial, max_seconds: float | None) -> BroadTrial:
    """The first ``max_seconds`` of ``trial`` (the whole trial when None or longer)."""
    if max_seconds is None:
        return trial
    n = int(math.floor(max_seconds * trial.fs_hz)) + 1
    if n >= trial.acc_mps2.shape[0]:
        return trial
    cut = slice(max(n, 2))
    return replace(trial, **{k: getattr(trial, k)[cut] for k in ("acc_mps2", "gyr_radps", "quat_wxyz", "movement")})


@dataclass
class FirmwareResult:
    """One firmware on one trial: ``source`` "frames" or "globals" (by symbol); ``thx_rad``, ``thy_rad`` (M,) float32
    per step (NaN: none), scored over the movement steps; ``instructions`` per AHRS step; the replica on its inputs."""

    label: str
    elf: str
    trial: str
    source: str
    truth: TruthRows
    thx_rad: np.ndarray
    thy_rad: np.ndarray
    err_rad: np.ndarray
    rmse_deg: float
    instructions: np.ndarray
    replica_rmse_deg: float | None = None
    replica_bit_exact: int = 0
    replica_steps: int = 0
    settings: MahonySettings | None = None
    emulated_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    gains: str = ""
    wall_s: float = 0.0  # the whole run_firmware (emulation, decoding, scoring), s

    @property
    def steps(self) -> int:
        return len(self.truth)

    @property
    def coverage(self) -> Coverage:
        """The share of the movement steps with truth its own attitude covered, where it diverged."""
        ok = np.isfinite(self.thx_rad) & np.isfinite(self.thy_rad)
        scored = np.asarray(self.truth.movement, bool) & np.isfinite(self.truth.q_wxyz).all(axis=1)
        return coverage_of(ok, scored, self.truth.step, self.truth.t_trial_s)

    def instructions_summary(self) -> dict[str, float | None]:
        a = self.instructions
        if a.size == 0:
            return dict.fromkeys(("median", "mean", "min", "max"))
        return {
            "median": float(np.median(a)),
            "mean": round(float(np.mean(a)), 1),
            "min": int(a.min()),
            "max": int(a.max()),
        }


def gains_text(settings: MahonySettings | None, thr, *, from_status: bool) -> str:
    """The gains a run used, in words: ``kp 10 (ground: thr < 200), ki 0.1, dt 6.25 ms (its status frames)``."""
    st = settings or MahonySettings()
    t = np.asarray(thr).reshape(-1)
    ground = t < st.min_thr
    if t.size and ground.all():
        kp = f"kp {st.kp_ground:g} (ground: thr < {st.min_thr})"
    elif t.size and not ground.any():
        kp = f"kp {st.kp_flight:g} (flight: thr >= {st.min_thr})"
    elif t.size:
        share = 100.0 * np.count_nonzero(ground) / t.size
        kp = f"kp {st.kp_ground:g} on {share:.0f} % of the steps (thr < {st.min_thr}), else {st.kp_flight:g}"
    else:
        kp = f"kp {st.kp_ground:g}/{st.kp_flight:g}"
    where = "its status frames" if from_status and settings is not None else "ST's defaults, assumed"
    extra = "" if st.correction else ", no accelerometer correction"
    return f"{kp}, ki {st.ki:g}, dt {st.dt_s * 1e3:g} ms{extra} ({where})"


def _globals_replica(inp: np.ndarray, out: np.ndarray, has_q: bool, first: str | None):
    """(settings, thx, thy, bit-exact per step) of the release bit-exact on the most steps (``first`` wins a tie)."""
    best = None
    for v in [first] + [v for v in st_mahony.VARIANTS if v != first] if first else list(st_mahony.VARIANTS):
        settings = MahonySettings(variant=v)
        q, px, py, _ = st_mahony.run(
            inp[:, 0:3].astype(_F32), inp[:, 3:6].astype(_F32), inp[:, 6].astype(np.int64), settings=settings
        )
        exact = (
            st_mahony.bits_equal(px, out[:, 0])
            & st_mahony.bits_equal(py, out[:, 1])
            & (st_mahony.bits_equal(q, out[:, 2:6]).all(axis=1) if has_q else True)
        )
        if best is None or exact.sum() > best[3].sum():
            best = (settings, px, py, exact)
    return best


def run_firmware(
    elf: Path | str,
    trial: BroadTrial,
    *,
    label: str | None = None,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
    variant: str | None = None,
) -> FirmwareResult:
    """Run ``elf`` on the emulated board fed with ``trial`` (to 3 s past its end) and score its attitude output; the
    replica runs the filter of ``variant``, else of the release the ELF's code or the data shows."""
    t0 = time.perf_counter()
    emu = Emulation(EmulationOptions(elf=elf, broad=trial, seed=seed))
    elf_variant, _ = elf_filter_variant(emu.elf)
    truth_rec = StepTruth(emu)
    symbols = SymbolAttitude(emu)  # the filter's globals each AHRS step
    label = label or "fw:" + Path(elf).name
    data, report = _emulate(emu, f"{label} on {trial.name}", progress)
    n = min(len(truth_rec.last_ticks), report.ahrs_steps)  # the steps that ran to their end
    if n == 0:
        if emu.elf.addr("ahrs_fusion_ag") is None and emu.elf.addr("stv_fw_step_begin") is None:
            raise UserError(
                f"{elf}: no ahrs_fusion_ag or stv_fw_step_begin symbol, so its AHRS steps cannot be "
                "told apart (an ELF with its symbols, not a stripped one)"
            )
        raise UserError(f"{elf}: the firmware made no AHRS step in {emu.duration_s:g} s on the emulated board")
    truth = truth_rec.rows(0, n)
    steps = symbols.take()[:n]
    tel = decode_bytes(bytes(data)) if data else None
    if tel is not None and np.count_nonzero(tel.attitude.exact):
        hint = (elf_variant, "firmware ELF") if elf_variant is not None else None
        out = _output_of_frames(tel, symbols, steps, truth, n, variant, hint)
    elif symbols.addr["euler_ahrs"] is not None:
        out = _output_of_globals(symbols, steps, n, variant or elf_variant)
    else:
        raise UserError(
            f"{elf}: no attitude frames on USART1 and no euler_ahrs symbol to read the attitude from "
            "(an ELF with its symbols, not a stripped .bin/.hex)"
        )
    err, rmse = score_euler(out.thx, out.thy, truth.q_wxyz, truth.movement)
    instructions = np.asarray(report.step_instructions, np.int64)
    res = FirmwareResult(label, str(elf), trial.name, out.source, truth, out.thx, out.thy, err, rmse, instructions)
    res.settings = out.settings
    res.emulated_s = report.emulated_s
    res.notes = out.notes
    res.gains = out.gains
    res.wall_s = time.perf_counter() - t0
    if out.replica_thx is not None:
        _, res.replica_rmse_deg = score_euler(out.replica_thx, out.replica_thy, truth.q_wxyz, truth.movement)
        res.replica_bit_exact, res.replica_steps = out.replica_exact, out.replica_steps
    return res


def _emulate(emu: Emulation, what: str, progress: Callable[[float], None] | None):
    """Run the emulation to its end: (the USART1 bytes, the emulation's report); its UserError names ``what``."""
    if progress is not None:  # every ≈ 1 s of AHRS steps (an unpatched build sends next to nothing on USART1)

        def on_step(mark) -> None:
            if emu.n_steps % 160 == 0:
                progress(min(mark.now / C.CPU_HZ / emu.duration_s, 1.0))

        emu.step_end_observers.append(on_step)
    data = bytearray()
    try:
        for chunk, _ in emu.chunks():
            data += chunk
    except UserError as exc:  # stuck, or hardware the emulator does not model: say which firmware
        raise UserError(f"{what}: {exc}") from None
    return data, emu.report()


@dataclass
class _Output:
    """The firmware's thx/thy per AHRS step (NaN: not seen), where they came from, and the replica's."""

    source: str
    thx: np.ndarray
    thy: np.ndarray
    gains: str
    settings: MahonySettings | None = None
    replica_thx: np.ndarray | None = None
    replica_thy: np.ndarray | None = None
    replica_exact: int = 0
    replica_steps: int = 0
    notes: list[str] = field(default_factory=list)


def _has_inputs(symbols: SymbolAttitude) -> bool:
    """The ELF has the filter's input globals (``acc_ahrs``, ``gyro_ahrs``)."""
    return symbols.addr["acc_ahrs"] is not None and symbols.addr["gyro_ahrs"] is not None


def _output_of_frames(tel, symbols: SymbolAttitude, steps, truth: TruthRows, n: int, variant, hint) -> _Output:
    """The attitude frames' thx/thy (frame step ``i`` = AHRS step ``i``) and the replica over their inputs;
    ``steps``: the first ``n`` steps read by symbol (``SYMBOL_DTYPE``)."""
    att = tel.attitude
    rows = np.flatnonzero(np.asarray(att.exact) & (att.step >= 0) & (att.step < n))
    frame_steps = np.asarray(att.step)[rows]
    lost = np.asarray(truth.movement, bool) & ~np.isin(np.arange(n), frame_steps)
    notes = [f"{int(lost.sum())} movement steps without an attitude frame (not scored)"] if lost.any() else []
    if _has_inputs(symbols) and len(steps) >= n:  # frame i is AHRS step i: its inputs say so
        if not np.array_equal(steps["acc_mg"][frame_steps], np.asarray(att.acc_mg, np.float32)[rows]):
            notes.append("the frames' inputs differ from acc_ahrs at the steps counted: the truth may be misaligned")
    rep = firmware_replay.replay_variants(tel, variant=variant, hint=hint).replay
    settings = rep.seeds[0].settings if rep.seeds else None
    return _Output(
        "frames",
        _on_rows(n, frame_steps, np.asarray(att.thx_rad, _F32)[rows]),
        _on_rows(n, frame_steps, np.asarray(att.thy_rad, _F32)[rows]),
        gains_text(settings, np.asarray(att.thr)[rows], from_status=settings is not None),
        settings,
        _on_rows(n, frame_steps, rep.thx_rad[rows]),
        _on_rows(n, frame_steps, rep.thy_rad[rows]),
        int(np.count_nonzero(rep.bit_exact[rows])),
        int(np.count_nonzero(rep.seeded[rows])),
        notes,
    )


def _output_of_globals(symbols: SymbolAttitude, steps, n: int, variant: str | None) -> _Output:
    """thx/thy read by symbol (``euler_ahrs``) and the replica over the inputs read by symbol, when there are any;
    ``steps``: the first ``n`` steps read by symbol (``SYMBOL_DTYPE``)."""
    out = np.column_stack([steps["euler_rad"][:, :2], steps["q_wxyz"]]).astype(np.float32).reshape(-1, 6)
    m = out.shape[0]
    has_inputs = _has_inputs(symbols)
    thr_in = steps["thr"].astype(np.float64) if has_inputs else []
    res = _Output("globals", _on_rows(n, slice(0, m), out[:, 0]), _on_rows(n, slice(0, m), out[:, 1]),
                  gains_text(None, thr_in, from_status=False))  # fmt: skip
    if has_inputs and m:
        inp = np.column_stack([steps["acc_mg"], steps["gyro_mdps"], steps["thr"]]).astype(np.float64)
        res.settings, px, py, exact = _globals_replica(inp, out, symbols.addr["ahrs"] is not None, variant)
        res.replica_thx, res.replica_thy = _on_rows(n, slice(0, m), px), _on_rows(n, slice(0, m), py)
        res.replica_exact, res.replica_steps = int(np.count_nonzero(exact)), m
    return res

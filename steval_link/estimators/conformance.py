"""Firmware conformance vectors: load a CSV of ``ahrs_fusion_ag`` calls and check the replica against it, bit for bit.

A vector file has one ``#`` comment line, the header :data:`COLUMNS` and one row per AHRS step from power-up; every
number parses (as a double, cast to float32) to the firmware's exact value. :func:`variant_scores` finds the release.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass, replace
from pathlib import Path

import numpy as np

from steval_link.estimators.st_mahony import VARIANTS, MahonySettings, bits_equal, run

#: the header every vector file has
COLUMNS = tuple(
    "step,thr,acc_x_mg,acc_y_mg,acc_z_mg,gyro_x_mdps,gyro_y_mdps,gyro_z_mdps,q0,q1,q2,q3,thx_rad,thy_rad".split(",")
)


@dataclass(frozen=True)
class ConformanceVectors:
    """One vector file: inputs of each call and the firmware's outputs after it (float32, firmware units)."""

    path: Path
    description: str
    step: np.ndarray  # (N,) int64
    thr: np.ndarray  # (N,) int64, gTHR
    acc_mg: np.ndarray  # (N, 3) float32
    gyro_mdps: np.ndarray  # (N, 3) float32
    q_wxyz: np.ndarray  # (N, 4) float32, ahrs.q after the call
    thx_rad: np.ndarray  # (N,) float32, pitch (about x)
    thy_rad: np.ndarray  # (N,) float32, roll (about y)

    def __len__(self) -> int:
        return int(self.step.shape[0])


@dataclass(frozen=True)
class ConformanceResult:
    """How the replica compares with one vector file: ``max_abs_dq`` / ``max_abs_dth`` the largest |replica −
    firmware| where both are finite; ``nan_mismatches`` the values NaN on one side only."""

    name: str
    steps: int
    exact_steps: int
    max_abs_dq: float
    max_abs_dth: float
    nan_mismatches: int
    first_mismatch_step: int | None

    @property
    def ok(self) -> bool:
        return self.exact_steps == self.steps

    def as_dict(self) -> dict:
        """The fields under their JSON names, and ``ok``."""
        keys = "file steps bit_exact_steps max_abs_dq max_abs_dth_rad nan_mismatches first_mismatch_step".split()
        return {**dict(zip(keys, astuple(self))), "ok": self.ok}


def load_conformance_csv(path) -> ConformanceVectors:
    """Read a vector file; ValueError (one sentence naming the file) when it is not one."""
    path = Path(path)
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    rows = [line for line in lines if line.strip() and not line.startswith("#")]
    if not rows:
        raise ValueError(f"{path}: no header line (expected {','.join(COLUMNS)})")
    if tuple(h.strip() for h in rows[0].split(",")) != COLUMNS:
        raise ValueError(f"{path}: unexpected header {rows[0][:80]!r} (expected {','.join(COLUMNS)})")
    description = next((line.lstrip("#").strip() for line in lines[: lines.index(rows[0])] if line[:1] == "#"), "")
    if len(rows) < 2:
        raise ValueError(f"{path}: no data rows")
    try:
        data = np.loadtxt(rows[1:], delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{path}: malformed data row ({exc})") from None
    if data.shape[1] != len(COLUMNS):
        raise ValueError(f"{path}: rows have {data.shape[1]} columns, expected {len(COLUMNS)}")
    step_thr = data[:, :2]
    if not np.all(np.isfinite(step_thr)) or np.any(step_thr != np.round(step_thr)):
        raise ValueError(f"{path}: the step and thr columns must hold integers")
    f32 = data.astype(np.float32)  # acc_mg, gyro_mdps, q_wxyz, thx_rad, thy_rad: the columns after step and thr
    floats = [np.ascontiguousarray(f32[:, cols]) for cols in (slice(2, 5), slice(5, 8), slice(8, 12), 12, 13)]
    return ConformanceVectors(path, description, data[:, 0].astype(np.int64), data[:, 1].astype(np.int64), *floats)


def _max_abs(a: np.ndarray, b: np.ndarray) -> float:
    both = np.isfinite(a) & np.isfinite(b)
    return float(np.max(np.abs(a[both].astype(np.float64) - b[both].astype(np.float64)), initial=0.0))


def check_conformance(
    vectors: ConformanceVectors, settings: MahonySettings | None = None, *, native: bool | None = None
) -> ConformanceResult:
    """Run the replica from the power-up state over the file's inputs and compare every output bit."""
    q, thx, thy, _ = run(vectors.acc_mg, vectors.gyro_mdps, vectors.thr, settings=settings, native=native)
    exact = bits_equal(q, vectors.q_wxyz).all(axis=1) & bits_equal(thx, vectors.thx_rad)
    exact &= bits_equal(thy, vectors.thy_rad)
    bad = np.flatnonzero(~exact)
    pairs = ((q, vectors.q_wxyz), (thx, vectors.thx_rad), (thy, vectors.thy_rad))
    nan_mism = sum(int(np.count_nonzero(np.isnan(a) != np.isnan(b))) for a, b in pairs)
    return ConformanceResult(
        name=vectors.path.name,
        steps=len(vectors),
        exact_steps=int(np.count_nonzero(exact)),
        max_abs_dq=_max_abs(q, vectors.q_wxyz),
        max_abs_dth=max(_max_abs(thx, vectors.thx_rad), _max_abs(thy, vectors.thy_rad)),
        nan_mismatches=nan_mism,
        first_mismatch_step=int(vectors.step[bad[0]]) if bad.size else None,
    )


def variant_scores(
    cases: list[ConformanceVectors], settings: MahonySettings | None = None, *, native: bool | None = None
) -> dict[str, int]:
    """Bit-exact steps over all ``cases`` of each of ``VARIANTS`` with ``settings``' constants."""
    base = settings or MahonySettings()
    return {
        variant: sum(check_conformance(c, replace(base, variant=variant), native=native).exact_steps for c in cases)
        for variant in VARIANTS
    }

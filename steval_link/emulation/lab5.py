"""The UMaine Lab 5 AHRS simulator: constant (optionally noisy) gyro and accelerometer inputs through an estimator.

With the default ``st-mahony`` estimator every iteration is bit-exact with the firmware (``lab5_baseline``
conformance vectors). Angles use the handout's names: ``eax`` = thx (pitch, about x), ``eay`` = thy (roll, about y),
``eaz`` = thz (yaw, the handout's ``atan2(2q1q2 + 2q0q3, q0² + q1² − q2² − q3²)``). Axes: x right, y forward, z up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from steval_link import constants as C
from steval_link.emulation.sensor_model import Lsm6dsl
from steval_link.estimators import registry
from steval_link.estimators.st_mahony import StMahony, handout_yaw

BASELINE_GYRO_MDPS = (1000.0, 2000.0, 4000.0)  #: Lab 5 baseline inputs
BASELINE_ACC_MG = (0.0, 0.0, 0.0)
TYPICAL_GYRO_NOISE_MDPS = Lsm6dsl.gyro_noise_mdps  #: LSM6DSL typical noise (Lab 5 appendix B), standard deviations
TYPICAL_ACC_NOISE_MG = Lsm6dsl.acc_noise_mg


@dataclass(frozen=True)
class SimulationResult:
    """Every iteration of a simulation run (N iterations)."""

    estimator: str  #: registry name of the estimator used
    options: dict  #: the estimator options the user gave (the timing passed is in ``estimator_dt_s``)
    dt_s: float  #: the simulation's period, s
    seed: int | None  #: the noise generator's seed (None when no noise was added)
    gyro_noise_mdps: float  #: noise standard deviation used, mdps
    acc_noise_mg: float  #: noise standard deviation used, mg
    step: np.ndarray  #: (N,) int64, 0-based iteration index
    acc_mg: np.ndarray  #: (N, 3) float32 inputs, mg
    gyro_mdps: np.ndarray  #: (N, 3) float32 inputs, mdps
    thr: np.ndarray  #: (N,) int64 throttle
    q_wxyz: np.ndarray  #: (N, 4) quaternion after each iteration (float32 for st-mahony, bit-exact)
    eax_rad: np.ndarray  #: (N,) thx, pitch about x
    eay_rad: np.ndarray  #: (N,) thy, roll about y
    eaz_rad: np.ndarray  #: (N,) thz, yaw about z
    valid: np.ndarray  #: (N,) bool, the estimator's validity flag
    settings: dict = field(default_factory=dict)
    estimator_dt_s: float | None = None  #: the period the estimator integrates with, s (None: accel, or unsaid)

    @property
    def iterations(self) -> int:
        return int(self.step.shape[0])

    @property
    def t_s(self) -> np.ndarray:
        """(N,) float64, simulated time after each iteration, s."""
        return (self.step + 1) * float(self.dt_s)

    def final_angles_rad(self) -> tuple[float, float, float]:
        """(eax, eay, eaz) after the last iteration, rad (NaN when there was none)."""
        if self.iterations == 0:
            return (float("nan"),) * 3
        return float(self.eax_rad[-1]), float(self.eay_rad[-1]), float(self.eaz_rad[-1])


def _vector3(values, what: str) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ValueError(f"{what} needs 3 finite values, got {list(np.ravel(values))}")
    return v


def run_simulation(
    *,
    gyro_mdps=BASELINE_GYRO_MDPS,
    acc_mg=BASELINE_ACC_MG,
    iterations: int = 100,
    gyro_noise_mdps: float = 0.0,
    acc_noise_mg: float = 0.0,
    seed: int | None = None,
    throttle: int = 0,
    estimator: str = "st-mahony",
    estimator_options: dict | None = None,
    dt_s: float | None = None,
) -> SimulationResult:
    """``iterations`` steps of constant inputs (gyro mdps, acc mg, throttle ``gTHR``) plus white Gaussian noise of
    these standard deviations, from power-up. ``seed`` None draws one (recorded). ``dt_s`` (None: 6.25 ms) is the
    estimator's period unless its options set their own. ValueError for bad inputs, estimators or options."""
    gyro, acc = _vector3(gyro_mdps, "gyro"), _vector3(acc_mg, "acc")
    iterations, throttle, dt = _check(iterations, gyro_noise_mdps, acc_noise_mg, throttle, dt_s)
    gyro, acc = np.tile(gyro, (iterations, 1)), np.tile(acc, (iterations, 1))
    given = dict(estimator_options or {})  # the user's options: the run's label
    options = dict(given)
    own = {} if estimator in registry.ESTIMATORS else dict(registry.resolve(estimator).reference.options)
    options.update({k: v for k, v in _timing(estimator, dt).items() if k not in options and k not in own})
    est = registry.create(estimator, **options)

    noisy = gyro_noise_mdps > 0 or acc_noise_mg > 0
    if noisy:
        seed = int(np.random.SeedSequence().entropy % (1 << 32)) if seed is None else seed
        rng = np.random.default_rng(seed)
        gyro = gyro + rng.normal(0.0, float(gyro_noise_mdps), size=gyro.shape)
        acc = acc + rng.normal(0.0, float(acc_noise_mg), size=acc.shape)
    gyro_in, acc_in = gyro.astype(np.float32), acc.astype(np.float32)
    thr = np.full(iterations, throttle, dtype=np.int64)
    est.reset()
    res = est.run(acc_in, gyro_in, thr)
    if isinstance(est, StMahony):
        eaz = handout_yaw(res.q_wxyz)  # float32, as the Lab 5 simulator's QuaternionToEuler computes it
        settings, est_dt = dict(est.settings.__dict__), float(est.settings.dt_s)
    else:
        eaz = np.asarray(res.thz_rad)  # NaN where the estimator has no yaw (e.g. accelerometer-only tilt)
        settings, est_dt = {}, _own_dt(est, {**own, **options})
    return SimulationResult(
        estimator=estimator,
        options=given,
        dt_s=dt,
        estimator_dt_s=est_dt,
        seed=seed if noisy else None,
        gyro_noise_mdps=float(gyro_noise_mdps),
        acc_noise_mg=float(acc_noise_mg),
        step=np.arange(iterations, dtype=np.int64),
        acc_mg=acc_in,
        gyro_mdps=gyro_in,
        thr=thr,
        q_wxyz=res.q_wxyz,
        eax_rad=res.thx_rad,
        eay_rad=res.thy_rad,
        eaz_rad=eaz,
        valid=res.valid,
        settings=settings,
    )


def _check(iterations, gyro_noise_mdps, acc_noise_mg, throttle, dt_s) -> tuple[int, int, float]:
    """(iterations, throttle, dt in s) of a run, checked; a ValueError naming the parameter when one is off."""
    iterations = int(iterations)
    if iterations < 0:
        raise ValueError(f"iterations must be ≥ 0, got {iterations}")
    for name, value in (("gyro noise", gyro_noise_mdps), ("acc noise", acc_noise_mg)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a standard deviation ≥ 0, got {value}")
    throttle = int(throttle)
    if not -32768 <= throttle <= 32767:
        raise ValueError(f"throttle is the firmware's int16 gTHR: −32768..32767, got {throttle}")
    dt = C.DT_S if dt_s is None else float(dt_s)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt_s must be a period > 0 s, got {dt_s}")
    return iterations, throttle, dt


def _timing(estimator: str, dt_s: float) -> dict:
    """The option that makes ``estimator`` integrate at ``dt_s``: ``dt_s``, ``rate_hz``, or none (accel)."""
    sel = registry.resolve(estimator)
    if sel.reference.kind == "builtin" and sel.reference.source == "st-mahony":
        return {"dt_s": dt_s}
    if registry.accepts(sel, "rate_hz"):
        return {"rate_hz": 1.0 / dt_s}
    return {}


def _own_dt(est, options: dict) -> float | None:
    """The period an estimator integrates with (its ``rate_hz`` option, else its ``dt``/``dt_s``), else None."""
    if "rate_hz" in options:
        return 1.0 / float(options["rate_hz"])
    inner = getattr(est, "inner", est)  # a user's estimator behind the guard
    for name in ("dt_s", "dt"):
        v = getattr(inner, name, None)
        if isinstance(v, (int, float)) and v > 0:
            return float(v)
    return None

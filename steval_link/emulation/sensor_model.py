"""LSM6DSL sensor model and the firmware's sensor pipeline (ST release 170120), as numpy functions.

1. LSM6DSL (:class:`Lsm6dsl`, :func:`quantise`): motion + bias + noise → int16 ADC counts → the ST driver's mg
   (0.122 mg/LSB, ±4 g) and mdps (70 mdps/LSB, ±2000 dps).
2. TIM9 ISR at ≈ 807.69 Hz: power-up calibration, offset removal, gyro IIR; acc and IIR output into 5-sample FIFOs.
3. Main loop every 5th tick (≈ 161.54 Hz): the boxcar average → ``acc_ahrs`` (mg), ``gyro_ahrs`` (mdps).

:func:`run_isr` runs 2–3. Arrays are (N, 3) in the firmware's axes: x right, y forward, z up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from steval_link import constants as C

_F32 = np.float32

CALIBRATION_SKIP_TICKS: int = 800  #: ticks ignored after power-up before the offset calibration starts
CALIBRATION_TICKS: int = 800  #: ticks summed for the offset calibration

#: gyro output data rate (CTRL2_G = 0x6C: 416 Hz, ±2000 dps); each tick reads the latest: a sample-and-hold
GYRO_ODR_HZ: float = 416.0


def gyro_hold_index(t_s, t0_s: float = 0.0, odr_hz: float = GYRO_ODR_HZ) -> np.ndarray:
    """(N,) int64 index of the output-register sample each time ``t_s`` (s) reads: ``floor((t − t0) · odr)``."""
    return np.floor((np.asarray(t_s, dtype=np.float64) - t0_s) * odr_hz + 1e-9).astype(np.int64)


def gyro_hold_times_s(t_s, t0_s: float = 0.0, odr_hz: float = GYRO_ODR_HZ) -> np.ndarray:
    """(N,) float64 time, s, at which the output register each time ``t_s`` reads was refreshed."""
    return t0_s + gyro_hold_index(t_s, t0_s, odr_hz) / odr_hz


ACC_SENSITIVITY_MG = 0.122  #: LSM6DSL ±4 g sensitivity, mg/LSB (``LSM6DSL_ACC_SENSITIVITY_FOR_FS_4G``)
GYRO_SENSITIVITY_MDPS = 70.0  #: LSM6DSL ±2000 dps sensitivity, mdps/LSB


#: the ISR's gyro IIR coefficients (a1, a2, b0, b1, b2) as the firmware's float32: Butterworth low-pass, 100 Hz
#: cut-off designed for 800 Hz; ``y = b0·x + b1·x1 + b2·x2 + a1·y1 + a2·y2`` (denominator ``1 − a1·z⁻¹ − a2·z⁻²``)
_IIR_F32 = tuple(
    _F32(v)
    for v in (0.94280904158206336, -0.33333333333333343, 0.09763107293781749, 0.19526214587563498, 0.09763107293781749)
)


@dataclass
class IirState:
    """Per-axis memory of the gyro IIR (float32, mdps): last two inputs and outputs. Zero at power-up."""

    x1: np.ndarray = field(default_factory=lambda: np.zeros(3, _F32))
    x2: np.ndarray = field(default_factory=lambda: np.zeros(3, _F32))
    y1: np.ndarray = field(default_factory=lambda: np.zeros(3, _F32))
    y2: np.ndarray = field(default_factory=lambda: np.zeros(3, _F32))


def adc_counts(value, sensitivity: float) -> np.ndarray:
    """ADC ``raw = round(value / sensitivity)`` saturated to int16 (NaN reads 0)."""
    raw = np.rint(np.nan_to_num(np.asarray(value, dtype=np.float64) / sensitivity))
    return np.clip(raw, -32768, 32767).astype(np.int16)


def driver_value(raw, sensitivity: float) -> np.ndarray:
    """The ST driver's ``(int32_t)(raw * sensitivity)``: int16 raw × float32 sensitivity, truncated toward 0."""
    return np.trunc(np.asarray(raw).astype(_F32) * _F32(sensitivity)).astype(np.int32)


def quantise(value, sensitivity: float) -> np.ndarray:
    """What the driver returns for a physical value (mg or mdps): int32, saturated at int16 counts; NaN reads 0."""
    return driver_value(adc_counts(value, sensitivity), sensitivity)


@dataclass(frozen=True)
class Lsm6dsl:
    """LSM6DSL as the STEVAL configures it (acc ±4 g, gyro ±2000 dps), read once per ISR tick. Noise: white, RMS
    per reading (datasheet typical, as Lab 5 Appendix B quotes). Biases: constant offsets before quantisation."""

    acc_noise_mg: float = 2.0
    gyro_noise_mdps: float = 75.0
    acc_bias_mg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyro_bias_mdps: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def read(self, acc_true_mg, gyro_true_mdps, rng: np.random.Generator | int | None = 0, t_tick_s=None):
        """Driver readings (int32 mg, int32 mdps), each (N, 3), of the true specific force and rate at each tick.
        With ``t_tick_s`` (s), gyro noise is drawn once per 416 Hz ODR sample and held; else fresh every tick."""
        rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        acc, gyro = np.asarray(acc_true_mg, dtype=np.float64), np.asarray(gyro_true_mdps, dtype=np.float64)
        acc_meas = acc + np.asarray(self.acc_bias_mg) + self.acc_noise_mg * rng.standard_normal(acc.shape)
        if t_tick_s is not None:
            t = np.asarray(t_tick_s, dtype=np.float64)
            idx = gyro_hold_index(t, t[0]) if t.size else np.zeros(0, np.int64)
            noise = rng.standard_normal((int(idx[-1]) + 1 if idx.size else 0, 3))[idx]
        else:
            noise = rng.standard_normal(gyro.shape)
        gyro_meas = gyro + np.asarray(self.gyro_bias_mdps) + self.gyro_noise_mdps * noise
        return quantise(acc_meas, ACC_SENSITIVITY_MG), quantise(gyro_meas, GYRO_SENSITIVITY_MDPS)


#: sigmas (mg, mdps) of the zero-g and zero-rate offsets drawn per seed: well inside the datasheet's ±40 mg / ±2 dps
ACC_BIAS_SIGMA_MG: float = 12.0
GYRO_BIAS_SIGMA_MDPS: float = 600.0


def seeded_lsm6dsl(rng: np.random.Generator) -> Lsm6dsl:
    """The LSM6DSL of a seed's sensor stream: acc offsets drawn first, then gyro offsets; default noise."""
    return Lsm6dsl(
        acc_bias_mg=tuple(float(v) for v in rng.normal(0.0, ACC_BIAS_SIGMA_MG, 3)),
        gyro_bias_mdps=tuple(float(v) for v in rng.normal(0.0, GYRO_BIAS_SIGMA_MDPS, 3)),
    )


def calibrate_offsets(acc_mg, gyro_mdps) -> tuple[np.ndarray, np.ndarray]:
    """The ISR's offsets (acc, gyro) int32: ``(int32_t)((float)sum * 0.00125f)`` of int32 sums (1/800 always)."""
    sums = [np.asarray(x, dtype=np.int64).sum(axis=0).astype(np.int32) for x in (acc_mg, gyro_mdps)]  # int32 wraps
    return tuple(np.trunc(s.astype(_F32) * _F32(0.00125)).astype(np.int32) for s in sums)


def remove_offsets(acc_mg, gyro_mdps, acc_offset_mg, gyro_offset_mdps) -> tuple[np.ndarray, np.ndarray]:
    """Offset removal of the ISR (int32): ``acc − off`` with z keeping 1000 mg (``acc_z − (off_z − 1000)``)."""
    acc_off = np.asarray(acc_offset_mg, dtype=np.int32) - np.array([0, 0, C.ACC_Z_KEPT_MG], dtype=np.int32)
    gyro = np.asarray(gyro_mdps, dtype=np.int32) - np.asarray(gyro_offset_mdps, dtype=np.int32)
    return np.asarray(acc_mg, dtype=np.int32) - acc_off, gyro


def gyro_iir(gyro_mdps, state: IirState | None = None) -> np.ndarray:
    """The ISR's gyro IIR over N ticks, bit-exact: (N, 3) float32 mdps, each product and sum rounded to float32 in
    C order (-O0, no FMA). ``state`` (None: zeros, as at power-up) is updated in place to filter in chunks."""
    x = np.asarray(gyro_mdps).astype(_F32)
    st = state if state is not None else IirState()
    a1, a2, b0, b1, b2 = _IIR_F32
    # feed-forward part, vectorised: x1/x2 are the previous inputs (from the state for the first two ticks)
    xp = np.concatenate([st.x2[None], st.x1[None], x], axis=0)
    ff = (b0 * xp[2:] + b1 * xp[1:-1]) + b2 * xp[:-2]
    y = np.concatenate([st.y2[None], st.y1[None], np.empty(x.shape, _F32)])
    for k in range(len(x)):  # the recursive part: (ff + a1*y1) + a2*y2, float32 each
        y[k + 2] = (ff[k] + a1 * y[k + 1]) + a2 * y[k]
    st.x2, st.x1, st.y2, st.y1 = xp[-2].copy(), xp[-1].copy(), y[-2].copy(), y[-1].copy()
    return y[2:]


def iir_frequency_response(freq_hz, fs_hz: float = C.ISR_RATE_HZ):
    """``(H, gain_db, phase_rad, group_delay_s)`` of the gyro IIR at ``freq_hz`` (Hz) for the sampling rate
    ``fs_hz`` (|H(0)| = 1; −3 dB near 101 Hz at the real 807.7 Hz tick)."""
    f = np.asarray(freq_hz, dtype=np.float64)
    a1, a2, b0, b1, b2 = (float(c) for c in _IIR_F32)
    z1 = np.exp(-2j * np.pi * f / fs_hz)
    num = b0 + b1 * z1 + b2 * z1 * z1
    den = 1.0 - a1 * z1 - a2 * z1 * z1
    h = num / den
    # group delay of a rational filter: τ = Re(Σ k c_k z^-k / Σ c_k z^-k)
    dnum = b1 * z1 + 2 * b2 * z1 * z1
    dden = -a1 * z1 - 2 * a2 * z1 * z1
    tau_samples = np.real(dnum / num) - np.real(dden / den)
    with np.errstate(divide="ignore"):
        gain_db = 20 * np.log10(np.abs(h))
    return h, gain_db, np.angle(h), tau_samples / fs_hz


#: delay of an AHRS step's gyro input relative to its accelerometer input, s (≈ 3.3 ms): the IIR's group delay at low
#: frequency (≈ 2.1 ms) plus the mean age of a 416 Hz sample-and-hold read (1.2 ms); both share the boxcar.
GYRO_LATENCY_S: float = float(iir_frequency_response([0.0])[3][0]) + 0.5 / GYRO_ODR_HZ


def fifo_average(fifo) -> np.ndarray:
    """The main loop's boxcar average (M, 5, 3) → (M, 3) float32: a float32 sum, then ``*= (1.0/5)`` in double."""
    f = np.asarray(fifo, dtype=_F32)
    s = np.zeros((f.shape[0], f.shape[2]), dtype=_F32)
    for i in range(f.shape[1]):
        s = s + f[:, i, :]
    return (s.astype(np.float64) * (1.0 / C.FIFO_ORDER)).astype(_F32)


@dataclass(frozen=True)
class IsrOutput:
    """Everything :func:`run_isr` computes (float32 arrays; indices into the input ticks)."""

    acc_ahrs_mg: np.ndarray  #: (M, 3) the main loop's ``acc_ahrs`` per AHRS step, mg
    gyro_ahrs_mdps: np.ndarray  #: (M, 3) ``gyro_ahrs`` per step, mdps
    gyro_fil_mdps: np.ndarray  #: (T, 3) the IIR output of every pipeline tick (for the ISR yaw and the PID)
    first_tick: int  #: the first pipeline tick (1599 after the power-up calibration)
    #: (M,) the tick whose ISR completed each step's FIFO: step k averages ticks ``step_tick[k]-4 … step_tick[k]``
    step_tick: np.ndarray


def run_isr(acc_mg_807, gyro_mdps_807, *, calibrate: bool = True) -> IsrOutput:
    """The TIM9 ISR and the main loop's averaging over per-tick driver readings (T, 3), integer mg and mdps.
    ``calibrate``: the power-up calibration (from tick 1599); False: from tick 0 with the offsets before it."""
    acc = np.trunc(np.asarray(acc_mg_807, dtype=np.float64)).astype(np.int32)
    gyro = np.trunc(np.asarray(gyro_mdps_807, dtype=np.float64)).astype(np.int32)
    if calibrate:
        end = CALIBRATION_SKIP_TICKS + CALIBRATION_TICKS
        if acc.shape[0] < end:
            raise ValueError(f"calibration needs {end} ticks ({end / C.ISR_RATE_HZ:.2f} s), got {acc.shape[0]}")
        acc_off, gyro_off = calibrate_offsets(acc[CALIBRATION_SKIP_TICKS:end], gyro[CALIBRATION_SKIP_TICKS:end])
        first = end - 1  # the calibrating ISR call also runs the pipeline on a fresh read
    else:
        acc_off, gyro_off, first = np.array([0, 0, C.ACC_Z_KEPT_MG], np.int32), np.zeros(3, np.int32), 0
    acc_c, gyro_c = remove_offsets(acc[first:], gyro[first:], acc_off, gyro_off)
    gyro_fil = gyro_iir(gyro_c)
    fifo = C.FIFO_ORDER
    m = acc_c.shape[0] // fifo
    n = m * fifo
    acc_ahrs = fifo_average(acc_c[:n].astype(_F32).reshape(m, fifo, 3))
    gyro_ahrs = fifo_average(gyro_fil[:n].reshape(m, fifo, 3))
    step_tick = first + fifo * np.arange(m, dtype=np.int64) + (fifo - 1)
    return IsrOutput(acc_ahrs, gyro_ahrs, gyro_fil, first, step_tick)


def isr_yaw_rad(gyro_fil_z_mdps, thr=None) -> np.ndarray:
    """The ISR's integrated yaw ``euler_ahrs.thz`` after each tick, float32 rad: ``thz += ((float)gyro_fil.z *
    (float)COE_MDPS_TO_RADPS) * 0.00125f``, reset to 0 while ``thr`` (per tick, scalar, None = 0) < MIN_THR."""
    gz = np.asarray(gyro_fil_z_mdps, dtype=_F32)
    inc = (gz * _F32(C.COE_MDPS_TO_RADPS)) * _F32(C.PID_DT_S)
    thr_arr = np.zeros(gz.shape[0], dtype=np.int64) if thr is None else np.broadcast_to(np.asarray(thr), gz.shape)
    out = np.zeros(gz.shape[0], dtype=_F32)
    # each run of ticks at flight throttle integrates from 0 (thz was reset before it), sequentially in float32
    low = np.concatenate(([True], thr_arr < C.MIN_THR, [True]))
    for start, stop in np.flatnonzero(np.diff(low.astype(np.int8))).reshape(-1, 2):
        out[start:stop] = np.cumsum(inc[start:stop], dtype=_F32)
    return out


def resample_to_tick(t_s, signal, hold_hz: float | None = None):
    """``(t_tick_s, signal_tick)``: ``signal`` (N, ...) at ``t_s`` interpolated onto the ISR ticks, float64.
    ``hold_hz``: each tick reads a register refreshed at that ODR (the gyro's 416 Hz sample-and-hold)."""
    t = np.asarray(t_s, dtype=np.float64)
    x = np.asarray(signal, dtype=np.float64)
    n = int(np.floor((t[-1] - t[0]) * C.ISR_RATE_HZ + 1e-9)) + 1
    t_tick = t[0] + np.arange(max(n, 0)) / C.ISR_RATE_HZ
    tt = t_tick if hold_hz is None else gyro_hold_times_s(t_tick, t[0], hold_hz)
    cols = [np.interp(tt, t, col) for col in x.reshape(t.shape[0], -1).T]
    return t_tick, np.stack(cols, axis=-1).reshape(tt.shape + x.shape[1:])

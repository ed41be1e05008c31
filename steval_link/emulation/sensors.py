"""Register models of the STEVAL-FCU001V1's SPI sensors, answering the firmware's ``Sensor_IO_Read/Write``.

Each sensor is a 128-byte register file with the identity, status and reset behaviour ST's drivers check, and
output registers filled from a motion source at the moment of the read:

- LSM6DSL (``spiDevice`` 0): WHO_AM_I 0x6A, STATUS_REG data ready, gyro ``OUTX_L_G`` 0x22..0x27 and acc
  ``OUTX_L_XL`` 0x28..0x2D as int16 ADC counts in the *sensor's* axes; the driver scales them with the full scale
  it configured (read back from CTRL1_XL / CTRL2_G), so ST's own scaling runs.
- LIS2MDL (1): WHO_AM_I 0x40, a constant field (the lab's magnetometer is unused by the AHRS).
- LPS22HB (2): WHO_AM_I 0xB1, a constant 1013.25 hPa and 25 °C.

The board's body axes (COORDINATE_SYSTEM 3: x right, y forward, z up) come from the sensor's by ST's
``ReadSensorRawData``: body x = −sensor y, body y = sensor x, body z = sensor z. :func:`body_to_sensor_counts`
does the inverse on ADC counts. :class:`SensorBus` logs every LSM6DSL sample it served (the *driver readings*
``(int32_t)(raw * sensitivity)`` in body axes), so a test can run :mod:`steval_link.emulation.sensor_model`'s ISR
pipeline on
exactly what the firmware read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from steval_link import constants as C
from steval_link.emulation import sensor_model as sm
from steval_link.emulation.board import UnmodelledHardware

LSM6DSL, LIS2MDL, LPS22HB = 0, 1, 2
_NAMES = {LSM6DSL: "LSM6DSL", LIS2MDL: "LIS2MDL", LPS22HB: "LPS22HB"}


class MotionSource(Protocol):
    """Per TIM9 tick ``k`` (0 = the first tick after power-up), the LSM6DSL's ADC counts in sensor axes."""

    def counts(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(acc int16[3], gyro int16[3]) sensor-axis counts of tick k."""
        ...


def body_to_sensor_counts(
    acc_mg, gyro_mdps, acc_sens: float = sm.ACC_SENSITIVITY_MG, gyro_sens: float = sm.GYRO_SENSITIVITY_MDPS
) -> tuple[np.ndarray, np.ndarray]:
    """Body-axis physical values (N, 3) → the LSM6DSL's int16 ADC counts in sensor axes (round, saturate)."""

    def counts(v, sens):
        raw = sm.adc_counts(v, sens)
        # sensor x = body y, sensor y = -body x (saturating the negation like the int16 register would)
        return np.stack([raw[:, 1], np.clip(-raw[:, 0].astype(np.int32), -32768, 32767), raw[:, 2]], -1).astype(
            np.int16
        )

    return counts(acc_mg, acc_sens), counts(gyro_mdps, gyro_sens)


def driver_readings(acc_counts, gyro_counts) -> tuple[np.ndarray, np.ndarray]:
    """What the firmware's ``ReadSensorRawData`` gets from sensor-axis counts: int32 mg / mdps in body axes."""

    def scale(raw, sens):
        v = sm.driver_value(raw, sens)
        return np.stack([-v[:, 1], v[:, 0], v[:, 2]], axis=-1)

    return scale(acc_counts, sm.ACC_SENSITIVITY_MG), scale(gyro_counts, sm.GYRO_SENSITIVITY_MDPS)


class _Regs:
    """A sensor's register file; ``read``/``write`` with the auto-increment the drivers use."""

    who_am_i_reg = 0x0F
    who_am_i = 0

    def __init__(self) -> None:
        self.r = bytearray(128)
        self.r[self.who_am_i_reg] = self.who_am_i

    def write(self, reg: int, data: bytes) -> None:
        for i, b in enumerate(data):
            a = (reg + i) & 0x7F
            if a != self.who_am_i_reg:
                self.r[a] = self.on_write(a, b)

    def on_write(self, reg: int, value: int) -> int:
        return value

    def read(self, reg: int, n: int, sample) -> bytes:
        self.refresh(sample)
        if reg + n <= 0x80:
            return bytes(self.r[reg : reg + n])
        return bytes(self.r[(reg + i) & 0x7F] for i in range(n))

    def refresh(self, sample) -> None:  # fill the output registers
        pass


class _Lsm6dsl(_Regs):
    who_am_i = 0x6A

    def __init__(self) -> None:
        super().__init__()
        self.r[0x12] = 0x04  # CTRL3_C: IF_INC
        self.r[0x1E] = 0x07  # STATUS_REG: XLDA, GDA, TDA

    def on_write(self, reg, value):
        if reg == 0x12:
            return value & ~0x81  # SW_RESET and BOOT clear themselves
        return value

    def refresh(self, sample) -> None:
        if sample is self._last:
            return
        self._last = sample
        acc, gyro = sample
        self.r[0x22:0x28] = np.asarray(gyro, "<i2").tobytes()
        self.r[0x28:0x2E] = np.asarray(acc, "<i2").tobytes()
        self.r[0x1E] = 0x07

    _last = None


class _Lis2mdl(_Regs):
    who_am_i_reg = 0x4F
    who_am_i = 0x40
    #: a plausible field, LSB (1.5 mG/LSB): ~ (200, 0, -400) mG
    FIELD = (133, 0, -267)

    def __init__(self) -> None:
        super().__init__()
        self.r[0x60] = 0x03  # CFG_REG_A: idle
        self.r[0x67] = 0x0F  # STATUS_REG: data ready
        self.r[0x68:0x6E] = np.asarray(self.FIELD, "<i2").tobytes()

    def on_write(self, reg, value):
        return value & ~0x60 if reg == 0x60 else value  # SOFT_RST, REBOOT clear themselves


class _Lps22hb(_Regs):
    who_am_i = 0xB1
    PRESSURE_HPA = 1013.25
    TEMPERATURE_C = 25.0

    def __init__(self) -> None:
        super().__init__()
        self.r[0x11] = 0x10  # CTRL_REG2: IF_ADD_INC
        self.r[0x27] = 0x03  # STATUS: P_DA, T_DA
        p = int(round(self.PRESSURE_HPA * 4096))
        self.r[0x28:0x2B] = p.to_bytes(3, "little")
        self.r[0x2B:0x2D] = int(round(self.TEMPERATURE_C * 100)).to_bytes(2, "little", signed=True)

    def on_write(self, reg, value):
        return value & ~0x84 if reg == 0x11 else value  # BOOT, SWRESET clear themselves


@dataclass
class ServedSample:
    tick: int
    acc_counts: tuple[int, int, int]
    gyro_counts: tuple[int, int, int]


class SensorBus:
    """The SPI2 sensors as ``Sensor_IO_Read/Write`` see them, fed by a motion source.

    The LSM6DSL's outputs at a read are those of the motion source's current tick: before TIM9 runs, the tick of
    the emulated time (``now // 104000``); once it runs, the tick the ISR's update event belongs to (so each TIM9
    tick reads one consecutive sample).

    Args:
        motion: per-tick sensor counts.
        log_limit: keep at most this many served LSM6DSL samples in :attr:`served` (for tests; 0 = none).
    """

    def __init__(self, motion: MotionSource, *, log_limit: int = 0) -> None:
        self.motion = motion
        self.devices = {LSM6DSL: _Lsm6dsl(), LIS2MDL: _Lis2mdl(), LPS22HB: _Lps22hb()}
        self.log_limit = log_limit
        self.served: list[ServedSample] = []
        self.reads = 0
        self._tick_offset: int | None = None
        self._last_tick = -1
        self._cached_k = None
        self._cached = None

    def tick_index(self, board) -> int:
        tim = board.tim9
        if tim.first_update is None:
            return board.now // C.TICK_CYCLES
        if self._tick_offset is None:
            self._tick_offset = -(-tim.first_update // C.TICK_CYCLES)  # first update → its own tick index
        return self._tick_offset + tim.updates - 1

    def tick_index_of_update(self, update: int) -> int:
        """Motion tick index of the TIM9 update number ``update`` (1 = the first)."""
        return (self._tick_offset or 0) + update - 1

    def read(self, device: int, reg: int, n: int, board) -> bytes:
        dev = self.devices.get(device)
        if dev is None:
            raise UnmodelledHardware(
                f"Sensor_IO_Read for SPI device {device} (not LSM6DSL/LIS2MDL/LPS22HB) in {board.where()}"
            )
        self.reads += 1
        sample = self._lsm6dsl_sample(board, reg <= 0x28 < reg + n) if device == LSM6DSL else None
        return dev.read(reg, n, sample)

    def lsm6dsl_image(self, board) -> bytes:
        """The LSM6DSL's 128 registers once a read of its outputs at this tick (as the ISR's first) filled them."""
        self.reads += 1
        dev = self.devices[LSM6DSL]
        dev.refresh(self._lsm6dsl_sample(board, True))
        return bytes(dev.r)

    def _lsm6dsl_sample(self, board, outputs: bool):
        """The motion's sample of this tick; ``outputs``: a read of the output registers (logged once per tick)."""
        k = self.tick_index(board)
        if k != self._cached_k:
            self._cached_k, self._cached = k, self.motion.counts(k)
        sample = self._cached
        if outputs and k != self._last_tick:
            self._last_tick = k
            if len(self.served) < self.log_limit:
                self.served.append(ServedSample(k, tuple(int(v) for v in sample[0]), tuple(int(v) for v in sample[1])))
        return sample

    def write(self, device: int, reg: int, data: bytes, board) -> None:
        dev = self.devices.get(device)
        if dev is not None:
            dev.write(reg, data)

    def served_driver_readings(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tick (N,), acc_mg int32 (N, 3), gyro_mdps int32 (N, 3)) of the logged reads, in body axes."""
        ticks = np.array([s.tick for s in self.served], np.int64)
        acc = np.array([s.acc_counts for s in self.served], np.int16).reshape(-1, 3)
        gyro = np.array([s.gyro_counts for s in self.served], np.int16).reshape(-1, 3)
        a, g = driver_readings(acc, gyro)
        return ticks, a, g

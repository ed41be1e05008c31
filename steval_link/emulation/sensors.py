"""Register models of the STEVAL-FCU001V1's SPI sensors, answering the firmware's ``Sensor_IO_Read/Write``.

Each is a 128-byte register file with the identity, status and reset behaviour ST's drivers check. The LSM6DSL
(``spiDevice`` 0) holds the motion's int16 ADC counts in the *sensor's* axes (``ReadSensorRawData`` maps them to
body axes: body x = −sensor y, body y = sensor x); the LIS2MDL (1) a constant field, the LPS22HB (2) 1013.25 hPa, 25 °C.
"""

from __future__ import annotations

import numpy as np

from steval_link import constants as C
from steval_link.emulation import sensor_model as sm
from steval_link.emulation.board import UnmodelledHardware

LSM6DSL, LIS2MDL, LPS22HB = 0, 1, 2


def body_to_sensor_counts(acc_mg, gyro_mdps) -> tuple[np.ndarray, np.ndarray]:
    """Body-axis physical values (N, 3) → the LSM6DSL's int16 ADC counts in sensor axes (round, saturate)."""

    def counts(v, sens):
        raw = sm.adc_counts(v, sens)
        minus_x = np.clip(-raw[:, 0].astype(np.int32), -32768, 32767)  # saturating, as the int16 register would
        return np.stack([raw[:, 1], minus_x, raw[:, 2]], -1).astype(np.int16)  # sensor x = body y, y = −body x

    return counts(acc_mg, sm.ACC_SENSITIVITY_MG), counts(gyro_mdps, sm.GYRO_SENSITIVITY_MDPS)


class _Regs:
    """A 128-byte register file with auto-increment; ``init``: reset bytes, ``self_clearing``: bits that clear."""

    def __init__(self, who_am_i_reg: int, who_am_i: int, init: dict[int, bytes], self_clearing: dict[int, int]):
        self.r = bytearray(128)
        for reg, data in {who_am_i_reg: bytes([who_am_i]), **init}.items():
            self.r[reg : reg + len(data)] = data
        self.who_am_i_reg = who_am_i_reg
        self.self_clearing = self_clearing
        self._last = None

    def write(self, reg: int, data: bytes) -> None:
        for i, b in enumerate(data):
            a = (reg + i) & 0x7F
            if a != self.who_am_i_reg:
                self.r[a] = b & ~self.self_clearing.get(a, 0)

    def read(self, reg: int, n: int, sample) -> bytes:
        self.refresh(sample)
        if reg + n <= 0x80:
            return bytes(self.r[reg : reg + n])
        return bytes(self.r[(reg + i) & 0x7F] for i in range(n))

    def refresh(self, sample) -> None:
        """The LSM6DSL's output registers from ``sample`` (acc, gyro counts): gyro OUTX_L_G, acc OUTX_L_XL."""
        if sample is None or sample is self._last:
            return
        self._last = sample
        acc, gyro = sample
        self.r[0x22:0x28] = np.asarray(gyro, "<i2").tobytes()
        self.r[0x28:0x2E] = np.asarray(acc, "<i2").tobytes()
        self.r[0x1E] = 0x07


def _devices() -> dict[int, _Regs]:
    """The sensors at reset. LIS2MDL: ~ (200, 0, -400) mG at 1.5 mG/LSB; LPS22HB: 4096 LSB/hPa, 100 LSB/°C."""
    pressure = int(round(1013.25 * 4096)).to_bytes(3, "little")
    temperature = int(round(25.0 * 100)).to_bytes(2, "little", signed=True)
    field = np.asarray((133, 0, -267), "<i2").tobytes()
    return {
        # CTRL3_C: IF_INC; STATUS_REG: XLDA, GDA, TDA; SW_RESET and BOOT clear themselves
        LSM6DSL: _Regs(0x0F, 0x6A, {0x12: b"\x04", 0x1E: b"\x07"}, {0x12: 0x81}),
        # CFG_REG_A: idle; STATUS_REG: data ready; SOFT_RST, REBOOT clear themselves
        LIS2MDL: _Regs(0x4F, 0x40, {0x60: b"\x03", 0x67: b"\x0f", 0x68: field}, {0x60: 0x60}),
        # CTRL_REG2: IF_ADD_INC; STATUS: P_DA, T_DA; BOOT, SWRESET clear themselves
        LPS22HB: _Regs(0x0F, 0xB1, {0x11: b"\x10", 0x27: b"\x03", 0x28: pressure, 0x2B: temperature}, {0x11: 0x84}),
    }


class SensorBus:
    """The SPI2 sensors as ``Sensor_IO_Read/Write`` see them, fed by ``motion.counts(k)`` (LSM6DSL counts of TIM9
    tick ``k``, 0 at power-up): before TIM9 runs, the tick of the emulated time; then of the ISR's update event.
    ``log_limit``: keep at most this many served LSM6DSL samples in :attr:`served` (for tests)."""

    def __init__(self, motion, *, log_limit: int = 0) -> None:
        self.motion = motion
        self.devices = _devices()
        self.log_limit = log_limit
        self.served: list[tuple] = []  #: (tick, acc counts, gyro counts)
        self.tick_offset: int | None = None  #: the motion tick of TIM9's first update
        self._last_tick = -1
        self._cached_k = self._cached = None

    def tick_index(self, board, *, updates: int | None = None, now: int | None = None) -> int:
        """The motion tick of TIM9's latest update, now or when TIM9 had made ``updates`` at clock ``now``."""
        tim = board.tim9
        updates, now = (tim.updates, board.now) if updates is None else (updates, now)
        if tim.first_update is None or not updates:
            return now // C.TICK_CYCLES
        if self.tick_offset is None:
            self.tick_offset = -(-tim.first_update // C.TICK_CYCLES)
        return self.tick_offset + updates - 1

    def read(self, device: int, reg: int, n: int, board) -> bytes:
        dev = self.devices.get(device)
        if dev is None:
            raise UnmodelledHardware(
                f"Sensor_IO_Read for SPI device {device} (not LSM6DSL/LIS2MDL/LPS22HB) in {board.where()}"
            )
        # the motion's sample only for a read of STATUS_REG or the outputs (0x1E..0x2D): the others do not see it
        sample = None
        if device == LSM6DSL and (reg < 0x2E and reg + n > 0x1E or reg + n > 0x80):
            sample = self._lsm6dsl_sample(board, reg <= 0x28 < reg + n)
        return dev.read(reg, n, sample)

    def lsm6dsl_image(self, board) -> bytes:
        """The LSM6DSL's 128 registers as a read of its outputs at this tick fills them."""
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
                self.served.append((k, np.array(sample[0], np.int16), np.array(sample[1], np.int16)))
        return sample

    def write(self, device: int, reg: int, data: bytes, board) -> None:
        dev = self.devices.get(device)
        if dev is not None:
            dev.write(reg, data)

    def served_driver_readings(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(tick, acc_mg, gyro_mdps) int32 of the logged reads as ``ReadSensorRawData`` gets them (body axes)."""
        ticks = np.array([s[0] for s in self.served], np.int64)
        readings = []
        for j, sens in ((1, sm.ACC_SENSITIVITY_MG), (2, sm.GYRO_SENSITIVITY_MDPS)):
            v = sm.driver_value(np.array([s[j] for s in self.served], np.int16).reshape(-1, 3), sens)
            readings.append(np.stack([-v[:, 1], v[:, 0], v[:, 2]], axis=-1))
        return ticks, readings[0], readings[1]

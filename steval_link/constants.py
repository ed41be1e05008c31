"""The STEVAL-FCU001V1 firmware's facts (ST release 170120), each stated once: clock, timer and AHRS rates, the
filter's default settings, the link's default baud rate. Every other module takes them from here.
"""

from __future__ import annotations

#: ``SystemCoreClock`` after HAL's PLL set-up, Hz (also the DWT cycle counter's rate)
CPU_HZ: int = 84_000_000
#: CPU cycles per TIM9 interrupt: APB2 timer clock 84 MHz, prescaler 51 (÷52), period 1999 (÷2000)
TICK_CYCLES: int = 52 * 2000
#: TIM9 interrupt rate, Hz (≈ 807.69 Hz, 1.238 ms): sensor read, offset removal, gyro IIR, FIFOs
ISR_RATE_HZ: float = CPU_HZ / TICK_CYCLES
#: TIM9 interrupt period, s (ticks land on exact core-clock cycle counts)
TICK_PERIOD_S: float = TICK_CYCLES / CPU_HZ
#: samples averaged per AHRS step (``FIFO_Order``): the main loop runs the AHRS on every 5th tick
FIFO_ORDER: int = 5
#: AHRS step rate, Hz (≈ 161.54 Hz, 6.19 ms)
AHRS_RATE_HZ: float = ISR_RATE_HZ / FIFO_ORDER
#: AHRS step period, s
AHRS_PERIOD_S: float = 1.0 / AHRS_RATE_HZ
#: AHRS step period, µs (the firmware's ``t_us`` advances by this much per step)
AHRS_PERIOD_US: float = 1e6 / AHRS_RATE_HZ
#: the ISR's offset removal keeps this much of the z offset, mg: at rest and level acc z reads +1000 mg (1 g)
ACC_Z_KEPT_MG: int = 1000
#: ``COE_MDPS_TO_RADPS``: mdps → rad/s as the firmware writes it (cast to float32 where it is used)
COE_MDPS_TO_RADPS: float = 1.745329252e-5

#: ``AHRS_KP_BIG``: proportional gain while on the ground (throttle below MIN_THR)
KP_GROUND: float = 10.0
#: ``AHRS_KP_NORM``: proportional gain in flight
KP_FLIGHT: float = 0.4
#: ``AHRS_KI``: integral gain (lab exercise 4 sets 1.0)
KI: float = 0.1
#: ``SENSOR_SAMPLING_TIME``: the dt the filter integrates with, s (not the real 6.19 ms step)
DT_S: float = 0.00625
#: ``MIN_THR``: throttle below which the ground gain is used and the ISR resets the integrated yaw
MIN_THR: int = 200

#: USART1 baud rate of the firmware patch's default build
BAUD: int = 115_200

#: delay of the gyro input of an AHRS step relative to its accelerometer input, s (≈ 3.3 ms): the ISR gyro IIR's
#: group delay plus the mean age of a 416 Hz sample-and-hold read (:mod:`steval_link.emulation.sensor_model` derives
#: it from the IIR coefficients; a test keeps the two equal).
GYRO_LATENCY_S: float = 0.003315483788573155

# ---- flight control (flight_control.h, rc.c, motor.h; MOTOR_DC, REMOCON_BLE: the default build) ----------------
#: outer (angle) loop gains ``ROLL/PITCH_PID_KP1``, ``YAW_PID_KP1`` per axis x (pitch), y (roll), z
OUTER_KP: tuple[float, float, float] = (3.0, 3.0, 4.0)
#: ``PID_SAMPLING_TIME``: the dt of both PID loops' integrators, s (the inner loop runs in the TIM9 ISR)
PID_DT_S: float = 0.00125
#: ``MAX_ADJ_AMOUNT``: the inner loop's output limit (PWM counts)
MAX_ADJ: float = 800.0
#: ``RC_FULLSCALE``, ``PITCH_MAX_DEG``/``ROLL_MAX_DEG``: a stick at ±1800 asks for ±30° pitch/roll
RC_FULLSCALE: int = 1800
MAX_TILT_DEG: float = 30.0
#: TIM4 PWM period in counts (1 MHz, 2 ms): the motor outputs' full scale; ``MOTOR_MAX_PWM_VALUE`` clamps at 1900
PWM_PERIOD: int = 2000
MOTOR_MAX_PWM: float = 1900.0
#: the inner loop's throttle term ``motor_thr = (int16)(0.05f·gTHR + 633.333f)`` (MOTOR_DC)
MOTOR_THR_GAIN: float = 0.05
MOTOR_THR_OFFSET: float = 633.333
#: the mixer of ``FlightControlPID_innerLoop``: motor i = motor_thr + Σ_axis MIXER[i][axis] · s2[axis]
#: (axis x pitch, y roll, z yaw): motor1 = thr - x - y + z, motor2 = thr + x - y - z, motor3 = thr + x + y + z,
#: motor4 = thr - x + y - z
MIXER: tuple[tuple[int, int, int], ...] = ((-1, -1, 1), (1, -1, -1), (1, 1, 1), (-1, 1, -1))

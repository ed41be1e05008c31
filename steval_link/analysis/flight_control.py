"""The firmware's flight control (ST's ``flight_control.c``, ``rc.c``, ``motor.c``) recomputed on the host from a
flight-control frame: the outer loop's P and I terms, the mixer, what each motor is and where it sits.

Float32 in the firmware's order of operations, so bit for bit: with ``ki1 = 0`` the outer loop ``s1`` is exactly
``P = kp1·(target − angle)`` for pitch and roll (yaw's ``thz`` is integrated in the ISR: close). The mixer::

    motor_thr = (int16)(0.05f·gTHR + 633.333f)
    motor1 = motor_thr − x_s2 − y_s2 + z_s2      (right rear,  clockwise)
    motor2 = motor_thr + x_s2 − y_s2 − z_s2      (right front, counter-clockwise)
    motor3 = motor_thr + x_s2 + y_s2 + z_s2      (left front,  clockwise)
    motor4 = motor_thr − x_s2 + y_s2 − z_s2      (left rear,   counter-clockwise)

Positions and spins follow from the signs (x right, y forward, z up): ``x_s2`` > 0 (nose up) speeds up the front
motors 2 and 3, ``y_s2`` > 0 (right side down) the left ones 3 and 4, ``z_s2`` > 0 (yaw counter-clockwise) 1 and 3,
whose props therefore spin clockwise. The outputs are 0 while disarmed or below ``MIN_THR``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from steval_link import constants as C
from steval_link.link.protocol import FC_ARMED


@dataclass(frozen=True)
class Motor:
    number: int  #: 1..4, as ``motorN_pwm`` and TIM4 channel N
    position: str  #: e.g. "right rear"
    spin: str  #: "clockwise" / "counter-clockwise", seen from above

    @property
    def label(self) -> str:
        return f"motor {self.number} ({self.position})"


def _position(row: tuple[int, int, int]) -> str:
    side = "left" if row[1] > 0 else "right"
    end = "front" if row[0] > 0 else "rear"
    return f"{side} {end}"


#: the four motors as the firmware's mixer places them (see the module docstring)
MOTORS: tuple[Motor, ...] = tuple(
    Motor(i + 1, _position(row), "clockwise" if row[2] > 0 else "counter-clockwise") for i, row in enumerate(C.MIXER)
)


def mixer_matrix() -> np.ndarray:
    """(4, 3) float32: motor i = motor_thr + row i · (x_s2, y_s2, z_s2)."""
    return np.asarray(C.MIXER, dtype=np.float32)


def motor_thr(thr) -> np.ndarray:
    """``(int16)(0.05f·(float)gTHR + 633.333f)`` as float32 (the inner loop's throttle term)."""
    t = np.asarray(thr).astype(np.float32)
    v = np.float32(C.MOTOR_THR_GAIN) * t + np.float32(C.MOTOR_THR_OFFSET)
    return np.trunc(v).astype(np.int16).astype(np.float32)


def mixer_pwm(thr, inner_s2) -> np.ndarray:
    """(N, 4) float32 motor PWM from gTHR (N,) and the inner outputs (N, 3), in the firmware's order of operations."""
    s2 = np.asarray(inner_s2, dtype=np.float32).reshape(-1, 3)
    mt = motor_thr(thr).reshape(-1)
    out = np.empty((len(s2), 4), np.float32)
    for i, row in enumerate(C.MIXER):
        v = mt.copy()
        for a in range(3):
            v = v + s2[:, a] if row[a] > 0 else v - s2[:, a]
        out[:, i] = v + np.float32(0.0)  # + MOTOR_OFFi (0)
    return out


def expected_motor_pwm(thr, inner_s2, armed) -> np.ndarray:
    """What ``motor_pwm`` holds after the ISR: the mixer while armed and ``gTHR ≥ MIN_THR``, else 0."""
    thr = np.asarray(thr).reshape(-1)
    out = mixer_pwm(thr, inner_s2)
    on = np.asarray(armed, dtype=bool).reshape(-1) & (thr >= C.MIN_THR)
    out[~on] = 0.0
    return out


def outer_p(euler_rc_rad, angles_rad) -> np.ndarray:
    """(N, 3) float32 outer-loop P terms ``kp1·(target − angle)``; angles (N, 3) thx pitch, thy roll, thz yaw."""
    rc = np.asarray(euler_rc_rad, dtype=np.float32).reshape(-1, 3)
    ang = np.asarray(angles_rad, dtype=np.float32).reshape(-1, 3)
    return np.asarray(C.OUTER_KP, dtype=np.float32) * (rc - ang)


def no_flight_figure_reason(fc) -> str | None:
    """Why a capture gets no flight-control figure (no frames, or never armed), or None."""
    if len(fc) == 0:
        return "the capture has no flight-control frames"
    if not (np.asarray(fc.fc_flags).astype(np.int64) & FC_ARMED).any():
        return (
            f"the drone was never armed in its {len(fc)} flight-control frames "
            "(targets at the sticks' rest, motors at 0)"
        )
    return None

"""Flight-control frames (type 4) to Rerun: targets, loop outputs, motor commands (also as thrust arrows), sticks.

P and I are recomputed with the firmware's gains: pitch and roll bit for bit (P = kp1·(target − angle), I = s1 − P);
yaw's P uses the attitude frame's ``thz``, which the ISR may move before the outer loop runs: approximate, no I."""

from __future__ import annotations

from typing import Any

import numpy as np
import rerun as rr

from steval_link import constants as C
from steval_link.analysis.flight_control import MOTORS, outer_p
from steval_viewer import drone_model
from steval_viewer import entities as ent
from steval_viewer.columns import Times, send_arrows, send_scalars, series_style

_MOTOR_COLORS = [(214, 39, 40), (255, 127, 14), (44, 160, 44), (31, 119, 180)]
_TARGET_COLOR = (40, 40, 40)


def flight_angles(fc: Any, att: Any) -> tuple[np.ndarray, np.ndarray]:
    """(thx, thy, thz (N, 3) float32 of the attitude row with each flight-control row's step, found (N,) bool)."""
    steps = np.asarray(att.step, dtype=np.int64)
    fs = np.asarray(fc.step, dtype=np.int64)
    ang = np.full((len(fs), 3), np.nan, np.float32)
    if not len(steps):
        return ang, np.zeros(len(fs), bool)
    order = np.argsort(steps, kind="stable")
    idx = order[np.clip(np.searchsorted(steps[order], fs), 0, len(steps) - 1)]
    found = steps[idx] == fs
    ang[found] = np.stack([att.thx_rad, att.thy_rad, att.thz_rad], axis=1)[idx[found]]
    return ang, found


def log_flight_static(rec: rr.RecordingStream) -> None:
    """Series styles of the flight-control view."""
    for path, label in zip(ent.FC_TARGETS, ("target thx (remote)", "target thy (remote)", "target thz (remote)")):
        series_style(rec, path, label, _TARGET_COLOR, 2.0)
    for path, axis in zip(ent.FC_OUTER, ("x pitch", "y roll", "z yaw")):
        series_style(rec, f"{path}/s1", f"{axis[0]}_s1 (firmware)", (214, 39, 40), 2.0)
        series_style(rec, f"{path}/p", "P = kp1·(target − angle)", (31, 119, 180))
        if path != ent.FC_OUTER[2]:
            series_style(rec, f"{path}/i", "I = s1 − P (ki1 = 0)", (44, 160, 44))
    series_style(rec, ent.FC_INNER, ["x_s2 pitch", "y_s2 roll", "z_s2 yaw"], ent.XYZ_COLORS)
    series_style(rec, ent.FC_MOTORS, [f"{m.label}" for m in MOTORS], _MOTOR_COLORS)
    sticks = ["gAIL (roll stick)", "gELE (pitch stick)", "gRUD (yaw stick)", "gTHR"]
    series_style(rec, ent.FC_STICKS, sticks, [*ent.XYZ_COLORS, (127, 127, 127)])
    series_style(rec, ent.FC_VBAT, "VBAT", (127, 127, 127))


def log_motors_static(rec: rr.RecordingStream) -> None:
    """The motor arrows' fixed parts (where, colour, label); their vectors come with the flight-control frames."""
    for m, p, color in zip(MOTORS, drone_model.firmware_motor_positions(), _MOTOR_COLORS):
        origin = [p + (0.0, 0.0, drone_model.PROP_Z)]  # the vectors come over time
        label = [f"M{m.number}"]
        arrow = rr.Arrows3D.from_fields(origins=origin, colors=[color], radii=[0.035], labels=label, show_labels=True)
        rec.log(ent.motor_path(m.number), arrow, static=True)


def log_flight_control(rec: rr.RecordingStream, tel: Any) -> int:
    """Log the flight-control rows of ``tel`` (``tel.fc``); returns the rows logged (0: none in the stream)."""
    fc = getattr(tel, "fc", None)
    if fc is None or len(fc) == 0:
        return 0
    times = Times(fc.t_fw_s, getattr(fc, "t_host_s", None), fc.step)
    rc = np.asarray(fc.euler_rc_rad, dtype=np.float64)
    for i, path in enumerate(ent.FC_TARGETS):
        send_scalars(rec, path, times, np.degrees(rc[:, i]))
    ang, found = flight_angles(fc, tel.attitude)
    p = outer_p(fc.euler_rc_rad, ang)
    s1 = np.asarray(fc.outer_s1_radps, dtype=np.float32)
    for i, path in enumerate(ent.FC_OUTER):
        send_scalars(rec, f"{path}/s1", times, s1[:, i])
        send_scalars(rec, f"{path}/p", times, p[:, i], found)
        if i < 2:
            send_scalars(rec, f"{path}/i", times, s1[:, i] - p[:, i], found)
    mp = np.asarray(fc.motor_pwm, dtype=np.float64)
    for path, values in ((ent.FC_INNER, fc.inner_s2_pwm), (ent.FC_MOTORS, mp), (ent.FC_STICKS, fc.rc)):
        send_scalars(rec, path, times, values)
    send_scalars(rec, ent.FC_VBAT, times, fc.vbat_v)
    # thrust arrows: the command TIM4 gets (clamped to 0..MOTOR_MAX_PWM), 1 unit = 100 % duty
    frac = np.clip(mp, 0.0, C.MOTOR_MAX_PWM) / C.PWM_PERIOD
    for k, m in enumerate(MOTORS):
        send_arrows(rec, ent.motor_path(m.number), times, np.column_stack([np.zeros((len(mp), 2)), frac[:, k]]))
    return len(fc)

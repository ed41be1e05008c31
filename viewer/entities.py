"""Entity paths, timelines, series labels and colours of every steval-link recording, in one place.

Tests, docs, the blueprint and both logging paths (replay and live) refer to these names, so a recording made by
``steval replay`` and one made live have the same layout. Units are in the path names.

Layout::

    world                                 view coordinates: x right, y forward (nose), z up (RIGHT_HAND_Z_UP)
    world/axes                            world x/y/z arrows (static)
    world/drone/firmware                  Transform3D: the firmware's ahrs.q (body -> earth)
    world/drone/firmware/model            the quadcopter (static mesh)
    world/drone/firmware/acc_gravity      gravity direction seen by the accelerometer (body frame, 1 g = 1 unit)
    world/drone/estimate/<source>         Transform3D of a host estimate (ST-Mahony replica, EKF, ...)
    world/drone/estimate/<source>/model   translucent wireframe ghost (static)
    plots/pitch_thx_deg/<source>          thx = rotation about x (pitch, nose up +), degrees
    plots/roll_thy_deg/<source>           thy = rotation about y (roll), degrees
    plots/yaw_thz_deg/firmware            thz = ISR-integrated yaw, degrees
    plots/acc_mg                          accelerometer x, y, z (mg), the inputs of ahrs_fusion_ag
    plots/gyro_dps                        gyro x, y, z (deg/s)
    plots/throttle_thr                    gTHR
    plots/fw_minus_replica_deg/thx|thy    firmware − ST-Mahony replica, degrees (0 when the replica is bit-exact)
    fc/pitch_thx_deg/target               the remote's target thx (euler_rc), degrees (flight-control frames)
    fc/roll_thy_deg/target                target thy, degrees
    fc/yaw_thz_deg/target                 target thz, degrees
    fc/outer_<axis>_radps/s1|p|i          the outer (angle) loop's output s1 (a rate setpoint, rad/s), and its P
                                          and I terms recomputed with the firmware's gains (axis pitch_x, roll_y,
                                          yaw_z)
    fc/inner_s2_pwm                       the inner (rate) loop's outputs x_s2, y_s2, z_s2 (PWM counts)
    fc/motor_pwm                          motor1..4_pwm (TIM4 counts, 2000 = 100 %)
    fc/sticks                             gAIL, gELE, gRUD, gTHR
    fc/vbat_v                             battery voltage, V
    world/drone/firmware/motors/m1..m4    each motor's command as a thrust arrow on its prop (1 unit = 100 %)
    link/frame_rate_hz                    attitude frames received per second (1 s bins)
    link/frames_missing                   frames lost on the link (sequence gaps), cumulative
    link/crc_failures                     frames rejected by the decoder's CRC check, cumulative
    link/tx_dropped                       frames the firmware dropped (TX queue full), cumulative, from status
    link/tx_queue_peak_bytes              TX queue high-water mark per status period
    link/ahrs_cycles                      CPU cycles of one ahrs_fusion_ag + QuaternionToEuler: min, mean, max
    log/firmware                          firmware text lines
    log/host                              host notes (decoder summary, estimator notes)
    log/commands                          commands the host sent to the drone, its acknowledgements, the settings
    text/<series>-<series>...             text telemetry: one entity per record shape, named by its series, a line
                                          per series (a student's PRINTF lines, ST's line, plotter formats)

BLE captures (ST's stock firmware over Bluetooth: raw samples, no firmware attitude)::

    world/drone/ble                       Transform3D: the first host estimate run on the BLE samples (solid model)
    world/drone/ble/model                 the quadcopter (static mesh)
    world/drone/ble/acc_gravity           gravity direction of the BLE accelerometer sample
    ble/acc_mg, ble/gyro_dps, ble/mag_mgauss   the motion notification's samples (one ISR sample each)
    ble/pressure_hpa, ble/battery_pct, ble/temperature_c, ble/rssi_dbm, ble/armed   environment and arming
    ble/notification_rate_hz              motion notifications per second (1 s bins)
    ble/note                              why the firmware replica cannot be bit-exact on BLE data (text)
    log/ble_console                       the console stdout/stderr characteristics
"""

from __future__ import annotations

import re

#: Timelines. ``fw_time``: firmware time (s since boot, from t_us); ``host_time``: host receive time (s since
#: capture start); ``ahrs_step``: the AHRS step counter.
TIMELINE_FW = "fw_time"
TIMELINE_HOST = "host_time"
TIMELINE_STEP = "ahrs_step"

WORLD = "world"
WORLD_AXES = "world/axes"
WORLD_AXIS_LABELS = "world/axis_labels"  #: the axes' names, as points beyond the arrow tips
DRONE_FIRMWARE = "world/drone/firmware"
DRONE_FIRMWARE_MODEL = "world/drone/firmware/model"
ACC_GRAVITY = "world/drone/firmware/acc_gravity"

PLOTS = "plots"
PLOT_PITCH = "plots/pitch_thx_deg"
PLOT_ROLL = "plots/roll_thy_deg"
PLOT_YAW = "plots/yaw_thz_deg"
PLOT_ACC = "plots/acc_mg"
PLOT_GYRO = "plots/gyro_dps"
PLOT_THROTTLE = "plots/throttle_thr"
PLOT_DIFF = "plots/fw_minus_replica_deg"
DIFF_THX = f"{PLOT_DIFF}/thx"
DIFF_THY = f"{PLOT_DIFF}/thy"

LINK = "link"
LINK_RATE = "link/frame_rate_hz"
LINK_MISSING = "link/frames_missing"
LINK_CRC = "link/crc_failures"
LINK_TX_DROPPED = "link/tx_dropped"
LINK_QUEUE = "link/tx_queue_peak_bytes"
LINK_CYCLES = "link/ahrs_cycles"

FC_TARGETS = ("fc/pitch_thx_deg/target", "fc/roll_thy_deg/target", "fc/yaw_thz_deg/target")
#: the outer loop per axis (x pitch, y roll, z yaw): s1 and its P and I terms
FC_OUTER = ("fc/outer_pitch_x_radps", "fc/outer_roll_y_radps", "fc/outer_yaw_z_radps")
FC_INNER = "fc/inner_s2_pwm"
FC_MOTORS = "fc/motor_pwm"
FC_STICKS = "fc/sticks"
FC_VBAT = "fc/vbat_v"


def motor_path(number: int) -> str:
    """The thrust arrow of motor ``number`` (1..4) on the firmware drone."""
    return f"world/drone/firmware/motors/m{number}"


BLE_MAG = "ble/mag_mgauss"
BLE_PRESSURE = "ble/pressure_hpa"
BLE_BATTERY = "ble/battery_pct"
BLE_TEMPERATURE = "ble/temperature_c"
BLE_RSSI = "ble/rssi_dbm"
BLE_ARMED = "ble/armed"
BLE_NOTE = "ble/note"

LOG_FIRMWARE = "log/firmware"
LOG_HOST = "log/host"
LOG_COMMANDS = "log/commands"
#: notes about the firmware's own filter output: the first row with NaN or out-of-range values (it diverged)
LOG_FILTER = "log/filter"

#: Source names (entity path segments). ``firmware`` is what the drone computed; ``st_mahony_replica`` the host's
#: bit-exact replica of it; other names come from the estimator registry (``ekf3``, ``mekf``, ``accel``, ``vqf``).
SOURCE_FIRMWARE = "firmware"
SOURCE_REPLICA = "st_mahony_replica"

#: Series label ("firmware" in the pitch plot's legend) and RGB colour (every plot and the 3D ghost) of the sources.
SOURCES = {
    "firmware": ("firmware", (214, 39, 40)),
    "st_mahony_replica": ("ST-Mahony replica", (255, 187, 0)),
    "st_mahony": ("ST-Mahony (Python)", (140, 86, 75)),
    "ekf3": ("EKF3", (31, 119, 180)),
    "mekf": ("MEKF", (148, 103, 189)),
    "accel": ("accelerometer only", (44, 160, 44)),
    "vqf": ("VQF", (227, 119, 194)),
}
_FALLBACK_COLORS = [(23, 190, 207), (188, 189, 34), (127, 127, 127), (0, 158, 115)]

#: RGB colours of the x, y, z axes (world arrows, three-axis series)
XYZ_COLORS = [(230, 60, 60), (60, 200, 60), (70, 110, 240)]

GHOST_PREFERENCE = ("st_mahony_replica", "ekf3", "mekf", "st_mahony", "vqf", "accel")


def source_name(name: str) -> str:
    """Entity-path segment for an estimator name: ``-`` and other separators become ``_`` (``MyEkf`` keeps its case)."""
    seg = re.sub(r"[^0-9a-zA-Z_]+", "_", name.strip()).strip("_")
    if not seg:
        raise ValueError(f"estimator name {name!r} has no usable characters")
    return seg


def source_label(source: str) -> str:
    """Readable label of a source segment (``ekf3`` -> ``EKF3``)."""
    return SOURCES[source][0] if source in SOURCES else source


def source_color(source: str) -> tuple[int, int, int]:
    """RGB colour of a source segment (stable for unknown names)."""
    if source in SOURCES:
        return SOURCES[source][1]
    return _FALLBACK_COLORS[sum(source.encode()) % len(_FALLBACK_COLORS)]


def pitch_path(source: str) -> str:
    """Time series of thx (pitch, about x) in degrees from ``source``."""
    return f"{PLOT_PITCH}/{source}"


def roll_path(source: str) -> str:
    """Time series of thy (roll, about y) in degrees from ``source``."""
    return f"{PLOT_ROLL}/{source}"


def yaw_path(source: str) -> str:
    """Time series of thz (yaw) in degrees from ``source``."""
    return f"{PLOT_YAW}/{source}"


def estimate_path(source: str) -> str:
    """3D transform of the ghost drone of ``source``."""
    return f"world/drone/estimate/{source}"


def estimate_model_path(source: str) -> str:
    """Static wireframe model of the ghost drone of ``source``."""
    return f"{estimate_path(source)}/model"

"""Entity paths, timelines, series labels and colours of every steval-link recording, in one place, so a replay and
a live recording have the same layout. Units are in the path names; ``viewer/README.md`` says what each holds."""

from __future__ import annotations

import re

#: Timelines: firmware s since boot (from t_us), host receive s since capture start, the AHRS step counter.
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
#: a BLE environment notification's values, in the order of ``BleEnvFrame``'s fields below
BLE_ENVIRONMENT = (BLE_PRESSURE, BLE_BATTERY, BLE_TEMPERATURE, BLE_RSSI)
BLE_NOTE = "ble/note"

LOG_FIRMWARE = "log/firmware"
LOG_HOST = "log/host"
LOG_COMMANDS = "log/commands"
#: notes about the firmware's own filter output: the first row with NaN or out-of-range values (it diverged)
LOG_FILTER = "log/filter"

#: Source names (entity path segments): the drone's output and the host's bit-exact replica of it.
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
    fallback = _FALLBACK_COLORS[sum(source.encode()) % len(_FALLBACK_COLORS)]
    return SOURCES[source][1] if source in SOURCES else fallback


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

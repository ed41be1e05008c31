"""Wire protocol v2 of the STEVAL-FCU001V1 telemetry (and v1, still decoded): layout, payload dtypes, encoders.

The layout is defined in ``firmware_patch/PROTOCOL.md``; this module is its Python side. Every multi-byte field is
little-endian and ``f32`` values carry the firmware's exact bits.

Frame: ``A5 5A | VT | LEN | payload[LEN] | CRC`` where ``VT`` = version << 4 | type. Version 2 (what the firmware
sends): CRC-32/ISO-HDLC (``zlib.crc32``), 4 bytes little-endian, over ``VT``, ``LEN`` and the payload. Version 1
(older captures): CRC-16/CCITT-FALSE (``binascii.crc_hqx(..., 0xFFFF)``), 2 bytes.
"""

from __future__ import annotations

import binascii
import struct
import zlib
from operator import itemgetter
from typing import Sequence

import numpy as np

from steval_link import constants as C

Vec = Sequence[float]  #: a vector argument (stored as float32)

SYNC = b"\xa5\x5a"
VERSION = 2  #: the version this tool's firmware patch sends
VERSION_1 = 1  #: the first protocol version (CRC-16), still decoded
HEADER_SIZE = len(SYNC) + 2  # sync, VT, LEN
CRC_SIZE = 4  #: v2: CRC-32
CRC_SIZE_V1 = 2  #: v1: CRC-16

TYPE_ATTITUDE = 1
TYPE_STATUS = 2
TYPE_TEXT = 3
TYPE_FLIGHT = 4  #: v2: flight control
TYPE_ACK = 5  #: v2: acknowledgement of a command
TYPE_COMMAND = 8  #: v2: host -> drone

TEXT_MAX_PAYLOAD = 255

#: Status ``flags`` bits.
FLAG_NO_CORRECTION = 1 << 0
FLAG_FRESH_SQUARES = 1 << 1
FLAG_TEXT_MODE = 1 << 2
FLAG_EVENT = 1 << 3  #: v2: sent at once because of a command (change, reset or request)
FLAG_INFLIGHT_TUNING = 1 << 4  #: v2: the build accepts filter changes while the motors may spin
FLAG_ARMED = 1 << 5  #: v2: the motors may spin now (throttle >= MIN_THR or armed)

#: Flight-control ``fc_flags`` bits.
FC_ARMED = 1 << 0
FC_RC_CONNECTED = 1 << 1
FC_RC_CAL = 1 << 2

#: Commands, SET_PARAM parameters, SET_MODE modes and ack results.
CMD_SET_PARAM = 1
CMD_RESET_FILTER = 2
CMD_REQUEST_STATUS = 3
CMD_SET_MODE = 4
PARAM_KP_GROUND = 1
PARAM_KP_FLIGHT = 2
PARAM_KI = 3
PARAM_MIN_THR = 4
PARAM_CORRECTION = 5
MODE_BINARY = 0
MODE_TEXT = 1
ACK_ACCEPTED = 0
ACK_REFUSED_ARMED = 1
ACK_UNKNOWN = 2
ACK_OUT_OF_RANGE = 3
ACK_NOT_IN_BUILD = 4

#: ``t_us`` wraps at 2**32 µs, ``seq`` (and a command's ``cmd_seq``) at 2**16, the status ``step`` at 2**32 steps.
T_US_MODULUS = 1 << 32
SEQ_MODULUS = 1 << 16
STEP_MODULUS = 1 << 32

#: Attitude payload, field by field (offsets as in PROTOCOL.md).
ATTITUDE_DTYPE = np.dtype(
    [
        ("t_us", "<u4"),
        ("acc_mg", "<f4", (3,)),
        ("gyro_mdps", "<f4", (3,)),
        ("q_wxyz", "<f4", (4,)),
        ("thz_rad", "<f4"),
        ("seq", "<u2"),
        ("thr", "<i2"),
    ]
)

#: Status payload, field by field (offsets as in PROTOCOL.md).
STATUS_DTYPE = np.dtype(
    [
        ("step", "<u4"),
        ("t_us", "<u4"),
        ("q_wxyz", "<f4", (4,)),
        ("int_xyz", "<f4", (3,)),
        ("kp_ground", "<f4"),
        ("kp_flight", "<f4"),
        ("ki", "<f4"),
        ("dt_s", "<f4"),
        ("cyc_min", "<u4"),
        ("cyc_mean", "<u4"),
        ("cyc_max", "<u4"),
        ("cpu_hz", "<u4"),
        ("tx_dropped", "<u4"),
        ("baud", "<u4"),
        ("cyc_n", "<u2"),
        ("min_thr", "<i2"),
        ("flags", "<u2"),
        ("queue_peak", "<u2"),
        ("fw_version", "u1", (2,)),  # v1: major, minor (its patch byte 0 reads as fc_every 0)
        ("fc_every", "u1"),  # v2: a flight-control frame every N steps (0 = none)
        ("param_gen", "u1"),  # v2: parameter changes and filter resets applied since boot, mod 256
    ]
)

#: Flight-control payload (type 4), sent after ``FlightControlPID_OuterLoop`` of step ``step``.
FLIGHT_DTYPE = np.dtype(
    [
        ("step", "<u4"),
        ("euler_rc_rad", "<f4", (3,)),  # targets thx (pitch), thy (roll), thz (yaw)
        ("rc", "<i2", (4,)),  # gAIL, gELE, gRUD, gTHR
        ("outer_s1", "<f4", (3,)),  # pid.x_s1, y_s1, z_s1 (rate setpoints, rad/s)
        ("inner_s2", "<f4", (3,)),  # pid.x_s2, y_s2, z_s2 (latest, from the TIM9 ISR)
        ("motor_pwm", "<f4", (4,)),  # motor1..4_pwm as computed
        ("vbat_v", "<f4"),
        ("fc_flags", "<u2"),
        ("fc_every", "u1"),
        ("reserved", "u1"),
    ]
)

#: Ack payload (type 5).
ACK_DTYPE = np.dtype(
    [("cmd_seq", "<u2"), ("cmd", "u1"), ("result", "u1"), ("step", "<u4"), ("rx_ok", "<u2"), ("rx_bad", "<u2")]
)

#: Command payload (type 8, host -> drone).
COMMAND_DTYPE = np.dtype([("cmd_seq", "<u2"), ("cmd", "u1"), ("param", "u1"), ("value", "<f4"), ("reserved", "<u4")])


#: The payload dtype of each fixed-size frame type: the one statement of the binary layout.
PAYLOAD_DTYPE = {
    TYPE_ATTITUDE: ATTITUDE_DTYPE,
    TYPE_STATUS: STATUS_DTYPE,
    TYPE_FLIGHT: FLIGHT_DTYPE,
    TYPE_ACK: ACK_DTYPE,
    TYPE_COMMAND: COMMAND_DTYPE,
}
#: Payload length of each fixed-size frame type, by protocol version (v1 knew attitude and status only).
FIXED_PAYLOAD_SIZE = {t: d.itemsize for t, d in PAYLOAD_DTYPE.items()}
FIXED_PAYLOAD_SIZE_V1 = {t: FIXED_PAYLOAD_SIZE[t] for t in (TYPE_ATTITUDE, TYPE_STATUS)}

ATTITUDE_PAYLOAD_SIZE = ATTITUDE_DTYPE.itemsize  # 52
STATUS_PAYLOAD_SIZE = STATUS_DTYPE.itemsize  # 88
ATTITUDE_FRAME_SIZE = HEADER_SIZE + ATTITUDE_PAYLOAD_SIZE + CRC_SIZE  # 60
STATUS_FRAME_SIZE = HEADER_SIZE + STATUS_PAYLOAD_SIZE + CRC_SIZE  # 96
FLIGHT_FRAME_SIZE = HEADER_SIZE + FLIGHT_DTYPE.itemsize + CRC_SIZE  # 80
ACK_FRAME_SIZE = HEADER_SIZE + ACK_DTYPE.itemsize + CRC_SIZE  # 20
COMMAND_FRAME_SIZE = HEADER_SIZE + COMMAND_DTYPE.itemsize + CRC_SIZE  # 20
ATTITUDE_FRAME_SIZE_V1 = HEADER_SIZE + ATTITUDE_PAYLOAD_SIZE + CRC_SIZE_V1  # 58
STATUS_FRAME_SIZE_V1 = HEADER_SIZE + STATUS_PAYLOAD_SIZE + CRC_SIZE_V1  # 94

#: Payload fields that carry nothing (padding); frames and rows do not keep them.
RESERVED = "reserved"
_STRUCT_CHAR = {"u1": "B", "u2": "H", "i2": "h", "u4": "I", "f4": "f"}


def payload_fields(dtype: np.dtype) -> tuple[str, ...]:
    """The names of the fields of payload ``dtype`` that a frame keeps (all but :data:`RESERVED`), in wire order."""
    return tuple(name for name in dtype.names if name != RESERVED)


def payload_layout(dtype: np.dtype) -> tuple[struct.Struct, itemgetter]:
    """How to read payload ``dtype`` with ``struct``: ``pick(layout.unpack_from(buf, pos))`` gives its
    :func:`payload_fields` in order, a subarray field as a tuple (a float32 is exact as a float)."""
    codes, picks, i = [], [], 0
    for name in dtype.names:
        sub = dtype.fields[name][0]
        count = sub.shape[0] if sub.shape else 1
        codes.append(f"{count}{_STRUCT_CHAR[sub.base.kind + str(sub.base.itemsize)]}")
        if name != RESERVED:
            picks.append(slice(i, i + count) if sub.shape else i)
        i += count
    layout = struct.Struct("<" + "".join(codes))
    assert layout.size == dtype.itemsize, dtype
    return layout, itemgetter(*picks)


def crc16(data: bytes | bytearray | memoryview) -> int:
    """v1 frame check: CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF, no reflection, no final XOR)."""
    return binascii.crc_hqx(data, 0xFFFF)


#: v2 frame check: CRC-32/ISO-HDLC (check value of ``b"123456789"``: 0xCBF43926).
crc32 = zlib.crc32
#: The frame check of each protocol version: (its size in bytes, the function of VT .. payload).
CHECK = {VERSION_1: (CRC_SIZE_V1, crc16), VERSION: (CRC_SIZE, crc32)}


def vt_byte(version: int, frame_type: int) -> int:
    """The ``VT`` byte of a frame: ``version << 4 | type``."""
    return (version << 4) | (frame_type & 0x0F)


def encode_frame(frame_type: int, payload: bytes, version: int = VERSION) -> bytes:
    """One complete frame of ``frame_type`` around ``payload`` (0..255 bytes); ``version`` 1 for v1 test data."""
    if not 0 <= len(payload) <= 255:
        raise ValueError(f"payload of {len(payload)} bytes does not fit one frame (0..255)")
    body = bytes((vt_byte(version, frame_type), len(payload))) + payload
    size, check = CHECK[version]
    return SYNC + body + check(body).to_bytes(size, "little")


def encode_attitude(
    *, t_us: int, acc_mg: Vec, gyro_mdps: Vec, q_wxyz: Vec, thz_rad: float, seq: int, thr: int
) -> bytes:
    """An attitude frame (v2); floats are stored as float32 (pass float32 values to keep their exact bits)."""
    fields = {**locals(), "t_us": t_us % T_US_MODULUS, "seq": seq % SEQ_MODULUS}  # the arguments are the fields
    return encode_frame(TYPE_ATTITUDE, _record(ATTITUDE_DTYPE, fields))


def encode_attitude_block(records: np.ndarray, version: int = VERSION) -> bytes:
    """Many attitude frames at once from a structured array of ``ATTITUDE_DTYPE`` (fast path for synthesis)."""
    records = np.ascontiguousarray(records, dtype=ATTITUDE_DTYPE)
    n = len(records)
    crc_size, check = CHECK[version]
    end = HEADER_SIZE + ATTITUDE_PAYLOAD_SIZE
    out = np.empty((n, end + crc_size), dtype=np.uint8)
    out[:, :HEADER_SIZE] = np.frombuffer(
        SYNC + bytes((vt_byte(version, TYPE_ATTITUDE), ATTITUDE_PAYLOAD_SIZE)), np.uint8
    )
    out[:, HEADER_SIZE:end] = records.view(np.uint8).reshape(n, -1)
    crcs = np.fromiter((check(out[i, 2:end].tobytes()) for i in range(n)), dtype=np.uint32, count=n)
    out[:, end:] = crcs.astype("<u4").view(np.uint8).reshape(n, 4)[:, :crc_size]
    return out.tobytes()


#: The status fields :func:`encode_status` fills in when not given (the firmware's defaults); the others are 0.
STATUS_DEFAULTS = dict(
    kp_ground=C.KP_GROUND, kp_flight=C.KP_FLIGHT, ki=C.KI, dt_s=C.DT_S, cpu_hz=C.CPU_HZ, baud=C.BAUD, min_thr=C.MIN_THR
)


def encode_status(*, step: int, t_us: int, q_wxyz: Vec, int_xyz: Vec, version: int = VERSION, **fields) -> bytes:
    """A status frame; other ``STATUS_DTYPE`` fields by name (default :data:`STATUS_DEFAULTS`, fw_version 2.0, 0)."""
    unknown = set(fields) - set(STATUS_DTYPE.names)
    if unknown:
        raise TypeError(f"encode_status() got unknown fields {sorted(unknown)}")
    fields = {**STATUS_DEFAULTS, "fw_version": (2, 0), **fields, "q_wxyz": q_wxyz, "int_xyz": int_xyz}
    fields.update(step=step % STEP_MODULUS, t_us=t_us % T_US_MODULUS)
    return encode_frame(TYPE_STATUS, _record(STATUS_DTYPE, fields), version)


def encode_text(line: str, version: int = VERSION) -> bytes:
    """Text frames for one log line (UTF-8, split into 255-byte pieces; an empty line is one space)."""
    data = line.rstrip("\r\n").encode("utf-8") or b" "
    return b"".join(
        encode_frame(TYPE_TEXT, data[i : i + TEXT_MAX_PAYLOAD], version) for i in range(0, len(data), TEXT_MAX_PAYLOAD)
    )


def _record(dtype: np.dtype, fields: dict) -> bytes:
    """The payload of ``dtype`` holding the ``fields`` that are its own (others ignored; missing ones are 0)."""
    rec = np.zeros((), dtype=dtype)
    for name in dtype.names:
        if name in fields:
            rec[name] = fields[name]
    return rec.tobytes()


def encode_flight(**fields) -> bytes:
    """A flight-control frame (type 4) from ``FLIGHT_DTYPE`` fields given by name (missing ones are 0)."""
    return encode_frame(TYPE_FLIGHT, _record(FLIGHT_DTYPE, fields))


def encode_ack(*, cmd_seq: int, cmd: int, result: int, step: int, rx_ok: int = 0, rx_bad: int = 0) -> bytes:
    """An acknowledgement frame (type 5)."""
    fields = {**locals(), "cmd_seq": cmd_seq % SEQ_MODULUS, "step": step % STEP_MODULUS}  # the arguments are the fields
    fields.update(rx_ok=rx_ok % SEQ_MODULUS, rx_bad=rx_bad % SEQ_MODULUS)
    return encode_frame(TYPE_ACK, _record(ACK_DTYPE, fields))


def encode_command(*, cmd_seq: int, cmd: int, param: int = 0, value: float = 0.0) -> bytes:
    """A host -> drone command frame (type 8); ``value`` is stored as float32."""
    fields = dict(cmd_seq=cmd_seq % SEQ_MODULUS, cmd=cmd, param=param, value=np.float32(value))
    return encode_frame(TYPE_COMMAND, _record(COMMAND_DTYPE, fields))

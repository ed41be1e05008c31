"""Wire protocol v1 of the STEVAL-FCU001V1 telemetry: frame layout, payload dtypes and the encoder.

The layout is defined in ``firmware_patch/PROTOCOL.md``; this module is its Python side. Every multi-byte field is
little-endian and ``f32`` values carry the firmware's exact bits.

Frame: ``A5 5A | VT | LEN | payload[LEN] | CRC16 (LE)`` where ``VT`` = version << 4 | type and the CRC is
CRC-16/CCITT-FALSE (``binascii.crc_hqx(..., 0xFFFF)``) over ``VT``, ``LEN`` and the payload.
"""

from __future__ import annotations

import binascii
import struct
from typing import Sequence

import numpy as np

from steval_link import constants as C

SYNC = b"\xa5\x5a"
VERSION = 1
HEADER_SIZE = 4  # sync (2) + VT + LEN
CRC_SIZE = 2
CRC_INIT = 0xFFFF

TYPE_ATTITUDE = 1
TYPE_STATUS = 2
TYPE_TEXT = 3

ATTITUDE_PAYLOAD_SIZE = 52
STATUS_PAYLOAD_SIZE = 88
TEXT_MAX_PAYLOAD = 255

ATTITUDE_FRAME_SIZE = HEADER_SIZE + ATTITUDE_PAYLOAD_SIZE + CRC_SIZE  # 58
STATUS_FRAME_SIZE = HEADER_SIZE + STATUS_PAYLOAD_SIZE + CRC_SIZE  # 94

#: Payload length of each fixed-size frame type.
FIXED_PAYLOAD_SIZE = {TYPE_ATTITUDE: ATTITUDE_PAYLOAD_SIZE, TYPE_STATUS: STATUS_PAYLOAD_SIZE}

#: Status ``flags`` bits.
FLAG_NO_CORRECTION = 1 << 0
FLAG_FRESH_SQUARES = 1 << 1
FLAG_TEXT_MODE = 1 << 2

#: ``t_us`` wraps at 2**32 µs, ``seq`` at 2**16 steps.
T_US_MODULUS = 1 << 32
SEQ_MODULUS = 1 << 16

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
assert ATTITUDE_DTYPE.itemsize == ATTITUDE_PAYLOAD_SIZE

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
        ("fw_version", "u1", (3,)),
        ("reserved", "u1"),
    ]
)
assert STATUS_DTYPE.itemsize == STATUS_PAYLOAD_SIZE


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF, no reflection, no final XOR)."""
    return binascii.crc_hqx(data, CRC_INIT)


def encode_frame(frame_type: int, payload: bytes) -> bytes:
    """One complete frame of ``frame_type`` around ``payload`` (0..255 bytes)."""
    if not 0 <= len(payload) <= 255:
        raise ValueError(f"payload of {len(payload)} bytes does not fit one frame (0..255)")
    body = bytes(((VERSION << 4) | (frame_type & 0x0F), len(payload))) + payload
    return SYNC + body + struct.pack("<H", crc16(body))


def encode_attitude(
    *,
    t_us: int,
    acc_mg: Sequence[float],
    gyro_mdps: Sequence[float],
    q_wxyz: Sequence[float],
    thz_rad: float,
    seq: int,
    thr: int,
) -> bytes:
    """An attitude frame; floats are stored as float32 (pass float32 values to keep their exact bits)."""
    rec = np.zeros((), dtype=ATTITUDE_DTYPE)
    rec["t_us"] = t_us % T_US_MODULUS
    rec["acc_mg"] = np.asarray(acc_mg, dtype=np.float32)
    rec["gyro_mdps"] = np.asarray(gyro_mdps, dtype=np.float32)
    rec["q_wxyz"] = np.asarray(q_wxyz, dtype=np.float32)
    rec["thz_rad"] = np.float32(thz_rad)
    rec["seq"] = seq % SEQ_MODULUS
    rec["thr"] = thr
    return encode_frame(TYPE_ATTITUDE, rec.tobytes())


def encode_attitude_block(records: np.ndarray) -> bytes:
    """Many attitude frames at once from a structured array of ``ATTITUDE_DTYPE`` (fast path for synthesis)."""
    records = np.ascontiguousarray(records, dtype=ATTITUDE_DTYPE)
    n = len(records)
    out = np.empty((n, ATTITUDE_FRAME_SIZE), dtype=np.uint8)
    out[:, 0] = SYNC[0]
    out[:, 1] = SYNC[1]
    out[:, 2] = (VERSION << 4) | TYPE_ATTITUDE
    out[:, 3] = ATTITUDE_PAYLOAD_SIZE
    out[:, HEADER_SIZE : HEADER_SIZE + ATTITUDE_PAYLOAD_SIZE] = records.view(np.uint8).reshape(n, -1)
    end = HEADER_SIZE + ATTITUDE_PAYLOAD_SIZE
    for i in range(n):
        crc = binascii.crc_hqx(out[i, 2:end].tobytes(), CRC_INIT)
        out[i, end] = crc & 0xFF
        out[i, end + 1] = crc >> 8
    return out.tobytes()


def encode_status(
    *,
    step: int,
    t_us: int,
    q_wxyz: Sequence[float],
    int_xyz: Sequence[float],
    kp_ground: float = C.KP_GROUND,
    kp_flight: float = C.KP_FLIGHT,
    ki: float = C.KI,
    dt_s: float = C.DT_S,
    cyc_min: int = 0,
    cyc_mean: int = 0,
    cyc_max: int = 0,
    cyc_n: int = 0,
    cpu_hz: int = C.CPU_HZ,
    tx_dropped: int = 0,
    baud: int = C.BAUD,
    min_thr: int = C.MIN_THR,
    flags: int = 0,
    queue_peak: int = 0,
    fw_version: Sequence[int] = (1, 0, 0),
) -> bytes:
    """A status frame: link statistics, filter settings and the filter-state snapshot after ``step``."""
    rec = np.zeros((), dtype=STATUS_DTYPE)
    rec["step"] = step % (1 << 32)
    rec["t_us"] = t_us % T_US_MODULUS
    rec["q_wxyz"] = np.asarray(q_wxyz, dtype=np.float32)
    rec["int_xyz"] = np.asarray(int_xyz, dtype=np.float32)
    rec["kp_ground"] = kp_ground
    rec["kp_flight"] = kp_flight
    rec["ki"] = ki
    rec["dt_s"] = dt_s
    rec["cyc_min"] = cyc_min
    rec["cyc_mean"] = cyc_mean
    rec["cyc_max"] = cyc_max
    rec["cyc_n"] = cyc_n
    rec["cpu_hz"] = cpu_hz
    rec["tx_dropped"] = tx_dropped
    rec["baud"] = baud
    rec["min_thr"] = min_thr
    rec["flags"] = flags
    rec["queue_peak"] = queue_peak
    rec["fw_version"] = fw_version
    return encode_frame(TYPE_STATUS, rec.tobytes())


def encode_text(line: str) -> bytes:
    """Text frames for one log line (UTF-8, split into 255-byte pieces; an empty line is one space)."""
    data = line.rstrip("\r\n").encode("utf-8") or b" "
    return b"".join(
        encode_frame(TYPE_TEXT, data[i : i + TEXT_MAX_PAYLOAD]) for i in range(0, len(data), TEXT_MAX_PAYLOAD)
    )

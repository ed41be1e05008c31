"""One decoded frame each: :class:`AttitudeFrame`, :class:`StatusFrame`, :class:`TextFrame`, and the v2 frames
:class:`FlightFrame`, :class:`AckFrame` (drone → host) and :class:`CommandFrame` (host → drone).

Field names follow the payload dtypes of :mod:`steval_link.link.protocol` (units in the names). Binary frames carry the
firmware's exact float32 values (as Python floats, which hold them exactly); text-mode rows (``exact=False``) carry
the rounded integers of the ``$ATT``/``$STA`` lines converted to the same units. ``offset`` is the stream byte offset
of the frame's first byte and ``nbytes`` its length on the wire (frame or text line including the line ending).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

NAN = math.nan
_NAN3 = (NAN, NAN, NAN)
_NAN4 = (NAN, NAN, NAN, NAN)


@dataclass(slots=True)
class AttitudeFrame:
    """One AHRS step (binary attitude frame, or a text-mode ``$ATT`` row when ``exact`` is False).

    ``t_us`` firmware time in µs mod 2³²; ``acc_mg`` (x, y, z) mg and ``gyro_mdps`` (x, y, z) mdps as passed to
    ``ahrs_fusion_ag``; ``q_wxyz`` the filter quaternion after the step (NaN in text mode); ``thz_rad`` the
    ISR-integrated yaw, rad; ``seq`` step counter mod 2¹⁶; ``thr`` gTHR. ``step`` is the full step counter when the
    frame itself carries it (text mode), else None (the binary frame only has ``seq``; :class:`Telemetry` unwraps
    it). ``thx_rad`` (pitch, about x) / ``thy_rad`` (roll, about y) come from the text line; NaN for binary frames,
    whose angles are recomputed bit-exactly from ``q_wxyz`` in :class:`~steval_link.link.telemetry.Telemetry`.
    """

    t_us: int
    acc_mg: tuple[float, float, float]
    gyro_mdps: tuple[float, float, float]
    q_wxyz: tuple[float, float, float, float]
    thz_rad: float
    seq: int
    thr: int
    exact: bool = True
    offset: int = 0
    nbytes: int = 0
    step: int | None = None
    thx_rad: float = NAN
    thy_rad: float = NAN


@dataclass(slots=True)
class StatusFrame:
    """Link statistics, filter settings and filter-state snapshot, about once a second (fields as STATUS_DTYPE).

    Text-mode ``$STA`` rows (``exact`` False) carry only step, t_us, cycle figures, tx_dropped, flags and ki; the
    other float fields are NaN and the other integers 0.
    """

    step: int
    t_us: int
    q_wxyz: tuple[float, float, float, float] = _NAN4
    int_xyz: tuple[float, float, float] = _NAN3
    kp_ground: float = NAN
    kp_flight: float = NAN
    ki: float = NAN
    dt_s: float = NAN
    cyc_min: int = 0
    cyc_mean: int = 0
    cyc_max: int = 0
    cpu_hz: int = 0
    tx_dropped: int = 0
    baud: int = 0
    cyc_n: int = 0
    min_thr: int = 0
    flags: int = 0
    queue_peak: int = 0
    fw_version: tuple[int, int] = (0, 0)
    fc_every: int = 0
    param_gen: int = 0
    exact: bool = True
    offset: int = 0
    nbytes: int = 0


@dataclass(slots=True)
class TextFrame:
    """One firmware log line (binary text frame, or a plain line of a text-mode stream), without line ending."""

    text: str
    offset: int = 0
    nbytes: int = 0


@dataclass(slots=True)
class FlightFrame:
    """Flight control of one AHRS step (v2 type 4; fields as FLIGHT_DTYPE). ``rc`` is (gAIL, gELE, gRUD, gTHR)."""

    step: int
    euler_rc_rad: tuple[float, float, float]
    rc: tuple[int, int, int, int]
    outer_s1: tuple[float, float, float]
    inner_s2: tuple[float, float, float]
    motor_pwm: tuple[float, float, float, float]
    vbat_v: float
    fc_flags: int
    fc_every: int
    offset: int = 0
    nbytes: int = 0


@dataclass(slots=True)
class AckFrame:
    """The drone's answer to one command (v2 type 5; fields as ACK_DTYPE)."""

    cmd_seq: int
    cmd: int
    result: int
    step: int
    rx_ok: int
    rx_bad: int
    offset: int = 0
    nbytes: int = 0


@dataclass(slots=True)
class CommandFrame:
    """One host → drone command (v2 type 8; fields as COMMAND_DTYPE)."""

    cmd_seq: int
    cmd: int
    param: int
    value: float
    offset: int = 0
    nbytes: int = 0


Frame = AttitudeFrame | StatusFrame | TextFrame | FlightFrame | AckFrame | CommandFrame


@dataclass(slots=True)
class DecoderStats:
    """Counters of one decoded stream (see the module docstring for the exact rules)."""

    frames_ok: int = 0  #: valid frames handed out (all types, binary and text mode)
    attitude: int = 0
    status: int = 0
    text: int = 0
    crc_failures: int = 0  #: binary frames with a valid header but a bad CRC; ``$`` lines with a bad checksum
    bytes_skipped: int = 0  #: bytes that were not part of a frame handed out
    seq_gaps: int = 0  #: gap events in the attitude ``seq`` (frames dropped on the way)
    frames_missing: int = 0  #: attitude frames lost in those gaps (sum of the missing ``seq`` values)
    seq_resets: int = 0  #: ``seq`` went backwards (firmware restart)
    unknown_frames: int = 0  #: CRC-valid frames of a type this decoder does not know
    bytes_total: int = 0  #: bytes fed
    flight: int = 0  #: v2 flight-control frames
    ack: int = 0  #: v2 acknowledgements
    command: int = 0  #: v2 host -> drone commands (decoded from the host's own bytes)
    v1_frames: int = 0  #: frames of protocol version 1 (CRC-16: about 1 in 65 536 damaged candidates passes)
    implausible: int = 0  #: CRC-valid frames held back by the plausibility checks (never handed out)
    held_values: int = 0  #: of ``implausible``: v1 frames held back for NaN or out-of-range values
    values_bad: int = 0  #: attitude rows handed out with NaN or out-of-range values (v2: the firmware sent them)

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict (JSON-friendly)."""
        return asdict(self)

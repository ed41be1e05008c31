"""One decoded frame each: :class:`AttitudeFrame`, :class:`StatusFrame`, :class:`TextFrame`, :class:`TextRecordFrame`
(text telemetry), and the v2 :class:`FlightFrame`, :class:`AckFrame` (drone → host), :class:`CommandFrame`.

The wire fields of each binary frame are made from the payload dtype of :mod:`steval_link.link.protocol`. Binary
frames carry the firmware's exact float32 values, text-mode rows (``exact=False``) the rounded integers of
``$ATT``/``$STA`` lines. ``offset``/``nbytes``: the frame's bytes in the stream (a line with its ending).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, make_dataclass

import numpy as np

from steval_link.link import protocol as P

NAN = math.nan


#: where a frame came from: its stream offset and its length on the wire, bytes
_WHERE = [("offset", int, 0), ("nbytes", int, 0)]
#: a binary frame (True) or a text-mode row, then where it came from
_EXACT_WHERE = [("exact", bool, True), *_WHERE]


def _wire_fields(payload: np.dtype, required: int | None = None, extra: list = _WHERE) -> type:
    """A slotted dataclass base with the fields of ``payload`` but ``RESERVED``, in wire order (a subarray as a
    tuple), then ``extra``; the fields after the first ``required`` default to NaN or 0."""
    fields = []
    for i, name in enumerate(P.payload_fields(payload)):
        sub = payload.fields[name][0]
        kind = float if sub.base.kind == "f" else int
        blank = NAN if kind is float else 0
        typ = tuple[(kind,) * sub.shape[0]] if sub.shape else kind
        if required is not None and i >= required:
            fields.append((name, typ, (blank,) * sub.shape[0] if sub.shape else blank))
        else:
            fields.append((name, typ))
    base = make_dataclass("WireFields", fields + extra, slots=True)
    base.__module__ = __name__
    return base


@dataclass(slots=True)
class AttitudeFrame(_wire_fields(P.ATTITUDE_DTYPE, extra=_EXACT_WHERE)):
    """One AHRS step (a binary frame, or a text-mode row: ``exact`` False): ``acc_mg``/``gyro_mdps`` as passed to
    ``ahrs_fusion_ag``, ``q_wxyz`` after the step (text: NaN), ``thz_rad`` the ISR-integrated yaw, ``thr`` gTHR.
    ``step``: text rows' full step (binary: None); ``thx_rad`` (pitch), ``thy_rad`` (roll): text rows' (binary: NaN)."""

    step: int | None = None
    thx_rad: float = NAN
    thy_rad: float = NAN

    @classmethod
    def text_row(cls, step: int, t_us: int, acc_mg, gyro_mdps, euler_rad, thr: int, offset: int, nbytes: int):
        """A row that is no binary frame (``exact`` False, no quaternion): ``euler_rad`` thx, thy, thz."""
        thx, thy, thz = euler_rad
        acc, gyro = tuple(acc_mg), tuple(gyro_mdps)
        seq, t_us = step % P.SEQ_MODULUS, t_us % P.T_US_MODULUS
        return cls(t_us, acc, gyro, (NAN,) * 4, thz, seq, thr, False, offset, nbytes, step, thx, thy)


@dataclass(slots=True)
class StatusFrame(_wire_fields(P.STATUS_DTYPE, required=2, extra=_EXACT_WHERE)):
    """Link statistics, filter settings and filter-state snapshot, about once a second. Text-mode ``$STA`` rows
    carry only step, t_us, cycle figures, tx_dropped, flags and ki (other floats NaN, integers 0)."""


@dataclass(slots=True)
class TextFrame:
    """One firmware log line (binary text frame, or a plain line of a text-mode stream), without line ending."""

    text: str
    offset: int = 0
    nbytes: int = 0


@dataclass(slots=True)
class TextRecordFrame:
    """One record of text telemetry: the ``values`` of one line or a few (NaN: an empty field), their ``names``
    (``col1..N`` when none), ``units`` as written, the format's ``kind`` ('table', 'labelled', 'teleplot', ...)."""

    names: tuple[str, ...]
    values: tuple[float, ...]
    units: tuple[str, ...]
    kind: str
    offset: int = 0
    nbytes: int = 0


@dataclass(slots=True)
class FlightFrame(_wire_fields(P.FLIGHT_DTYPE)):
    """Flight control of one AHRS step (v2 type 4; fields as FLIGHT_DTYPE). ``rc`` is (gAIL, gELE, gRUD, gTHR)."""


@dataclass(slots=True)
class AckFrame(_wire_fields(P.ACK_DTYPE)):
    """The drone's answer to one command (v2 type 5; fields as ACK_DTYPE)."""


@dataclass(slots=True)
class CommandFrame(_wire_fields(P.COMMAND_DTYPE)):
    """One host → drone command (v2 type 8; fields as COMMAND_DTYPE)."""


Frame = AttitudeFrame | StatusFrame | TextFrame | TextRecordFrame | FlightFrame | AckFrame | CommandFrame
#: The frame class of each fixed-size binary frame type, in the order of ``protocol.PAYLOAD_DTYPE`` (its wire fields).
FRAME_OF_TYPE = {
    P.TYPE_ATTITUDE: AttitudeFrame,
    P.TYPE_STATUS: StatusFrame,
    P.TYPE_FLIGHT: FlightFrame,
    P.TYPE_ACK: AckFrame,
    P.TYPE_COMMAND: CommandFrame,
}


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
    text_records: int = 0  #: records of text telemetry (``TextRecordFrame``), each counted once
    text_dropped: int = 0  #: whole printable lines dropped as not text (random bytes; their bytes are skipped)
    blank_bytes: int = 0  #: bytes of blank lines (spaces, tabs) and of the ``\r`` of ``\n\r`` endings: not damage

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict (JSON-friendly)."""
        return asdict(self)

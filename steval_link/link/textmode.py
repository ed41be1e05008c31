"""Text mode of the wire protocol: ``$ATT``/``$STA`` lines with an NMEA-style checksum, and plain log lines.

A text-mode line is ASCII (log lines may be any printable UTF-8), at most :data:`MAX_LINE_BYTES` bytes including
its ``\\n`` (an optional ``\\r`` before it is dropped)::

    $ATT,<step>,<t_ms>,<thr>,<thx_mdeg>,<thy_mdeg>,<thz_mdeg>,<acc_x_mg>,<acc_y_mg>,<acc_z_mg>,
         <gyro_x_mdps>,<gyro_y_mdps>,<gyro_z_mdps>*HH
    $STA,<step>,<t_ms>,<cyc_min>,<cyc_mean>,<cyc_max>,<cyc_n>,<tx_dropped>,<flags>,<ki_micro>*HH

``HH`` is the XOR of every byte between ``$`` and ``*`` as two upper-case hex digits. Values are integers rounded
toward zero (angles in millidegrees, acc in mg, gyro in mdps, ``t_ms`` = ``t_us // 1000``, ``ki_micro`` = KI × 10⁶).
See ``firmware_patch/PROTOCOL.md``.
"""

from __future__ import annotations

import functools
import math
import operator
import re

from steval_link.link import protocol as P
from steval_link.link.frames import AttitudeFrame, StatusFrame, TextFrame

#: Longest line accepted, in bytes, including the line ending.
MAX_LINE_BYTES = 512

_INT = rb"-?[0-9]{1,11}"
_ATT_RE = re.compile(rb"\$ATT((?:," + _INT + rb"){12})\*([0-9A-F]{2})")
_STA_RE = re.compile(rb"\$STA((?:," + _INT + rb"){9})\*([0-9A-F]{2})")
_SENTENCE_RE = re.compile(rb"\$([A-Z][A-Z0-9]{2,}(?:,[^*]*)?)\*([0-9A-F]{2})")
#: Bytes that may never appear inside a text line (control characters except TAB, and DEL).
BAD_LINE_BYTE = re.compile(rb"[\x00-\x08\x0a-\x1f\x7f]")

_MDEG_TO_RAD = math.pi / 180_000.0


def checksum(body: bytes) -> int:
    """XOR of the bytes of ``body`` (the text between ``$`` and ``*``)."""
    return functools.reduce(operator.xor, body, 0)


def _sentence(body: str) -> bytes:
    raw = body.encode("ascii")
    return b"$" + raw + b"*%02X\r\n" % checksum(raw)


def _trunc(x: float) -> int:
    """Round toward zero, as the firmware's integer conversion does."""
    try:
        return operator.index(x)  # any integer type, exactly
    except TypeError:
        return int(math.trunc(float(x)))


def format_att(
    *, step: int, t_ms: int, thr: int, thx_mdeg: int, thy_mdeg: int, thz_mdeg: int, acc_mg, gyro_mdps
) -> bytes:
    """One ``$ATT`` line with checksum and ``\\r\\n`` (integers; floats are rounded toward zero)."""
    vals = [step, t_ms, thr, thx_mdeg, thy_mdeg, thz_mdeg, *acc_mg, *gyro_mdps]
    return _sentence("ATT," + ",".join(str(_trunc(v)) for v in vals))


#: The fields of a ``$STA`` line, in order.
STA_FIELDS = ("step", "t_ms", "cyc_min", "cyc_mean", "cyc_max", "cyc_n", "tx_dropped", "flags", "ki_micro")


def format_sta(**fields: int) -> bytes:
    """One ``$STA`` line of the :data:`STA_FIELDS` (each one required) with checksum and ``\\r\\n``."""
    return _sentence("STA," + ",".join(str(_trunc(fields[k])) for k in STA_FIELDS))


def parse_sentence(line: bytes, *, offset: int = 0, nbytes: int = 0) -> AttitudeFrame | StatusFrame | TextFrame | None:
    """One ``$`` line (no ending) as a frame (another name: a :class:`TextFrame`); None when it does not check."""
    m = _SENTENCE_RE.fullmatch(line)
    if m is None or checksum(m.group(1)) != int(m.group(2), 16):
        return None
    if not line.startswith((b"$ATT,", b"$STA,")):
        return TextFrame(line.decode("ascii", "replace"), offset=offset, nbytes=nbytes)
    attitude = line.startswith(b"$ATT,")
    fields = (_ATT_RE if attitude else _STA_RE).fullmatch(line)
    if fields is None:
        return None
    v = [int(x) for x in fields.group(1)[1:].split(b",")]
    if attitude:
        step, t_ms, thr = v[0], v[1], v[2]
        if step < 0 or t_ms < 0 or not -32768 <= thr <= 32767:
            return None
        acc, gyro, euler = map(float, v[6:9]), map(float, v[9:12]), (x * _MDEG_TO_RAD for x in v[3:6])
        return AttitudeFrame.text_row(step, t_ms * 1000, acc, gyro, euler, thr, offset, nbytes)
    if min(v[:8]) < 0:
        return None
    kw = dict(zip(STA_FIELDS[2:8], v[2:8]), step=v[0] % P.STEP_MODULUS, t_us=(v[1] * 1000) % P.T_US_MODULUS)
    return StatusFrame(**kw, ki=v[8] / 1e6, exact=False, offset=offset, nbytes=nbytes)


def decode_line(raw: bytes) -> str | None:
    """The text of one line (a trailing ``\\r`` dropped), or None when it is empty, not UTF-8 or not printable."""
    if raw.endswith(b"\r"):
        raw = raw[:-1]
    if not raw or BAD_LINE_BYTE.search(raw):
        return None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        return None
    return text if text.replace("\t", " ").isprintable() else None

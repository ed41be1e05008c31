"""A decoded capture as an MCAP file (``steval export --mcap``) for Foxglove, PlotJuggler, ROS 2 tools and Rerun: JSON
messages (``jsonschema`` schemas, written in full in the file) logged at the firmware's time (ns since boot), one per
frame (:data:`TOPICS`): ``/attitude/transform`` (``foxglove.FrameTransform`` ``world`` → ``drone``), ``/attitude/pose``
(``foxglove.PoseInFrame``), ``/attitude`` (``steval.Attitude``: IMU inputs, the firmware's estimate), ``/status`` and
``/flight_control``. Foxglove quaternions are the firmware's ``q`` normalised (text-mode rows: from their angles).
Numbers are float32 written with 9 significant digits; NaN is ``null``."""

from __future__ import annotations

import contextlib
import json
import math
import re
import struct
import zlib
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from steval_link.analysis.frame_tables import RENAMED
from steval_link.errors import ParamError
from steval_link.link import protocol as P
from steval_link.quat import quaternion_from_euler

INSTALL_HINT = 'pip install "steval-link[mcap]"'
_TIME = dict(type="object", title="time", properties={k: {"type": "integer", "minimum": 0} for k in ("sec", "nsec")})
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}

#: foxglove.FrameTransform (https://docs.foxglove.dev/docs/visualization/message-schemas/frame-transform)
FRAME_TRANSFORM_SCHEMA = {
    "title": "foxglove.FrameTransform",
    "description": "A transform between two reference frames in 3D space",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": _VEC3,
        "rotation": _QUAT,
    },
}
#: foxglove.PoseInFrame (https://docs.foxglove.dev/docs/visualization/message-schemas/pose-in-frame)
POSE_IN_FRAME_SCHEMA = {
    "title": "foxglove.PoseInFrame",
    "description": "A timestamped pose for an object or reference frame in 3D space",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}},
    },
}


def _num(description: str) -> dict[str, Any]:
    return {"type": ["number", "null"], "description": description}


def _arr(n: int, description: str) -> dict[str, Any]:
    return dict(type="array", items={"type": ["number", "null"]}, minItems=n, maxItems=n, description=description)


def _int(description: str) -> dict[str, Any]:
    return {"type": "integer", "description": description}


#: steval.Attitude: one attitude frame (PROTOCOL.md type 1): the inputs and outputs of one AHRS step.
ATTITUDE_SCHEMA = {
    "title": "steval.Attitude",
    "description": "One AHRS step of the STEVAL-FCU001V1 (attitude frame): the exact inputs of ahrs_fusion_ag and "
    "the firmware's estimate. Axes x right, y forward, z up.",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "step": _int("AHRS step counter (unwrapped)"),
        "seq": _int("sequence number as sent (u16)"),
        "t_fw_s": _num("firmware time, s since boot"),
        "t_host_s": _num("host receive time, s since the capture started (null when unknown)"),
        "acc_mg": _arr(3, "accelerometer x, y, z, mg (input of ahrs_fusion_ag)"),
        "gyro_mdps": _arr(3, "gyroscope x, y, z, mdps (input of ahrs_fusion_ag)"),
        "thr": _int("throttle gTHR"),
        "q_wxyz": _arr(
            4, "ahrs.q after the step, w x y z, as the firmware holds it (|q| about 0.9983); null in text mode"
        ),
        "thx_pitch_rad": _num("pitch: rotation about x, nose up +, rad"),
        "thy_roll_rad": _num("roll: rotation about y, rad"),
        "thz_yaw_rad": _num("yaw integrated from the gyro in the ISR, rad"),
        "exact": {"type": "boolean", "description": "true for binary frames (bit-exact), false for text-mode rows"},
    },
}
#: steval.Status: one status frame (PROTOCOL.md type 2), about once a second.
STATUS_SCHEMA = {
    "title": "steval.Status",
    "description": "Status frame: the filter's state and settings, AHRS cycle counts, link counters.",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "step": _int("the AHRS step the snapshot follows"),
        "t_fw_s": _num("firmware time, s since boot"),
        "q_wxyz": _arr(4, "filter quaternion after the step"),
        "int_xyz": _arr(3, "integral terms exInt, eyInt, ezInt"),
        "kp_ground": _num("kp below min_thr"),
        "kp_flight": _num("kp at or above min_thr"),
        "ki": _num("AHRS_KI"),
        "dt_s": _num("integration period assumed by the filter, s"),
        "min_thr": _int("gain-switch throttle"),
        "correction": {"type": "boolean", "description": "accelerometer correction on (flag bit 0 clear)"},
        "flags": _int("bit 0 no correction, 1 fresh squares, 2 text mode, 3 event, 4 in-flight tuning, 5 armed"),
        "ahrs_cycles_min": _int("DWT cycles of ahrs_fusion_ag + QuaternionToEuler since the last status, min"),
        "ahrs_cycles_mean": _int("... mean"),
        "ahrs_cycles_max": _int("... max"),
        "ahrs_cycles_n": _int("steps counted"),
        "cpu_hz": _int("core clock, Hz"),
        "tx_dropped_frames": _int("frames the TX queue could not take since boot"),
        "baud": _int("USART1 baud"),
        "queue_peak_bytes": _int("TX queue peak"),
        "fw_version": _arr(2, "patch version major, minor"),
        "fc_every": _int("a flight-control frame every N steps (0: none)"),
        "param_gen": _int("parameter changes and resets since boot, mod 256"),
    },
}
#: steval.FlightControl: one flight-control frame (PROTOCOL.md type 4).
FLIGHT_CONTROL_SCHEMA = {
    "title": "steval.FlightControl",
    "description": "Flight-control frame, sent after FlightControlPID_OuterLoop: targets, sticks, PID outputs, "
    "motors. Axes x pitch (about x), y roll (about y), z yaw.",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "step": _int("AHRS step"),
        "t_fw_s": _num("firmware time of the step, s since boot"),
        "target_rad": _arr(3, "the remote's targets euler_rc: pitch thx, roll thy, yaw thz, rad"),
        "rc": _arr(4, "gAIL, gELE, gRUD, gTHR"),
        "outer_s1_radps": _arr(3, "outer loop outputs x_s1, y_s1, z_s1 (rate setpoints), rad/s"),
        "inner_s2_pwm": _arr(3, "inner loop outputs x_s2, y_s2, z_s2, PWM counts"),
        "motor_pwm": _arr(4, "motor1..4 PWM, TIM4 counts of 2000"),
        "vbat_v": _num("battery, V"),
        "armed": {"type": "boolean"},
        "rc_connected": {"type": "boolean"},
        "rc_cal": {"type": "boolean"},
        "fc_every": _int("a frame every N steps"),
    },
}

#: topic → (its schema, what one message stands for)
_TOPIC_SCHEMAS = {
    "/attitude/transform": (FRAME_TRANSFORM_SCHEMA, "attitude frame"),
    "/attitude/pose": (POSE_IN_FRAME_SCHEMA, "attitude frame"),
    "/attitude": (ATTITUDE_SCHEMA, "attitude frame"),
    "/status": (STATUS_SCHEMA, "status frame"),
    "/flight_control": (FLIGHT_CONTROL_SCHEMA, "flight-control frame"),
}
#: topic → (schema name, what one message stands for)
TOPICS = {topic: (schema["title"], what) for topic, (schema, what) in _TOPIC_SCHEMAS.items()}


def require_mcap():
    """The ``mcap.records`` module; UserError naming the install command when the package is missing."""
    try:
        import mcap.records as records  # optional package (extra "mcap")
        import zstandard  # noqa: F401  (the mcap package's own dependency, for the chunks)
    except ImportError:
        raise ParamError(f"{{mcap}} needs the mcap package, which is not installed: {INSTALL_HINT}", "mcap") from None
    return records


def _times_ns(t_s: np.ndarray) -> np.ndarray:
    t = np.nan_to_num(np.asarray(t_s, np.float64), nan=0.0)
    return np.maximum(np.round(t * 1e9), 0).astype(np.int64)


def _display_q(att) -> np.ndarray:
    """(N, 4) normalised wxyz for the Foxglove messages; text-mode rows from their angles."""
    q = np.asarray(att.q_wxyz, np.float64).copy()
    missing = ~np.isfinite(q).all(axis=1)
    if missing.any():
        angles = (att.thx_rad, att.thy_rad, att.thz_rad)
        q[missing] = quaternion_from_euler(*(np.nan_to_num(np.asarray(v, np.float64)[missing]) for v in angles))
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.sqrt((q * q).sum(axis=1))
        q = np.where((n > 1e-6)[:, None], q / n[:, None], np.array([1.0, 0, 0, 0]))
    return q


_STAMP_ROT = b'{"sec":%d,"nsec":%d}\n{"x":%.9g,"y":%.9g,"z":%.9g,"w":%.9g}\n'
_ROW = (
    b'{"timestamp":%s,"parent_frame_id":"world","child_frame_id":"drone",'
    b'"translation":{"x":0,"y":0,"z":0},"rotation":%s}\n'
    b'{"timestamp":%s,"frame_id":"world","pose":{"position":{"x":0,"y":0,"z":0},"orientation":%s}}\n'
    b'{"timestamp":%s,"step":%d,"seq":%d,"t_fw_s":TFW,"t_host_s":%.6f,'
    b'"acc_mg":[%.9g,%.9g,%.9g],"gyro_mdps":[%.9g,%.9g,%.9g],"thr":%d,"q_wxyz":[%.9g,%.9g,%.9g,%.9g],'
    b'"thx_pitch_rad":%.9g,"thy_roll_rad":%.9g,"thz_yaw_rad":%.9g,"exact":%s}\n'
)
#: t_fw_s in µs for a block of binary frames (exact, finite, host times all known or all unknown), else 9 digits
_ROWS = {True: _ROW.replace(b"TFW", b"%.6f"), False: _ROW.replace(b"TFW", b"%.9g")}
#: a number ``%`` wrote for a non-finite value, to be written as JSON null
_NON_FINITE = re.compile(rb"(?<=[:,\[])-?(?:nan|inf)(?=[,\]}])")


def _attitude_blocks(att, rows: int = 8192):
    """Yield (first row, log times ns (m,), [transform, pose, attitude JSON bytes per row ...]) per block of
    ``rows`` attitude rows: one ``%`` over the whole block, then null for every value that is not finite."""
    n = len(att)
    ns_all = _times_ns(att.t_fw_s)
    q_all = _display_q(att)
    for a in range(0, n, rows):
        sl = slice(a, min(n, a + rows))
        ns = ns_all[sl]
        m = len(ns)
        # the timestamp and the rotation once per row, then placed three and two times as text
        stamp_rot = np.concatenate([np.stack(divmod(ns, 1_000_000_000), axis=1), q_all[sl][:, [1, 2, 3, 0]]], axis=1)
        pieces = ((_STAMP_ROT * m) % tuple(stamp_rot.ravel().tolist())).split(b"\n")
        values = np.concatenate(
            [
                np.stack([att.step[sl], att.seq[sl], att.t_fw_s[sl], att.t_host_s[sl]], axis=1).astype(np.float64),
                np.asarray(att.acc_mg[sl], np.float64),
                np.asarray(att.gyro_mdps[sl], np.float64),
                np.asarray(att.thr[sl], np.float64)[:, None],
                np.asarray(att.q_wxyz[sl], np.float64),
                np.stack([att.thx_rad[sl], att.thy_rad[sl], att.thz_rad[sl]], axis=1).astype(np.float64),
            ],
            axis=1,
        )
        table = np.empty((m, 6 + values.shape[1]), dtype=object)
        table[:, 0] = table[:, 2] = table[:, 4] = pieces[0:-1:2]
        table[:, 1] = table[:, 3] = pieces[1:-1:2]
        table[:, 5:-1] = values
        table[:, -1] = [b"true" if e else b"false" for e in np.asarray(att.exact[sl], bool).tolist()]
        finite = bool(np.isfinite(np.delete(values, 3, axis=1)).all())
        host = np.isfinite(values[:, 3])
        binary = finite and bool(np.asarray(att.exact[sl], bool).all()) and (host.all() or not host.any())
        text = (_ROWS[binary] * m) % tuple(table.ravel().tolist())
        if not (finite and host.all()):
            text = _NON_FINITE.sub(b"null", text)
        yield a, ns, text.split(b"\n")[:-1]


def _list(v) -> list:
    return [None if isinstance(x, float) and not math.isfinite(x) else x for x in np.asarray(v).tolist()]


#: the messages' booleans: (flags column, bit, the value when the bit is set)
_BITS = {
    "correction": ("flags", P.FLAG_NO_CORRECTION, False),
    "armed": ("fc_flags", P.FC_ARMED, True),
    "rc_connected": ("fc_flags", P.FC_RC_CONNECTED, True),
    "rc_cal": ("fc_flags", P.FC_RC_CAL, True),
}


def _row_messages(rows, schema: dict) -> tuple[np.ndarray, list[bytes]]:
    """Log times ns and JSON per row of a frame table: one field per property of ``schema``, in its order."""
    ns_all = _times_ns(rows.t_fw_s)
    columns = {"timestamp": [{"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000} for ns in ns_all.tolist()]}
    for key, prop in schema["properties"].items():
        if key in _BITS:
            name, bit, when_set = _BITS[key]
            columns[key] = (((np.asarray(getattr(rows, name), np.int64) & bit) != 0) == when_set).tolist()
        elif key != "timestamp":
            values = np.asarray(getattr(rows, RENAMED.get(key, key)))
            columns[key] = [_list(v) for v in values] if prop["type"] == "array" else _list(values)
    return ns_all, [
        json.dumps(dict(zip(columns, row)), separators=(",", ":"), allow_nan=False).encode()
        for row in zip(*columns.values())
    ]


def write_mcap(tel, out: BinaryIO | Path, *, metadata: dict[str, Any] | None = None, progress=None) -> dict[str, int]:
    """Write ``tel`` as MCAP to ``out`` (file or path), ``metadata`` as records; returns the message count per topic."""
    records = require_mcap()
    with open(out, "wb") if isinstance(out, (str, Path)) else contextlib.nullcontext(out) as stream:
        w = McapWriter(stream, records)
        present = {"/status": len(tel.status), "/flight_control": len(tel.fc)}
        channel = {
            topic: w.channel(topic, w.schema(TOPICS[topic][0], schema))
            for topic, (schema, _) in _TOPIC_SCHEMAS.items()
            if present.get(topic, 1)
        }
        three = np.array([channel["/attitude/transform"], channel["/attitude/pose"], channel["/attitude"]], np.uint16)
        n = len(tel.attitude)
        for first, ns, datas in _attitude_blocks(tel.attitude):
            m = len(ns)
            w.add_block(np.tile(three, m), np.repeat(ns, 3), np.repeat(np.arange(first, first + m), 3), datas)
            if progress is not None:
                progress((first + m) / max(n, 1), "attitude messages")
        for topic, rows in (("/status", tel.status), ("/flight_control", tel.fc)):
            ns, datas = _row_messages(rows, _TOPIC_SCHEMAS[topic][0])
            for a in range(0, len(datas), 8192):
                block = slice(a, a + 8192)
                ids = np.full(len(datas[block]), channel.get(topic, 0), np.uint16)
                w.add_block(ids, ns[block], np.arange(len(datas))[block], datas[block])
        for name, data in (metadata or {}).items():
            w.metadata(name, {str(k): json.dumps(v) for k, v in data.items()})
        w.finish()
    return {topic: w.counts[c] for topic, c in channel.items()}


# ---- the file format, written fast: zstd chunks, message indexes, a summary with statistics and chunk indexes ----

MCAP_MAGIC = b"\x89MCAP0\r\n"
_INDEX_HEAD = struct.Struct("<BQHI")
_MESSAGE_DTYPE = np.dtype(  # packed: 31 bytes, a message record's head
    [("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"), ("seq", "<u4")]
    + [("log_time", "<u8"), ("publish_time", "<u8")]
)


class McapWriter:
    """A chunked, indexed MCAP writer packing each block's message heads with numpy: the ``mcap`` package's
    ``Writer`` spends about 15 µs a message, 26 s on a 1-hour capture. Its other records are the package's own."""

    def __init__(self, stream: BinaryIO, records) -> None:
        import zstandard  # the mcap package's own dependency: there only when it is installed
        from mcap.data_stream import RecordBuilder  # the optional package (extra "mcap")

        self.builder = RecordBuilder
        self.r = records
        self.f = stream
        self.pos = 0
        self.zstd = zstandard.ZstdCompressor(level=1)
        self.schemas: list = []
        self.channels: list = []
        self.chunk_indexes: list = []
        self.metadata_indexes: list = []
        self.counts: dict[int, int] = {}
        self.t_start: int | None = None
        self.t_end = 0
        self._out(MCAP_MAGIC)
        self._record(records.Header(profile="", library="steval-link"))

    def _out(self, data: bytes) -> None:
        self.f.write(data)
        self.pos += len(data)

    def _record(self, record) -> int:
        """Write ``record``; returns where it starts."""
        start = self.pos
        b = self.builder()
        record.write(b)
        self._out(b.end())
        return start

    def schema(self, name: str, schema: dict) -> int:
        rec = self.r.Schema(
            id=len(self.schemas) + 1, name=name, encoding="jsonschema", data=json.dumps(schema).encode()
        )
        self.schemas.append(rec)
        self._record(rec)
        return rec.id

    def channel(self, topic: str, schema_id: int) -> int:
        rec = self.r.Channel(
            id=len(self.channels) + 1, topic=topic, message_encoding="json", schema_id=schema_id, metadata={}
        )
        self.channels.append(rec)
        self.counts[rec.id] = 0
        self._record(rec)
        return rec.id

    def add_block(self, channels: np.ndarray, t_ns: np.ndarray, seq: np.ndarray, datas: list[bytes]) -> None:
        """Messages ``datas`` (one per entry of ``channels``, ``t_ns``, ``seq``) as one chunk of their own."""
        m = len(datas)
        if m == 0:
            return
        lens = np.fromiter(map(len, datas), np.int64, m)
        starts = np.zeros(m, np.int64)
        np.cumsum(31 + lens[:-1], out=starts[1:])
        head = np.zeros(m, _MESSAGE_DTYPE)
        head["opcode"] = 0x05
        head["length"] = 22 + lens
        head["channel"] = channels
        head["seq"] = seq
        head["log_time"] = head["publish_time"] = t_ns
        hb = head.tobytes()
        parts: list[bytes] = [b""] * (2 * m)
        parts[0::2] = [hb[i : i + 31] for i in range(0, 31 * m, 31)]
        parts[1::2] = datas
        data = b"".join(parts)
        t_ns = np.asarray(t_ns, np.int64)
        t0, t1 = int(t_ns.min()), int(t_ns.max())
        packed = self.zstd.compress(data)
        start = self._record(
            self.r.Chunk(
                compression="zstd",
                data=packed,
                message_start_time=t0,
                message_end_time=t1,
                uncompressed_crc=zlib.crc32(data),
                uncompressed_size=len(data),
            )
        )
        length = self.pos - start
        offsets: dict[int, int] = {}
        for channel in np.unique(channels).tolist():
            rows = np.flatnonzero(channels == channel)
            self.counts[channel] += len(rows)
            pairs = np.stack([t_ns[rows], starts[rows]], axis=1).astype("<u8").tobytes()
            offsets[channel] = self.pos
            self._out(_INDEX_HEAD.pack(0x07, 6 + len(pairs), channel, len(pairs)) + pairs)
        self.chunk_indexes.append(
            self.r.ChunkIndex(
                message_start_time=t0,
                message_end_time=t1,
                chunk_start_offset=start,
                chunk_length=length,
                message_index_offsets=offsets,
                message_index_length=self.pos - start - length,
                compression="zstd",
                compressed_size=len(packed),
                uncompressed_size=len(data),
            )
        )
        self.t_start = t0 if self.t_start is None else min(self.t_start, t0)
        self.t_end = max(self.t_end, t1)

    def metadata(self, name: str, values: dict[str, str]) -> None:
        start = self._record(self.r.Metadata(name=name, metadata=values))
        self.metadata_indexes.append(self.r.MetadataIndex(offset=start, length=self.pos - start, name=name))

    def finish(self) -> None:
        from mcap.opcode import Opcode as op  # the optional package (extra "mcap")

        r = self.r
        self._record(r.DataEnd(data_section_crc=0))
        summary_start = self.pos
        stats = r.Statistics(
            message_count=sum(self.counts.values()),
            schema_count=len(self.schemas),
            channel_count=len(self.channels),
            attachment_count=0,
            metadata_count=len(self.metadata_indexes),
            chunk_count=len(self.chunk_indexes),
            message_start_time=self.t_start or 0,
            message_end_time=self.t_end,
            channel_message_counts=dict(self.counts),
        )
        offsets = []
        for opcode, group in (
            (op.SCHEMA, self.schemas),
            (op.CHANNEL, self.channels),
            (op.STATISTICS, [stats]),
            (op.CHUNK_INDEX, self.chunk_indexes),
            (op.METADATA_INDEX, self.metadata_indexes),
        ):
            if group:
                start = self.pos
                for rec in group:
                    self._record(rec)
                offsets.append(r.SummaryOffset(group_opcode=opcode, group_start=start, group_length=self.pos - start))
        summary_offset_start = self.pos
        for rec in offsets:
            self._record(rec)
        self._record(r.Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=0))
        self._out(MCAP_MAGIC)

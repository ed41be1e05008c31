"""The BLE notifications of ST's stock firmware (release 170120, ``Src/sensor_service.c``): UUIDs, payload layouts,
one notification decoded, tick unwrapping, and the capture's ``B`` chunks that hold them.

What the drone sends while a central is connected (once per AHRS step for each characteristic, skipping 30 motion
updates after a failed one: ``ACC_BLUENRG_CONGESTION``):

=========== ======================================== ===== ==================================================
char id     characteristic (UUID)                    bytes layout (little endian)
=========== ======================================== ===== ==================================================
1 motion    ``00e00000-0001-11e1-ac36-0002a5d5c51b`` 20    u16 tick, acc i16×3 mg, gyro i16×3 mdps/100, mag
                                                           i16×3 mgauss
2 env       ``001d0000-0001-11e1-ac36-0002a5d5c51b`` 12    u16 tick, i32 pressure hPa×100, u16 battery ‰,
                                                           i16 temperature 0.1 °C, i16 RSSI dBm×10
3 arming    ``20000000-0001-11e1-ac36-0002a5d5c51b`` 3     u16 tick, u8 armed
4 stdout    ``00000001-000e-11e1-ac36-0002a5d5c51b`` ≤20   console text
5 stderr    ``00000002-000e-11e1-ac36-0002a5d5c51b`` ≤20   console text
=========== ======================================== ===== ==================================================

The tick is ``HAL_GetTick() >> 3``: 8 ms units, wrapping every 2^16 ticks (524.288 s). The motion sample is the
ISR's last single sample after offset removal, *before* the gyro IIR filter and the 5-sample boxcar: not the AHRS
input, so a replica of the firmware's filter cannot be bit-exact on BLE data. Battery is VBAT·100/4.2 in ‰ (clipped
to 1000), RSSI dBm·10.
"""

from __future__ import annotations

from dataclasses import dataclass
from struct import Struct

from steval_link.link.capture import CHUNK_BLE

CHAR_MOTION, CHAR_ENV, CHAR_ARMING, CHAR_STDOUT, CHAR_STDERR = 1, 2, 3, 4, 5
#: characteristic id (the capture's ``B`` chunk byte) → its name and UUID prefix (the rest is :data:`_UUID_TAIL`)
_CHARS = {
    CHAR_MOTION: ("motion", "00e00000-0001"),
    CHAR_ENV: ("environment", "001d0000-0001"),
    CHAR_ARMING: ("arming", "20000000-0001"),
    CHAR_STDOUT: ("stdout", "00000001-000e"),
    CHAR_STDERR: ("stderr", "00000002-000e"),
}
_UUID_TAIL = "-11e1-ac36-0002a5d5c51b"
CHAR_UUIDS = {cid: prefix + _UUID_TAIL for cid, (_, prefix) in _CHARS.items()}
CHAR_NAMES = {cid: name for cid, (name, _) in _CHARS.items()}
#: the firmware advertises "DRN1" + its version digits (release 170120: "DRN1110")
DEVICE_NAME_PREFIX = "DRN1"
#: one tick of ``HAL_GetTick() >> 3``, s
TICK_S = 0.008
TICK_WRAP = 1 << 16


class BadPayload(ValueError):
    """A notification whose length does not match its characteristic."""


def char_id_of_uuid(uuid: str) -> int | None:
    """The characteristic id of a UUID (any case), None for one this tool does not read."""
    return next((k for k, v in CHAR_UUIDS.items() if v == str(uuid).lower()), None)


#: characteristic id → payload layout of the fixed-size notifications
_LAYOUTS = {CHAR_MOTION: Struct("<H3h3h3h"), CHAR_ENV: Struct("<HiHhh"), CHAR_ARMING: Struct("<HB")}


def unpack_payload(char_id: int, payload: bytes) -> tuple[int, ...]:
    """The raw fields of a motion, environment or arming notification (the table above), else :class:`BadPayload`."""
    layout = _LAYOUTS[char_id]
    if len(payload) != layout.size:
        raise BadPayload(f"{CHAR_NAMES[char_id]} notification of {len(payload)} bytes (expected {layout.size})")
    return layout.unpack(payload)


class TickUnwrapper:
    """u16 ticks → int64 ticks, one at a time: a small step back (out-of-order samples) stays back; a host gap
    longer than a wrap (524 s) adds the whole wraps the host clock says passed."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.value = 0

    def __call__(self, tick: int, dt_host_s: float | None = None) -> int:
        tick %= TICK_WRAP
        if self.last is None:
            self.value = tick
        else:
            d = (tick - self.last) % TICK_WRAP
            if d > TICK_WRAP - 256:
                d -= TICK_WRAP
            if dt_host_s is not None and dt_host_s == dt_host_s:
                d += max(0, round((dt_host_s - d * TICK_S) / (TICK_WRAP * TICK_S))) * TICK_WRAP
            self.value += d
        self.last = tick
        return self.value


def ble_chunk(char_id: int, payload: bytes) -> bytes:
    """The payload of a capture's ``B`` chunk: the characteristic id, then the notification's bytes."""
    return bytes([char_id]) + bytes(payload)


def ble_records(chunks: dict[int, list[tuple[float, bytes]]]) -> list[tuple[float, int, bytes]]:
    """``(t_host_s, char id, payload)`` of a capture's ``B`` chunks (``Capture.chunks`` / ``Recording.chunks``)."""
    return [(t, p[0], p[1:]) for t, p in chunks.get(CHUNK_BLE, []) if p]


def ble_items(chunks: dict, events=()) -> list[tuple[int | None, bytes, float]]:
    """``(char id, payload, t_host_s)`` of a capture's ``B`` chunks as a live link hands them: ``(None, b"", t)`` where
    a ``reconnect`` event says the link was lost."""
    marks = sorted(e.t_host_s for e in events if e.kind == "reconnect")
    out: list[tuple[int | None, bytes, float]] = []
    m = 0
    for t, cid, payload in ble_records(chunks):
        while m < len(marks) and marks[m] <= t:
            out.append((None, b"", marks[m]))
            m += 1
        out.append((cid, payload, t))
    return out


def is_ble_source(src) -> bool:
    """A capture recorded over BLE (``B`` chunks, or ``extra.link`` = "ble" in its header)."""
    chunks = getattr(src, "chunks", None) or {}
    extra = (getattr(src, "header", None) or {}).get("extra") or {}
    return bool(chunks.get(CHUNK_BLE)) or (isinstance(extra, dict) and extra.get("link") == "ble")


@dataclass(frozen=True, slots=True)
class BleMotionFrame:
    """One motion notification: ``tick`` unwrapped (8 ms units), the stock layout's fields (acc mg, gyro mdps, mag
    mgauss), ``t_host_s`` its arrival, ``repeat``: the same payload as the motion notification before it."""

    tick: int
    acc_mg: tuple[int, int, int]
    gyro_mdps: tuple[int, int, int]
    mag_mgauss: tuple[int, int, int]
    t_host_s: float
    repeat: bool = False


@dataclass(frozen=True, slots=True)
class BleEnvFrame:
    tick: int
    pressure_hpa: float
    battery_pct: float
    temperature_c: float
    rssi_dbm: float
    t_host_s: float


@dataclass(frozen=True, slots=True)
class BleArmingFrame:
    tick: int
    armed: bool
    t_host_s: float


@dataclass(frozen=True, slots=True)
class BleConsoleFrame:
    stream: str  #: "stdout" or "stderr"
    text: str
    t_host_s: float


class BleDecoder:
    """Notifications → typed frames on one unwrapped tick clock; bad and unknown notifications counted, skipped."""

    def __init__(self) -> None:
        self.unwrap = TickUnwrapper()
        self.counts = {n: 0 for n in CHAR_NAMES.values()}
        self.bad_payloads = 0
        self.unknown = 0
        self._last_t: float | None = None
        self._last_motion: bytes | None = None

    def feed(self, char_id: int, payload: bytes, t_host_s: float):
        """The frame of one notification (None: skipped)."""
        name = CHAR_NAMES.get(char_id)
        if name is None:
            self.unknown += 1
            return None
        self.counts[name] += 1
        if char_id in (CHAR_STDOUT, CHAR_STDERR):
            return BleConsoleFrame(name, bytes(payload).decode("utf-8", "replace"), t_host_s)
        try:
            v = unpack_payload(char_id, payload)
        except BadPayload:
            self.bad_payloads += 1
            return None
        dt = None if self._last_t is None else t_host_s - self._last_t
        self._last_t = t_host_s
        tick = self.unwrap(v[0], dt)
        if char_id == CHAR_MOTION:
            repeat = bytes(payload) == self._last_motion
            self._last_motion = bytes(payload)
            return BleMotionFrame(tick, v[1:4], (v[4] * 100, v[5] * 100, v[6] * 100), v[7:10], t_host_s, repeat)
        if char_id == CHAR_ENV:
            return BleEnvFrame(tick, v[1] / 100.0, v[2] / 10.0, v[3] / 10.0, v[4] / 10.0, t_host_s)
        return BleArmingFrame(tick, bool(v[1]), t_host_s)


@dataclass(frozen=True, slots=True)
class BleLayout:
    """What a motion notification's fields hold. ``stock``: raw sensors (acc mg, gyro mdps/100, mag mgauss).
    ``euler``: a modified firmware's own attitude in the acc fields (thx, thy, thz, rad × ``angle_scale``)."""

    name: str
    angle_scale: float = 0.0  #: payload units per radian (euler)

    @property
    def sends_attitude(self) -> bool:
        return self.angle_scale > 0

    def describe(self) -> str:
        if not self.sends_attitude:
            return "stock (acc mg, gyro mdps/100, mag mgauss: raw sensors)"
        return f"euler (thx, thy, thz rad x {self.angle_scale:g} in the acc fields: the drone's own attitude)"


#: the layouts by name (the capture header's ``ble_layout``)
LAYOUTS = {"stock": BleLayout("stock"), "euler": BleLayout("euler", 1000.0)}


def layout_named(name: str | None) -> BleLayout:
    """The layout of a name (None: stock); ValueError naming the known ones."""
    key = (name or "stock").strip().lower()
    if key not in LAYOUTS:
        raise ValueError(f"BLE layout {name!r}: known layouts are {', '.join(LAYOUTS)}")
    return LAYOUTS[key]

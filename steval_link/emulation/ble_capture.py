"""A BLE capture from the real firmware under emulation (``steval emulate ELF --ble``, ``recordings/ble_demo.stv``).

:class:`EmulatedBlueNrg`, the BlueNRG-MS at the HCI level (``Board.hci_handler``), gives distinct GATT handles (each
``aci_gatt_update_char_value`` names its characteristic by UUID), an RSSI, and records every update (no radio
congestion). :func:`record_ble` connects a central at ``connect_s`` and writes each notification of steval's
characteristics as a ``B`` chunk at its emulated time: what ``steval live --ble`` records, minus the radio's timing.
"""

from __future__ import annotations

import itertools
import struct
import uuid
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from steval_link import constants as C
from steval_link.emulation.runner import Emulation, EmulationOptions
from steval_link.link.ble_payloads import CHAR_MOTION, CHAR_NAMES, ble_chunk, char_id_of_uuid
from steval_link.link.capture import CHUNK_BLE, CaptureWriter

#: HCI (OGF, OCF) of the requests answered
GATT_ADD_SERV = (0x3F, 0x0102)
GATT_ADD_CHAR = (0x3F, 0x0104)
GATT_UPD_CHAR_VAL = (0x3F, 0x0106)
READ_RSSI = (5, 5)
UUID_TYPE_128 = 0x02


@dataclass(frozen=True, slots=True)
class HciNotification:
    """One ``aci_gatt_update_char_value`` as the firmware issued it."""

    t_sent_s: float  #: emulated time of the HCI request, s since reset (the link delivers it at once)
    char_id: int | None  #: steval's id of the characteristic (ble_payloads), None for others (e.g. device name)
    value: bytes


class EmulatedBlueNrg:
    """``Board.hci_handler`` for the SPBTLE-RF module (see the module docstring)."""

    def __init__(self) -> None:
        self.rssi_dbm = -62
        self._next_handle = 0x0010
        self.char_id_of_handle: dict[int, int | None] = {}
        self.notifications: deque[HciNotification] = deque()
        self.updates = 0  #: aci_gatt_update_char_value requests

    def _alloc(self, n: int) -> int:
        self._next_handle += n
        return self._next_handle - n

    def __call__(self, ogf: int, ocf: int, params: bytes, board) -> bytes:
        if (ogf, ocf) == GATT_ADD_SERV:
            return struct.pack("<BH", 0, self._alloc(16))
        if (ogf, ocf) == GATT_ADD_CHAR and len(params) >= 5:
            handle = self._alloc(3)  # declaration, value, CCCD
            raw = params[3 : 3 + (16 if params[2] == UUID_TYPE_128 else 2)][::-1]
            self.char_id_of_handle[handle] = char_id_of_uuid(uuid.UUID(bytes=raw) if len(raw) == 16 else raw.hex())
            return struct.pack("<BH", 0, handle)
        if (ogf, ocf) == GATT_UPD_CHAR_VAL and len(params) >= 6:
            _serv, char, _off, length = struct.unpack_from("<HHBB", params)
            self.updates += 1
            cid = self.char_id_of_handle.get(char)
            self.notifications.append(HciNotification(board.now / C.CPU_HZ, cid, bytes(params[6 : 6 + length])))
            return b"\x00"  # accepted
        if (ogf, ocf) == READ_RSSI:
            return struct.pack("<BHb", 0, 0, self.rssi_dbm)
        return b""


#: the name the 170120 firmware advertises, and the address it derives from this board's unique ID (its banner)
EMULATED_NAME = "DRN1110"
EMULATED_ADDRESS = "C0:28:38:35:21:34"


@dataclass
class BleRecording:
    """What :func:`record_ble` wrote and measured."""

    path: Path
    connect_s: float
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(CHAR_NAMES.values(), 0))  #: per characteristic
    emulated_s: float = 0.0
    updates: int = 0  #: aci_gatt_update_char_value requests of the firmware (all characteristics)
    motion_s: list[float] = field(default_factory=list)  #: emulated time of each motion notification, s

    def lines(self) -> list[str]:
        counts = ", ".join(f"{k} {v}" for k, v in self.counts.items() if v)
        span = self.motion_s[-1] - self.motion_s[0] if self.motion_s else 0.0
        rate = (len(self.motion_s) - 1) / span if span > 0 else 0.0  # first to last motion notification
        return [
            f"{self.path}: {sum(self.counts.values())} BLE notifications ({counts}) in {self.emulated_s:.1f} s "
            f"emulated, central connected at {self.connect_s:g} s",
            f"motion notifications: {rate:.2f} Hz; firmware update requests {self.updates}",
        ]


def record_ble(
    options: EmulationOptions,
    out: str | Path,
    *,
    connect_s: float = 0.5,
    tick_start_ms: int = 0,
    command: str | None = None,
) -> BleRecording:
    """Run the firmware and write its BLE notifications to a new capture ``out`` (see the module docstring)."""
    nrg = EmulatedBlueNrg()
    emu = Emulation(options, bluenrg=nrg, tick_start_ms=tick_start_ms, ble_connect_s=connect_s)
    extra = {
        "link": "ble",
        "emulated": True,
        "firmware": Path(str(options.elf)).name,
        "command": command or options.command(),
        "device": EMULATED_NAME,
        "address": EMULATED_ADDRESS,
        "note": "host times are the emulated delivery times, s since power-up (no radio timing model)",
    }
    rec = BleRecording(Path(out), connect_s)
    with CaptureWriter(out, port=f"ble:{EMULATED_NAME} {EMULATED_ADDRESS}", baud=0, extra=extra) as w:
        for _ in itertools.chain(emu.chunks(), [None]):  # after each chunk of emulated time, and once at the end
            while nrg.notifications:
                n = nrg.notifications.popleft()
                if n.char_id is not None:
                    w.write_chunk(CHUNK_BLE, ble_chunk(n.char_id, n.value), n.t_sent_s)
                    rec.counts[CHAR_NAMES[n.char_id]] += 1
                    if n.char_id == CHAR_MOTION:
                        rec.motion_s.append(n.t_sent_s)
    rec.emulated_s = emu.board.now / C.CPU_HZ
    rec.updates = nrg.updates
    return rec

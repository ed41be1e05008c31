"""The BlueNRG-MS radio of the emulated board, at the HCI level.

:class:`EmulatedBlueNrg` answers the firmware's ``hci_send_req`` (``Board.hci_handler``): distinct GATT handles for
``aci_gatt_add_serv`` / ``aci_gatt_add_char`` (so each ``aci_gatt_update_char_value`` names its characteristic by
UUID, as on the chip), an RSSI for ``hci_read_rssi``, and every ``aci_gatt_update_char_value`` the firmware issues
recorded exactly as its HCI command parameters carry it (service handle, char handle, offset, length, value): the
source of truth for the payload decoder. Every update is accepted at once (no radio congestion is modelled).
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass

from steval_link import constants as C
from steval_link.link.ble_payloads import char_id_of_uuid

OGF_VENDOR = 0x3F
OCF_GATT_ADD_SERV = 0x0102
OCF_GATT_ADD_CHAR = 0x0104
OCF_GATT_UPD_CHAR_VAL = 0x0106
OGF_STATUS_PARAM = 0x05
OCF_READ_RSSI = 0x0005
UUID_TYPE_128 = 0x02


@dataclass(frozen=True, slots=True)
class HciNotification:
    """One ``aci_gatt_update_char_value`` as the firmware issued it (decoded HCI command parameters)."""

    t_s: float  #: emulated time of the HCI request, s since reset
    t_sent_s: float  #: when the link delivered it (= t_s: no congestion model)
    service_handle: int
    char_handle: int
    offset: int
    value: bytes
    uuid: str | None  #: the characteristic's UUID (from its aci_gatt_add_char), None if unknown
    char_id: int | None  #: steval's id of that characteristic (ble_payloads), None for others (e.g. device name)


def _uuid_str(le: bytes) -> str:
    h = le[::-1].hex()
    return f"{h[:8]}-{h[8:12]}-{h[12:16]}-{h[16:20]}-{h[20:]}"


class EmulatedBlueNrg:
    """``Board.hci_handler`` for the SPBTLE-RF module (see the module docstring)."""

    def __init__(self, *, rssi_dbm: int = -62, keep: int = 1_000_000) -> None:
        self.rssi_dbm = int(rssi_dbm)
        self._next_handle = 0x0010
        self.uuid_of_handle: dict[int, str] = {}
        self.notifications: deque[HciNotification] = deque(maxlen=keep)
        self.updates = 0  #: aci_gatt_update_char_value requests

    def _alloc(self, n: int) -> int:
        h = self._next_handle
        self._next_handle += n
        return h

    def __call__(self, ogf: int, ocf: int, params: bytes, board) -> bytes:
        if ogf == OGF_VENDOR and ocf == OCF_GATT_ADD_SERV:
            return struct.pack("<BH", 0, self._alloc(16))
        if ogf == OGF_VENDOR and ocf == OCF_GATT_ADD_CHAR and len(params) >= 5:
            handle = self._alloc(3)  # declaration, value, CCCD
            n = 16 if params[2] == UUID_TYPE_128 else 2
            self.uuid_of_handle[handle] = _uuid_str(params[3 : 3 + n])
            return struct.pack("<BH", 0, handle)
        if ogf == OGF_VENDOR and ocf == OCF_GATT_UPD_CHAR_VAL and len(params) >= 6:
            serv, char, off, length = struct.unpack_from("<HHBB", params)
            self.updates += 1
            uuid = self.uuid_of_handle.get(char)
            cid = char_id_of_uuid(uuid) if uuid else None
            t = board.now / C.CPU_HZ
            self.notifications.append(HciNotification(t, t, serv, char, off, bytes(params[6 : 6 + length]), uuid, cid))
            return b"\x00"  # accepted
        if ogf == OGF_STATUS_PARAM and ocf == OCF_READ_RSSI:
            return struct.pack("<BHb", 0, 0, self.rssi_dbm)
        return b""

    def attach(self, board) -> EmulatedBlueNrg:
        board.hci_handler = self
        return self

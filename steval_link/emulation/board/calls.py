"""Function-level replacements, by symbol: the SPI sensors (``Sensor_IO_Read``/``Sensor_IO_Write``), the BlueNRG
glue (``hci_send_req``), and the fault handlers that stop the run with their name.

``Sensor_IO_Read``/``Sensor_IO_Write`` answer from the sensor register models
(:mod:`steval_link.emulation.sensors`), so ST's drivers and scaling run unchanged. ``hci_send_req`` (the only path to
the BlueNRG chip) returns success with a zeroed reply, so the BLE init runs its real code (or the reply of the
board's ``hci_handler``, :mod:`steval_link.emulation.ble_capture`). The replaced calls are reported to optional
observers (``board.call_observers[name]``).
"""

from __future__ import annotations

import struct
from typing import Callable

from steval_link.emulation.board.fault import describe_fault_handler
from steval_link.emulation.board.memory_map import FirmwareStuck

#: DrvContextTypeDef.spiDevice: the byte that names the sensor behind a driver handle
SPI_DEVICE_OFFSET = 3
SPI_READ_FLAG = 0x80
#: tHciRequest: ogf, ocf, event, cparam, clen, rparam, rlen
HCI_REQUEST = struct.Struct("<HHiIiIi")
FAULT_HANDLERS = (
    "HardFault_Handler",
    "MemManage_Handler",
    "BusFault_Handler",
    "UsageFault_Handler",
    "Default_Handler",
    "Error_Handler",
    "_Error_Handler",
)


class FirmwareCalls:
    """Installs the replacements and fault-handler stops on a board."""

    def __init__(self, board) -> None:
        self.board = board

    def install(self, skip: tuple[str, ...] = ()) -> None:
        """Hook the replaced functions (but those in ``skip``: the C core's) and the fault handlers."""
        b, e = self.board, self.board.elf
        for name in ("Sensor_IO_Read", "Sensor_IO_Write", "hci_send_req"):
            a = e.addr(name)
            if a is not None and name not in skip:
                b.code_hook(a, self.replacement_hook(name))
        # fault handlers and the default handler loop forever: stop with their name
        for name in FAULT_HANDLERS:
            a = e.addr(name)
            if a is not None:
                b.code_hook(a, self._fault_handler(name))

    def replacement_hook(self, name: str) -> Callable:
        """The code hook that runs the Python replacement of ``name`` and returns to its caller."""
        fn = {
            "Sensor_IO_Read": self._sensor_read,
            "Sensor_IO_Write": self._sensor_write,
            "hci_send_req": self._hci_send_req,
        }[name]
        b = self.board
        observers = b.call_observers.setdefault(name, [])
        regs = b.regs
        R0, PC = regs.R[0], regs.PC
        read_args, set_reg = regs.read_args, regs.set

        def hook(uc, address, size, user):
            r0, r1, r2, r3, lr = read_args()
            b.sync_now()
            rv = fn(r0, r1, r2, r3)
            for ob in observers:
                ob(b, r0, r1, r2, r3)
            set_reg(R0, rv)
            set_reg(PC, lr | 1)

        return hook

    def _sensor_read(self, handle, reg, buf, n) -> int:
        b = self.board
        device = b.uc.mem_read(handle + SPI_DEVICE_OFFSET, 1)[0]
        b.uc.mem_write(buf, b.sensors.read(device, reg & ~SPI_READ_FLAG & 0xFF, n & 0xFFFF, b))
        return 0

    def _sensor_write(self, handle, reg, buf, n) -> int:
        b = self.board
        device = b.uc.mem_read(handle + SPI_DEVICE_OFFSET, 1)[0]
        b.sensors.write(device, reg & ~SPI_READ_FLAG & 0xFF, bytes(b.uc.mem_read(buf, n & 0xFFFF)), b)
        return 0

    def _hci_send_req(self, req, is_async, _r2, _r3) -> int:
        b = self.board
        ogf, ocf, _event, cparam, clen, rparam, rlen = HCI_REQUEST.unpack(b.uc.mem_read(req, HCI_REQUEST.size))
        reply = b""
        if b.hci_handler is not None:  # e.g. emulation.ble_capture: GATT handles, RSSI, the notifications sent
            params = bytes(b.uc.mem_read(cparam, clen)) if cparam and 0 < clen <= 1024 else b""
            reply = b.hci_handler(ogf, ocf, params, b) or b""
        if rparam and rlen > 0:
            b.uc.mem_write(rparam, (bytes(reply) + bytes(rlen))[:rlen])
        b.hci_requests += 1
        return 0

    def _fault_handler(self, name: str):
        b = self.board

        def hook(uc, address, size, user):
            b.sync_now()
            b.stop_with(FirmwareStuck(f"{describe_fault_handler(b, name)} at t = {b.now / b.cpu_hz:.6f} s"))

        return hook

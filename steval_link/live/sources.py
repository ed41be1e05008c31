"""The links a live session reads, behind one interface (as cflib's link drivers), chosen by a URL (as pyserial's
``serial_for_url``).

==================================  ==========================================================================
``/dev/ttyUSB0``, ``COM3``, ``auto``  a serial port, or the one that carries frames (:mod:`.serial_source`)
``replay://FILE.stv[?speed=X]``       a capture played at its recorded pace, as a serial port (the same driver)
``emulated:``                         the emulated board running an ELF (:mod:`.emulated`, ``steval emulate``)
``ble:NAME``, ``ble:ADDRESS``, ``ble:``  ST's stock firmware over Bluetooth (:mod:`.ble_source`, ``--ble``)
==================================  ==========================================================================

A :class:`~steval_link.live.source.Source` moves bytes into the capture first (in its own thread or round), decodes
them for the live side and says how the link is doing; :class:`~steval_link.live.session.LiveSession` owns the rest
once: the capture file, the viewer, the command prompt, the stop requests and signals, the summary.
"""

from __future__ import annotations

from typing import Any

from steval_link.live.serial_source import SerialSource
from steval_link.live.source import Source

__all__ = ["BLE_SCHEME", "EMULATED_SCHEME", "source_for"]

BLE_SCHEME = "ble:"
EMULATED_SCHEME = "emulated:"


def source_for(url: str, **settings: Any) -> Source:
    """The source a URL names (see the module doc); ``settings`` go to its driver (``baud``, ``wait`` for a serial
    port; ``emulation``, ``realtime``, ``commands`` for the emulated board; ``backend`` for BLE)."""
    low = url.lower()
    if low.startswith(BLE_SCHEME):
        from steval_link.live.ble_source import BleSource  # reason: BLE loads only when a session uses it

        target = url[len(BLE_SCHEME) :].strip()
        return BleSource(None if target in ("", "auto") else target, **settings)
    if low.startswith(EMULATED_SCHEME):
        from steval_link.live.emulated import EmulatedSource  # reason: the emulator loads only when used

        return EmulatedSource(**settings)
    return SerialSource(url, **settings)

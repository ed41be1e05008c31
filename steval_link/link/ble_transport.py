"""The BLE transport: scan, connect, subscribe to the drone's notifications, reconnect when the link is lost.

:class:`BleBackend` is the small interface to a radio (:class:`BleakBackend`: bleak, the optional extra
``steval-link[ble]``). Radio and permission failures become one-sentence UserErrors (:func:`explain_ble_error`).
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import time
from collections.abc import Callable
from dataclasses import KW_ONLY, dataclass, field
from typing import Protocol

from steval_link.errors import UserError
from steval_link.link.ble_payloads import CHAR_NAMES, CHAR_UUIDS, DEVICE_NAME_PREFIX

SCAN_TIMEOUT_S = 5.0
#: longest wait between two reconnection attempts, s
RETRY_MAX_S = 5.0


class BleError(Exception):
    """A BLE operation failed (connection refused, characteristic missing, link lost while connecting...)."""


@dataclass(frozen=True, slots=True)
class BleDevice:
    name: str | None
    address: str
    rssi_dbm: float | None = None


class BleBackend(Protocol):
    async def scan(self, timeout_s: float) -> list[BleDevice]: ...

    async def connect(self, address: str, on_disconnect: Callable[[], None]) -> None: ...

    async def start_notify(self, uuid: str, callback: Callable[[bytes], None]) -> None: ...

    async def disconnect(self) -> None: ...


def explain_ble_error(exc: BaseException) -> str | None:
    """One sentence for a failure of the platform's Bluetooth stack (no adapter, adapter off, no permission, no
    BlueZ), None when it is not one of those (a connection failure, handled by retrying)."""
    text = " ".join(str(a) for a in getattr(exc, "args", ()) if a is not None) or str(exc)
    low = (text + " " + str(getattr(exc, "dbus_error", "") or "")).lower()
    reason = getattr(exc, "reason", None)
    reason = getattr(reason, "name", str(reason or "")).upper()
    denied = ("accessdenied", "not authorized", "permission", "unauthorized", "notpermitted", "notauthorized")
    if "DENIED" in reason or isinstance(exc, PermissionError) or any(w in low for w in denied):
        return (
            "Bluetooth permission denied: on Linux add yourself to the 'bluetooth' group or run BlueZ's polkit "
            "rules; on macOS/Windows allow Bluetooth for this terminal in the system's privacy settings."
        )
    off = ("powered off", "turned off", "notready", "not ready", "poweredoff")
    if reason == "POWERED_OFF" or any(w in low for w in off):
        return "the Bluetooth adapter is switched off: turn Bluetooth on (e.g. bluetoothctl power on) and retry."
    no_adapter = "no bluetooth adapters" in low or ("adapter" in low and ("not found" in low or "no such" in low))
    if reason in ("NO_BLUETOOTH", "NO_BLE_CENTRAL_ROLE") or no_adapter:
        return "no Bluetooth LE adapter found on this computer (plug in a USB dongle or enable the built-in one)."
    if isinstance(exc, FileNotFoundError) or "serviceunknown" in low or ("bluez" in low and "unknown" in low):
        return (
            "no Bluetooth service reachable: BlueZ (bluetoothd) and the D-Bus system bus must be running "
            "(e.g. sudo systemctl start bluetooth), and a Bluetooth adapter present."
        )
    return None


def _raise_explained(exc: BaseException) -> None:
    """Raise the :func:`explain_ble_error` sentence of ``exc`` as a UserError, when it has one."""
    why = explain_ble_error(exc)
    if why:
        raise UserError(why) from None


def is_address(text: str) -> bool:
    """A BLE address (``C0:11:22:33:44:55``) or a macOS CoreBluetooth UUID, rather than a name."""
    t = text.strip()
    return bool(re.fullmatch(r"[0-9A-Fa-f]{2}(:[0-9A-Fa-f]{2}){5}", t)) or (len(t) == 36 and t.count("-") == 4)


def pick_device(devices: list[BleDevice], target: str | None) -> BleDevice | None:
    """The device ``target`` names (an address, or a name: exact, then case-insensitive prefix); without a target
    the strongest ``DRN1…`` advertiser (ST's drone firmware)."""
    if target:
        t = target.strip()
        if is_address(t):
            return next((d for d in devices if d.address.lower() == t.lower()), None)
        exact = [d for d in devices if d.name == t]
        prefixed = [d for d in devices if d.name and d.name.lower().startswith(t.lower())]
        return exact[0] if exact else _strongest(prefixed)
    return _strongest([d for d in devices if d.name and d.name.startswith(DEVICE_NAME_PREFIX)])


def _strongest(devices: list[BleDevice]) -> BleDevice | None:
    return max(devices, key=lambda d: -1e9 if d.rssi_dbm is None else d.rssi_dbm, default=None)


def bleak_backend() -> BleakBackend:
    """A :class:`BleakBackend`, or a UserError when bleak is not installed."""
    try:
        import bleak  # noqa: F401  # reason: optional extra, checked before anything else runs
    except ImportError:
        raise UserError('BLE needs bleak: pip install "steval-link[ble]" (or pip install bleak).') from None
    return BleakBackend()


class BleakBackend:
    """:class:`BleBackend` with bleak (imported when made: :func:`bleak_backend`)."""

    def __init__(self) -> None:
        self._client = None

    async def scan(self, timeout_s: float) -> list[BleDevice]:
        from bleak import BleakScanner  # reason: optional extra

        found = await BleakScanner.discover(timeout=timeout_s, return_adv=True)
        return [
            BleDevice(adv.local_name or dev.name, dev.address, None if adv.rssi is None else float(adv.rssi))
            for dev, adv in found.values()
        ]

    async def connect(self, address: str, on_disconnect: Callable[[], None]) -> None:
        from bleak import BleakClient  # reason: optional extra
        from bleak.exc import BleakError  # reason: optional extra

        client = BleakClient(address, disconnected_callback=lambda _c: on_disconnect())
        try:
            await client.connect()
        except (BleakError, asyncio.TimeoutError, OSError) as exc:
            if explain_ble_error(exc):
                raise
            raise BleError(f"connection to {address} failed: {exc or type(exc).__name__}") from None
        self._client = client

    async def start_notify(self, uuid: str, callback: Callable[[bytes], None]) -> None:
        from bleak.exc import BleakError  # reason: optional extra

        try:
            await self._client.start_notify(uuid, lambda _ch, data: callback(bytes(data)))
        except BleakError as exc:
            raise BleError(str(exc)) from None

    async def disconnect(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(Exception):  # already gone: nothing to release
                await client.disconnect()


@dataclass(eq=False)
class BleLink:
    """Find the drone (:func:`pick_device`), subscribe to each of ``CHAR_UUIDS``, hand each notification to
    ``on_notification(char id, bytes, t_unix_s)`` and reconnect a lost link (back off up to :data:`RETRY_MAX_S`).
    ``on_event(kind, text)`` hears "connect", "disconnect", "reconnect" and "missing" (a characteristic lacking)."""

    backend: BleBackend
    target: str | None
    on_notification: Callable[[int, bytes, float], None]
    _: KW_ONLY
    on_event: Callable[[str, str], None] | None = None
    retry_max_s: float = RETRY_MAX_S
    device: BleDevice | None = field(default=None, init=False)
    connections: int = field(default=0, init=False)
    losses: int = field(default=0, init=False)
    notifications: int = field(default=0, init=False)
    _lost: asyncio.Event | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        self.on_event = self.on_event or (lambda kind, text: None)

    async def find(self) -> BleDevice | None:
        """Scan once for the target; platform failures raise UserError."""
        try:
            devices = await self.backend.scan(SCAN_TIMEOUT_S)
        except Exception as exc:  # noqa: BLE001 - the platform's errors come in many types
            _raise_explained(exc)
            raise UserError(f"Bluetooth scan failed: {exc or type(exc).__name__}") from None
        return pick_device(devices, self.target)

    async def _connect(self, dev: BleDevice) -> None:
        self._lost = asyncio.Event()
        await self.backend.connect(dev.address, self._lost.set)
        for cid, uuid in CHAR_UUIDS.items():
            try:
                await self.backend.start_notify(uuid, self._handler(cid))
            except BleError as exc:
                if cid == 1:  # no motion characteristic: not ST's drone firmware
                    await self.backend.disconnect()
                    raise UserError(
                        f"{dev.name or dev.address} has no AccGyroMag characteristic ({uuid}): not ST's drone firmware?"
                    ) from None
                self.on_event("missing", f"{CHAR_NAMES[cid]}: {exc}")
        self.device = dev
        self.connections += 1

    def _handler(self, cid: int) -> Callable[[bytes], None]:
        def cb(data: bytes) -> None:
            self.notifications += 1
            self.on_notification(cid, data, time.time())

        return cb

    async def find_first(self) -> BleDevice:
        """The drone, found by a first scan; UserError when the platform fails or it is not found."""
        dev = await self.find()
        if dev is None:
            what = repr(self.target) if self.target else f"a {DEVICE_NAME_PREFIX}… drone"
            raise UserError(
                f"no BLE device matching {what} found in {SCAN_TIMEOUT_S:g} s of scanning "
                "(is the drone on, in range, and not connected to a phone?)."
            )
        return dev

    async def run(self, stop: asyncio.Event, dev: BleDevice | None = None) -> None:
        """Connect to ``dev`` (None: :meth:`find_first`) and stay connected until ``stop`` is set."""
        if dev is None:
            dev = await self.find_first()
        try:
            await self._connect(dev)
        except UserError:
            raise
        except Exception as exc:  # noqa: BLE001 - BleError, or the platform's own (no permission, adapter off...)
            _raise_explained(exc)
            raise UserError(f"cannot connect to {dev.name or ''} {dev.address}: {exc}".replace("  ", " ")) from None
        self.on_event("connect", f"{dev.name or ''} {dev.address}".strip())
        delay = first_delay = min(0.5, self.retry_max_s)  # s before the next attempt, doubling up to retry_max_s
        while not stop.is_set():
            await _first(stop, self._lost)
            if stop.is_set():
                break
            self.losses += 1
            self.on_event("disconnect", "BLE link lost")
            while not stop.is_set():
                await _first(stop, asyncio.sleep(delay))
                if stop.is_set():
                    break
                try:
                    found = await self.find()
                    if found is not None:
                        await self._connect(found)
                        self.on_event("reconnect", f"{found.name or ''} {found.address}".strip())
                        delay = first_delay
                        break
                except UserError:
                    raise
                except Exception as exc:  # noqa: BLE001 - retried unless the platform itself failed
                    _raise_explained(exc)
                delay = min(delay * 2, self.retry_max_s)
        await self.backend.disconnect()


async def _first(stop: asyncio.Event, other) -> None:
    """Wait until ``stop`` is set or ``other`` (an Event or a coroutine) completes."""
    t1 = asyncio.ensure_future(stop.wait())
    t2 = asyncio.ensure_future(other.wait() if isinstance(other, asyncio.Event) else other)
    done, pending = await asyncio.wait({t1, t2}, return_when=asyncio.FIRST_COMPLETED)
    for t in pending:
        t.cancel()

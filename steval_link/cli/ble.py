"""``steval ble scan``: the BLE devices in range, ST's drones (``DRN1…``) first."""

from __future__ import annotations

import asyncio
import sys

import typer

from steval_link.cli.app import sub_app
from steval_link.errors import UserError
from steval_link.link.ble_payloads import DEVICE_NAME_PREFIX, LAYOUTS, layout_named
from steval_link.link.ble_transport import BleBackend, BleDevice, bleak_backend, explain_ble_error

ble_app = sub_app("ble", "Bluetooth LE: find drones running ST's unmodified firmware (then: steval live --ble).")


def scan_devices(backend: BleBackend, timeout_s: float) -> list[BleDevice]:
    """Scan once; platform failures (no adapter, adapter off, no permission, no BlueZ) raise UserError."""
    try:
        return asyncio.run(backend.scan(timeout_s))
    except UserError:
        raise
    except Exception as exc:  # noqa: BLE001 - every platform raises its own types
        why = explain_ble_error(exc)
        raise UserError(why or f"Bluetooth scan failed: {exc or type(exc).__name__}") from None


def format_devices(devices: list[BleDevice], show_all: bool) -> list[str]:
    """One line per device: name, address, RSSI; ST's drones first (strongest first)."""

    out = []
    for d in sorted(devices, key=lambda d: (not _is_drone(d), -(d.rssi_dbm if d.rssi_dbm is not None else -1e9))):
        if not (_is_drone(d) or show_all):
            continue
        rssi = f"{d.rssi_dbm:.0f} dBm" if d.rssi_dbm is not None else "? dBm"
        note = "  STEVAL drone (ST firmware)" if _is_drone(d) else ""
        out.append(f"{d.name or '(no name)':<20} {d.address:<38} {rssi:>8}{note}")
    return out


def _is_drone(d: BleDevice) -> bool:
    return bool(d.name and d.name.startswith(DEVICE_NAME_PREFIX))


@ble_app.command("scan")
def scan_command(
    timeout: float = typer.Option(5.0, "--timeout", "-t", help="Seconds to listen for advertisements."),
    show_all: bool = typer.Option(False, "--all", "-a", help="List every BLE device, not only ST's drones."),
) -> None:
    """List the drones in range that advertise ST's firmware (name DRN1…), strongest first.

    Connect to one with: steval live --ble NAME-or-ADDRESS (or --ble alone for the strongest).
    """
    if not timeout > 0:
        raise UserError(f"--timeout must be positive, got {timeout}")
    devices = scan_devices(bleak_backend(), timeout)
    lines = format_devices(devices, show_all)
    if not lines:
        print(
            f"steval: no drone advertising {DEVICE_NAME_PREFIX}… found in {timeout:g} s ({len(devices)} other BLE "
            "device(s); --all lists them). Is the drone on, and not connected to a phone?",
            file=sys.stderr,
        )
        raise typer.Exit(1)
    print("\n".join(lines))


BLE_LAYOUT_HELP = (
    "What the drone's motion notifications hold: stock (ST's firmware: raw acc, gyro, mag) or euler (a modified "
    "firmware that sends its Euler angles, rad x 1000, in the acc fields and gyro-integrated odometry in the gyro "
    "fields: its attitude is shown as the firmware's own)."
)


def check_ble_layout(name: str) -> str:
    """``--ble-layout NAME``: one of the known layouts (one sentence naming them)."""
    try:
        return layout_named(name).name
    except ValueError:
        raise UserError(f"--ble-layout {name}: choose one of {', '.join(LAYOUTS)}") from None

"""A BLE capture from the real firmware under emulation (``steval emulate ELF --ble``, ``recordings/ble_demo.stv``).

The firmware runs on the emulated board with :class:`~steval_link.emulation.bluenrg.EmulatedBlueNrg` as its radio;
a central connects at ``connect_s`` (the stock firmware then sends its motion, environment and arming notifications
from the main loop, once per AHRS step each). Every notification the emulated chip accepted is written as a capture
``B`` chunk, with the emulated time at which the link delivered it (s since power-up) as its host time: what
``steval live --ble`` would record from this drone, minus the radio's own timing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from steval_link import constants as C
from steval_link.emulation.bluenrg import EmulatedBlueNrg
from steval_link.emulation.runner import Emulation, EmulationOptions
from steval_link.link.ble_payloads import CHAR_NAMES, ble_chunk
from steval_link.link.capture import CHUNK_BLE, CaptureWriter

#: the name the release 170120 firmware advertises, and the static random address it derives from this emulated
#: board's unique ID (its banner prints "BoardMAC = c0:28:38:35:21:34")
EMULATED_NAME = "DRN1110"
EMULATED_ADDRESS = "C0:28:38:35:21:34"


@dataclass
class BleRecording:
    """What :func:`record_ble` wrote and measured."""

    path: Path
    emulated_s: float
    connect_s: float
    counts: dict[str, int] = field(default_factory=dict)  #: notifications written per characteristic
    updates: int = 0  #: aci_gatt_update_char_value requests of the firmware (all characteristics)
    first_s: float | None = None
    last_s: float | None = None

    def rate_hz(self, name: str = "motion") -> float:
        """Notifications per emulated second of one characteristic, first to last notification."""
        n = self.counts.get(name, 0)
        if n < 2 or self.first_s is None or self.last_s is None or self.last_s <= self.first_s:
            return 0.0
        return (n - 1) / (self.last_s - self.first_s)

    def lines(self) -> list[str]:
        counts = ", ".join(f"{k} {v}" for k, v in self.counts.items() if v)
        return [
            f"{self.path}: {sum(self.counts.values())} BLE notifications ({counts}) in {self.emulated_s:.1f} s "
            f"emulated, central connected at {self.connect_s:g} s",
            f"motion notifications: {self.rate_hz('motion'):.2f} Hz; firmware update requests {self.updates}",
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
    rec = BleRecording(path=Path(out), emulated_s=0.0, connect_s=connect_s, counts={n: 0 for n in CHAR_NAMES.values()})
    with CaptureWriter(out, port=f"ble:{EMULATED_NAME} {EMULATED_ADDRESS}", baud=0, extra=extra) as w:

        def drain() -> None:
            while nrg.notifications:
                n = nrg.notifications.popleft()
                if n.char_id is None:
                    continue
                w.write_chunk(CHUNK_BLE, ble_chunk(n.char_id, n.value), n.t_sent_s)
                rec.counts[CHAR_NAMES[n.char_id]] += 1
                if n.char_id == 1:
                    rec.first_s = n.t_sent_s if rec.first_s is None else rec.first_s
                    rec.last_s = n.t_sent_s

        for _data, _t in emu.chunks():
            drain()
        drain()
    rec.emulated_s = emu.board.now / C.CPU_HZ
    rec.updates = nrg.updates
    return rec

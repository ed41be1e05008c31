"""Digests of short firmware-in-the-loop runs: what the emulated board's speed work must not change.

For one ELF (identified by the sha256 of its load segments and symbols), each run gives the sha256 of the USART1
byte stream, the sha256 of the decoded attitude frames (every field but the stream offset) and the median
instructions per AHRS step. ``tests/data/emulate_digests.json`` maps the ELF's image sha256 to the expected digests
of each run (``tests/test_emulate_digest.py``).

Record (with a stated reason; it works on the board before and after the speed work, also copied out of the tree
and run from another checkout: ``--table`` names the JSON to update)::

    python tests/support/emulate_digest.py ELF --record "reference firmware, board before the C core"

Print without recording: ``python tests/support/emulate_digest.py ELF [--runs hand-tilts,commands]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import statistics
import sys
from pathlib import Path

#: the checkout: the current directory when it is one (the script copied out to run on another checkout), else this
#: file's
ROOT = Path.cwd() if (Path.cwd() / "steval_link").is_dir() else Path(__file__).resolve().parents[2]
DIGESTS = Path(__file__).resolve().parents[1] / "data" / "emulate_digests.json"
COMMANDS = ROOT / "recordings" / "live_params.commands"

#: run name → (scenario, duration s, seed, with host commands, BLE capture)
RUNS = {
    "hand-tilts": ("hand-tilts", 8.0, 3, False, False),
    "commands": ("hand-tilts", 10.0, 3, True, False),
    "flight": ("flight", 27.0, 3, False, False),
    "ble": ("hand-tilts", 8.0, 3, False, True),
}
#: the runs the regression test checks (the short ones)
TEST_RUNS = ("hand-tilts", "commands")


def elf_sha256(elf: Path) -> str:
    """sha256 of what the board runs: the load segments (address, bytes) and the symbols (name, address, size);
    not the debug sections, whose paths differ from one build folder to the next."""
    from steval_link.emulation.elf import Elf

    e = Elf(elf)
    h = hashlib.sha256()
    for addr, data in e.segments:
        h.update(addr.to_bytes(4, "little") + len(data).to_bytes(4, "little") + bytes(data))
    for sym in sorted(e.symbols, key=lambda x: (x.name, x.addr)):
        h.update(f"{sym.name} {sym.addr:08x} {sym.size} {int(sym.is_func)}\n".encode())
    return h.hexdigest()


def _frame_digest(stream: bytes) -> tuple[str, int]:
    from steval_link.link.decoder import StreamDecoder
    from steval_link.link.frames import AttitudeFrame

    h = hashlib.sha256()
    n = 0
    for f in StreamDecoder().feed(stream):
        if isinstance(f, AttitudeFrame):
            fields = [getattr(f, x.name) for x in dataclasses.fields(f) if x.name != "offset"]
            h.update(repr(fields).encode())
            n += 1
    return h.hexdigest(), n


def run(elf: Path, name: str) -> dict:
    """One run's digests (see the module docstring)."""
    from steval_link.emulation.runner import Emulation, EmulationOptions

    scenario, duration_s, seed, commands, ble = RUNS[name]
    opts = EmulationOptions(elf=elf, scenario=scenario, duration_s=duration_s, seed=seed)
    if ble:  # what `steval emulate --ble` records: every notification the emulated BlueNRG accepted
        from steval_link.emulation.ble_capture import EmulatedBlueNrg

        nrg = EmulatedBlueNrg()
        emu = Emulation(opts, bluenrg=nrg, ble_connect_s=0.5)
        h = hashlib.sha256()
        n = 0
        for _ in emu.chunks():
            pass
        for note in nrg.notifications:
            h.update(repr((note.char_id, bytes(note.value), note.t_sent_s)).encode())
            n += 1
        return {"ble_notifications_sha256": h.hexdigest(), "ble_notifications": n}
    emu = Emulation(opts)
    if commands:
        from steval_link.link.commands import CommandChannel, parse_script

        channel = CommandChannel(lambda b: None, first_seq=1)
        for t_s, command in parse_script(COMMANDS.read_text(encoding="utf-8"), str(COMMANDS)):
            if t_s < duration_s:
                emu.send_at(channel.next_frame(command).frame, t_s)
    stream = emu.run()
    frames_sha, n = _frame_digest(stream)
    rep = emu.report()
    steps = rep.step_instructions
    return {
        "usart1_sha256": hashlib.sha256(stream).hexdigest(),
        "usart1_bytes": len(stream),
        "frames_sha256": frames_sha,
        "attitude_frames": n,
        "step_instructions_median": int(statistics.median(steps)) if steps else None,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("elf", type=Path)
    ap.add_argument("--runs", default=",".join(TEST_RUNS), help=f"comma-separated, of: {', '.join(RUNS)}")
    ap.add_argument("--record", metavar="REASON", help="store the digests in the table, with this reason")
    ap.add_argument("--table", type=Path, default=DIGESTS, help="the digest table (default: tests/data/...)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    sha = elf_sha256(args.elf)
    out = {name: run(args.elf, name) for name in args.runs.split(",") if name}
    print(json.dumps({sha: {"elf": args.elf.name, "runs": out}}, indent=2))
    if args.record:
        table = json.loads(args.table.read_text()) if args.table.exists() else {}
        entry = table.setdefault(sha, {"elf": args.elf.name, "runs": {}, "reasons": []})
        entry["runs"].update(out)
        entry["reasons"].append(args.record)
        args.table.parent.mkdir(parents=True, exist_ok=True)
        args.table.write_text(json.dumps(table, indent=2, sort_keys=True) + "\n")
        print(f"recorded in {args.table}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

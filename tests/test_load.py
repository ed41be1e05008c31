"""``link.load``: a recording to ``Telemetry`` in one pass (capture → decoder → telemetry), with the same results,
bit for bit, as the two-pass loader it replaced (``capture.load_telemetry`` of 158eea4, whose outputs on the
bundled recordings, a raw dump and damaged copies of each are recorded below as digests)."""

from __future__ import annotations

import dataclasses
import hashlib
import warnings
from pathlib import Path

import numpy as np
import pytest

from steval_link.errors import UserError
from steval_link.link import telemetry as T
from steval_link.link.capture import Capture, read_capture
from steval_link.link.load import Recording, load_telemetry, read_recording

REC = Path(__file__).resolve().parents[1] / "recordings"
ATTITUDE = "step seq t_us t_fw_s t_host_s acc_mg gyro_mdps thr q_wxyz thz_rad thx_rad thy_rad exact offset values_bad"


def _file(tmp_path: Path, name: str, damage: int | None) -> Path:
    """``recordings/name`` (``demo.bin``: the serial bytes of demo.stv as a raw dump), as is or damaged: bytes
    flipped (one per 3000) and the tail cut (``damage`` 0, 1, 2: 70, 80, 90 % kept)."""
    raw = read_capture(REC / "demo.stv").data if name == "demo.bin" else (REC / name).read_bytes()
    if damage is not None:
        rng = np.random.default_rng([damage, len(raw)])
        b = bytearray(raw)
        for i in rng.integers(0, len(b), size=max(1, len(b) // 3000)):
            b[i] ^= int(rng.integers(1, 256))
        raw = bytes(b[: int(len(b) * (0.7 + 0.1 * damage))])
    path = tmp_path / name
    path.write_bytes(raw)
    return path


def _digest(path: Path) -> str:
    """A short digest of everything ``load_telemetry(path)`` returns (or of its one-sentence error)."""
    h = hashlib.sha256()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            tel = load_telemetry(path)
        except UserError as exc:
            return "error:" + hashlib.sha256(str(exc).replace(str(path), "<path>").encode()).hexdigest()[:16]
    arrays = [getattr(tel.attitude, n) for n in ATTITUDE.split()]
    arrays += [getattr(tel.status, f.name) for f in dataclasses.fields(tel.status)]
    arrays += [tel.flight, tel.acks, tel.commands]
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode() + a.tobytes())
    # counters added after the digests were taken (text telemetry, blank lines) enter only when they are not 0
    late = ("text_records", "text_dropped", "blank_bytes")
    stats = {k: v for k, v in tel.stats.as_dict().items() if v or k not in late}
    rest = (tel.text, sorted(stats.items()), tel.events, tel.source)
    h.update(repr(rest).replace(str(path), "<path>").encode())
    return h.hexdigest()[:16]


#: ``_digest`` of the loader of 158eea4 (capture → decoder → telemetry → decoder → telemetry → capture → decoder).
#: Re-recorded since: textmode.log's four, when a log file's first line became kept when whole (its banner's first
#: line "STEVAL-FCU001V1 FW rev.1.0 - Sep 2017" is now a text line, not 39 bytes skipped; nothing else changed).
#: And ble_demo.stv's four, when a BLE capture became the one Telemetry (the loader refused it before).
EXPECTED = {
    ("ble_demo.stv", None): "6c6b33d9df2e3bbc",
    ("ble_demo.stv", 0): "aade67dc44b75ea9",
    ("ble_demo.stv", 1): "9b36c177deb7625d",
    ("ble_demo.stv", 2): "5258f9d91e6658c6",
    ("broad_07.stv", None): "50a8699257cd684b",
    ("broad_07.stv", 0): "cf58d2e6fb2e7a2b",
    ("broad_07.stv", 1): "error:eb49d22ad7d030b5",
    ("broad_07.stv", 2): "fe5604a84aa0fdb9",
    ("demo.stv", None): "6594e53ac1241aed",
    ("demo.stv", 0): "0fa3e0d1d3575222",
    ("demo.stv", 1): "aa44c12393e9ea46",
    ("demo.stv", 2): "efbcced30cca85cc",
    ("flight.stv", None): "5c85a4338187348a",
    ("flight.stv", 0): "f489a7decf712ece",
    ("flight.stv", 1): "b705a81494d73500",
    ("flight.stv", 2): "ee9c01cf9a47e8a5",
    ("freefall.stv", None): "3625786c64ad230a",
    ("freefall.stv", 0): "017bc344d89342d6",
    ("freefall.stv", 1): "error:bffbdad5460c10b4",
    ("freefall.stv", 2): "4b07c6020b5857d3",
    ("live_params.stv", None): "6909c8df2131985a",
    ("live_params.stv", 0): "a583c6eb522f7ca8",
    ("live_params.stv", 1): "f2919123bd12ffd6",
    ("live_params.stv", 2): "1058d6c4af6a26ee",
    ("midflight_drops.stv", None): "b65cc51d4c16dfcb",
    ("midflight_drops.stv", 0): "a4364ca4d237bce4",
    ("midflight_drops.stv", 1): "ba2a379829c5016d",
    ("midflight_drops.stv", 2): "error:149fe65917f8ac42",
    ("preflight_ok.stv", None): "927b055337afd1a2",
    ("preflight_ok.stv", 0): "7405ddbee5644a62",
    ("preflight_ok.stv", 1): "31d8167f69e93f46",
    ("preflight_ok.stv", 2): "30370193d13610d5",
    ("preflight_swapped_motors.stv", None): "58ddd94e2e4f2f94",
    ("preflight_swapped_motors.stv", 0): "8db7ee6251f2bed4",
    ("preflight_swapped_motors.stv", 1): "a212e08cc809df61",
    ("preflight_swapped_motors.stv", 2): "4e7cc04afdd28cc6",
    ("textmode.log", None): "835ebf64b7d716fa",
    ("textmode.log", 0): "a86a3a5dd75be94a",
    ("textmode.log", 1): "5e665b60658b5656",
    ("textmode.log", 2): "ba3391a702dae983",
    ("demo.bin", None): "f3682314c5fccc33",
    ("demo.bin", 0): "0aed68c79b0e5542",
    ("demo.bin", 1): "7123f173bf819936",
    ("demo.bin", 2): "844d761d9602e3ed",
}


@pytest.mark.parametrize("name, damage", [(n, d) for n, d in EXPECTED])
def test_one_pass_loader_gives_what_the_two_pass_loader_gave(tmp_path, name, damage):
    assert _digest(_file(tmp_path, name, damage)) == EXPECTED[name, damage]


def test_the_loader_builds_telemetry_once_with_its_final_counters_and_commands(monkeypatch):
    """One pass: when ``Telemetry.from_parts`` runs, the counters and the host's commands (chunks H) are final;
    nothing is decoded or patched afterwards."""
    built = []
    from_parts = T.Telemetry.from_parts.__func__

    def spy(cls, parts, stats, **kw):
        tel = from_parts(cls, parts, stats, **kw)
        built.append((stats.as_dict(), tel.commands.copy()))
        return tel

    monkeypatch.setattr(T.Telemetry, "from_parts", classmethod(spy))
    tel = load_telemetry(REC / "live_params.stv")
    assert len(built) == 1
    stats, commands = built[0]
    assert stats == tel.stats.as_dict() and stats["frames_ok"] > 0
    assert len(commands) > 0 and np.array_equal(commands, tel.commands)


def test_a_source_is_a_capture_read_back_or_a_file_of_bytes(tmp_path):
    src = read_recording(REC / "live_params.stv")
    cap = read_capture(REC / "live_params.stv")
    assert isinstance(src, Capture) and src.kind == "stv" and src.warnings == []
    for field in dataclasses.fields(Capture):
        if field.name != "path":
            got, want = getattr(src, field.name), getattr(cap, field.name)
            assert np.array_equal(got, want) if isinstance(want, np.ndarray) else got == want, field.name
    dump = _file(tmp_path, "demo.bin", None)
    raw = read_recording(dump)
    assert isinstance(raw, Recording) and raw.kind == "bytes" and raw.data == dump.read_bytes()
    assert raw.header == {} and raw.events == [] and raw.host == [] and len(raw.chunk_offsets) == 0
    cut = read_recording(_file(tmp_path, "flight.stv", 2))
    assert cut.truncated and cut.warnings == [cut.warning] and "damaged" in cut.warning

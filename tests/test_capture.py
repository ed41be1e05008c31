"""Capture files: round trip, events, crash safety (truncation anywhere), auto-detection, clear user errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from support.streams import StreamBuilder

from steval_link.errors import UserError
from steval_link.link import protocol as P
from steval_link.link.capture import MAGIC, CaptureTruncatedWarning, CaptureWriter, read_capture
from steval_link.link.load import load_telemetry, read_recording


def write_capture(path, data: bytes, chunk: int = 100, events=()):
    with CaptureWriter(path, port="/dev/ttyUSB0", baud=115200, extra={"note": "test"}) as w:
        for i, j in enumerate(range(0, len(data), chunk)):
            for at, kind, text in events:
                if at == j:
                    w.mark_event(kind, text, t_host_s=i * 0.01)
            w.write(data[j : j + chunk], t_host_s=(i + 1) * 0.01)
    return path


def test_round_trip_bytes_times_header_events(tmp_path, stream: StreamBuilder):
    data = stream.flight(300).bytes()
    path = write_capture(
        tmp_path / "a.stv", data, 100, events=[(1000, "disconnect", "USB unplugged"), (1000, "reconnect", "")]
    )
    cap = read_capture(path)
    assert cap.data == data and not cap.truncated and cap.warning is None
    assert cap.chunk_offsets.tolist() == list(range(0, len(data), 100))
    np.testing.assert_allclose(cap.chunk_times_s, (np.arange(len(cap.chunk_offsets)) + 1) * 0.01)
    h = cap.header
    assert h["port"] == "/dev/ttyUSB0" and h["baud"] == 115200 and h["extra"] == {"note": "test"}
    assert h["start_time_utc"].endswith("+00:00") and h["tool_version"]
    assert [(e.kind, e.text, e.offset) for e in cap.events] == [
        ("disconnect", "USB unplugged", 1000),
        ("reconnect", "", 1000),
    ]
    tel = load_telemetry(path)
    assert tel.source["kind"] == "stv" and len(tel.attitude) == 300
    assert [e.kind for e in tel.events] == ["disconnect", "reconnect"]
    # host time: frames completed in chunk i get chunk i's time, less the bytes after them at 115200 baud
    last = tel.attitude.offset + P.ATTITUDE_FRAME_SIZE - 1
    chunk = last // 100
    end = np.minimum((chunk + 1) * 100, len(data))
    np.testing.assert_allclose(
        tel.attitude.t_host_s,
        np.maximum((chunk + 1) * 0.01 - (end - last - 1) * 10 / 115200, np.where(chunk > 0, chunk * 0.01, -np.inf)),
    )


def test_truncated_anywhere_reads_up_to_last_complete_chunk(tmp_path, stream: StreamBuilder):
    data = stream.flight(40, status_every=0).bytes()
    path = write_capture(tmp_path / "full.stv", data, 500)
    full = path.read_bytes()
    header_end = 12 + int.from_bytes(full[8:12], "little") + 4
    chunk_ends = [header_end]
    pos = header_end
    while pos < len(full):
        length = int.from_bytes(full[pos + 1 : pos + 5], "little")
        pos += 13 + length + 4
        chunk_ends.append(pos)
    for cut in list(range(header_end, len(full), 97)) + [len(full) - 1]:
        p = tmp_path / "cut.stv"
        p.write_bytes(full[:cut])
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            cap = read_capture(p)
        complete = max(e for e in chunk_ends if e <= cut)
        assert cap.truncated == (cut != complete) == bool(w)
        if w:
            assert issubclass(w[0].category, CaptureTruncatedWarning) and "cut short" in str(w[0].message)
        assert cap.data == data[: 500 * (chunk_ends.index(complete))]
    # cut inside the header: a clear user error
    p.write_bytes(full[: header_end - 3])
    with pytest.raises(UserError, match="header"):
        read_capture(p)


def test_damaged_chunk_inside_is_skipped_with_warning(tmp_path, stream: StreamBuilder):
    data = stream.flight(40, status_every=0).bytes()
    path = write_capture(tmp_path / "d.stv", data, 500)
    raw = bytearray(path.read_bytes())
    raw[-337 - 200] ^= 0xFF  # inside the 4th of 5 data chunks (the 5th holds 320 bytes: 337 in the file)
    path.write_bytes(bytes(raw))
    with pytest.warns(CaptureTruncatedWarning, match="CRC"):
        cap = read_capture(path)
    assert cap.truncated and cap.data == data[:1500] + data[2000:]
    assert [(e.kind, e.offset) for e in cap.events] == [("damaged", 1500)]
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        tel = load_telemetry(path)
    assert any(issubclass(x.category, CaptureTruncatedWarning) for x in w)
    assert tel.source["warnings"]
    # every frame not touched by the lost chunk is decoded, the loss shows as a sequence gap
    FS = P.ATTITUDE_FRAME_SIZE
    lost = {i for i in range(40) if i * FS + FS > 1500 and i * FS < 2000}
    assert tel.attitude.seq.tolist() == [i for i in range(40) if i not in lost]
    assert tel.stats.frames_missing == len(lost)


def test_kill_9_loses_nothing_written(tmp_path, stream: StreamBuilder):
    """A writer process killed mid-recording leaves a readable capture with every chunk it wrote."""
    data = stream.flight(200, status_every=0).bytes()
    src = tmp_path / "src.bin"
    src.write_bytes(data)
    path = tmp_path / "killed.stv"
    code = (
        "import sys, time\n"
        "from steval_link.link.capture import CaptureWriter\n"
        f"data = open({str(src)!r}, 'rb').read()\n"
        f"w = CaptureWriter({str(path)!r}, port='p', baud=115200)\n"
        "for i in range(0, len(data), 60):\n"
        "    w.write(data[i:i+60])\n"
        "print('written', flush=True)\n"
        "time.sleep(60)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    try:
        assert proc.stdout.readline().strip() == b"written"
        proc.kill()
    finally:
        proc.wait()
    cap = read_capture(path)
    assert cap.data == data and not cap.truncated


def test_writer_syncs_at_least_once_a_second(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(time.monotonic()), real_fsync(fd)))
    with CaptureWriter(tmp_path / "s.stv", port="p", baud=1, sync_interval_s=0.05) as w:
        n0 = len(synced)
        w.write(b"abc")
        time.sleep(0.5)
        assert len(synced) > n0  # the background thread synced the pending chunk without another write
    cap = read_capture(tmp_path / "s.stv")
    assert cap.data == b"abc"


def test_writer_never_overwrites(tmp_path):
    p = tmp_path / "x.stv"
    p.write_bytes(b"precious")
    with pytest.raises(FileExistsError):
        CaptureWriter(p, port="p", baud=1)
    assert p.read_bytes() == b"precious"


def test_raw_dump_and_text_log_are_detected_by_content(tmp_path, make_stream):
    b = make_stream(3).flight(100)
    raw = tmp_path / "log.txt"  # a binary dump with a misleading extension
    raw.write_bytes(b.bytes()[17:])
    tel = load_telemetry(raw)
    assert tel.source["kind"] == "raw" and len(tel.attitude) == 99
    assert np.isnan(tel.attitude.t_host_s).all()

    t = make_stream(4)
    for i in range(0, 320, 16):
        t.att_line(i)
    text = tmp_path / "putty.bin"
    text.write_bytes(t.bytes())
    tel = load_telemetry(text)
    assert tel.source["kind"] == "text" and len(tel.attitude) == 20 and not tel.attitude.exact.any()

    stv_named_raw = tmp_path / "capture.dat"
    write_capture(stv_named_raw, b.bytes())
    assert load_telemetry(stv_named_raw).source["kind"] == "stv"


@pytest.mark.parametrize(
    "content, match",
    [
        (None, "no such file"),
        (b"", "empty"),
        (b"hello world\nthis is not a capture\n" * 20, "not a steval capture"),
        (MAGIC + b"\x05\x00", "header"),
        (MAGIC[:5], "header"),
    ],
)
def test_user_errors_are_one_sentence(tmp_path, content, match):
    p = tmp_path / "in.stv"
    if content is not None:
        p.write_bytes(content)
    with pytest.raises(UserError, match=match) as exc:
        load_telemetry(p)
    assert "\n" not in str(exc.value)


def test_empty_capture_and_capture_without_frames(tmp_path):
    with CaptureWriter(tmp_path / "e.stv", port="p", baud=115200):
        pass
    with pytest.raises(UserError, match="empty capture"):
        load_telemetry(tmp_path / "e.stv")
    with CaptureWriter(tmp_path / "g.stv", port="p", baud=9600) as w:
        w.write(bytes(range(256)) * 4)
    with pytest.raises(UserError, match="wrong baud"):
        load_telemetry(tmp_path / "g.stv")


def test_directory_and_unreadable(tmp_path):
    with pytest.raises(UserError, match="directory"):
        read_recording(tmp_path)


def test_header_is_json_documented_fields(tmp_path):
    p = write_capture(tmp_path / "h.stv", b"\x00")
    raw = p.read_bytes()
    assert raw.startswith(MAGIC)
    n = int.from_bytes(raw[8:12], "little")
    head = json.loads(raw[12 : 12 + n])
    assert set(head) == {
        "format",
        "format_version",
        "port",
        "baud",
        "start_time_utc",
        "start_time_unix_s",
        "tool_version",
        "extra",
    }


def test_many_damaged_chunks_give_one_short_warning(tmp_path, stream: StreamBuilder, monkeypatch, capsys):
    """A capture damaged in 60 places (e.g. a flaky SD card) warns once: count, bytes, the first few byte ranges,
    not one clause per place (that used to be a 13 kB line)."""
    import json

    from support.cli import run_cli

    data = stream.flight(1200, status_every=0).bytes()
    path = write_capture(tmp_path / "flaky.stv", data, 500)
    raw = bytearray(path.read_bytes())
    header_end = 12 + int.from_bytes(raw[8:12], "little") + 4
    starts, pos = [], header_end
    while pos < len(raw):
        starts.append(pos)
        pos += 13 + int.from_bytes(raw[pos + 1 : pos + 5], "little") + 4
    hit = starts[1:-1:2][:60]
    for p in hit:
        raw[p + 13 + 100] ^= 0xFF  # inside the payload: CRC mismatch
    path.write_bytes(bytes(raw))

    code, out, err = run_cli(monkeypatch, capsys, "replay", path)
    assert code == 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("steval: warning:") and len(lines[0]) < 400, err
    first = hit[0]
    assert f"{len(hit)} places" in err and f"{first}–{first + 517 - 1}" in err and f"and {len(hit) - 3} more" in err
    assert f"{517 * len(hit)} damaged bytes" in err
    code, out, err = run_cli(monkeypatch, capsys, "replay", path, "--json")
    assert code == 0 and [len(w) < 400 for w in json.loads(out)["warnings"]] == [True]


def test_resolve_capture_out_never_makes_folders(tmp_path, monkeypatch):
    from steval_link.cli.checks import user_message
    from steval_link.link.capture import resolve_capture_out

    monkeypatch.chdir(tmp_path)
    assert resolve_capture_out(None) is None
    assert resolve_capture_out("flight.stv") == Path("flight.stv")
    inside = resolve_capture_out(tmp_path)  # an existing directory: write inside it
    assert inside.parent == tmp_path and inside.name.startswith("steval-") and inside.suffix == ".stv"
    for bad, words in (
        ("missing/sub/flight.stv", "does not exist"),
        ("missing/", "does not exist"),
        ("flight.stv/x.stv", None),
    ):
        if bad.startswith("flight.stv/"):
            (tmp_path / "flight.stv").write_bytes(b"x")
            words = "is not a directory"
        with pytest.raises(UserError, match=words) as exc:
            resolve_capture_out(bad)
        assert str(exc.value).startswith("out= ")  # the parameter; the CLI names its flag
        assert user_message(exc.value).startswith("--out ")
    with pytest.raises(UserError, match="already exists"):
        resolve_capture_out("flight.stv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.stv"]  # nothing created


def test_capture_without_bytes_can_be_discarded(tmp_path):
    with CaptureWriter(tmp_path / "empty.stv", port="p", baud=115200, discard_empty=True) as w:
        w.mark_event("stop", "no bytes")
    assert w.discarded and not (tmp_path / "empty.stv").exists()
    with CaptureWriter(tmp_path / "one.stv", port="p", baud=115200, discard_empty=True) as w:
        w.write(b"\x00")
    assert not w.discarded and read_capture(tmp_path / "one.stv").data == b"\x00"
    with CaptureWriter(tmp_path / "kept.stv", port="p", baud=115200) as w:  # default: kept
        pass
    assert not w.discarded and (tmp_path / "kept.stv").exists()

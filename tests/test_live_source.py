"""One live session over one source interface: the URL that chooses a driver, the reader's locked write (a command
never meets a port being swapped by a reconnection), the session's one stop mechanism and its one capture opening."""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import pytest
import serial

from steval_link.errors import UserError
from steval_link.link.transport import Protocol, SerialReader
from steval_link.live.ble_source import BleSource
from steval_link.live.emulated import EmulatedSource
from steval_link.live.serial_source import SerialSource
from steval_link.live.session import LiveOptions, LiveSession, source_for
from steval_link.live.sources import Chunk, LinkInfo, LinkStatus, Source

ROOT = Path(__file__).resolve().parents[1]


def test_the_url_chooses_the_driver():
    assert isinstance(source_for("/dev/ttyUSB0"), SerialSource) and source_for("COM3", baud=460800).baud == 460800
    assert source_for("auto", wait=True).wait and isinstance(source_for("replay://recordings/demo.stv"), SerialSource)
    assert source_for("replay://recordings/demo.stv").replay and not source_for("/dev/ttyUSB0").replay
    for url, target in (("ble:DRN1110", "DRN1110"), ("BLE:auto", None), ("ble:", None)):
        ble = source_for(url, backend=object())
        assert isinstance(ble, BleSource) and ble.target == target
        assert not ble.describe().takes_commands and ble.describe().kind == "ble"
    emu = source_for("emulated:", emulation=object(), realtime=True)
    assert isinstance(emu, EmulatedSource) and emu.realtime


class FakePort:
    """A port whose first read fails (an unplug) when ``fail_first``; remembers whether it was open at each write."""

    def __init__(self, name: str, fail_first: bool = False) -> None:
        self.port = name
        self.is_open = True
        self.fail_first = fail_first
        self.writes: list[tuple[bytes, bool]] = []
        self.in_waiting = 0

    def read(self, size: int = 1) -> bytes:
        if self.fail_first:
            self.fail_first = False
            raise serial.SerialException("device reports readiness to read but returned no data")
        time.sleep(0.005)
        return b""

    def write(self, data: bytes) -> int:
        self.writes.append((data, self.is_open))
        return len(data)

    def close(self) -> None:
        self.is_open = False


class Events(Protocol):
    def __init__(self) -> None:
        self.events: list[str] = []

    def connection_made(self, port: str) -> None:
        self.events.append(f"made {port}")

    def connection_lost(self, exc) -> None:
        self.events.append("lost" if exc is not None else "closed")


def _wait(cond, timeout_s: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not cond():
        time.sleep(0.005)
    return cond()


def test_a_write_and_a_reconnection_hold_the_same_lock():
    old, new = FakePort("/dev/ttyUSB0", fail_first=True), FakePort("/dev/ttyUSB1")
    proto = Events()
    reader = SerialReader(old, proto, baud=115200, find_port=lambda: "/dev/ttyUSB1", opener=lambda path: new)
    reader.lock.acquire()  # as a command being written while the port fails
    try:
        reader.start()
        time.sleep(0.1)
        assert reader.serial is old and old.is_open and proto.events == ["made /dev/ttyUSB0"]  # the swap waits
        done, outcome = threading.Event(), []

        def command() -> None:
            try:
                outcome.append(reader.write(b"\xa5cmd"))
            except serial.SerialException as exc:  # between the loss and the reopening: not sent, said so
                outcome.append(str(exc))
            done.set()

        threading.Thread(target=command, daemon=True).start()
        assert not done.wait(0.1)  # and a write waits for the lock too
    finally:
        reader.lock.release()
    assert done.wait(2.0) and outcome[0] in (4, "the port is not connected")
    assert _wait(lambda: reader.serial is new)
    reader.write(b"\xa5next")
    reader.stop()
    assert proto.events == ["made /dev/ttyUSB0", "lost", "made /dev/ttyUSB1", "closed"]
    sent = old.writes + new.writes  # never to a port closed under it
    assert new.writes[-1] == (b"\xa5next", True) and all(was_open for _, was_open in sent)
    assert len(sent) == (2 if outcome[0] == 4 else 1)
    with pytest.raises(serial.SerialException, match="not connected"):  # an OSError: the prompt says "not sent"
        reader.write(b"\xa5late")


class ScriptedSource(Source):
    """A source of a few rounds that counts the session's calls."""

    def __init__(self, rounds: int, fail_at: int | None = None) -> None:
        self.rounds, self.fail_at, self.calls, self.n = rounds, fail_at, [], 0
        self.status = LinkStatus(connected=True, port="script")

    def open(self, note) -> None:
        self.calls.append("open")

    def describe(self) -> LinkInfo:
        return LinkInfo("script", 115200, {"scripted": True}, note="reading a script")

    def chunks(self, record, clock):
        self.calls.append("start")
        return self._rounds(record)

    def _rounds(self, record):
        while self.n < self.rounds and "close" not in self.calls:
            self.n += 1
            if self.n == self.fail_at:
                raise UserError("the script failed")
            chunk = Chunk("D", b"\xa5" * 10, 0.01 * self.n)
            record(chunk)
            self.status.bytes_total += 10
            yield [chunk]

    def close(self) -> None:
        self.calls.append("close")


def test_one_session_drives_any_source_and_owns_the_capture_and_the_stop(tmp_path):
    import io

    from steval_link.link.capture import read_capture

    src = ScriptedSource(rounds=5)
    err = io.StringIO()
    summary = LiveSession(LiveOptions(out=tmp_path / "a.stv", prompt=False), src, stream=err, tty=False).run()
    assert src.calls == ["open", "start", "close"] and summary.bytes_total == 50
    assert summary.stopped_by == "end" and summary.line().startswith("recorded ")
    cap = read_capture(tmp_path / "a.stv")
    assert cap.header["port"] == "script" and cap.header["extra"]["scripted"] is True
    assert [(e.kind, e.text) for e in cap.events] == [("stop", "end")] and len(cap.data) == 50
    assert "reading a script; recording to" in err.getvalue()
    # a stop requested (Ctrl-C, --duration) ends it at the next round, the same way for every source
    src = ScriptedSource(rounds=1000)
    session = LiveSession(LiveOptions(out=tmp_path / "b.stv", prompt=False), src, stream=io.StringIO())
    rounds = src._rounds
    src._rounds = lambda record: (
        (session.request_stop("interrupted") if src.n == 2 else None, chunks)[1] for chunks in rounds(record)
    )
    assert session.run().stopped_by == "interrupted" and src.n == 2
    assert [e.text for e in read_capture(tmp_path / "b.stv").events] == ["interrupted"]
    # a source's error: the capture is closed whole first, then the error is raised
    src = ScriptedSource(rounds=10, fail_at=3)
    with pytest.raises(UserError, match="the script failed"):
        LiveSession(LiveOptions(out=tmp_path / "c.stv", prompt=False), src, stream=io.StringIO()).run()
    assert src.calls[-1] == "close" and len(read_capture(tmp_path / "c.stv").data) == 20
    # the capture exists already: one sentence, and the input is released
    src = ScriptedSource(rounds=1)
    with pytest.raises(UserError, match="already exists"):
        LiveSession(LiveOptions(out=tmp_path / "a.stv", prompt=False), src, stream=io.StringIO()).run()
    assert src.calls == ["open", "close"]


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (
            ["live", "--port", "ble:DRN1110", "--no-view"],
            "--port ble:DRN1110: a BLE drone is read with steval live --ble DRN1110",
        ),
        (["live", "--port", "emulated:", "--no-view"], "the emulated board is run with steval emulate FIRMWARE.elf"),
        (["record", "--port", "BLE:"], "a BLE drone is read with steval live --ble"),
        (["preflight", "--port", "emulated:x.elf"], "steval emulate FIRMWARE.elf"),
        (["live", "--ble", "--port", "replay://recordings/demo.stv"], "a session reads one source; drop one of them"),
    ],
)
def test_a_port_option_that_names_another_source_is_one_sentence(monkeypatch, capsys, tmp_path, args, words):
    """`--port` takes a serial port or replay://; BLE and the emulated board have their own commands."""
    from support.cli import run_cli

    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(monkeypatch, capsys, *args)
    assert code == 2 and err.count("\n") == 1 and words in err and "Traceback" not in err, err
    assert not list(tmp_path.rglob("*.stv"))


def test_spawn_without_a_display_is_said_before_the_work(monkeypatch, capsys, tmp_path):
    """Headless, `--spawn` cannot open a window: one sentence naming the other sinks, before any summary."""
    from support.cli import run_cli

    from steval_viewer.sink_options import free_port

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    demo = str(ROOT / "recordings" / "demo.stv")
    code, out, err = run_cli(monkeypatch, capsys, "replay", demo, "--spawn", "--grpc-port", free_port())
    assert code == 2 and out == "" and err.count("\n") == 1 and "no display for the desktop viewer (--spawn)" in err
    code, out, err = run_cli(monkeypatch, capsys, "live", "--port", "replay://" + demo, "--duration", "1")
    assert code == 2 and "--no-view to record only" in err


def test_the_link_interface_is_narrow_and_runs_one_way():
    """Source has five public methods (open, describe, chunks, write, close), no driver adds one, and no driver
    module names a session at all (the session reads the sources, never the reverse)."""
    import ast
    import inspect

    from steval_link.live import ble_source, emulated, serial_source, sources

    def public(cls) -> set[str]:
        return {n for n, v in vars(cls).items() if not n.startswith("_") and inspect.isfunction(v)}

    assert public(Source) == {"open", "describe", "chunks", "write", "close"}
    for cls in (SerialSource, EmulatedSource, BleSource):
        assert public(cls) <= public(Source), cls.__name__
        assert inspect.ismethod(cls.from_url)  # each driver parses its own URL
    for module in (sources, serial_source, emulated, ble_source):
        tree = ast.parse(inspect.getsource(module))
        names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
        names |= {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
        names |= {a.arg for a in ast.walk(tree) if isinstance(a, ast.arg)}
        assert not {"session", "LiveSession"} & names, module.__name__


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_the_emulated_source_records_every_byte_and_step_of_the_board(reference_elf):
    # the capture of an emulated session holds the board's USART1 bytes at their emulated times, in order, and the
    # attitude read by symbol of every AHRS step
    from steval_link.emulation.runner import Emulation, EmulationOptions
    from steval_link.emulation.symbol_attitude import SYMBOL_DTYPE

    options = EmulationOptions(elf=reference_elf, scenario="hand-tilts", duration_s=7.0, seed=2)
    alone = [(data, t_s) for data, t_s in Emulation(options).chunks()]
    source = EmulatedSource(options)
    source.open()
    recorded: list = []
    for _batch in source.chunks(recorded.append, None):
        pass
    source.close()
    assert [(c.data, c.t_s) for c in recorded if c.kind == "D"] == alone
    s_rows = sum(len(c.data) for c in recorded if c.kind == "S") // SYMBOL_DTYPE.itemsize
    assert s_rows == source.status.symbol_rows > 500
    assert source.status.report is not None and source.status.report.emulated_s == pytest.approx(7.0)

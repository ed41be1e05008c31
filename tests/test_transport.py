"""Serial transport and port detection on pseudo-terminals: reading, unplug/replug, probing, error messages."""

from __future__ import annotations

import os
import threading
import time

import pytest
import serial
from support.ptyfeed import PtyFeeder, flight_stream, uart_resample

from steval_link.cli.checks import user_message
from steval_link.link import autodetect
from steval_link.link.decoder import StreamDecoder
from steval_link.link.transport import Protocol, SerialReader, open_error_message, open_serial

fcntl = pytest.importorskip("fcntl", reason="POSIX file control on a pseudo-terminal: not on Windows")

pytestmark = pytest.mark.slow  # real time: processes on pseudo-terminals


class Collector(Protocol):
    """Keeps every event of the reader thread with the monotonic time it happened."""

    def __init__(self) -> None:
        self.chunks: list[tuple[bytes, float]] = []
        self.events: list[tuple[str, str, float]] = []
        self.lock = threading.Lock()

    def connection_made(self, port: str) -> None:
        self.events.append(("made", port, time.monotonic()))

    def data_received(self, data: bytes, t_unix_s: float) -> None:
        with self.lock:
            self.chunks.append((data, t_unix_s))

    def connection_lost(self, exc) -> None:
        self.events.append(("lost", "" if exc is None else type(exc).__name__, time.monotonic()))

    def data(self) -> bytes:
        with self.lock:
            return b"".join(c for c, _ in self.chunks)


def wait_for(cond, timeout_s: float, poll_s: float = 0.01) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(poll_s)
    return cond()


def test_reader_delivers_every_byte_in_order_with_increasing_times(tmp_path):
    data = flight_stream(320)  # ~2 s at the real rate
    with PtyFeeder(data, tmp_path / "ttyUSB0") as feeder:
        ser = open_serial(str(feeder.link), 115200)
        proto = Collector()
        reader = SerialReader(ser, proto, baud=115200)
        reader.start()
        feeder.start()
        assert feeder.wait_done(30)
        assert wait_for(lambda: len(proto.data()) >= feeder.sent, 10)
        reader.stop()
    assert reader.error is None
    assert proto.data() == feeder.sent_bytes() == data
    times = [t for _, t in proto.chunks]
    assert times == sorted(times)
    assert abs(times[0] - time.time()) < 60  # wall-clock seconds (Unix epoch)
    # paced at the real rate: 2 s of stream arrives over about 2 s, in many small chunks
    assert times[-1] - times[0] > 1.0
    assert len(proto.chunks) > 20
    assert [e[0] for e in proto.events] == ["made", "lost"]


def test_reader_survives_unplug_and_finds_renamed_port_again(tmp_path):
    data = flight_stream(800)  # ~5 s
    link0 = tmp_path / "ttyUSB0"
    with PtyFeeder(data, link0) as feeder:
        ser = open_serial(str(link0), 115200)
        finder = autodetect.PortFinder(autodetect.PortIdentity.of(str(link0)))
        assert finder.pattern.endswith("ttyUSB*")
        proto = Collector()

        def lost_hook(exc, _orig=proto.connection_lost):
            finder.mark_lost()
            _orig(exc)

        proto.connection_lost = lost_hook
        reader = SerialReader(ser, proto, baud=115200, find_port=finder.find)
        reader.start()
        feeder.start()
        assert wait_for(lambda: len(proto.data()) > 5000, 10)
        before = len(proto.data())
        feeder.unplug()
        assert wait_for(lambda: any(e[0] == "lost" for e in proto.events), 5)
        time.sleep(0.5)  # unplugged for a while: the reader keeps polling
        assert reader.is_alive() and not reader.connected.is_set()
        t_plug = time.monotonic()
        feeder.replug(tmp_path / "ttyUSB1")  # comes back under another name
        assert wait_for(lambda: sum(e[0] == "made" for e in proto.events) == 2, 10)
        t_made = proto.events[-1][2]
        assert proto.events[-1][1] == str(tmp_path / "ttyUSB1")
        assert t_made - t_plug < 1.5  # spec: resumes within 2 s of the port reappearing
        assert wait_for(lambda: feeder.done.is_set(), 30)
        time.sleep(0.3)
        reader.stop()
    got = proto.data()
    assert len(got) > before
    # nothing received is lost, and what arrived after the replug is the stream's continuation
    sent = feeder.sent_bytes()
    assert got[:before] == sent[:before]
    dec = StreamDecoder()
    frames = dec.feed(got)
    seqs = [f.seq for f in frames if hasattr(f, "seq")]
    assert seqs == sorted(seqs) and len(seqs) > 400
    assert dec.stats.frames_missing > 0  # the frames sent while unplugged are gone (and counted)
    kinds = [e[0] for e in proto.events]
    assert kinds == ["made", "lost", "made", "lost"]
    assert proto.events[1][1] in ("SerialException", "OSError")  # I/O error or "readiness to read but no data"


def test_port_finder_prefers_same_path_then_new_sibling(tmp_path):
    (tmp_path / "ttyACM0").write_text("")
    (tmp_path / "ttyACM3").write_text("")  # another device that was already there
    finder = autodetect.PortFinder(autodetect.PortIdentity.of(str(tmp_path / "ttyACM0")))
    assert finder.find() == str(tmp_path / "ttyACM0")
    (tmp_path / "ttyACM0").unlink()
    finder.mark_lost()
    assert finder.find() is None  # ttyACM3 was present before: not taken for ours
    (tmp_path / "ttyACM1").write_text("")
    assert finder.find() == str(tmp_path / "ttyACM1")
    (tmp_path / "ttyACM0").write_text("")
    assert finder.find() == str(tmp_path / "ttyACM0")
    assert autodetect.family_glob("/dev/ttyUSB0") == "/dev/ttyUSB*"
    assert autodetect.family_glob("COM3") == "COM*"
    assert autodetect.family_glob("/dev/ttyS") is None


def test_choose_port_probes_candidates_and_picks_the_one_with_frames(tmp_path):
    good = flight_stream(400)
    noise = uart_resample(flight_stream(400, seed=1), 921600, 115200) * 8
    with PtyFeeder(good, tmp_path / "ttyUSB0", loop=True) as a, PtyFeeder(noise, tmp_path / "ttyUSB1", loop=True) as b:
        a.start()
        b.start()
        ports = [str(a.link), str(b.link)]
        assert autodetect.choose_port("auto", 115200, candidates=ports) == str(a.link)
        assert autodetect.choose_port(str(tmp_path / "ttyUSB*"), 115200) == str(a.link)
        with pytest.raises(autodetect.PortChoiceError, match="none of the serial ports") as info:
            autodetect.choose_port("auto", 115200, candidates=[str(b.link)] * 2, probe_s=0.4)
        assert str(b.link) in user_message(info.value) and "--port" in user_message(info.value)
    with pytest.raises(autodetect.PortChoiceError, match="no serial ports found"):
        autodetect.choose_port("auto", 115200, candidates=[])
    assert autodetect.choose_port("/dev/ttyUSB9", 115200) == "/dev/ttyUSB9"  # a path is taken as is


@pytest.mark.parametrize(
    "baud_tx, baud_rx, expect",
    [(921600, 115200, "--baud 921600"), (115200, 921600, "--baud 115200"), (57600, 115200, "--baud 57600")],
)
def test_wrong_baud_message_suggests_the_right_rate(baud_tx, baud_rx, expect):
    stream = flight_stream(300)
    seconds = len(stream) * 10 / baud_tx
    seen = uart_resample(stream, baud_tx, baud_rx)
    dec = StreamDecoder()
    frames = [f for f in dec.feed(seen) if not hasattr(f, "text")]
    assert frames == []
    found = autodetect.no_frames_message("/dev/ttyUSB0", baud_rx, seen, seconds)
    msg = user_message(found)  # the CLI names the flag; the library its parameter
    assert msg.startswith(f"no valid frames at {baud_rx} baud on /dev/ttyUSB0; bytes look like ")
    assert expect in msg and expect.replace("--baud ", "baud= ") in str(found)
    assert "\n" not in msg


def test_describe_bytes_names_text_zeros_and_silence():
    assert "text" in autodetect.describe_bytes(b"Hello from another board\r\n" * 10)
    assert "0x00" in autodetect.describe_bytes(bytes(500))
    assert "0xFF" in autodetect.describe_bytes(b"\xff" * 500)
    assert "no bytes" in user_message(autodetect.no_frames_message("/dev/x", 115200, b"", 3.0))
    assert "flash the steval firmware" in user_message(
        autodetect.no_frames_message("/dev/x", 115200, b"AT+OK\r\n" * 50, 1.0)
    )


def test_open_errors_are_one_sentence_with_the_fix(tmp_path):
    with pytest.raises(serial.SerialException) as info:
        open_serial(str(tmp_path / "ttyUSB7"), 115200)
    msg = user_message(open_error_message(str(tmp_path / "ttyUSB7"), info.value, ["/dev/ttyUSB0", "/dev/ttyACM0"]))
    assert msg == (
        f"no serial port {tmp_path / 'ttyUSB7'}; available ports: /dev/ttyUSB0, /dev/ttyACM0 "
        "(pick one with --port, or --port auto)"
    )
    # busy: another program holds the port's lock
    with PtyFeeder(b"", tmp_path / "ttyUSB0") as feeder:
        holder = os.open(str(feeder.link), os.O_RDWR | os.O_NOCTTY)
        fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)
        try:
            with pytest.raises(serial.SerialException) as info:
                open_serial(str(feeder.link), 115200)
        finally:
            os.close(holder)
        msg = user_message(open_error_message(str(feeder.link), info.value))
        assert "is busy: close the other program using it (screen, minicom, Arduino IDE" in msg
    err = serial.SerialException(13, "could not open port /dev/ttyUSB0: [Errno 13] Permission denied: '/dev/ttyUSB0'")
    assert "sudo usermod -aG dialout $USER" in user_message(open_error_message("/dev/ttyUSB0", err))
    not_tty = tmp_path / "plain.txt"
    not_tty.write_text("x")
    with pytest.raises(serial.SerialException) as info:
        open_serial(str(not_tty), 115200)
    assert "not a serial port" in user_message(open_error_message(str(not_tty), info.value))


def busy(reopen_error) -> bool:
    return reopen_error is not None and "is busy" in user_message(open_error_message(*reopen_error))


def test_reader_keeps_trying_a_port_that_came_back_busy_and_says_why(tmp_path):
    with PtyFeeder(flight_stream(300), tmp_path / "ttyACM0") as feeder:
        ser = open_serial(str(feeder.link), 115200)
        proto = Collector()
        reader = SerialReader(ser, proto, baud=115200, find_port=lambda: str(feeder.link) if feeder.plugged else None)
        reader.start()
        feeder.start()
        assert wait_for(lambda: len(proto.data()) > 1000, 10)
        feeder.unplug()
        assert wait_for(lambda: any(e[0] == "lost" for e in proto.events), 5)
        feeder.replug()
        holder = os.open(str(feeder.link), os.O_RDWR | os.O_NOCTTY)  # e.g. ModemManager probing the new port
        fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)
        try:
            # a try made while the node was going away may have found no node first: wait for the busy one
            assert wait_for(lambda: busy(reader.reopen_error), 5)
            path, exc = reader.reopen_error
            assert path == str(feeder.link) and "is busy" in user_message(open_error_message(path, exc))
            assert not reader.connected.is_set()
        finally:
            os.close(holder)
        assert wait_for(lambda: reader.connected.is_set(), 5)  # released: reopened at the next poll
        assert reader.reopen_error is None
        reader.stop()
    assert [e[0] for e in proto.events] == ["made", "lost", "made", "lost"]


def test_an_open_error_of_another_kind_is_one_sentence_too(tmp_path, monkeypatch, capsys):
    """A port that is a directory (or any error the known causes do not name): one line, exit 2, no traceback."""
    from support.cli import run_cli

    with pytest.raises(serial.SerialException) as info:
        open_serial(str(tmp_path), 115200)
    assert user_message(open_error_message(str(tmp_path), info.value)).startswith(f"cannot open {tmp_path}")
    for args in (["live", "--port", str(tmp_path), "--no-view"], ["command", "status", "--port", str(tmp_path)]):
        code, _, err = run_cli(monkeypatch, capsys, *args)
        assert code == 2 and err.startswith(f"steval: error: cannot open {tmp_path}") and "Traceback" not in err, err

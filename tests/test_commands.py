"""Host side of the two-way link: typed commands, the command channel, acks, the capture's H chunks, the live
pipeline's command log, and ``steval param`` / ``steval command`` against a fake drone on a pseudo-terminal."""

from __future__ import annotations

import os
import select
import threading
import time

import numpy as np
import pytest
from support.cli import run_cli
from support.viewers import NullViewer

from steval_link.errors import UserError
from steval_link.link import protocol as P
from steval_link.link.capture import CaptureWriter, read_capture
from steval_link.link.commands import (
    Command,
    CommandChannel,
    ack_of_text,
    describe_ack,
    parse_command,
    parse_script,
)
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AckFrame, CommandFrame
from steval_link.live.pipeline import LivePipeline

# ---- typed commands ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "line,cmd",
    [
        ("set ki 1.0", Command(P.CMD_SET_PARAM, P.PARAM_KI, 1.0)),
        ("ki 1", Command(P.CMD_SET_PARAM, P.PARAM_KI, 1.0)),
        ("  SET kp_ground 2.5 ", Command(P.CMD_SET_PARAM, P.PARAM_KP_GROUND, 2.5)),
        ("set kp-flight 0.25", Command(P.CMD_SET_PARAM, P.PARAM_KP_FLIGHT, 0.25)),
        ("set min_thr 300", Command(P.CMD_SET_PARAM, P.PARAM_MIN_THR, 300.0)),
        ("correction off", Command(P.CMD_SET_PARAM, P.PARAM_CORRECTION, 0.0)),
        ("set correction on", Command(P.CMD_SET_PARAM, P.PARAM_CORRECTION, 1.0)),
        ("reset", Command(P.CMD_RESET_FILTER)),
        ("reset-filter", Command(P.CMD_RESET_FILTER)),
        ("status", Command(P.CMD_REQUEST_STATUS)),
        ("mode text", Command(P.CMD_SET_MODE, P.MODE_TEXT)),
        ("mode binary", Command(P.CMD_SET_MODE, P.MODE_BINARY)),
    ],
)
def test_typed_commands(line, cmd):
    assert parse_command(line) == cmd
    assert parse_command(cmd.describe()) == cmd  # what we print reads back


@pytest.mark.parametrize(
    "line,message",
    [
        ("", "empty command"),
        ("fly", "not a command"),
        ("set kd 1", "unknown parameter 'kd'"),
        ("set ki -1", "finite number >= 0"),
        ("set ki nan", "finite number >= 0"),
        ("set ki 5000", "at most 1000"),
        ("set ki fast", "takes a number"),
        ("set min_thr 20.5", "whole number"),
        ("correction maybe", "on or off"),
        ("mode fancy", "text or binary"),
    ],
)
def test_bad_commands_are_one_sentence(line, message):
    with pytest.raises(UserError) as exc:
        parse_command(line)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_script_lines_and_errors():
    script = parse_script("# lab 4 and 5\n6 set ki 1.0\n\n3.5 status  # first\n12 correction off\n")
    assert [(t, c.describe()) for t, c in script] == [(3.5, "status"), (6.0, "set ki 1"), (12.0, "correction off")]
    with pytest.raises(UserError, match="x.txt line 2: .*emulated time"):
        parse_script("1 status\nsoon status\n", "x.txt")
    with pytest.raises(UserError, match="line 1: unknown parameter"):
        parse_script("1 set foo 2\n")


def test_channel_numbers_records_and_matches():
    sent, recorded = [], []
    ch = CommandChannel(sent.append, recorded.append, first_seq=65535)
    a = ch.send(parse_command("set ki 1"))
    b = ch.send(parse_command("status"))
    assert (a.cmd_seq, b.cmd_seq) == (65535, 0)  # wraps
    assert sent == recorded == [a.frame, b.frame]
    frames = StreamDecoder().feed(b"".join(sent))
    assert [(f.cmd_seq, f.cmd, f.param, f.value) for f in frames if isinstance(f, CommandFrame)] == [
        (65535, P.CMD_SET_PARAM, P.PARAM_KI, 1.0),
        (0, P.CMD_REQUEST_STATUS, 0, 0.0),
    ]
    stale = AckFrame(cmd_seq=1234, cmd=1, result=0, step=9, rx_ok=1, rx_bad=0)
    assert ch.match(stale) is None
    wrong_cmd = AckFrame(cmd_seq=0, cmd=P.CMD_SET_PARAM, result=0, step=9, rx_ok=1, rx_bad=0)
    assert ch.match(wrong_cmd) is None
    ack = AckFrame(cmd_seq=65535, cmd=P.CMD_SET_PARAM, result=0, step=420, rx_ok=3, rx_bad=2)
    assert ch.match(ack) is a and ch.match(ack) is None
    assert describe_ack(a.command, ack) == (
        "set ki 1: accepted, applies from step 420 (commands received 3, rejected 2)"
    )
    refused = AckFrame(cmd_seq=0, cmd=P.CMD_SET_PARAM, result=P.ACK_REFUSED_ARMED, step=9, rx_ok=4, rx_bad=2)
    assert "refused: the motors may spin" in describe_ack(a.command, refused)


def test_text_mode_ack_lines():
    ack = ack_of_text("#ACK 7 4 0 1234 5 6")
    assert (ack.cmd_seq, ack.cmd, ack.result, ack.step, ack.rx_ok, ack.rx_bad) == (7, 4, 0, 1234, 5, 6)
    assert ack_of_text("#ACK 7 4") is None and ack_of_text("hello") is None


# ---- the capture's H chunks ------------------------------------------------------------------------------------


def test_capture_keeps_what_the_host_sent(tmp_path):
    path = tmp_path / "x.stv"
    cmd = Command(P.CMD_RESET_FILTER).encode(5)
    with CaptureWriter(path, port="test", baud=115200) as w:
        w.write(b"\xa5\x5a" + b"abc", 0.5)
        w.write_host(cmd, 0.75)
        w.write(b"def", 1.0)
    cap = read_capture(path)
    assert cap.header["format_version"] == 2
    assert cap.data == b"\xa5\x5aabcdef"  # the host's bytes never mix with the drone's
    assert [(h.t_host_s, h.data, h.offset) for h in cap.host] == [(0.75, cmd, 5)]


def test_format_1_captures_still_read():
    from pathlib import Path

    v1 = Path(__file__).parent / "data" / "v1" / "freefall.stv"
    cap = read_capture(v1)
    assert cap.header["format_version"] == 1 and cap.host == [] and cap.data


# ---- the live pipeline's command log --------------------------------------------------------------------------


class _Viewer(NullViewer):
    def __init__(self):
        self.events = []

    def log_event(self, text, t, level):
        self.events.append((text, t, level))


def test_pipeline_logs_commands_acks_and_settings_on_the_timeline():
    viewer = _Viewer()
    pipe = LivePipeline([], viewer)
    pipe.feed_host(Command(P.CMD_SET_PARAM, P.PARAM_KI, 1.0).encode(3), 100.0)
    status = P.encode_status(
        step=41, t_us=0, q_wxyz=(1, 0, 0, 0), int_xyz=(0, 0, 0), ki=1.0, flags=P.FLAG_EVENT, param_gen=1
    )
    data = P.encode_ack(cmd_seq=3, cmd=P.CMD_SET_PARAM, result=0, step=42, rx_ok=1) + status
    pipe.feed([(data, 100.5)])
    pipe.flush_view()
    texts = [(t, lv) for t, _, lv in viewer.events]
    assert ("sent: set ki 1", "DEBUG") in texts
    assert ("set ki 1: accepted, applies from step 42 (commands received 1, rejected 0)", "INFO") in texts
    assert any(t.startswith("drone: kp_ground") and "ki 1," in t and t.endswith("from step 42") for t, _ in texts)
    assert list(pipe.notes) == ["set ki 1: accepted, applies from step 42 (commands received 1, rejected 0)"]
    refused = P.encode_ack(cmd_seq=4, cmd=P.CMD_RESET_FILTER, result=P.ACK_REFUSED_ARMED, step=50, rx_ok=2)
    pipe.feed([(refused, 101.0)])
    pipe.flush_view()
    assert viewer.events[-1][2] == "WARN" and "refused" in viewer.events[-1][0]


# ---- steval param / steval command against a fake drone on a pseudo-terminal ----------------------------------


class FakeDrone:
    """Answers command frames on a pty like the patched firmware: an ack, then an EVENT status (accepted); it
    refuses filter changes while ``armed``; ``silent`` answers nothing; it streams attitude-like noise meanwhile."""

    def __init__(self, link, *, armed=False, silent=False, ack=True, stream: list[bytes] | None = None):
        pty = pytest.importorskip("pty", reason="the fake drone runs on a pseudo-terminal (POSIX only)")
        tty = pytest.importorskip("tty", reason="the fake drone runs on a pseudo-terminal (POSIX only)")
        self.master, slave = pty.openpty()
        tty.setraw(slave)
        self.slave_name = os.ttyname(slave)
        os.symlink(self.slave_name, link)
        self._slave = slave
        self.armed, self.silent, self.ack = armed, silent, ack
        self.settings = {"kp_ground": 10.0, "kp_flight": 0.4, "ki": 0.1, "min_thr": 200, "flags": 0}
        self.step = 1000
        self.gen = 0
        self.received = []
        self.stream = stream or []  # frames to send, 3 every 20 ms (a drone's stream)
        self._k = 0
        self._stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def close(self):
        if self._stop:
            return
        self._stop = True
        self.thread.join(2)
        os.close(self.master)
        os.close(self._slave)

    def _run(self):
        dec = StreamDecoder()
        while not self._stop:
            r, _, _ = select.select([self.master], [], [], 0.02)
            self.step += 3
            if self.stream:
                out = b"".join(self.stream[(self._k + i) % len(self.stream)] for i in range(3))
                self._k += 3
                try:
                    os.write(self.master, out)
                except OSError:
                    return
            if not r:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:
                return
            for f in dec.feed(data):
                if isinstance(f, CommandFrame):
                    self.received.append(f)
                    self._answer(f)

    def _answer(self, f):
        if self.silent:
            return
        result = P.ACK_ACCEPTED
        if f.cmd in (P.CMD_SET_PARAM, P.CMD_RESET_FILTER) and self.armed:
            result = P.ACK_REFUSED_ARMED
        elif f.cmd == P.CMD_SET_PARAM:
            name = {
                P.PARAM_KP_GROUND: "kp_ground",
                P.PARAM_KP_FLIGHT: "kp_flight",
                P.PARAM_KI: "ki",
                P.PARAM_MIN_THR: "min_thr",
            }.get(f.param)
            if name:
                self.settings[name] = f.value
            else:
                self.settings["flags"] = 0 if f.value else P.FLAG_NO_CORRECTION
            self.gen += 1
        out = b""
        if self.ack:
            out += P.encode_ack(
                cmd_seq=f.cmd_seq, cmd=f.cmd, result=result, step=self.step + 1, rx_ok=len(self.received)
            )
        if result == P.ACK_ACCEPTED:
            s = self.settings
            out += P.encode_status(
                step=self.step,
                t_us=self.step * 6190,
                q_wxyz=(1, 0, 0, 0),
                int_xyz=(0, 0, 0),
                kp_ground=s["kp_ground"],
                kp_flight=s["kp_flight"],
                ki=s["ki"],
                min_thr=int(s["min_thr"]),
                flags=s["flags"] | P.FLAG_EVENT,
                param_gen=self.gen,
            )
        os.write(self.master, b"\x00\x17" + out)


@pytest.fixture
def drone(tmp_path):
    made = []

    def make(**kw):
        d = FakeDrone(tmp_path / "ttyFAKE", **kw)
        made.append(d)
        return d, str(tmp_path / "ttyFAKE")

    yield make
    for d in made:
        d.close()


def test_param_set_and_get(drone, monkeypatch, capsys, tmp_path):
    d, port = drone()
    code, out, err = run_cli(monkeypatch, capsys, "param", "set", "ki", "1.0", "--port", port)
    assert code == 0, err
    assert out.splitlines()[0].startswith("set ki 1: accepted, applies from step ")
    assert "ki 1," in out
    assert d.received[-1].param == P.PARAM_KI and d.received[-1].value == 1.0
    code, out, err = run_cli(monkeypatch, capsys, "param", "get", "ki", "--port", port)
    assert code == 0, err
    assert out.startswith("ki = 1.0 (after step ")
    code, out, err = run_cli(
        monkeypatch, capsys, "param", "set", "correction", "off", "--port", port, "--out", tmp_path / "p.stv"
    )
    assert code == 0, err
    code, out, err = run_cli(monkeypatch, capsys, "param", "get", "--port", port)
    assert "correction off" in out and "ki 1," in out
    cap = read_capture(tmp_path / "p.stv")  # --out: the exchange, the command bytes as H chunks
    assert len(cap.host) == 1 and cap.host[0].data[2] == (P.VERSION << 4) | P.TYPE_COMMAND


def test_commands_reset_status_mode(drone, monkeypatch, capsys):
    d, port = drone()
    for args, cmd in (
        (["reset-filter"], P.CMD_RESET_FILTER),
        (["status"], P.CMD_REQUEST_STATUS),
        (["mode", "text"], P.CMD_SET_MODE),
    ):
        code, out, err = run_cli(monkeypatch, capsys, "command", *args, "--port", port)
        assert code == 0, err
        assert ": accepted" in out and d.received[-1].cmd == cmd


@pytest.mark.slow  # ≥ 0.5 s of CPU: runs with --runslow, as in CI
def test_refused_and_silent_are_one_line_errors(drone, monkeypatch, capsys, tmp_path):
    d, port = drone(armed=True)
    code, out, err = run_cli(monkeypatch, capsys, "param", "set", "ki", "1", "--port", port)
    assert code == 2
    assert err.startswith("steval: error: set ki 1: refused: the motors may spin") and err.count("\n") == 1
    d.close()
    os.unlink(port)
    d2, port = drone(silent=True)
    t0 = time.monotonic()
    code, out, err = run_cli(monkeypatch, capsys, "command", "status", "--port", port, "--timeout", "0.5")
    assert code == 2 and time.monotonic() - t0 < 3
    assert "steval: error: " in err and "within 0.5 s" in err and err.count("\n") == 1
    code, out, err = run_cli(monkeypatch, capsys, "param", "set", "kd", "1", "--port", port)
    assert code == 2 and "unknown parameter 'kd'" in err
    code, out, err = run_cli(monkeypatch, capsys, "param", "set", "ki", "1", "--port", str(tmp_path / "nope"))
    assert code == 2 and err.startswith("steval: error: ") and err.count("\n") == 1


def test_console_sends_typed_lines_and_reports_mistakes():
    from steval_link.live.session import CommandConsole

    sent, notes = [], []
    console = CommandConsole(sent.append, notes.append, enabled=False)
    console.type_line("set ki 1.0\n")
    console.type_line("\n")
    console.type_line("blah\n")
    console.type_line("correction off\n")
    assert console.poll() == 2
    assert [f[2] for f in sent] == [(P.VERSION << 4) | P.TYPE_COMMAND] * 2
    assert notes[0] == "sent: set ki 1" and notes[1].startswith("not a command: 'blah'")
    assert notes[2] == "sent: correction off"
    assert np.frombuffer(sent[1][8:12], "<f4")[0] == 0.0


@pytest.mark.slow  # real time: a steval live child for 4 s, typed to after sleep(1.5)
def test_live_prompt_sends_typed_commands_and_records_them(drone, tmp_path):
    """The user's path: steval live with typed lines on stdin; the answer is printed, the capture keeps the bytes
    sent (H chunk) and the drone's ack."""
    import subprocess
    import sys
    from pathlib import Path

    data = read_capture(Path(__file__).resolve().parents[1] / "recordings" / "demo.stv").data
    dec = StreamDecoder()
    frames = [
        data[f.offset : f.offset + f.nbytes] for f in dec.feed(data)[100:700] if f.nbytes == P.ATTITUDE_FRAME_SIZE
    ]
    d, port = drone(stream=frames)
    out = tmp_path / "live.stv"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from steval_link.cli import main; main()",
            "live",
            "--port",
            port,
            "--no-view",
            "--duration",
            "4",
            "--prompt",
            "--out",
            str(out),
            "-e",
            "none",
            "--rrd",
            str(tmp_path / "live.rrd"),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(1.5)
    proc.stdin.write("set ki 1.0\nfly away\n")
    proc.stdin.flush()
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    assert "type a command and Enter" in stderr
    assert "sent: set ki 1" in stderr and "set ki 1: accepted, applies from step" in stderr
    assert "not a command: 'fly away'" in stderr
    assert d.received and d.received[0].param == P.PARAM_KI
    cap = read_capture(out)
    assert len(cap.host) == 1 and cap.host[0].data == Command(P.CMD_SET_PARAM, P.PARAM_KI, 1.0).encode(
        d.received[0].cmd_seq
    )
    acks = [f for f in StreamDecoder().feed(cap.data) if isinstance(f, AckFrame)]
    assert [a.cmd_seq for a in acks] == [d.received[0].cmd_seq]
    from steval_viewer.rrd_check import read_rrd

    # on the timeline: the command sent and its ack
    assert read_rrd(tmp_path / "live.rrd").samples.get("log/commands", 0) >= 2


def test_console_on_a_terminal_reads_keys_and_shows_the_line_being_typed():
    """On a terminal the typed line survives the health line's redraws (shown in it) and Enter sends it; the
    terminal gets its line mode back on close."""
    pty = pytest.importorskip("pty", reason="a terminal console needs a pseudo-terminal (POSIX only)")
    termios = pytest.importorskip("termios", reason="a terminal console needs termios (POSIX only)")

    from steval_link.live.session import CommandConsole

    master, slave = pty.openpty()
    stream = os.fdopen(slave, "rb", buffering=0)
    before = termios.tcgetattr(slave)
    sent, notes = [], []
    console = CommandConsole(sent.append, notes.append, stream=stream)
    try:
        assert not termios.tcgetattr(slave)[3] & termios.ICANON
        os.write(master, b"set ki 2x\x7f.5")
        deadline = time.monotonic() + 3
        while console.typing != "set ki 2.5" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert console.typing == "set ki 2.5" and console.take_typing_change()
        assert console.decorate("frames 10").startswith("> set ki 2.5_")
        os.write(master, b"\r")
        while not console.poll() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert notes == ["sent: set ki 2.5"] and len(sent) == 1 and console.typing == ""
    finally:
        console.close()
        assert termios.tcgetattr(slave)[3] == before[3]
        os.close(master)


def test_a_port_held_by_steval_live_says_to_use_its_prompt(drone, monkeypatch, capsys):
    from steval_link.link.transport import open_serial

    d, port = drone()
    held = open_serial(port, 115200)  # as steval live holds it (exclusive)
    try:
        code, out, err = run_cli(monkeypatch, capsys, "param", "set", "ki", "1", "--port", port)
    finally:
        held.close()
    assert code == 2 and "is busy" in err and "type the command at its prompt" in err and err.count("\n") == 1

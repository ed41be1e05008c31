"""``steval param`` / ``steval command``: send a command to the drone on a serial port, then read until its
acknowledgement (and the ``EVENT`` status frame that follows an accepted one) or ``timeout_s``."""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from pathlib import Path

import serial

from steval_link.errors import ParamError, UserError
from steval_link.link import protocol as P
from steval_link.link.commands import Command, CommandChannel, ack_of_text, describe_ack
from steval_link.link.decoder import StreamDecoder
from steval_link.link.frames import AckFrame, StatusFrame, TextFrame
from steval_link.link.transport import close_quietly
from steval_link.live.serial_source import open_port
from steval_link.live.session import open_capture

__all__ = ["Reply", "run_command"]


@dataclass
class Reply:
    """What the drone answered to one command: its ack and the EVENT status frame after it (None if none came)."""

    command: Command
    ack: AckFrame
    status: StatusFrame | None
    text: str

    @property
    def accepted(self) -> bool:
        return int(self.ack.result) == P.ACK_ACCEPTED


def run_command(port: str, baud: int, command: Command, *, timeout_s: float = 2.0, out: Path | None = None) -> Reply:
    """Send ``command`` and return the drone's reply (UserError on no answer). ``out``: also record the exchange
    (received bytes, the bytes sent as ``H`` chunks) to this new capture."""
    try:
        path, ser = open_port(port, baud)
    except UserError as exc:  # the advice to wait goes: no waiting for one command
        message = re.sub(r" \(or use [^)]*\)$", "", getattr(exc, "template", str(exc)))
        if " is busy" in message:
            message += " (if steval live has it, type the command at its prompt instead)"
        raise ParamError(message, *getattr(exc, "params", ())) from None
    capture = None
    try:
        if out is not None:
            capture = open_capture(out, port=path, baud=baud, extra={"source": "steval param/command"})

        def write(frame: bytes) -> None:
            try:
                ser.write(frame)
                ser.flush()
            except (serial.SerialException, OSError) as exc:
                raise UserError(f"cannot write to {path}: {exc}") from None

        channel = CommandChannel(write, capture.write_host if capture is not None else None)
        return _answer(ser, path, channel, command, timeout_s, capture)
    finally:
        if capture is not None:
            capture.close()
        close_quietly(ser)


def _answer(ser, path: str, channel: CommandChannel, command: Command, timeout_s: float, capture) -> Reply:
    sent = channel.send(command)
    decoder = StreamDecoder()
    deadline = time.monotonic() + timeout_s
    ack: AckFrame | None = None
    got_bytes = False
    while time.monotonic() < deadline:
        try:
            data = ser.read(4096)
        except (serial.SerialException, OSError) as exc:
            raise UserError(f"reading {path} failed: {exc}") from None
        if not data:
            continue
        got_bytes = True
        if capture is not None:
            capture.write(data)
        for frame in decoder.feed(data):
            if isinstance(frame, TextFrame):
                frame = ack_of_text(frame.text) or frame
            if ack is None and isinstance(frame, AckFrame) and channel.match(frame) is sent:
                ack = frame
                if int(ack.result) != P.ACK_ACCEPTED:  # a refused command: no status frame follows
                    return Reply(command, ack, None, describe_ack(command, ack))
            elif ack is not None and isinstance(frame, StatusFrame) and int(frame.flags) & P.FLAG_EVENT:
                return Reply(command, ack, frame, describe_ack(command, ack))
    if ack is not None:  # the ack came, the status frame did not (dropped): the ack is the answer
        return Reply(command, ack, None, describe_ack(command, ack))
    if not got_bytes:
        raise UserError(
            f"no answer from the drone on {path} within {timeout_s:g} s (nothing received: is it on, and "
            "is the adapter's RX wired to PA9 and its TX to PA10 on header P7?)"
        )
    if not decoder.stats.frames_ok:
        raise ParamError(
            f"no answer from the drone on {path} within {timeout_s:g} s (no valid frames either: wrong "
            "{baud}, or not a STEVAL with the steval-link firmware)",
            "baud",
        )
    raise UserError(
        f"the drone on {path} did not acknowledge '{command.describe()}' within {timeout_s:g} s (its "
        "frames arrive: is the adapter's TX wired to PA10 on header P7, and does the firmware have the "
        "two-way link, protocol v2?)"
    )

"""The command prompt of a live session: lines typed while viewing (``set ki 1.0``, ``reset``...) become commands
to the drone. A thread reads them; on a POSIX terminal key by key without echo, and the session shows the line being
typed in its health line, so the redrawn line never wipes it."""

from __future__ import annotations

import contextlib
import os
import queue
import sys
import threading
from collections.abc import Callable
from typing import TextIO

from steval_link.errors import UserError
from steval_link.link.commands import CommandChannel, parse_command

__all__ = ["CommandConsole", "PROMPT_HELP"]

PROMPT_HELP = (
    "type a command and Enter: set ki 1.0 | correction off | correction on | reset | status | "
    "set min_thr 300 | mode text"
)


class CommandConsole:
    """Typed lines → commands → ``send(frame)``; ``record(frame)`` gets each frame once sent. ``stream``: where the
    lines come from (default stdin); ``enabled=False`` reads nothing."""

    def __init__(
        self,
        send: Callable[[bytes], object],
        note: Callable[[str], None],
        *,
        record: Callable[[bytes], object] | None = None,
        stream: TextIO | None = None,
        enabled: bool = True,
    ) -> None:
        self.channel = CommandChannel(send, record)
        self.note = note
        self._lines: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.typing = ""  # the line being typed on a terminal (shown in the health line), "" otherwise
        self.typing_changed = False
        self._restore = None
        if enabled:
            src = stream if stream is not None else sys.stdin
            target = self._read_keys if self._raw_terminal(src) else self._read
            threading.Thread(target=target, args=(src,), name="steval-prompt", daemon=True).start()

    def _raw_terminal(self, stream) -> bool:
        """Switch a terminal to key-by-key input without echo (Ctrl-C still interrupts); False when not one."""
        try:
            import termios  # reason: POSIX only (Windows reads whole lines)
            import tty

            fd = stream.fileno()
            if not os.isatty(fd):
                return False
            old = termios.tcgetattr(fd)
            tty.setcbreak(fd, termios.TCSANOW)
        except (ImportError, AttributeError, ValueError, OSError):
            return False
        self._restore = (fd, old)
        return True

    def close(self) -> None:
        """Give the terminal its line mode and echo back (idempotent)."""
        if self._restore is not None:
            import termios  # reason: only set on POSIX

            (fd, old), self._restore = self._restore, None
            with contextlib.suppress(OSError, ValueError):
                termios.tcsetattr(fd, termios.TCSANOW, old)

    def _read(self, stream: TextIO) -> None:
        with contextlib.suppress(OSError, ValueError):  # stdin closed
            for line in stream:
                self._lines.put(line)

    def _read_keys(self, stream) -> None:
        fd, buf = stream.fileno(), ""
        with contextlib.suppress(OSError):
            while b := os.read(fd, 64):
                for ch in b.decode("utf-8", "replace"):
                    if ch in "\r\n":
                        self._lines.put(buf + "\n")
                        buf = ""
                    elif ch in "\x7f\b":
                        buf = buf[:-1]
                    elif ch == "\x15":  # Ctrl-U: the whole line
                        buf = ""
                    elif ch.isprintable():
                        buf += ch
                self.typing = buf
                self.typing_changed = True

    def type_line(self, line: str) -> None:
        self._lines.put(line)

    def decorate(self, health_line: str) -> str:
        """The health line after the command being typed (on a terminal)."""
        if self._restore is None:
            return health_line
        return f"> {self.typing}_  | {health_line}"

    def take_typing_change(self) -> bool:
        """True once after each key typed (the session then redraws at once, so typing shows without delay)."""
        changed, self.typing_changed = self.typing_changed, False
        return changed

    def poll(self, notes=()) -> int:
        """Send what was typed since the last call; print ``notes`` (the pipeline's answers). Returns commands sent."""
        n = 0
        while not self._lines.empty():
            line = self._lines.get_nowait()
            if not line.strip():
                continue
            try:
                command = parse_command(line)
            except UserError as exc:
                self.note(str(exc))
                continue
            try:
                self.channel.send(command)
            except (OSError, UserError) as exc:
                self.note(f"{command.describe()}: not sent ({exc})")
                continue
            self.note(f"sent: {command.describe()}")
            n += 1
        for _ in range(len(notes)):
            self.note(notes.popleft())
        return n

"""The command prompt of a live session (``steval live``, ``steval emulate``): lines typed in the terminal while
viewing become commands to the drone.

``set ki 1.0``, ``correction off``, ``reset``, ``status``, ``mode text`` (see
:func:`steval_link.link.commands.parse_command`). A thread reads the lines (stdin blocks); the session's loop calls
:meth:`CommandConsole.poll` every round, which sends the commands, and prints what the pipeline noted about them
(the acknowledgements, one sentence each). The pipeline logs every command sent and answered on the viewer's
timeline (``log/commands``); the capture gets the bytes sent (``H`` chunks) from the session's ``record``.
"""

from __future__ import annotations

import queue
import sys
import threading
from collections.abc import Callable
from typing import TextIO

from steval_link.errors import UserError
from steval_link.link.commands import Command, CommandChannel, Sent, parse_command

__all__ = ["CommandConsole", "PROMPT_HELP"]

PROMPT_HELP = ("type a command and Enter: set ki 1.0 | correction off | correction on | reset | status | "
               "set min_thr 300 | mode text")


class CommandConsole:
    """Typed lines → :class:`~steval_link.link.commands.Command` → ``send(frame)``.

    ``record(frame)`` gets each frame once it is sent (the capture and the pipeline's log). ``stream``: where the
    lines come from (default stdin); None and ``enabled=False`` read nothing (scripts still use :meth:`send`)."""

    def __init__(self, send: Callable[[bytes], object], note: Callable[[str], None], *,
                 record: Callable[[bytes], object] | None = None, stream: TextIO | None = None,
                 enabled: bool = True) -> None:
        self.channel = CommandChannel(send, record)
        self.note = note
        self._lines: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.enabled = enabled
        if enabled:
            src = stream if stream is not None else sys.stdin
            threading.Thread(target=self._read, args=(src,), name="steval-prompt", daemon=True).start()

    def _read(self, stream: TextIO) -> None:
        try:
            for line in stream:
                self._lines.put(line)
        except (OSError, ValueError):  # stdin closed
            pass

    def type_line(self, line: str) -> None:
        """As if ``line`` had been typed (tests, scripted sessions)."""
        self._lines.put(line)

    def send(self, command: Command) -> Sent | None:
        try:
            sent = self.channel.send(command)
        except (OSError, UserError) as exc:
            self.note(f"{command.describe()}: not sent ({exc})")
            return None
        self.note(f"sent: {command.describe()}")
        return sent

    def poll(self, notes=()) -> int:
        """Send what was typed since the last call; print ``notes`` (the pipeline's answers). Returns commands sent."""
        n = 0
        while True:
            try:
                line = self._lines.get_nowait()
            except queue.Empty:
                break
            if not line.strip():
                continue
            try:
                command = parse_command(line)
            except UserError as exc:
                self.note(str(exc))
                continue
            if self.send(command) is not None:
                n += 1
        for _ in range(len(notes)):
            self.note(notes.popleft())
        return n

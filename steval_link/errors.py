"""The one exception type for user errors, and the safe rendering of their message as one terminal line."""


class UserError(Exception):
    """Bad input from the user (missing file, not a capture, wrong option): one clear sentence, exit code 2."""

    exit_code = 2


def printable(text: str) -> str:
    """``text`` as one safe terminal line: control characters, escape sequences and undecodable bytes (the
    surrogate escapes of a non-UTF-8 argument) become ``\\xNN`` / ``\\uNNNN``; newlines become spaces."""
    out = []
    for ch in str(text):
        if ch in "\r\n\t":
            out.append(" ")
        elif ch.isprintable():
            out.append(ch)
        elif 0xDC80 <= ord(ch) <= 0xDCFF:  # a raw byte from argv (surrogateescape)
            out.append(f"\\x{ord(ch) - 0xDC00:02x}")
        elif ord(ch) < 0x100:
            out.append(f"\\x{ord(ch):02x}")
        else:
            out.append(f"\\u{ord(ch):04x}")
    return "".join(out)


def param_word(name: str) -> str:
    """How the library names its parameter ``name`` in a sentence: ``name=``."""
    return f"{name}="


class ParamError(UserError):
    """A bad value of a library parameter. ``template`` names each of ``params`` as ``{name}``: the message reads
    ``name=`` there, and :meth:`worded` lets a caller name it its own way (the CLI names the flag)."""

    def __init__(self, template: str, *params: str) -> None:
        self.template, self.params = template, params
        super().__init__(self.worded(param_word))

    def worded(self, word) -> str:
        """The message with ``word(name)`` for each parameter."""
        text = self.template
        for name in self.params:
            text = text.replace("{" + name + "}", word(name))
        return text

"""Text telemetry: numeric records in any serial text (a student's ``PRINTF``, ST's output, plotter formats).

:class:`TextTelemetryReader` hands each plain line back as a ``TextRecordFrame`` or a ``TextFrame``. Lines it reads
(each value a C ``printf`` number: ``%d``, ``%f``, ``%10.2f``, ``%e``, ``nan``, ``inf``):

* bare values split by tab, comma, semicolon or spaces, named by a header line of labels before them
  (``t,pitch,roll``; ``pitch(deg)`` keeps its unit), else ``col1..N``;
* labelled values: ``label:value`` / ``label = value`` pairs (Arduino's plotter, ``Drone_Pitch = %f``), a label
  with several values as a vector (``Accel: x y z m/s2`` gives ``Accel_x/y/z``), a word after the values as unit;
* Teleplot lines ``>name:value`` (``>name:t_ms:value``, ``§unit`` and ``|flags`` allowed);
* ST's release 221117 line, named from ST's source, and its ``%f``-less form (the float fields empty: NaN).

A record's shape (names or count, and the int/float/empty kind of each value, per line) is learned: lines become
records once it repeated :data:`CONFIRM` times in a row. A record is one line, a block between blank lines, a cycle
of lines of different shapes, or the rows of a matrix (values coming back every 2..4 lines). Lines wait meanwhile (at
most :data:`MAX_PENDING`); lines that never fit go out as text. A learned one-line shape has a :class:`LineTemplate`
for the bulk decoder.

Written here rather than taken from a library: the plotter tools (Arduino's, Teleplot, Serial Studio) each parse
their one format inside an application; none is a library that learns a record from mixed lines.
"""

from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass

import numpy as np

from steval_link.link.frames import TextFrame, TextRecordFrame

#: Times a record shape must repeat in a row before its lines are records.
CONFIRM = 3
#: Lines held while a shape is learned; older ones go out as text lines.
MAX_PENDING = 48
#: Longest record, in lines.
MAX_RECORD_LINES = 8
#: Lines of one table seen before its shape is decided (whether rows come back every 2..4 lines: a matrix).
VALUE_LINES = 13

#: ST's release 221117 main loop: ``PRINTF("%d\t%d\t%d\t%d\t%f\t%f\t%f\t%f\t%f\n", gELE, gAIL, gRUD, gTHR,
#: motor_pwm.motor1_pwm, euler_ahrs.thx * 57.3, euler_ahrs.thy * 57.3, euler_rc.thx * 57.3, euler_rc.thy * 57.3)``.
ST_221117_NAMES = ("gELE", "gAIL", "gRUD", "gTHR", "motor1_pwm", "thx", "thy", "rc_thx", "rc_thy")
ST_221117_UNITS = ("", "", "", "", "", "deg", "deg", "deg", "deg")
ST_221117 = "st-221117"

_NUM = r"[-+]?(?:\d+\.?\d*(?:[eE][-+]?\d+)?|\.\d+(?:[eE][-+]?\d+)?|nan|inf|NAN|INF|NaN|Inf)"
_NUM_RE = re.compile(_NUM)
_INT_RE = re.compile(r"[-+]?\d+")
#: A unit written right after its number (``3.92V``, ``25.3C``, ``12ms``, ``9.81m/s2``): a known unit only, so that
#: ``0x1F`` or ``2nd`` are not read as numbers.
_UNIT_SUFFIX = (
    r"(?:%|°C?|°/s|hPa|mdps|dps|rpm|bar|deg|rad(?:/s)?|[kMmuµn]?(?:Hz|Pa|V|A|W|s|g|G|C|F|K)|mg|m/s2|m/s\^2|m/s²|m)"
)
_TOKEN = re.compile(
    rf"(?P<num>{_NUM})(?![\w.°%/²^])|(?P<glued>{_NUM}{_UNIT_SUFFIX})(?![\w.])|(?P<sep>[:=])|(?P<delim>[,;\t])"
    r"|(?P<word>[^\s:=,;\t]+)|\s+"
)
_GLUED = re.compile(rf"({_NUM})(.+)")
_TELEPLOT = re.compile(rf">([^:|§\s][^:|§]*):(?:({_NUM}):)?({_NUM})(?:§([^|]*))?(?:\|[a-z]*)?")
_LABEL_UNIT = re.compile(r"(.+?)\s*[\(\[]([^\)\]]+)[\)\]]")
_HEADER_WORD = re.compile(r"[A-Za-z_][\w./%\-]*(?:\s*[\(\[][^\)\]]+[\)\]])?")
#: Characters of ordinary text lines besides letters and digits (of any script): the usual punctuation.
_PUNCTUATION = frozenset(" \t.,:;=_-+/()%#!?'\"[]<>*@&|°µ—–")
_SUFFIXES = {2: ("x", "y"), 3: ("x", "y", "z")}


def _kind(field: str) -> str:
    """'i' an integer, 'f' any other number, '-' empty."""
    return "-" if not field else "i" if _INT_RE.fullmatch(field) else "f"


def _number(field: str) -> float:
    return float(field) if field else math.nan


@dataclass(frozen=True, slots=True)
class ParsedLine:
    """One line read as numbers: ``shape`` (what a repeat must match), ``names`` (None: bare values), ``kind``."""

    shape: tuple
    names: tuple[str, ...] | None
    units: tuple[str, ...]
    values: tuple[float, ...]
    kind: str


def _split(text: str) -> tuple[str | None, list[str]]:
    """A line's separator (tab, comma, semicolon; None: spaces) and its fields."""
    sep = next((c for c in "\t,;" if c in text), None)
    return sep, [f.strip() for f in (text.split(sep) if sep else text.split())]


def _split_bare(text: str) -> list[str] | None:
    """The fields of a line of bare values (None when a field is not a number)."""
    sep, fields = _split(text)
    if sep and len(fields) > 1 and fields[-1] == "" and not _st_fields(fields):
        fields.pop()  # one separator after the last value (``%f\t\n``)
    return None if not any(fields) or any(f and not _NUM_RE.fullmatch(f) for f in fields) else fields


def _st_fields(fields: list[str]) -> bool:
    """ST 221117's nine fields: four integers, then five floats or (``%f``-less) five empty fields."""
    if len(fields) != 9 or not all(_INT_RE.fullmatch(f) for f in fields[:4]):
        return False
    rest = fields[4:]
    return all(f == "" for f in rest) or all(f and "." in f for f in rest)


def _bare_line(text: str) -> ParsedLine | None:
    fields = _split_bare(text)
    if fields is None:
        return None
    kinds = tuple(_kind(f) for f in fields)
    values = tuple(_number(f) for f in fields)
    if "\t" in text and _st_fields(fields):
        return ParsedLine((ST_221117, kinds), ST_221117_NAMES, ST_221117_UNITS, values, ST_221117)
    return ParsedLine(("table", kinds), None, ("",) * len(fields), values, "table")


def _label_and_unit(label: str) -> tuple[str, str]:
    m = _LABEL_UNIT.fullmatch(label)
    return (m.group(1).strip().replace(" ", "_"), m.group(2).strip()) if m else (label, "")


def _tokens(text: str) -> list[tuple[str, str]] | None:
    out, pos = [], 0
    for m in _TOKEN.finditer(text):
        if m.start() != pos:
            return None
        pos = m.end()
        if m.lastgroup == "glued":  # a number and its unit: as if a space were between them
            number, unit = _GLUED.fullmatch(m.group(0)).groups()
            out += [("num", number), ("word", unit)]
        elif m.lastgroup:
            out.append((m.lastgroup, m.group(m.lastgroup)))
    return out if pos == len(text) else None


def _groups(tokens: list[tuple[str, str]]) -> list[list] | None:
    """``[label, [value fields], unit]`` groups of a labelled line, or None when it does not read as one."""
    groups: list[list] = []
    i, n = 0, len(tokens)
    while i < n:
        kind, val = tokens[i]
        if kind == "delim":
            i += 1
        elif kind == "num":
            groups.append([None, [val], ""])
            i += 1
        elif kind == "word":
            j = i
            while j < n and tokens[j][0] == "word":
                j += 1
            words = [w for _, w in tokens[i:j]]
            if j < n and tokens[j][0] == "sep":
                if groups and groups[-1][0] is not None and len(words) == 2 and not groups[-1][2]:
                    groups[-1][2] = words[0]  # "... 1013.2 hPa  Temp: 25.1"
                    words = words[1:]
                elif groups and len(words) > 1:
                    return None
                group = [" ".join(words), [], ""]
                i = j + 1
                while i < n and tokens[i][0] in ("num", "delim"):
                    if tokens[i][0] == "num":
                        group[1].append(tokens[i][1])
                    i += 1
                if not group[1]:
                    return None
                groups.append(group)
            elif len(words) == 1 and groups and groups[-1][0] is not None and not groups[-1][2]:
                groups[-1][2] = words[0]  # the unit after the values
                i = j
            else:
                return None
        else:
            return None  # a ':' or '=' without a label
    return groups if any(g[0] is not None for g in groups) else None


def _labelled_line(text: str) -> ParsedLine | None:
    tokens = _tokens(text)
    groups = None if tokens is None else _groups(tokens)
    if groups is None:
        return None
    names, units, numbers = [], [], []  # numbers: every value field, in order
    for label, fields, unit in groups:
        if label is None:
            label_names = [f"col{len(names) + 1}"]
        else:
            label, label_unit = _label_and_unit(label.replace(" ", "_"))
            unit = unit or label_unit
            suffixes = _SUFFIXES.get(len(fields)) or tuple(str(k + 1) for k in range(len(fields)))
            label_names = [label] if len(fields) == 1 else [f"{label}_{s}" for s in suffixes]
        names += label_names
        units += [unit] * len(fields)
        numbers += fields
    if len(set(names)) != len(names):
        return None
    shape = ("labelled", tuple(names), tuple(map(_kind, numbers)))
    return ParsedLine(shape, tuple(names), tuple(units), tuple(map(_number, numbers)), "labelled")


def _teleplot_line(text: str) -> ParsedLine | None:
    m = _TELEPLOT.fullmatch(text.strip())
    if m is None:
        return None
    name, t_ms, value, unit = m.group(1).strip(), m.group(2), m.group(3), (m.group(4) or "").strip()
    names, values, units = (name,), (float(value),), (unit,)
    if t_ms is not None:
        names, values, units = (f"{name}_t_ms", name), (float(t_ms), float(value)), ("ms", unit)
    return ParsedLine(("teleplot", names), names, units, values, "teleplot")


def parse_line(text: str) -> ParsedLine | None:
    """The numbers of one text line, or None when it is not a line of numbers (then it is text)."""
    if text.startswith(">"):
        return _teleplot_line(text)
    return (_bare_line(text) or _labelled_line(text)) if any(c.isdigit() or c in "ni" for c in text) else None


# possessive (no backtracking): about 6 times faster on long runs of lines
_INT_PAT = rb"[-+]?+\d++"
_EXP = rb"(?:[eE][-+]?+\d++)?+"
_FLOAT_PAT = rb"[-+]?+(?:\d++\.\d*+" + _EXP + rb"|\.\d++" + _EXP + rb"|\d++[eE][-+]?+\d++|nan|inf|NAN|INF|NaN|Inf)"
_ST_FLOAT_PAT = rb"[-+]?+(?:\d++\.\d*+|\.\d++)" + _EXP
#: Separators and ``\\r`` as spaces (the bulk reader's number table).
_TO_SPACES = bytes.maketrans(b":=,;\t\r", b"      ")


@dataclass(frozen=True)
class LineTemplate:
    """Lines of one learned one-line record shape, for the bulk decoder: ``valid`` matches a run of whole lines
    that fit, ``groups`` one line with its numbers as groups; ``sep`` a table's separator (None: spaces, or a
    labelled line whose ``words`` go before the numbers are read); ``kinds`` of the values ('i', 'f', '-' empty)."""

    valid: re.Pattern[bytes]
    valid_blanks: re.Pattern[bytes]  #: as ``valid``, blank lines allowed between the lines
    groups: re.Pattern[bytes]
    sep: bytes | None
    words: tuple[bytes, ...]
    trailing: bool
    names: tuple[str, ...]
    units: tuple[str, ...]
    kind: str
    kinds: tuple[str, ...]

    def values(self, chunk: bytes, count: int) -> np.ndarray:
        """The (count, len(kinds)) values of ``chunk``, ``count`` whole lines that ``valid`` matched."""
        cols = [i for i, k in enumerate(self.kinds) if k != "-"]
        out = np.full((count, len(self.kinds)), np.nan)
        table = _number_table(self, chunk, count, len(cols)) if count >= _TABLE_MIN_ROWS else None
        if table is None:  # the one-line-at-a-time way: each line's groups
            table = np.array(self.groups.findall(chunk), dtype=bytes).reshape(count, -1).astype(np.float64)
        out[:, cols] = table
        return out


#: Fewer lines than this are read line by line (a table parser's own start costs more).
_TABLE_MIN_ROWS = 256


def _number_table(t: LineTemplate, chunk: bytes, count: int, ncols: int) -> np.ndarray | None:
    """The numbers of ``chunk`` as a (count, ncols) table by pandas' C parser; None without pandas or a whole table."""
    try:
        import pandas as pd  # optional: a C parser of number tables, about 20 times numpy's
    except ImportError:
        return None
    sep = t.sep
    if sep is None:  # spaces, or a labelled line: its words and separators out, the numbers left
        for w in t.words:
            chunk = chunk.replace(w, b" ")
        chunk, sep = chunk.translate(_TO_SPACES), None
    try:
        df = pd.read_csv(
            io.BytesIO(chunk),
            sep=r"\s+" if sep is None else sep.decode(),
            header=None,
            dtype=np.float64,
            skipinitialspace=True,
            engine="c",
        )
    except (ValueError, pd.errors.ParserError):
        return None
    table = df.to_numpy(np.float64)
    if sep is not None:
        if t.trailing:
            table = table[:, :-1]
        table = table[:, [i for i, k in enumerate(t.kinds) if k != "-"]]
    return table if table.shape == (count, ncols) else None


def line_template(shape: _Shape) -> LineTemplate | None:
    """The :class:`LineTemplate` of a one-line shape, from its example line; None for Teleplot, non-ASCII or ``$``."""
    example, line = shape.example, shape.lines[0]
    if not example.isascii() or "$" in example or line[0] == "teleplot":
        return None
    kinds = line[-1]
    words: tuple[bytes, ...] = ()
    sep, trailing = None, False
    if line[0] == "labelled":
        body, words = _labelled_template(example, kinds)
    else:
        sep_text = _split(example)[0]
        if line[0] == "table" and sep_text == "\t" and len(kinds) == 9:
            return None  # ST's count of fields: the line might read as ST's (another shape)
        number = {"i": _INT_PAT, "f": _ST_FLOAT_PAT if line[0] == ST_221117 else _FLOAT_PAT}
        fields = [b" *+" if k == "-" else b" *+(" + number[k] + b") *+" for k in kinds]
        if sep_text is None:
            body = b" *+" + b" ++".join(b"(" + number[k] + b")" for k in kinds) + b" *+"
        else:
            sep = sep_text.encode()
            body = re.escape(sep).join(fields)
            if example.rstrip(" ").endswith(sep_text) and line[0] != ST_221117 and kinds[-1] != "-":
                body += re.escape(sep) + b" *+"  # one separator after the last value
                trailing = True
    if body is None:
        return None
    plain = re.sub(rb"\((?!\?)", b"(?:", body)  # the same without groups
    valid = re.compile(b"(?:" + plain + rb"\r?+\n)*+")
    blanks = re.compile(b"(?:" + plain + rb"\r?+\n(?:\r?+\n)*+)*+")
    groups = re.compile(body + rb"\r?+\n")
    return LineTemplate(valid, blanks, groups, sep, words, trailing, shape.names, shape.units, shape.kind, kinds)


def _labelled_template(example: str, kinds: tuple) -> tuple[bytes | None, tuple[bytes, ...]]:
    """The regex of a labelled line like ``example`` and its words (labels, units), longest first."""
    parts, words, k = [], set(), 0  # the regex's pieces, the words (labels, units), values seen
    for m in _TOKEN.finditer(example):
        if m.lastgroup == "glued":
            return None, ()  # (read line by line)
        if m.lastgroup == "num":
            if k >= len(kinds):
                return None, ()
            parts.append(b"(" + (_INT_PAT if kinds[k] == "i" else _FLOAT_PAT) + rb")(?![\w.])")
            k += 1
        elif m.lastgroup is None:
            parts.append(rb"[ \t]++" if "\t" not in m.group(0) else re.escape(m.group(0).encode()))
        else:
            parts.append(re.escape(m.group(0).encode()))
            if m.lastgroup == "word":
                words.add(m.group(0).encode())
    if k != len(kinds) or any(_NUM_RE.search(w.decode()) or w.lower() in _NUMBER_PIECES for w in words):
        return None, ()  # a word the number reader could take for part of a number
    return b"".join(parts), tuple(sorted(words, key=len, reverse=True))


_NUMBER_PIECES = {b"n", b"a", b"i", b"f", b"na", b"an", b"in", b"nf", b"e"}


def header_names(text: str) -> tuple[tuple[str, ...], tuple[str, ...]] | None:
    """(names, units) of a header line of labels (``t,pitch,roll``, ``pitch(deg)\\troll(deg)``, ``a b c``), or None."""
    fields = _split(text)[1]
    if len(fields) < 2 or not all(_HEADER_WORD.fullmatch(f) for f in fields):
        return None
    pairs = [_label_and_unit(f) for f in fields]
    names = tuple(p[0] for p in pairs)
    return (names, tuple(p[1] for p in pairs)) if len(set(names)) == len(names) else None


def looks_like_text(text: str) -> bool:
    """True when a line reads as printed text: three characters or more, two alphanumeric, 85 % ordinary."""
    if len(text) < 3 or sum(c.isalnum() for c in text) < 2:
        return False
    ordinary = sum(c.isalnum() or c in _PUNCTUATION for c in text)
    return ordinary >= 0.85 * len(text)


@dataclass(slots=True)
class _Line:
    """A line waiting in the reader: its parse (None for a text line or a marker), its frame and kind."""

    parsed: ParsedLine | None
    text: str
    offset: int
    nbytes: int
    #: "rec" a line of numbers; "text"; "blank"; "cut" a line that may be the tail of a cut line; "break" damage
    kind: str


@dataclass(slots=True)
class _Shape:
    """A learned record: its line shapes, names and units, whether a blank line ends it."""

    lines: tuple
    names: tuple[str, ...]
    units: tuple[str, ...]
    kind: str
    blank_ended: bool
    example: str = ""  #: the text of a line of it (a one-line record): what :func:`line_template` is made from


class TextTelemetryReader:
    """Plain text lines in, records and text lines out (see the module docstring). One per stream."""

    def __init__(self) -> None:
        self._pending: list[_Line] = []
        self._shapes: list[_Shape] = []
        self._current: tuple[_Shape, list[_Line]] | None = None
        self._header: tuple | None = None
        self._block_start = True  # the next line starts a block (after a blank or text line, or at the start)
        self._template: tuple | None = None  # (shape, its compiled line template) for the bulk decoder

    def line(self, text: str, offset: int, nbytes: int) -> list:
        """A whole plain line (without its ending) at stream ``offset``: the frames it completes."""
        parsed = parse_line(text)
        item = _Line(parsed, text, offset, nbytes, "rec" if parsed else "text")
        if parsed is not None:
            out, taken = self._follow(item)
            self._block_start = False
            return out if taken else out + self._learn(item)
        self._header = header_names(text) or self._header
        self._block_start = True
        return self._cut_current() + self._learn(item)

    def cut_line(self, text: str) -> list:
        """A line that may be the tail of a cut line: never a record, its shape only tells where one starts."""
        parsed = parse_line(text)
        self._block_start = False
        if parsed is None:
            self._header = header_names(text) or self._header
            return []
        return self._learn(_Line(parsed, text, -1, 0, "cut"))

    def end_block(self, kind: str) -> list:
        """A "blank" line ends a block of lines; a "break": bytes were lost (the lines around are not consecutive)."""
        out = self._cut_current()
        self._block_start = kind == "blank"
        return out + (self._learn(_Line(None, "", -1, 0, kind)) if self._pending else [])

    def finish(self) -> list:
        """End of stream: whatever waits goes out as text lines (an incomplete record is not a record)."""
        pending, self._pending = self._pending, []
        return self._cut_current() + self._flush(pending)

    def bulk_template(self) -> LineTemplate | None:
        """The latest one-line shape's :class:`LineTemplate` when a line fitting it would be a record now, else None."""
        shape = self._shapes[-1] if self._shapes else None
        if self._current is not None or shape is None or len(shape.lines) != 1 or not shape.example:
            return None
        if self._template is None or self._template[0] is not shape:
            self._template = (shape, line_template(shape))
        return self._template[1]

    @property
    def idle(self) -> bool:
        """No line waits to be learned from."""
        return not self._pending

    def bulk_records(self, *, blank_last: bool = False) -> None:
        """Lines fitting :meth:`bulk_template` were made records in bulk; ``blank_last``: a blank line came last."""
        self._block_start = blank_last

    def _follow(self, item: _Line) -> tuple[list, bool]:
        """The line in a learned shape: the frames it completes (or cuts short), and whether the line was taken."""
        out: list = []
        if self._current is not None:
            shape, lines = self._current
            if shape.lines[len(lines)] == item.parsed.shape:
                lines.append(item)
                if len(lines) == len(shape.lines):
                    out += [self._record(shape, lines)] if lines[0].kind != "cut" else self._cut_current()
                    self._current = None
                return out, True
            out += self._cut_current()
        for shape in self._shapes:
            if shape.lines[0] == item.parsed.shape and (self._block_start or not shape.blank_ended):
                if len(shape.lines) == 1:
                    out.append(self._record(shape, [item]))
                else:
                    self._current = (shape, [item])
                return out, True
        return out, False

    def _cut_current(self) -> list:
        """The lines of the record in progress as text lines (it ends unfinished); [] when there is none."""
        current, self._current = self._current, None
        return [TextFrame(x.text, x.offset, x.nbytes) for x in current[1] if x.kind != "cut"] if current else []

    def _record(self, shape: _Shape, lines: list[_Line]) -> TextRecordFrame:
        values = tuple(v for x in lines for v in x.parsed.values)
        first, last = lines[0], lines[-1]
        return TextRecordFrame(
            shape.names, values, shape.units, shape.kind, first.offset, last.offset + last.nbytes - first.offset
        )

    def _learn(self, item: _Line) -> list:
        pending = self._pending
        pending.append(item)
        shape, start = _find_shape(pending, self._header)
        if shape is not None:
            self._shapes = [s for s in self._shapes if s.lines[0] not in shape.lines] + [shape]
            self._pending = []
            return self._flush(pending[:start]) + self._replay(shape, pending[start:])
        if item.kind in ("text", "break") and not any(x.kind in ("rec", "cut") for x in pending[:-1]):
            self._pending = []
            return self._flush(pending)
        return self._flush([pending.pop(0)]) if len(pending) > MAX_PENDING else []

    def _replay(self, shape: _Shape, items: list[_Line]) -> list:
        """The waiting lines from the start of the first record of a newly learned shape, through the shape."""
        out: list = []
        self._block_start = True
        for x in items:
            if x.kind == "cut" and len(shape.lines) > 1 and x.parsed.shape == shape.lines[0]:
                out += self._cut_current()
                self._current = (shape, [x])  # it holds the first line's place: that record is not whole
            elif x.kind == "rec":
                done, taken = self._follow(x)
                out += done if taken else done + self._flush([x])
            elif x.kind in ("blank", "text", "break"):
                out += self._cut_current() + self._flush([x])
            self._block_start = x.kind in ("blank", "text")
        return out

    @staticmethod
    def _flush(items: list[_Line]) -> list:
        return [TextFrame(x.text, x.offset, x.nbytes) for x in items if x.kind in ("rec", "text")]


def _find_shape(pending: list[_Line], header: tuple | None) -> tuple[_Shape | None, int]:
    """A shape the latest lines repeat :data:`CONFIRM` times in a row, where its first record starts; or (None, 0)."""
    # the latest run of lines of numbers, with blank markers, back to a text line
    start = next((k + 1 for k in range(len(pending) - 1, -1, -1) if pending[k].kind in ("text", "break")), 0)
    tail = list(range(start, len(pending)))
    if not tail:
        return None, 0
    blocks = _blank_blocks(pending, tail)
    if blocks is not None:
        return blocks
    lines = [k for k in tail if pending[k].kind in ("rec", "cut")]
    sizes = [len(b) for b in _blocks(pending, tail)] if any(pending[k].kind == "blank" for k in tail) else []
    shapes = [pending[k].parsed.shape for k in lines]
    n = len(shapes)
    if not sizes and n and shapes[-1][0] == "table" and all(x == shapes[-1] for x in shapes[-VALUE_LINES:]):
        # rows of one table: a record of several rows when their values repeat every few rows (a matrix)
        if n < VALUE_LINES:
            return None, 0
        period = _value_period([pending[k].parsed.values for k in lines[-4 * VALUE_LINES :]])
        if period > 1:
            first = n - 1
            while first > 0 and shapes[first - 1] == shapes[-1]:
                first -= 1
            items = [pending[lines[first + j]].parsed for j in range(period)]
            return _make_shape((shapes[-1],) * period, items, header, blank_ended=False), lines[first]
    for period in range(1, MAX_RECORD_LINES + 1):
        # one more line than the cycles (a blank line may still come and make them one block)
        if n < CONFIRM * period + (0 if sizes else 1):
            break
        if any(period < s <= MAX_RECORD_LINES for s in sizes):
            continue  # blocks between blank lines longer than the cycle: a block shape, not a cycle
        cycle = shapes[n - period :]
        if len(set(cycle)) != period:
            continue
        first = n - period  # back while the lines repeat the cycle: the run's first line starts the record
        while first > 0 and shapes[first - 1] == cycle[(first - 1 - n) % period]:
            first -= 1
        if (n - first) // period < CONFIRM:
            continue
        items = [pending[lines[first + j]].parsed for j in range(period)]
        shape = _make_shape(tuple(p.shape for p in items), items, header, blank_ended=False)
        shape.example = pending[lines[-1]].text if period == 1 else ""
        return shape, lines[first]
    return None, 0


def _value_period(rows: list[tuple[float, ...]]) -> int:
    """p (2..4) when the values come back every p rows (a matrix: mean change over p rows < ¼ that over 1), else 1."""
    v = np.array(rows, np.float64)
    if len(v) < VALUE_LINES or not np.isfinite(v).all():
        return 1
    step1 = float(np.abs(np.diff(v, axis=0)).mean())
    if step1 <= 0:
        return 1
    return next((p for p in range(2, 5) if float(np.abs(v[p:] - v[:-p]).mean()) < 0.25 * step1), 1)


def _blocks(pending: list[_Line], tail: list[int]) -> list[list[int]]:
    """The lines of each block between blank lines of ``tail`` (the open last one included)."""
    blocks: list[list[int]] = [[]]
    for k in tail:
        if pending[k].kind != "blank":
            blocks[-1].append(k)
        elif blocks[-1]:
            blocks.append([])
    return [b for b in blocks if b]


def _blank_blocks(pending: list[_Line], tail: list[int]) -> tuple[_Shape, int] | None:
    """A shape of blocks ended by blank lines (``Drone_Pitch = ...\\n\\n``, a matrix and an empty line), seen
    :data:`CONFIRM` times in a row at the end of ``tail``; None when the lines are not such blocks."""
    if pending[tail[-1]].kind != "blank":
        return None
    blocks = _blocks(pending, tail)
    if len(blocks) < CONFIRM:
        return None
    last = [pending[k].parsed.shape for k in blocks[-1]]
    # one line per block: the lines' own repetition is the shape
    if len(last) == 1 or len(last) > MAX_RECORD_LINES or any(pending[k].kind == "cut" for k in blocks[-1]):
        return None
    shapes = [[pending[k].parsed.shape for k in b] for b in reversed(blocks)]
    same = next((i for i, b in enumerate(shapes) if b != last), len(shapes))  # blocks of that shape at the end
    if same < CONFIRM:
        return None
    first = blocks[len(blocks) - same][0]
    return _make_shape(tuple(last), [pending[k].parsed for k in blocks[-1]], None, blank_ended=True), first


def _make_shape(lines: tuple, items: list[ParsedLine], header: tuple | None, *, blank_ended: bool) -> _Shape:
    """A record of the parsed lines ``items``, named by the lines, else a header of their count, else ``col1..N``."""
    names, units = [], []
    total = sum(len(p.values) for p in items)
    fits = header is not None and (len(header[0]) == total or (len(items) == 1 and len(header[0]) == total + 1))
    if fits and all(p.names is None for p in items):
        names, units = list(header[0])[:total], list(header[1])[:total]  # one more label: its field left empty last
    else:
        for p in items:
            if p.names is None:
                names += [f"col{len(names) + k + 1}" for k in range(len(p.values))]
            else:
                names += list(p.names)
            units += list(p.units)
    given = list(names)  # a name given again gets _2, _3...
    for k, name in enumerate(given):
        if name in given[:k]:
            names[k] = f"{name}_{given[:k].count(name) + 1}"
    kinds = {p.kind for p in items}
    return _Shape(lines, tuple(names), tuple(units), kinds.pop() if len(kinds) == 1 else "labelled", blank_ended)

"""Line tokenizer shared by the RNDF and MDF readers (DARPA 2006 format text, sec. 2.3.1 and 3.3).

The files are "tab-delimited ASCII"; real ones also use runs of spaces, trailing tabs, CRLF (and we also
take lone CR) line ends, and ``/* ... */`` comments on their own lines, at line ends, before the header and
after ``end_file``.  A comment may span lines and separates tokens like whitespace (``end_file/*x*/`` is
``end_file``).  What is left on each line is split on any whitespace; blank lines vanish, line numbers are
kept for the error messages.

Outside comments only printable ASCII is allowed: a stray byte (a NUL, UTF-8 of a copy-pasted character)
is reported with its line rather than ending up inside a name or a number.  Comment text is
not checked; it is never read.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from .errors import RoadnetError

_NOT_ASCII = re.compile(r"[^\t\f\v \x21-\x7e]")


@dataclass(frozen=True, slots=True)
class Line:
    """The tokens of one non-blank source line (comments removed) and its 1-based line number."""

    number: int
    tokens: tuple[str, ...]

    @property
    def keyword(self) -> str:
        return self.tokens[0]


def decode(data: bytes) -> str:
    """File bytes to text. Latin-1 maps every byte to one character, so a bad byte is reported by the
    tokenizer with its position instead of a UnicodeDecodeError without one."""
    return data.decode("latin-1")


def count_lines(text: str) -> int:
    """Number of the last line (where an unexpected end of file is reported)."""
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text.count("\n") + (0 if text.endswith("\n") else 1) if text else 1


def tokenize(text: str, path: str, error: type[RoadnetError]) -> list[Line]:
    """Split `text` into non-blank lines of tokens; raise `error` for a stray byte or an open comment."""
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    out: list[Line] = []
    in_comment = False
    comment_line = 0
    for number, raw in enumerate(text.split("\n"), start=1):
        parts: list[str] = []
        pos = 0
        while pos <= len(raw):
            if in_comment:
                end = raw.find("*/", pos)
                if end < 0:
                    break
                in_comment = False
                parts.append(" ")
                pos = end + 2
            else:
                start = raw.find("/*", pos)
                if start < 0:
                    parts.append(raw[pos:])
                    break
                parts.append(raw[pos:start])
                parts.append(" ")
                in_comment = True
                comment_line = number
                pos = start + 2
        code = "".join(parts)
        bad = _NOT_ASCII.search(code)
        if bad is not None:
            raise error(path, number, f"expected ASCII text, found byte 0x{ord(bad.group()):02x}")
        tokens = tuple(code.split())
        if tokens:
            out.append(Line(number, tokens))
    if in_comment:
        raise error(path, comment_line, "expected '*/' to close the comment opened on this line")
    return out


_INT_RE = re.compile(r"\d{1,9}")
# Plain decimal notation, what the format uses for lat/lon ("fixed, six decimals") and speeds; exponents
# are taken too. Python's float() would also take "nan", "inf" and "1_0": none of them is a coordinate.
_FLOAT_RE = re.compile(r"[+-]?(?:\d{1,20}(?:\.\d{0,20})?|\.\d{1,20})(?:[eE][+-]?\d{1,3})?")


class Cursor:
    """Walks the tokenized lines of one file and turns bad values into `error(path, line, expected)`."""

    def __init__(self, text: str, path: str, error: type[RoadnetError]) -> None:
        self.path = path
        self.error = error
        self.lines = tokenize(text, path, error)
        self.eof_line = count_lines(text)
        self.pos = 0

    # -- walking

    def peek(self) -> Line | None:
        return self.lines[self.pos] if self.pos < len(self.lines) else None

    def take(self, expected: str) -> Line:
        """The next line; at the end of the file, the error says what was `expected` instead."""
        line = self.peek()
        if line is None:
            raise self.error(self.path, self.eof_line, f"expected {expected}, found the end of the file")
        self.pos += 1
        return line

    def fail(self, line: Line, expected: str) -> RoadnetError:
        return self.error(self.path, line.number, expected)

    def unexpected(self, line: Line, expected: str) -> RoadnetError:
        return self.fail(line, f"expected {expected}, found {line.keyword!r}")

    # -- values

    def args(self, line: Line, count: int, usage: str, optional: int = 0) -> tuple[str, ...]:
        """The `count` (up to `count + optional`) values after the keyword; `usage` shows the statement."""
        n = len(line.tokens) - 1
        if not count <= n <= count + optional:
            raise self.fail(line, f"expected '{usage}'")
        return line.tokens[1:]

    def text(self, line: Line) -> str:
        """Free-format header text (names, dates): the rest of the line, possibly empty."""
        return " ".join(line.tokens[1:])

    def integer(self, line: Line, token: str, what: str, minimum: int = 0) -> int:
        if _INT_RE.fullmatch(token) is None or int(token) < minimum:
            kind = {0: "a non-negative integer", 1: "a positive integer"}.get(
                minimum, f"an integer >= {minimum}"
            )
            raise self.fail(line, f"expected {kind} {what}, found {token!r}")
        return int(token)

    def number(self, line: Line, token: str, what: str) -> float:
        if _FLOAT_RE.fullmatch(token) is None:
            raise self.fail(line, f"expected a decimal number {what}, found {token!r}")
        value = float(token)
        if value != value or value in (float("inf"), float("-inf")):  # 1e999 overflows to inf
            raise self.fail(line, f"expected a finite number {what}, found {token!r}")
        return value

"""I++ DME line protocol (spec 1.4.3, 6.1.4 and 6.2): parse command lines, format response lines.

Pure functions and small value types, no machine and no sockets. The
grammar is the spec's production language: optional spaces only around
commas and after "(" and before ")", numbers with at most 16 digits and a
1-3 digit exponent, strings without double quotes inside.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from .errors import IppError

MAX_LINE = 65536  # characters, the spec's limit (6.2)
UNSOLICITED = "E0000"  # tag of server events and of "Illegal tag"


@dataclass(frozen=True)
class Text:
    """A quoted string argument."""

    value: str


@dataclass(frozen=True)
class Enum:
    """A bare name argument (MachineCsy, PartCsy, ...)."""

    name: str


@dataclass(frozen=True)
class ETag:
    """An event tag used as an argument (StopDaemon(E0005))."""

    tag: str


@dataclass(frozen=True)
class Prop:
    """A property or axis argument: X(), X(10), Tool.PtMeasPar.Speed(5), Tool()."""

    name: str
    args: tuple[float, ...] = ()


Argument = float | Text | Enum | ETag | Prop


@dataclass(frozen=True)
class Command:
    tag: str
    name: str
    args: tuple[Argument, ...]
    text: str  # the line without its terminator, for logs and error responses

    @property
    def is_event_tag(self) -> bool:
        return self.tag.startswith("E")

    @property
    def fast(self) -> bool:
        """Fast-queue commands end with an upper-case E (AbortE, GetErrStatusE, ...)."""
        return self.name.endswith("E")


class ParseError(Exception):
    """A line that is not a well-formed command; ``tag`` is where the error response goes."""

    def __init__(self, tag: str, error: IppError) -> None:
        super().__init__(str(error))
        self.tag = tag
        self.error = error


_TAG = re.compile(r"(?:\d{5}|E\d{4})")
_NUMBER = re.compile(r"[+-]?(?:(\d+)\.?(\d*)|\.(\d+))(?:[Ee][+-]?\d{1,3})?")
_NUMBERISH = re.compile(r"[0-9+\-.Ee]+")
_BASIC = re.compile(r"[A-Za-z][A-Za-z0-9]*")
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]*(?:\.[A-Za-z][A-Za-z0-9]*)*")
_ETAG_ARG = re.compile(r"E\d{4}(?![A-Za-z0-9.(])")


def valid_tag(tag: str) -> bool:
    return bool(_TAG.fullmatch(tag)) and tag not in ("00000", UNSOLICITED)


class _Reader:
    """Recursive descent over one line. Errors: 0509 for a malformed number (as NIST's checker),
    0502 for a malformed argument list, 0008 for a line that is not a command at all."""

    def __init__(self, text: str, pos: int, method: str) -> None:
        self.s, self.i, self.method = text, pos, method

    def fail(self, what: str, number: int = 502) -> IppError:
        return IppError(number, self.method, f"{what} at column {self.i + 1}")

    def spaces(self) -> None:
        while self.i < len(self.s) and self.s[self.i] == " ":
            self.i += 1

    def peek(self) -> str:
        return self.s[self.i] if self.i < len(self.s) else ""

    def expect(self, ch: str) -> None:
        if self.peek() != ch:
            raise self.fail(f"expected {ch!r}")
        self.i += 1

    def number(self) -> float:
        token = _NUMBERISH.match(self.s, self.i)
        text = token.group(0) if token else ""
        m = _NUMBER.fullmatch(text)
        if not m:
            raise self.fail(f"{text or self.peek()!r} is not a number", 509)
        if sum(len(g or "") for g in m.groups()) > 16:
            raise self.fail(f"{text} has more than 16 digits", 509)
        self.i = token.end()  # type: ignore[union-attr]
        return float(text)

    def string(self) -> Text:
        end = self.s.find('"', self.i + 1)
        if end < 0 or end == self.i + 1:
            raise self.fail("unterminated or empty string")
        value = self.s[self.i + 1:end]
        self.i = end + 1
        return Text(value)

    def arglist(self, parse_one) -> tuple:
        """``{s} "(" {s} [item {SCommaS item}] {s} ")"``."""
        self.spaces()
        self.expect("(")
        self.spaces()
        items = []
        if self.peek() != ")":
            while True:
                items.append(parse_one())
                self.spaces()
                if self.peek() == ",":
                    self.i += 1
                    self.spaces()
                    continue
                break
        self.spaces()
        self.expect(")")
        return tuple(items)

    def argument(self) -> Argument:
        ch = self.peek()
        if ch == '"':
            return self.string()
        if ch and (ch.isdigit() or ch in "+-."):
            return self.number()
        m = _ETAG_ARG.match(self.s, self.i)
        if m:
            self.i = m.end()
            return ETag(m.group(0))
        m = _NAME.match(self.s, self.i)
        if not m:
            raise self.fail("expected an argument")
        self.i = m.end()
        save = self.i
        self.spaces()
        if self.peek() == "(":
            return Prop(m.group(0), self.arglist(self.number))
        self.i = save
        if "." in m.group(0):
            raise self.fail("a property needs its parentheses")
        return Enum(m.group(0))


def parse_line(line: str) -> Command:
    """Parse one command line (without CR LF). Raises :class:`ParseError` with the tag to answer on."""
    bad = next((c for c in line if not 32 <= ord(c) <= 126), None)
    head = line[:5]
    tag = head if valid_tag(head) else UNSOLICITED
    if bad is not None:
        raise ParseError(tag, IppError(7, "", f"character code {ord(bad)}"))
    if len(line) > MAX_LINE:
        raise ParseError(tag, IppError(8, "", f"line longer than {MAX_LINE} characters"))
    if not valid_tag(head):
        raise ParseError(UNSOLICITED, IppError(1, "", f"line starts with {head!r}"))
    if len(line) < 6 or line[5] != " ":
        raise ParseError(tag, IppError(2, ""))
    m = _BASIC.match(line, 6)
    if not m:
        raise ParseError(tag, IppError(8, "", "expected a command name at column 7"))
    name = m.group(0)
    r = _Reader(line, m.end(), name)
    r.spaces()
    if r.peek() != "(":
        raise ParseError(tag, IppError(8, name, "expected '(' after the command name"))
    try:
        args = r.arglist(r.argument)
        if r.i != len(line):
            raise r.fail("unexpected characters after the command")
    except IppError as exc:
        raise ParseError(tag, exc) from None
    return Command(tag, name, args, line[6:])


# --- responses -------------------------------------------------------------------


def fmt_number(v: float, decimals: int = 6) -> str:
    """A number in the spec's syntax: fixed point, trailing zeros dropped, never an exponent beyond 3 digits."""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, int):
        return str(v)
    if not math.isfinite(v):
        raise ValueError(f"cannot send {v} over I++ DME")
    text = f"{v:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def fmt_args(values) -> str:
    return ", ".join(fmt_number(v) if isinstance(v, (int, float)) else str(v) for v in values)


def ack(tag: str) -> str:
    return f"{tag} &"


def complete(tag: str) -> str:
    return f"{tag} %"


def data(tag: str, body: str) -> str:
    return f"{tag} # {body}"


def error(tag: str, err: IppError) -> str:
    method = re.sub(r"[^A-Za-z0-9.]", "", err.method) or "Server"
    return f'{tag} ! Error({err.severity}, {err.number:04d}, "{method}", "{err.text}")'


def prop(name: str, *values) -> str:
    return f"{name}({fmt_args(values)})"


def quote(text: str) -> str:
    return '"' + text.replace('"', "'") + '"'


# --- responses as a client reads them (the client and the tests) -------------------


@dataclass(frozen=True)
class Response:
    tag: str
    kind: str  # "&", "%", "#", "!"
    body: str = ""

    @property
    def error_number(self) -> int | None:
        if self.kind != "!":
            return None
        m = re.match(r"Error\s*\(\s*(\d)\s*,\s*(\d{1,4})", self.body)
        return int(m.group(2)) if m else None

    @property
    def severity(self) -> int | None:
        m = re.match(r"Error\s*\(\s*(\d)\s*,", self.body) if self.kind == "!" else None
        return int(m.group(1)) if m else None


def parse_response(line: str) -> Response:
    """Split a response line into tag, kind and body (the body's syntax is left to the caller)."""
    line = line.rstrip("\r\n")
    if len(line) < 7 or line[5] != " " or line[6] not in "&%#!":
        raise ValueError(f"not an I++ DME response line: {line!r}")
    if len(line) > 7 and line[7] != " ":
        raise ValueError(f"column 8 of a response must be a space: {line!r}")
    return Response(line[:5], line[6], line[8:].strip())


_ITEM = re.compile(r'\s*(?:"([^"]*)"|([A-Za-z][A-Za-z0-9.]*)\s*\(([^()]*(?:\([^()]*\)[^()]*)*)\)|([^,()\s]+))\s*(?:,|$)')


def data_items(body: str) -> list[tuple[str, list]]:
    """The items of a data body: [(name, [values])]; a string is ('"', [text]), a bare number ('#', [value]).

    Handles property lists (``X(1), Y(2)``), methods (``IsHomed(1)``), string
    pairs (``"Speed", "Number"``) and number lists, with or without NIST's
    surrounding parentheses.
    """
    b = body.strip()
    if b.startswith("(") and b.endswith(")"):
        b = b[1:-1]
    items: list[tuple[str, list]] = []
    pos = 0
    while pos < len(b):
        m = _ITEM.match(b, pos)
        if not m or m.end() == pos:
            raise ValueError(f"cannot read the data {body!r} at {b[pos:]!r}")
        pos = m.end()
        if m.group(1) is not None:
            items.append(('"', [m.group(1)]))
        elif m.group(2) is not None:
            vals = [v.strip() for v in m.group(3).split(",") if v.strip()]
            items.append((m.group(2), [_value(v) for v in vals]))
        else:
            items.append(("#", [_value(m.group(4))]))
    return items


def _value(text: str):
    try:
        return float(text)
    except ValueError:
        return text.strip('"')

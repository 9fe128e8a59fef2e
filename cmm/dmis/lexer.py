"""DMIS text to statements: ``$$`` comments, ``$`` continuation, tokens.

A DMIS program is one statement per line; a line ending in a single ``$`` continues on the next one, and ``$$``
starts a comment that runs to the end of the line (outside quoted text). Keywords are case-insensitive and are
upper-cased here; quoted text ('...') keeps its case. Every statement keeps the line it starts on, so errors
name the line the operator sees in an editor.
"""

from __future__ import annotations

import re
from dataclasses import dataclass


class DmisSyntaxError(ValueError):
    """A DMIS program that cannot be read, naming the line."""

    def __init__(self, line: int, message: str) -> None:
        super().__init__(f"line {line}: {message}")
        self.line = line


@dataclass(frozen=True)
class Token:
    kind: str  # "num", "str", "word", "op"
    text: str
    value: float | str | None = None


@dataclass(frozen=True)
class RawStatement:
    line: int  # the line the statement starts on (1-based)
    text: str  # comments removed, continuations joined


def _strip_comment(line: str, number: int) -> str:
    """The line without its ``$$`` comment; quoted text may hold ``$``."""
    quoted = False
    for k, ch in enumerate(line):
        if ch == "'":
            quoted = not quoted
        elif ch == "$" and not quoted and line[k:k + 2] == "$$":
            return line[:k]
    if quoted:
        raise DmisSyntaxError(number, "a quoted text is not closed (a ' is missing)")
    return line


def statements(text: str) -> list[RawStatement]:
    """The program's statements with their first line numbers."""
    out: list[RawStatement] = []
    pending: list[str] = []
    start = 0
    lines = text.splitlines()
    for number, raw in enumerate(lines, 1):
        line = _strip_comment(raw, number).rstrip()
        if not pending:
            start = number
        if line.endswith("$"):
            pending.append(line[:-1])
            continue
        pending.append(line)
        joined = " ".join(p.strip() for p in pending).strip()
        pending = []
        if joined:
            out.append(RawStatement(start, joined))
    if pending and " ".join(pending).strip():
        raise DmisSyntaxError(start, "the last statement ends with a continuation '$' but no line follows")
    return out


_TOKEN = re.compile(r"""
    (?P<ws>\s+)
  | (?P<str>'[^']*')
  | (?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?(?![A-Za-z_]))
  | (?P<dword>\d+[A-Za-z_]\w*)
  | (?P<dotop>\.(?:EQ|NE|LT|LE|GT|GE|AND|OR|NOT)\.)
  | (?P<word>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op>[/,=()+\-*^:])
""", re.VERBOSE | re.IGNORECASE)


def tokens(stmt: RawStatement) -> list[Token]:
    out: list[Token] = []
    pos = 0
    text = stmt.text
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            raise DmisSyntaxError(stmt.line, f"unexpected character {text[pos]!r} in {text!r}")
        pos = m.end()
        kind = m.lastgroup
        s = m.group()
        if kind == "ws":
            continue
        if kind == "str":
            out.append(Token("str", s, s[1:-1]))
        elif kind == "num":
            out.append(Token("num", s, float(s)))
        elif kind == "dotop":
            out.append(Token("op", s.upper()))
        elif kind in ("word", "dword"):  # 2D, 3D are words
            out.append(Token("word", s.upper(), s.upper()))
        else:
            out.append(Token("op", s))
    return out

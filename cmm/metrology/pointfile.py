"""Point files for the command line: one `x y z` point per line.

Comma, semicolon or whitespace separated; one header line allowed before the
first point; the first line may instead be the number of points (the NIST
algorithm-testing data set format), which is then checked; blank lines and
`#` comments skipped; `-` reads stdin.
"""

from __future__ import annotations

import io
import math
import re
import sys
from typing import Iterable, TextIO

import numpy as np

_SPLIT = re.compile(r"[,\s;]+")


class PointFileError(ValueError):
    """A points file could not be read; the message names the file and line."""


def parse_points(lines: Iterable[str], name: str = "<input>") -> list[tuple[float, float, float]]:
    """Rows of three finite numbers; raises PointFileError naming the line."""
    points: list[tuple[float, float, float]] = []
    header_seen = False
    count: tuple[int, int] | None = None  # (declared number of points, line)
    for number, raw in enumerate(lines, start=1):
        text = raw.split("#", 1)[0].strip()
        if not text:
            continue
        try:
            values = [float(f) for f in _SPLIT.split(text) if f]
        except ValueError:
            if not points and not header_seen and count is None:  # a header such as "x,y,z"
                header_seen = True
                continue
            raise PointFileError(f"{name} line {number}: expected 3 finite numbers 'x y z', got {raw.strip()!r}") from None
        if not points and count is None and len(values) == 1 and values[0].is_integer() and values[0] >= 0:
            count = (int(values[0]), number)  # NIST format: the first line is the number of points
            continue
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise PointFileError(f"{name} line {number}: expected 3 finite numbers 'x y z', got {raw.strip()!r}")
        points.append((values[0], values[1], values[2]))
    if not points:
        raise PointFileError(f"{name}: no points found")
    if count is not None and count[0] != len(points):
        raise PointFileError(f"{name} line {count[1]}: the file says {count[0]} points but holds {len(points)}")
    return points


def read_text(path: str, stdin: TextIO | None = None) -> str:
    """The whole file (or stdin for '-'), with a clear error for missing or binary files."""
    if path == "-":
        return (stdin or sys.stdin).read()
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.read()
    except FileNotFoundError:
        raise PointFileError(f"file '{path}' does not exist") from None
    except UnicodeDecodeError:
        raise PointFileError(f"file '{path}' is not a text file") from None
    except OSError as exc:
        raise PointFileError(f"cannot read {path}: {exc.strerror or exc}") from None


def read_points(path: str, stdin: TextIO | None = None) -> list[tuple[float, float, float]]:
    return parse_points(read_text(path, stdin).splitlines(), "<stdin>" if path == "-" else path)


def _fast_array(text: str) -> np.ndarray | None:
    """The points of a plain numeric file parsed in C (numpy), or None when the file has
    comments, a header, blank lines or anything unusual (the line-by-line parser then
    reads it and names the bad line)."""
    if "#" in text:
        return None
    body = text.translate(str.maketrans(",;\r", "   ")).strip()
    if not body or "\n\n" in body or "\n \n" in body:
        return None
    first_end = body.find("\n")
    first = body[: first_end if first_end >= 0 else len(body)].split()
    count = None
    if len(first) == 1 and first[0].isdigit():  # NIST: the number of points first
        count, body = int(first[0]), body[first_end + 1:] if first_end >= 0 else ""
    try:  # numpy's C reader; it refuses rows whose number of columns changes
        values = np.loadtxt(io.StringIO(body), dtype=np.float64, ndmin=2) if body else np.empty((0, 3))
    except ValueError:
        return None
    if values.shape[0] == 0 or values.shape[1] != 3 or not np.all(np.isfinite(values)):
        return None
    points = values
    if count is not None and count != len(points):
        return None
    return points


def read_points_array(path: str, stdin: TextIO | None = None) -> np.ndarray:
    """Like read_points but returns an (n, 3) float64 array; large plain files are parsed
    by numpy (millions of points in seconds), anything else line by line."""
    text = read_text(path, stdin)
    fast = _fast_array(text)
    if fast is not None:
        return fast
    return np.asarray(parse_points(text.splitlines(), "<stdin>" if path == "-" else path), dtype=np.float64)

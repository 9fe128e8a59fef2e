"""Hit-id lists as operators type them."""

from __future__ import annotations

import re


def parse_ids(text: str) -> list[int]:
    """'1-4, 7 9' -> [1, 2, 3, 4, 7, 9]."""
    ids: list[int] = []
    for part in re.split(r"[,\s]+", text.strip()):
        if not part:
            continue
        m = re.fullmatch(r"(\d+)\s*-\s*(\d+)", part)
        if m:
            a, b = int(m.group(1)), int(m.group(2))
            ids.extend(range(min(a, b), max(a, b) + 1))
        elif part.isdigit():
            ids.append(int(part))
        else:
            raise ValueError(f"'{part}' is not a hit number or a range like 3-7")
    return ids


def parse_targets(text: str) -> list[int | dict[str, list[int]]]:
    """Datum targets as typed, in order: hit numbers, target areas and lines of hits.
    'area(12-14) line(15 16) 17' -> [{'area': [12, 13, 14]}, {'line': [15, 16]}, 17]."""
    out: list[int | dict[str, list[int]]] = []
    for m in re.finditer(r"(area|line)\s*\(([^()]*)\)|([^\s,()]+)|([()])", text, re.I):
        if m.group(1):
            out.append({m.group(1).lower(): parse_ids(m.group(2))})
        elif m.group(3) and re.fullmatch(r"\d+(-\d+)?", m.group(3)):
            out.extend(parse_ids(m.group(3)))
        else:
            raise ValueError(f"'{m.group(0)}' is not a hit number, a range like 3-7, area(hits) or line(hits)")
    return out

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

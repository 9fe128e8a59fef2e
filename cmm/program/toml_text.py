"""TOML values and keys as text, for the files the station writes (calibration records, programs).

Python reads TOML with tomllib but has no writer; the files are small and
hand-laid-out, so only values need formatting.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def toml_key(k: str) -> str:
    """A key as written: bare when TOML allows it, else quoted (a set-up named "XY+" needs the quotes)."""
    return k if _BARE_KEY.fullmatch(k) else json.dumps(k)


def toml_value(v: Any) -> str:
    """One TOML value: booleans, integers, finite floats (full precision), strings, arrays, inline tables."""
    if hasattr(v, "tolist"):  # numpy arrays and scalars
        v = v.tolist()
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"TOML cannot hold the number {v}")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write a {type(v).__name__} to TOML")

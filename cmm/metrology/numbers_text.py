"""Numbers in operators' sentences: formatted, never a 300-digit expansion of 1e308 or a bare ``inf`` / ``nan``.

:func:`num` writes a value for a message (``num(1e308)`` -> ``1e+308``, ``num(235.71234)`` -> ``235.712``,
``num(float('inf'))`` -> ``infinite``); :func:`finite` refuses a value that is not a finite number with one
sentence naming what it was for.
"""

from __future__ import annotations

import math
from typing import Any

LARGE = 1e6  # beyond this a value is written in scientific notation (no machine travels a kilometre)


def num(value: Any, digits: int = 3) -> str:
    """``value`` for a message: fixed-point with ``digits`` decimals, scientific when huge, words when not a
    finite number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return repr(value)
    if math.isnan(v):
        return "not a number"
    if math.isinf(v):
        return "infinite" if v > 0 else "minus infinite"
    if abs(v) >= LARGE:
        return f"{v:.{max(digits, 1)}g}"
    return f"{v:.{digits}f}"


def finite(value: Any, what: str, unit: str = "mm") -> float:
    """``value`` as a float; ValueError in one sentence when it is not a finite number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number of {unit}, not {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{what} must be a finite number of {unit}, not {num(v)}")
    return v

"""Measured values of characteristics, as a part's record in a trend carries them (:class:`Measured`: value,
nominal, absolute limits, unit), made from a report's characteristics (:func:`measured`) or from fitted features
(:func:`feature_values`). The runners make them; the trends (:mod:`cmm.session.trends`) store and chart them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

from .characteristics import Characteristic

SEP = " / "  # feature / characteristic


class TrendError(RuntimeError):
    """A trends action refused, in an operator's words."""


@dataclass(frozen=True)
class Measured:
    """One characteristic of one part: limits are absolute (nominal + tolerance); None: no limit that side."""

    name: str  # "boss / diameter"
    value: float
    nominal: float | None = None
    lower: float | None = None
    upper: float | None = None
    unit: str = "mm"

    @property
    def ok(self) -> bool | None:
        if self.lower is None and self.upper is None:
            return None
        return not ((self.upper is not None and self.value > self.upper + 1e-12)
                    or (self.lower is not None and self.value < self.lower - 1e-12))

    def row(self) -> list[Any]:
        return [self.name, self.value, self.nominal, self.lower, self.upper, self.unit]


def measured(c: Characteristic) -> Measured | None:
    """A report characteristic as a trend value; None when it was not measured (it needs a nominal).
    Form and position (nominal 0, tolerance zone from 0 up) have an upper limit only."""
    if c.actual is None:
        return None
    name = f"{c.feature}{SEP}{c.name}"
    if c.nominal is None:
        return Measured(name, float(c.actual), None, None, None, c.unit)
    one_sided = c.lower == 0.0 and c.nominal == 0.0
    return Measured(name, float(c.actual), float(c.nominal), None if one_sided else c.nominal + c.lower,
                    c.nominal + c.upper, c.unit)


def feature_values(features: Iterable[Any], default_tolerance: dict[str, float] | None = None) -> list[Measured]:
    """The characteristics of fitted features (:class:`~cmm.journal.records.FeatureRecord`: a live feature's
    ``record()``) as trend values."""
    out = []
    for f in features:
        for c in f.characteristics({**(default_tolerance or {}), **(f.tolerance or {})}):
            m = measured(c)
            if m is not None:
                out.append(m)
    return out

"""The one deviation colour scale shared by the 3D scene and the inspection report.

Signed deviations (mm, + = material outside nominal) fall into tolerance
bands, the way commercial CMM colour maps show them:

    d < -2 tol          blue      material missing, more than twice the tolerance
    -2 tol <= d < -tol  cyan      material missing, out of tolerance
    |d| <= tol          green     within tolerance
    tol < d <= 2 tol    amber     excess material, out of tolerance
    d > 2 tol           red       excess material, more than twice the tolerance
    |d| > cutoff, NaN   grey      beyond the maximum distance (not on this surface) or unknown

The max-distance cut-off keeps points that belong to another surface (or a
part that was never aligned) from painting the map: they are grey and the
legend says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

RGB = tuple[int, int, int]

BLUE: RGB = (40, 90, 230)
CYAN: RGB = (40, 190, 230)
GREEN: RGB = (40, 180, 70)
AMBER: RGB = (245, 170, 30)
RED: RGB = (220, 40, 40)
GREY: RGB = (150, 150, 150)


@dataclass(frozen=True)
class ColourScale:
    """Tolerance bands (mm) and the max-distance cut-off (default 25 x the tolerance)."""

    tolerance: float = 0.01
    cutoff: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tolerance) and self.tolerance > 0):
            raise ValueError(f"the colour scale tolerance must be a positive number of mm, got {self.tolerance}")
        if self.cutoff is not None and not (math.isfinite(self.cutoff) and self.cutoff > 0):
            raise ValueError(f"the colour scale cut-off must be a positive number of mm, got {self.cutoff}")

    @property
    def max_distance(self) -> float:
        return self.cutoff if self.cutoff is not None else 25.0 * self.tolerance

    def band(self, d: float) -> int:
        """-2, -1, 0, 1, 2 for the bands; None-like 3 for grey (beyond the cut-off or unknown)."""
        if d is None or not math.isfinite(d) or abs(d) > self.max_distance:
            return 3
        t = self.tolerance
        if abs(d) <= t:
            return 0
        if d > 0:
            return 1 if d <= 2 * t else 2
        return -1 if d >= -2 * t else -2

    def colour(self, d: float | None) -> RGB:
        return _BAND_COLOURS[self.band(float("nan") if d is None else float(d))]

    def colours(self, deviations: np.ndarray) -> np.ndarray:
        """n x 3 uint8 colours of an array of deviations (NaN: grey)."""
        return np.array([self.colour(float(d)) for d in np.asarray(deviations, float).ravel()],
                        dtype=np.uint8).reshape(-1, 3)

    def css(self, d: float | None) -> str:
        r, g, b = self.colour(d)
        return f"rgb({r},{g},{b})"

    def legend(self) -> list[tuple[RGB, str]]:
        """(colour, label in um) from excess material down to missing material, then grey."""
        t = self.tolerance * 1000
        return [(RED, f"> +{2 * t:g} µm"), (AMBER, f"+{t:g} .. +{2 * t:g} µm"), (GREEN, f"within ±{t:g} µm"),
                (CYAN, f"-{2 * t:g} .. -{t:g} µm"), (BLUE, f"< -{2 * t:g} µm"),
                (GREY, f"beyond ±{self.max_distance:g} mm or unknown")]

    def counts(self, deviations: list[float | None]) -> dict[int, int]:
        """How many deviations fall in each band (band number -> count)."""
        out = {b: 0 for b in (2, 1, 0, -1, -2, 3)}
        for d in deviations:
            out[self.band(float("nan") if d is None else float(d))] += 1
        return out


_BAND_COLOURS: dict[int, RGB] = {-2: BLUE, -1: CYAN, 0: GREEN, 1: AMBER, 2: RED, 3: GREY}

"""The one deviation colour scale shared by the 3D scene and the inspection report.

Signed deviations (mm, + = material outside nominal) fall into tolerance
bands, the way commercial CMM colour maps (CALYPSO, PolyWorks) show them, with
``T`` the tolerance (out-of-tolerance limit) and ``W = warning x T`` the
warning limit:

    d < -T            blue      out of tolerance, material missing
    -T <= d < -W      cyan      warning: in tolerance, near the lower limit
    |d| <= W          green     in tolerance
    W < d <= T        amber     warning: in tolerance, near the upper limit
    d > T             red       out of tolerance, excess material
    |d| > cutoff, NaN grey      beyond the maximum deviation (not on this surface) or unknown

The defaults (T = 0.02 mm, warning 50 %) colour as before: green within
+-10 um, amber/cyan to +-20 um, red/blue beyond. The max-deviation cut-off
keeps points that belong to another surface (or a part that was never
aligned) from painting the map. ``reach`` is the colour map's spatial cut-off
(:mod:`cmm.metrology.colour_map`): surface farther than this from every
measured point stays grey. The legend says both.
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

DEFAULT_TOLERANCE = 0.02  # mm: out of tolerance beyond +-20 um
DEFAULT_WARNING = 0.5  # the warning limit as a fraction of the tolerance
DEFAULT_REACH = 15.0  # mm: surface farther than this from every hit stays grey


def _positive(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"the colour scale {name} must be a positive number of mm, got {value}")


@dataclass(frozen=True)
class ColourScale:
    """Tolerance bands (mm), the max-deviation cut-off (default 25 x the tolerance) and the map's reach (mm)."""

    tolerance: float = DEFAULT_TOLERANCE
    cutoff: float | None = None
    warning: float = DEFAULT_WARNING
    reach: float = DEFAULT_REACH

    def __post_init__(self) -> None:
        _positive("tolerance", self.tolerance)
        if self.cutoff is not None:
            _positive("cut-off", self.cutoff)
        _positive("reach", self.reach)
        if not (isinstance(self.warning, (int, float)) and 0 < self.warning <= 1):
            raise ValueError(f"the warning limit must be a fraction of the tolerance in (0, 1] (e.g. 0.7 for 70 %), "
                             f"got {self.warning}")

    @property
    def max_distance(self) -> float:
        """The max-deviation cut-off (mm): larger deviations are grey."""
        return self.cutoff if self.cutoff is not None else 25.0 * self.tolerance

    @property
    def warning_limit(self) -> float:
        return self.warning * self.tolerance

    def band(self, d: float | None) -> int:
        """-2 (blue), -1 (cyan), 0 (green), 1 (amber), 2 (red); 3 for grey (beyond the cut-off or unknown).
        The scalar twin of :meth:`bands` (same limits): the report calls it per hit, a one-element array costs 15x."""
        d = math.nan if d is None else float(d)
        a = abs(d)
        if not math.isfinite(d) or a > self.max_distance:
            return 3
        b = 0 if a <= self.warning_limit else 1 if a <= self.tolerance else 2
        return -b if d < 0 else b

    def bands(self, deviations: np.ndarray) -> np.ndarray:
        """The band of each deviation (NaN: 3, grey), vectorised for a colour map's vertices."""
        d = np.asarray(deviations, dtype=np.float64).ravel()
        a = np.abs(d)
        with np.errstate(invalid="ignore"):
            out = np.where(a <= self.warning_limit, 0,
                           np.where(a <= self.tolerance, 1, 2)) * np.where(d < 0, -1, 1)
            out = np.where(~np.isfinite(d) | (a > self.max_distance), 3, out)
        return out.astype(np.int8)

    def colour(self, d: float | None) -> RGB:
        return _BAND_COLOURS[self.band(d)]

    def colours(self, deviations: np.ndarray) -> np.ndarray:
        """n x 3 uint8 colours of an array of deviations (NaN: grey)."""
        return _PALETTE[self.bands(deviations) + 2]

    def css(self, d: float | None) -> str:
        r, g, b = self.colour(d)
        return f"rgb({r},{g},{b})"

    def legend(self) -> list[tuple[RGB, str]]:
        """(colour, label in um) from excess material down to missing material, then grey."""
        t, w = self.tolerance * 1000, self.warning_limit * 1000
        grey = (GREY, f"beyond ±{self.max_distance:g} mm, unknown, or no hit within {self.reach:g} mm")
        if self.warning >= 1:  # no warning band
            return [(RED, f"> +{t:g} µm out of tolerance"), (GREEN, f"within ±{t:g} µm"),
                    (BLUE, f"< -{t:g} µm out of tolerance"), grey]
        return [(RED, f"> +{t:g} µm out of tolerance"), (AMBER, f"+{w:g} .. +{t:g} µm warning"),
                (GREEN, f"within ±{w:g} µm"), (CYAN, f"-{t:g} .. -{w:g} µm warning"),
                (BLUE, f"< -{t:g} µm out of tolerance"), grey]

    def counts(self, deviations: list[float | None]) -> dict[int, int]:
        """How many deviations fall in each band (band number -> count)."""
        out = {b: 0 for b in (2, 1, 0, -1, -2, 3)}
        for d in deviations:
            out[self.band(d)] += 1
        return out


_BAND_COLOURS: dict[int, RGB] = {-2: BLUE, -1: CYAN, 0: GREEN, 1: AMBER, 2: RED, 3: GREY}
_PALETTE = np.array([_BAND_COLOURS[b] for b in range(-2, 4)], dtype=np.uint8)  # index = band + 2

"""Statistical process control of one characteristic over a series of parts: control charts and capability.

Pure functions over a list of measured values (in part order):

- :func:`individuals_chart`: the individuals / moving range (I-MR) chart; sigma within = MR-bar / d2(2);
  X limits = mean +- 3 sigma, MR limits = D3(2) MR-bar, D4(2) MR-bar;
- :func:`xbar_r_chart`: X-bar and R chart over consecutive subgroups of ``n`` parts (2 .. 25); sigma within =
  R-bar / d2(n); X-bar limits = grand mean +- A2(n) R-bar, R limits = D3(n) R-bar, D4(n) R-bar;
- :func:`capability`: Cp, Cpk (within sigma) and Pp, Ppk (overall sample standard deviation) against the
  tolerance limits; a characteristic with only an upper limit (form, position) has Cpk = CPU and no Cp.

The constants are the published table (ASTM E2587, Montgomery *Introduction to Statistical Quality
Control*, Appendix VI); ``tests/test_spc.py`` checks them against the exact range distribution of normal
samples and the charts against textbook data sets with published limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# n -> (d2, d3, A2, D3, D4): the standard control chart constants for subgroups of n
CONSTANTS: dict[int, tuple[float, float, float, float, float]] = {
    2: (1.128, 0.853, 1.880, 0.0, 3.267),
    3: (1.693, 0.888, 1.023, 0.0, 2.574),
    4: (2.059, 0.880, 0.729, 0.0, 2.282),
    5: (2.326, 0.864, 0.577, 0.0, 2.114),
    6: (2.534, 0.848, 0.483, 0.0, 2.004),
    7: (2.704, 0.833, 0.419, 0.076, 1.924),
    8: (2.847, 0.820, 0.373, 0.136, 1.864),
    9: (2.970, 0.808, 0.337, 0.184, 1.816),
    10: (3.078, 0.797, 0.308, 0.223, 1.777),
    11: (3.173, 0.787, 0.285, 0.256, 1.744),
    12: (3.258, 0.778, 0.266, 0.283, 1.717),
    13: (3.336, 0.770, 0.249, 0.307, 1.693),
    14: (3.407, 0.763, 0.235, 0.328, 1.672),
    15: (3.472, 0.756, 0.223, 0.347, 1.653),
    16: (3.532, 0.750, 0.212, 0.363, 1.637),
    17: (3.588, 0.744, 0.203, 0.378, 1.622),
    18: (3.640, 0.739, 0.194, 0.391, 1.608),
    19: (3.689, 0.734, 0.187, 0.403, 1.597),
    20: (3.735, 0.729, 0.180, 0.415, 1.585),
    21: (3.778, 0.724, 0.173, 0.425, 1.575),
    22: (3.819, 0.720, 0.167, 0.434, 1.566),
    23: (3.858, 0.716, 0.162, 0.443, 1.557),
    24: (3.895, 0.712, 0.157, 0.451, 1.548),
    25: (3.931, 0.708, 0.153, 0.459, 1.541),
}


class SpcError(ValueError):
    """A chart that cannot be drawn from these values, in an operator's words."""


@dataclass(frozen=True)
class Limits:
    centre: float
    lower: float
    upper: float


@dataclass(frozen=True)
class Chart:
    """A two-part control chart: the location chart (individuals or subgroup means) and the spread chart
    (moving ranges or subgroup ranges), each with its limits and the indices of the points beyond them."""

    kind: str  # "I-MR" or "X-bar-R"
    subgroup: int  # 1 for I-MR
    points: np.ndarray  # individuals or subgroup means
    location: Limits
    spread_points: np.ndarray  # moving ranges (len n-1) or subgroup ranges
    spread: Limits
    sigma: float  # within sigma: MR-bar / d2(2) or R-bar / d2(n)
    out_of_control: list[int] = field(default_factory=list)  # indices into points beyond the location limits
    spread_out_of_control: list[int] = field(default_factory=list)


@dataclass(frozen=True)
class Capability:
    n: int
    mean: float
    sigma_within: float
    sigma_overall: float
    cp: float | None
    cpk: float | None
    pp: float | None
    ppk: float | None


def _values(values: list[float] | np.ndarray, least: int, what: str) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64).ravel()
    if not np.all(np.isfinite(x)):
        raise SpcError(f"{what}: a value is not a number")
    if len(x) < least:
        raise SpcError(f"{what} needs at least {least} values, there {'is' if len(x) == 1 else 'are'} {len(x)}")
    return x


def _beyond(x: np.ndarray, lim: Limits) -> list[int]:
    return [int(i) for i in np.flatnonzero((x > lim.upper) | (x < lim.lower))]


def individuals_chart(values: list[float] | np.ndarray) -> Chart:
    """The I-MR chart of individual values in order."""
    x = _values(values, 2, "an individuals chart")
    mr = np.abs(np.diff(x))
    d2, _d3, _a2, D3, D4 = CONSTANTS[2]
    mr_bar = float(mr.mean())
    mean = float(x.mean())
    sigma = mr_bar / d2
    loc = Limits(mean, mean - 3.0 * sigma, mean + 3.0 * sigma)
    spr = Limits(mr_bar, D3 * mr_bar, D4 * mr_bar)
    return Chart("I-MR", 1, x, loc, mr, spr, sigma, _beyond(x, loc), _beyond(mr, spr))


def xbar_r_chart(values: list[float] | np.ndarray, n: int) -> Chart:
    """The X-bar-R chart of consecutive subgroups of ``n`` values; an incomplete last subgroup is left out."""
    if n not in CONSTANTS:
        raise SpcError(f"subgroups of {n} parts: choose 2 to {max(CONSTANTS)} (or 1 for an individuals chart)")
    x = _values(values, 2 * n, f"an X-bar-R chart of subgroups of {n}")
    groups = x[: len(x) // n * n].reshape(-1, n)
    means = groups.mean(axis=1)
    ranges = groups.max(axis=1) - groups.min(axis=1)
    d2, _d3, A2, D3, D4 = CONSTANTS[n]
    grand, r_bar = float(means.mean()), float(ranges.mean())
    loc = Limits(grand, grand - A2 * r_bar, grand + A2 * r_bar)
    spr = Limits(r_bar, D3 * r_bar, D4 * r_bar)
    return Chart("X-bar-R", n, means, loc, ranges, spr, r_bar / d2, _beyond(means, loc), _beyond(ranges, spr))


def chart(values: list[float] | np.ndarray, subgroup: int = 1) -> Chart:
    """An individuals chart for ``subgroup`` 1, else an X-bar-R chart of that subgroup size."""
    return individuals_chart(values) if subgroup <= 1 else xbar_r_chart(values, subgroup)


def capability(values: list[float] | np.ndarray, lower: float | None, upper: float | None,
               sigma_within: float | None = None) -> Capability:
    """Cp, Cpk, Pp, Ppk against the limits ``lower`` / ``upper`` (None: that side has no limit).

    ``sigma_within`` is the control chart's (R-bar / d2); by default the individuals chart's (MR-bar / d2).
    An index is None when its sigma is 0 or a limit it needs is missing.
    """
    x = _values(values, 2, "a capability study")
    mean = float(x.mean())
    within = individuals_chart(x).sigma if sigma_within is None else float(sigma_within)
    overall = float(x.std(ddof=1))

    def indices(s: float) -> tuple[float | None, float | None]:
        if not s > 0.0 or (lower is None and upper is None):
            return None, None
        sides = []
        if upper is not None:
            sides.append((upper - mean) / (3.0 * s))
        if lower is not None:
            sides.append((mean - lower) / (3.0 * s))
        p = (upper - lower) / (6.0 * s) if upper is not None and lower is not None else None
        return p, min(sides)

    cp, cpk = indices(within)
    pp, ppk = indices(overall)
    return Capability(len(x), mean, within, overall, cp, cpk, pp, ppk)


def out_of_tolerance(values: list[float] | np.ndarray, lower: float | None, upper: float | None) -> list[int]:
    """Indices of the values outside the tolerance limits (a limit None is open)."""
    x = np.asarray(values, dtype=np.float64).ravel()
    bad = np.zeros(len(x), bool)
    if upper is not None:
        bad |= x > upper + 1e-12
    if lower is not None:
        bad |= x < lower - 1e-12
    return [int(i) for i in np.flatnonzero(bad)]


def normal_range_mean(n: int) -> float:
    """d2: the mean range of ``n`` standard normal values, by quadrature (what the table rounds)."""
    from scipy import integrate

    return integrate.quad(lambda x: 1.0 - _cdf(x) ** n - _cdf(-x) ** n, -9.0, 9.0, limit=200)[0]


# the standard normal's cdf and pdf in plain floats (scipy.stats' per-call overhead made the double integral slow)
def _cdf(x: float) -> float:
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


def _pdf(x: float) -> float:
    return math.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)


def normal_range_moments(n: int) -> tuple[float, float]:
    """(d2, d3): mean and standard deviation of the range of ``n`` standard normal values, by quadrature
    (slow: a double integral; for checking the table)."""
    from scipy import integrate

    lim = 9.0
    d2 = normal_range_mean(n)

    # E[R^2] = 2 * integral over w > 0 of w * P(R > w); P(R <= w) = n * int f(x) (F(x+w) - F(x))^(n-1) dx
    def p_range_le(w: float) -> float:
        return n * integrate.quad(lambda x: _pdf(x) * (_cdf(x + w) - _cdf(x)) ** (n - 1),
                                  -lim, lim, limit=200)[0]

    er2 = 2.0 * integrate.quad(lambda w: w * (1.0 - p_range_le(w)), 0.0, 2 * lim, limit=200)[0]
    return d2, math.sqrt(max(er2 - d2 * d2, 0.0))

"""Small geometric helpers shared by the fitting modules (pure numpy)."""

from __future__ import annotations

from typing import Any

import numpy as np

from cmm.metrology.features import FitError

# Relative singular-value threshold below which a point set is treated as
# lower-dimensional (collinear / coplanar).  Far below any probing noise.
RANK_TOL = 1e-10


# mm: no measured coordinate is this large; beyond it squares and sums of the fits lose all precision (1e308
# would overflow them and read as "all points coincide")
MAX_COORDINATE = 1e9


def as_points(points: Any, kind: str, min_points: int, dim: int = 3) -> np.ndarray:
    """Validate and return points as a float64 (m, dim) array.

    Raises FitError with an operator-readable sentence for wrong shape,
    too few points or non-finite coordinates.
    """
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FitError(f"the points for a {kind} are not numbers: {exc}") from None
    if arr.ndim == 1 and arr.size == dim:
        arr = arr.reshape(1, dim)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise FitError(f"a {kind} needs points with {dim} coordinates each, got an array of shape {arr.shape}")
    m = arr.shape[0]
    if m < min_points:
        article = "an" if kind[0] in "aeiou" else "a"
        raise FitError(f"{article} {kind} needs at least {min_points} points, got {m}")
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise FitError(f"point {int(np.argmax(bad)) + 1} of {m} has a NaN or infinite coordinate")
    huge = (np.abs(arr) > MAX_COORDINATE).any(axis=1)
    if huge.any():
        k = int(np.argmax(huge))
        raise FitError(f"coordinates too large: point {k + 1} of {m} has a coordinate of "
                       f"{float(np.abs(arr[k]).max()):.3g} mm, beyond {MAX_COORDINATE:.0e} mm (1000 km): "
                       "check the units and the file's columns")
    return arr


def centre(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid and centred points."""
    c = points.mean(axis=0)
    return c, points - c


def principal_axes(centred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values (descending) and principal directions (rows) of centred points.

    Computed from the small triangular factor R (R^T R = X^T X, same singular values and
    right vectors), so 1e6 points need no 1e6 x 3 U matrix."""
    from cmm.metrology.fit_solver import _triangular

    _, s, vt = np.linalg.svd(_triangular(centred), full_matrices=False)
    return s, vt


def check_rank(s: np.ndarray, kind: str, need: int) -> None:
    """Refuse point sets spanning fewer than `need` dimensions (1 = line, 2 = plane, 3 = space)."""
    if s[0] == 0.0:
        raise FitError(f"all points coincide: a {kind} through them is not defined")
    if need >= 2 and s[1] <= RANK_TOL * s[0]:
        raise FitError(f"the points are collinear: a {kind} through them is not defined")
    if need >= 3 and s[2] <= RANK_TOL * s[0]:
        raise FitError(f"the points are coplanar: a {kind} through them is not defined")


def unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.sqrt(v @ v)
    if not np.isfinite(n) or n == 0.0:
        raise FitError("a direction of zero length was given")
    return v / n


def canonical_direction(u: np.ndarray) -> np.ndarray:
    """Unit vector with a canonical sign: its largest-magnitude component positive."""
    u = unit(u)
    return -u if u[np.argmax(np.abs(u))] < 0 else u


def axis_point_closest_to_origin(p: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The point of the line p + t u nearest the origin (u unit)."""
    return p - np.dot(p, u) * u


def axis_foot(p: np.ndarray, u: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The point of the line p + t u nearest q (u unit): a feature's location point is the foot of
    its data centroid q on its axis."""
    return p + np.dot(q - p, u) * u


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross is slow for single vectors: hot in the fits)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def frame_with_axis(u: np.ndarray) -> np.ndarray:
    """A right-handed orthonormal 3x3 matrix whose third column is u (unit)."""
    u = unit(u)
    helper = np.eye(3)[np.argmin(np.abs(u))]
    e1 = _cross(helper, u)
    e1 /= np.sqrt(e1 @ e1)
    e2 = _cross(u, e1)
    return np.column_stack([e1, e2, u])


def tilt(frame: np.ndarray, alpha: float, beta: float) -> np.ndarray:
    """The axis frame[:, 2] tilted by small angles: frame @ unit(alpha, beta, 1)."""
    return frame @ unit(np.array([alpha, beta, 1.0]))


def nominal_value(nominal: Any, *names: str) -> Any:
    """First of `names` found on a nominal given as a mapping or an object, else None."""
    if nominal is None:
        return None
    for name in names:
        value = nominal.get(name) if isinstance(nominal, dict) else getattr(nominal, name, None)
        if value is not None:
            return value
    return None


def algebraic_ball(centred: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic (Kasa) circle/sphere on centred points: a start value, not a result."""
    a = np.column_stack([2.0 * centred, np.ones(len(centred))])
    b = np.einsum("ij,ij->i", centred, centred)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    c = sol[:-1]
    r2 = sol[-1] + c @ c
    return c, float(np.sqrt(max(r2, 0.0)))


class ScaledPoints:
    """Points centred on their centroid and divided by their RMS radius."""

    def __init__(self, x: np.ndarray):
        self.c, xc = centre(x)
        self.scale = float(np.sqrt(np.mean(np.einsum("ij,ij->i", xc, xc)))) or 1.0
        self.x = xc / self.scale

    def to_mm(self, p: np.ndarray) -> np.ndarray:
        return self.c + self.scale * p

    def to_scaled(self, p: Any) -> np.ndarray:
        return (np.asarray(p, dtype=np.float64) - self.c) / self.scale


def subsample(x: np.ndarray, k: int) -> np.ndarray:
    """At most k evenly spaced rows of x (all of them when there are fewer)."""
    return x if len(x) <= k else x[np.linspace(0, len(x) - 1, k).astype(int)]


def hemisphere_directions(k: int) -> np.ndarray:
    """k roughly evenly spread unit vectors on the upper hemisphere (Fibonacci lattice)."""
    i = np.arange(k) + 0.5
    z = 1.0 - i / k  # uniform in z on (0, 1]: equal areas
    phi = np.pi * (1.0 + 5**0.5) * i
    rho = np.sqrt(1.0 - z * z)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def angular_coverage_deg(points: np.ndarray, p: np.ndarray, u: np.ndarray) -> float:
    """Degrees of the circle around axis (p, u) that the points cover (360 - largest gap)."""
    loc = (points - p) @ frame_with_axis(u)
    a = np.sort(np.arctan2(loc[:, 1], loc[:, 0]))
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
    return float(360.0 - np.degrees(gaps.max()))


# a combination of free DOF that moves the distances of points to a surface by less than this fraction of its own
# motion (mm, or rad x the points' lever arm) is not located by the surface (a translation along a face): linearised
# fits (ICP, profile) leave it alone. Without this, a float32 mesh's or a tilted datum's 1e-5 .. 1e-4 effect made
# the fits slide the points hundreds of mm along the face
DEAD_DOF = 1e-2


def live_dof(A: np.ndarray, scales: np.ndarray, dead: float = DEAD_DOF) -> np.ndarray:
    """A basis (columns of A x k) of the combinations of A's unknowns the rows respond to; each basis column moves
    the unknowns by 1 in units of ``scales`` (1 for a translation in mm, the lever arm for a turn in rad)."""
    sc = np.asarray(scales, dtype=np.float64)
    As = A / sc
    if not As.size:
        return np.zeros((A.shape[1], 0))
    _, sv, vt = np.linalg.svd(As / np.sqrt(len(As)), full_matrices=False)
    return vt[sv > dead].T / sc[:, None]

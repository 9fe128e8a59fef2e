"""Feature result records returned by the fits.

Every result carries the fit statistics (FitResult fields) and its geometry:

- residuals: signed orthogonal distances of the points to the feature
  (positive outside / along the normal); for a 3D line the distance is
  unsigned; for a 3D circle they are the in-plane radial deviations and the
  out-of-plane deviations are in ``plane_residuals``.
- sigma = |d| / sqrt(m - n) (NaN when m == n), n = number of parameters.
- form = max(residuals) - min(residuals)  (3D line: 2 * max distance, the
  diameter of the cylinder around the line that holds the points).
- covariance: sigma^2 (J^T J)^-1 of the minimal parameters named in
  ``param_names`` (local parametrisation at the solution, see fit_ls).
- uncertainty: standard uncertainties (square roots of the covariance
  diagonal) keyed by parameter name, mm for lengths and rad for angles;
  empty when not defined (criteria other than least squares, m == n).
- warnings: sentences for the operator when the data do not determine the
  feature well (short arcs and caps, cones that are nearly cylinders), when
  several distinct solutions fit almost equally well, or when a criterion's
  global optimum could not be proven.
- proof: for a cylinder by minzone / mic / mcc (all round), the domain its optimum
  was searched in and the outcome: ``proven``, ``cone_deg`` (axis directions
  within this angle of the least-squares axis), ``gap_um`` (value minus the
  lowest bound over the domain), ``cells`` (direction cells bounded; of them
  ``near_cells`` within 0.05 deg of the optimum), minimum zone also
  ``centre_mm`` (axes within this distance of the least-squares axis at the
  data centre); None otherwise.
- alternative: a fit with a nominal reports the minimum near the nominal; when
  a clearly different solution far from it fits the points better, that
  solution is kept here (same kind, same units) and the result needs a
  ``check`` by the operator: it is never silently swapped in.

Conventions: unit vectors are normalised; undirected axes (line, plane
normal, circle normal, cylinder, torus) have a canonical sign (largest
component positive); the location ``point`` of lines, cylinders and cones is
the projection of the data centroid onto the axis (plane: the centroid), and
the reported position uncertainty holds at that point; the cone direction
points from the apex into the cone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np


class FitError(ValueError):
    """A fit was refused or failed; str(error) is a sentence for the operator."""


def proof_text(proof: dict[str, Any] | None, short: bool = False) -> str:
    """A criterion fit's ``proof`` record in words ("" when there is none); ``short`` for the feature tree."""
    if not proof:
        return ""
    where = f"within {proof['cone_deg']:.3g} deg of the LS axis"
    if proof.get("centre_mm") is not None:
        where += f" and {proof['centre_mm']:.3g} mm of it at the data centre"
    if short:
        return f"proven {where}" if proof["proven"] else f"not proven (gap {proof['gap_um']:.2g} um)"
    if proof["proven"]:
        return f"global optimum proven among axes {where} ({proof['cells']} direction cells bounded)"
    return (f"global optimum not proven: among axes {where} only to within {proof['gap_um']:.2g} um "
            f"({proof['cells']} direction cells bounded)")


@dataclass(frozen=True, kw_only=True, eq=False)
class FitResult:
    residuals: np.ndarray = field(repr=False)
    sigma: float
    form: float
    covariance: np.ndarray = field(repr=False)
    n_points: int
    method: str
    param_names: tuple[str, ...] = field(default=(), repr=False)
    uncertainty: dict[str, float] = field(default_factory=dict, repr=False)
    warnings: tuple[str, ...] = field(default=())
    alternative: FitResult | None = field(default=None, repr=False)
    proof: dict[str, Any] | None = None

    kind: ClassVar[str] = "feature"
    _stat_fields: ClassVar[frozenset[str]] = frozenset(
        {"residuals", "sigma", "form", "covariance", "n_points", "method", "param_names", "plane_residuals",
         "uncertainty", "warnings", "alternative", "proof"}
    )

    @property
    def check(self) -> bool:
        """True when a clearly different solution fits better than the reported one (see ``alternative``)."""
        return self.alternative is not None

    def geometry(self) -> dict[str, Any]:
        """The geometric parameters as plain Python floats / lists."""
        out: dict[str, Any] = {}
        for f in fields(self):
            if f.name in self._stat_fields:
                continue
            value = getattr(self, f.name)
            out[f.name] = value.tolist() if isinstance(value, np.ndarray) else float(value)
        return out

    def summary(self) -> dict[str, Any]:
        """kind, method, n_points, form, sigma, the geometry, the standard uncertainties
        (``uncertainty``: name -> mm or rad) and ``warnings`` (JSON-ready)."""
        sigma = float(self.sigma)
        out = {
            "kind": self.kind,
            "method": self.method,
            "n_points": int(self.n_points),
            "form": float(self.form),
            "sigma": None if math.isnan(sigma) else sigma,
            **self.geometry(),
            "uncertainty": {k: float(v) for k, v in self.uncertainty.items() if math.isfinite(v)},
            "warnings": list(self.warnings),
        }
        if self.proof is not None:  # the domain a criterion's global optimum was searched and proven in
            out["proof"] = dict(self.proof)
        if self.alternative is not None:  # the better-fitting solution far from the nominal: the result needs a check
            alt = self.alternative.summary()
            out["alternative"] = {k: v for k, v in alt.items() if k not in ("warnings", "uncertainty")}
        return out


class _Sized:
    """Mixin: diameter from radius (also reported by geometry())."""

    radius: float

    @property
    def diameter(self) -> float:
        return 2.0 * self.radius

    def geometry(self) -> dict[str, Any]:
        g = super().geometry()  # type: ignore[misc]
        g["diameter"] = float(self.diameter)
        return g


@dataclass(frozen=True, kw_only=True, eq=False)
class Point(FitResult):
    point: np.ndarray
    kind: ClassVar[str] = "point"


@dataclass(frozen=True, kw_only=True, eq=False)
class Line(FitResult):
    point: np.ndarray  # the data centroid (on the LS line; other criteria: its projection onto the line)
    direction: np.ndarray
    kind: ClassVar[str] = "line"


@dataclass(frozen=True, kw_only=True, eq=False)
class Plane(FitResult):
    point: np.ndarray  # centroid of the points, on the plane
    normal: np.ndarray
    kind: ClassVar[str] = "plane"


@dataclass(frozen=True, kw_only=True, eq=False)
class Circle(_Sized, FitResult):
    center: np.ndarray
    normal: np.ndarray
    radius: float
    plane_residuals: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    kind: ClassVar[str] = "circle"


@dataclass(frozen=True, kw_only=True, eq=False)
class Sphere(_Sized, FitResult):
    center: np.ndarray
    radius: float
    kind: ClassVar[str] = "sphere"


@dataclass(frozen=True, kw_only=True, eq=False)
class Cylinder(_Sized, FitResult):
    point: np.ndarray  # the projection of the data centroid onto the axis
    direction: np.ndarray
    radius: float
    kind: ClassVar[str] = "cylinder"


@dataclass(frozen=True, kw_only=True, eq=False)
class Cone(FitResult):
    apex: np.ndarray
    point: np.ndarray  # the projection of the data centroid onto the axis
    direction: np.ndarray  # from the apex into the cone
    half_angle: float  # radians

    kind: ClassVar[str] = "cone"

    @property
    def half_angle_deg(self) -> float:
        return math.degrees(self.half_angle)

    def geometry(self) -> dict[str, Any]:
        g = super().geometry()
        g["half_angle_deg"] = float(self.half_angle_deg)
        return g


@dataclass(frozen=True, kw_only=True, eq=False)
class Torus(FitResult):
    center: np.ndarray
    normal: np.ndarray  # axis of revolution
    major_radius: float
    minor_radius: float
    kind: ClassVar[str] = "torus"


@dataclass(frozen=True, kw_only=True, eq=False)
class Line2D(FitResult):
    """A line in a plane's 2D coordinates; residuals signed along ``normal``."""

    point: np.ndarray  # the projection of the data centroid onto the line
    direction: np.ndarray
    normal: np.ndarray
    kind: ClassVar[str] = "line2d"


@dataclass(frozen=True, kw_only=True, eq=False)
class Circle2D(_Sized, FitResult):
    center: np.ndarray
    radius: float
    kind: ClassVar[str] = "circle2d"


FEATURE_CLASSES: dict[str, type[FitResult]] = {
    cls.kind: cls for cls in (Point, Line, Plane, Circle, Sphere, Cylinder, Cone, Torus, Line2D, Circle2D)
}

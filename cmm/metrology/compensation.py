"""Probe hit compensation: pre-travel (constant or by direction) and stylus radius.

With the unit approach direction u (pointing into the surface), the latched
tip centre T lies past the contact centre by the pre-travel delta(u):
    contact centre  C = T - delta(u) * u
    surface point   M = C + r * n
where n is the chosen normal (the approach direction, or a better one such as
a fitted feature's or the part mesh's, oriented into the material). The
thesis's single-axis formula M_x = x(t+dt) + ed_x - r is the case u = n = -x.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Basis terms of the directional pre-travel model, in order. With phi the
# azimuth of u and s = |u_xy|: a kinematic-seat probe gives a 3-lobed pattern
# in the XY plane (cos 3phi, sin 3phi) and a different value along Z.
PRETRAVEL_TERMS = ("const", "s_cos1", "s_sin1", "s_cos3", "s_sin3", "z2")
# Optional terms (not in the default fit): the lobes weighted by s^2 = 1 - u_z^2,
# as the horizontal force share of a kinematic seat (delta = s^2 d_xy(phi) + u_z^2 d_z);
# the probe qualification fits ("const", "s2_cos3", "s2_sin3", "z2").
EXTRA_PRETRAVEL_TERMS = ("s2_cos3", "s2_sin3")
ALL_PRETRAVEL_TERMS = PRETRAVEL_TERMS + EXTRA_PRETRAVEL_TERMS


def _term_columns(u: np.ndarray) -> dict[str, np.ndarray]:
    s = np.hypot(u[:, 0], u[:, 1])
    phi = np.arctan2(u[:, 1], u[:, 0])
    return {"const": np.ones(len(u)), "s_cos1": s * np.cos(phi), "s_sin1": s * np.sin(phi),
            "s_cos3": s * np.cos(3 * phi), "s_sin3": s * np.sin(3 * phi), "z2": u[:, 2] ** 2,
            "s2_cos3": s * s * np.cos(3 * phi), "s2_sin3": s * s * np.sin(3 * phi)}


def pretravel_basis(directions: np.ndarray, terms: tuple[str, ...] = PRETRAVEL_TERMS) -> np.ndarray:
    """Design matrix (n x len(terms)) of the directional model at unit ``directions``."""
    unknown = set(terms) - set(ALL_PRETRAVEL_TERMS)
    if unknown:
        raise ValueError(f"unknown pre-travel terms {sorted(unknown)}; known: {', '.join(ALL_PRETRAVEL_TERMS)}")
    cols = _term_columns(np.atleast_2d(np.asarray(directions, dtype=np.float64)))
    return np.column_stack([cols[k] for k in terms])


@dataclass
class PretravelModel:
    """delta(u) in mm: a constant plus optional directional coefficients."""

    coefficients: dict[str, float] = field(default_factory=dict)

    @classmethod
    def constant(cls, delta: float) -> "PretravelModel":
        return cls({"const": float(delta)})

    @classmethod
    def fit(cls, directions: np.ndarray, deltas: np.ndarray,
            terms: tuple[str, ...] = PRETRAVEL_TERMS) -> "PretravelModel":
        """Least-squares fit of the model (the given basis terms) to measured pre-travel by direction."""
        a = pretravel_basis(directions, terms)
        coef, *_ = np.linalg.lstsq(a, np.asarray(deltas, dtype=np.float64), rcond=None)
        return cls({k: float(v) for k, v in zip(terms, coef)})

    def __call__(self, directions: np.ndarray) -> np.ndarray:
        unknown = set(self.coefficients) - set(ALL_PRETRAVEL_TERMS)
        if unknown:
            raise ValueError(f"unknown pre-travel terms {sorted(unknown)}; known: {', '.join(ALL_PRETRAVEL_TERMS)}")
        terms = tuple(self.coefficients)
        if not terms:
            return np.zeros(len(np.atleast_2d(directions)))
        coef = np.array([self.coefficients[k] for k in terms])
        return pretravel_basis(directions, terms) @ coef

    @property
    def is_directional(self) -> bool:
        return any(v != 0.0 for k, v in self.coefficients.items() if k != "const")

    def describe(self) -> str:
        if not self.is_directional:
            return f"constant {self.coefficients.get('const', 0.0) * 1000:.2f} um"
        terms = ", ".join(f"{k} {v * 1000:+.2f}" for k, v in self.coefficients.items() if v)
        return f"directional (um): {terms}"


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    v = np.atleast_2d(np.asarray(v, dtype=np.float64))
    n = np.linalg.norm(v, axis=1, keepdims=True)
    if not np.all(np.isfinite(v)) or np.any(n < 1e-12):
        raise ValueError(f"{what} must be finite, non-zero vectors")
    return v / n


def compensate(
    trigger: np.ndarray,
    approach: np.ndarray,
    tip_radius: float,
    pretravel: PretravelModel | float = 0.0,
    normal: np.ndarray | None = None,
) -> np.ndarray:
    """Surface points from latched tip centres.

    ``trigger``: (n, 3) latched tip centres (or one point); ``approach``: unit
    approach directions into the surface; ``normal``: the normal to offset
    along, oriented like ``approach`` (into the material); defaults to the
    approach direction. Returns points of the same shape as ``trigger``.
    """
    t = np.asarray(trigger, dtype=np.float64)
    single = t.ndim == 1
    t2 = np.atleast_2d(t)
    u = _unit(approach, "approach directions")
    n = u if normal is None else _unit(normal, "normals")
    # a normal given with the opposite sense (out of the material) is flipped
    n = np.where(np.sum(n * u, axis=1, keepdims=True) < 0, -n, n)
    model = pretravel if isinstance(pretravel, PretravelModel) else PretravelModel.constant(pretravel)
    delta = model(u)[:, None]
    m = t2 - delta * u + tip_radius * n
    return m[0] if single else m

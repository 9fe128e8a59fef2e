"""The expanded uncertainty of a constructed distance (cmm.metrology.construct) from its two operands' budgets
(cmm.metrology.uncertainty), or the reason there is none.

A distance that depends on the operands' locations only (centre to centre, parallel axes measured in the
alignment's plane) takes each operand's budget: the sensitivity of the distance to each location value
(numerically, the construction redone with that value moved), applied to each term. A term of the same source
in both operands (the probe, the machine, the temperature: the same for both features) is combined as fully
correlated at the worse sign, a bound; the random terms (scatter, sampling) of the two features are independent
and combined in quadrature. k: Student's t at 95.45 % for the Welch-Satterthwaite degrees of freedom of the
sampling terms, as in a feature's budget.

Refused, with the reason: a distance that depends on an operand's direction (a plane's normal, an axis measured
in 3-D) or an angle (the budgets give no uncertainty of a direction), an operand without a budget, geometry
constructions (an intersection, a mid-point: their position has no budget of its own).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .uncertainty import coverage_factor

RANDOM = ("scatter", "sampling")  # independent from hit to hit, so from feature to feature
LOCATION_KEYS = {"circle": "center", "sphere": "center", "point": "point", "cylinder": "point", "cone": "apex",
                 "line": "point", "plane": "point"}
DIRECTION_KEYS = {"plane": "normal", "circle": "normal", "cylinder": "direction", "cone": "direction",
                  "line": "direction"}
STEP = 1e-4  # mm (a location) and rad (a direction) for the numerical sensitivities


def _perp(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.cross(v, [1.0, 0.0, 0.0] if abs(v[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    return a, np.cross(v, a)


def _moves(kind: str, g: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """(budget value, the geometry with that value moved by STEP) of an operand's location."""
    key = LOCATION_KEYS.get(kind)
    if key is None or g.get(key) is None:
        return []
    p = np.asarray(g[key], float)
    if kind == "plane":  # its budget's offset: along its normal
        n = np.asarray(g["normal"], float)
        return [("offset", {**g, key: (p + STEP * n / np.linalg.norm(n)).tolist()})]
    return [(name, {**g, key: (p + STEP * np.eye(3)[i]).tolist()}) for i, name in enumerate("xyz")]


def _tilts(kind: str, g: dict[str, Any]) -> list[dict[str, Any]]:
    key = DIRECTION_KEYS.get(kind)
    if key is None or g.get(key) is None:
        return []
    d = np.asarray(g[key], float)
    d = d / np.linalg.norm(d)
    return [{**g, key: (d + STEP * e).tolist()} for e in _perp(d)]


def distance_uncertainty(operation: str, a: tuple[str, dict[str, Any]], b: tuple[str, dict[str, Any]],
                         budgets: tuple[dict | None, dict | None], *, workplane: Any = None,
                         three_d: bool = False) -> dict[str, Any]:
    """``{"U": mm, "k": k, "u_c": mm}`` of the constructed value, or ``{"why": reason}`` when it has none."""
    from .construct import construct

    if operation != "distance":
        what = "an angle depends on the features' directions" if operation == "angle" else \
            "a constructed point or line"
        return {"why": f"no uncertainty: {what}, whose uncertainty the features' budgets do not give"}
    names = ("first", "second")
    for i, bud in enumerate(budgets):
        if not bud or not bud.get("terms"):
            return {"why": f"no uncertainty: the {names[i]} feature has no uncertainty budget "
                           "(a least-squares fit of a plane, circle, sphere, cylinder, cone or point has one)"}

    def value(x: tuple[str, dict], y: tuple[str, dict]) -> float:
        return float(construct(operation, x, y, workplane=workplane, three_d=three_d).value)

    v0 = value(a, b)
    ops = [a, b]
    for i, (kind, g) in enumerate(ops):
        for tilted in _tilts(kind, g):
            moved = [(kind, tilted) if j == i else ops[j] for j in range(2)]
            if abs(value(*moved) - v0) / STEP > 1e-3:  # more than 1 um per rad: the direction matters
                return {"why": f"no uncertainty: the distance depends on the {kind}'s "
                               f"{DIRECTION_KEYS[kind]}, whose uncertainty its budget does not give"}
    systematic: dict[str, float] = {}  # per source: |contributions| summed over both operands (a bound)
    random_sq, ws = 0.0, 0.0
    for i, (kind, g) in enumerate(ops):
        terms = budgets[i]["terms"]  # type: ignore[index]
        sens = {}
        for name, moved_g in _moves(kind, g):
            moved = [(kind, moved_g) if j == i else ops[j] for j in range(2)]
            sens[name] = (value(*moved) - v0) / STEP
        for t in terms:
            # a term's contributions to x, y, z come from one error pattern: added linearly (a bound)
            c = sum(abs(s) * float(t["u"].get(name, 0.0)) for name, s in sens.items())
            if t["source"] in RANDOM:
                random_sq += c * c
                if t.get("dof"):
                    ws += c ** 4 / float(t["dof"])
            else:
                systematic[t["source"]] = systematic.get(t["source"], 0.0) + c
    u = math.sqrt(random_sq + sum(v * v for v in systematic.values()))
    nu = u ** 4 / ws if ws > 0 and u > 0 else math.inf
    k = coverage_factor(nu)
    return {"U": k * u, "k": k, "u_c": u,
            "note": "from the two features' budgets: the same source in both as fully correlated (a bound), "
                    "their scatter and sampling as independent"}

"""The expanded uncertainty of a geometric tolerance's value (cmm.metrology.gdt_eval) from the error sources of
the budgets (cmm.metrology.uncertainty) of its feature and its datum features, or the reason there is none.

The value is propagated through its own evaluation, as a feature's budget propagates through the fit: every
source is a pattern of errors of the hits, the features (the toleranced one and the datum features) are refitted
to the moved hits (cylinders and cones by the linearised fit) and the tolerance evaluated again on them. A
source common to every feature (the probe's qualification and directional errors, the machine's scale and
squareness, the part's expansion: one physical error of the set-up) moves all their hits at once, so its effects
on the feature and on the datums add with their real signs; the scatter of each hit and the part's form under
each hit (sampling) are independent from hit to hit, taken one hit at a time and combined in quadrature. Each
pattern moves the hits by +- its standard uncertainty: (v+ - v-) / 2 is the linear change, and
sqrt((v+^2 + v-^2) / 2 - v^2) the length of the change of the deviation the value measures (exact for a value
linear in the errors and for a value that is the length of a deviation vector, v = |dev + delta|). A value more
than its U from zero takes the linear propagation; nearer zero (a perpendicularity of 1 um against errors of
1 um) its error can take the whole deviation's error in any direction, which the linear change (along the
deviation read) misses: the lengths bound it. k: Student's t at 95.45 % for the Welch-Satterthwaite degrees of
freedom of the sampling terms (``cmm.metrology.uncertainty.sampling_form``).

The sampling term counts for the datum features and for a toleranced feature whose value stands on its fitted
geometry (position, the orientation of an axis, coaxiality); where the value is the zone of the toleranced
feature's own points (the orientation of a plane, runout, form) the part's form under those hits is what is
measured and only the datums' sampling counts, as for a feature's form value.

Refused, with the reason: a feature or datum feature without a budget (not a least-squares plane, circle,
sphere, cylinder, cone or point), a composite position, a profile (its best fit to the CAD mesh is not
propagated).
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np

from .uncertainty import PRIOR_DOF, Sources, coverage_factor, sampling_form

BUDGET_KINDS = ("plane", "circle", "sphere", "cylinder", "cone", "point")
ON_GEOMETRY = ("position", "concentricity", "coaxiality")  # values of the fitted geometry (orientation: an axis)


def _numbers(v: Any) -> Any:
    """A geometry entry as numbers when it is a list of numbers; anything else as it is."""
    if isinstance(v, list):
        try:
            return np.asarray(v, float)
        except (TypeError, ValueError):
            return v
    return v


class _Moving:
    """A feature whose hits move: its new geometry for hit displacements (refit or the linearised fit)."""

    def __init__(self, f: Any, sources: Sources) -> None:
        from .uncertainty import _Axial, _normals

        self.f = f
        self.kind = f.kind
        self.x = np.asarray(f.points, float).reshape(-1, 3)
        g = dict(f.geometry)
        arr = {k: _numbers(v) for k, v in g.items()}  # the fit's words (a cone's check) stay words
        if self.kind == "point":
            self.n = np.tile(np.asarray(g.get("normal", [0.0, 0.0, 1.0]), float), (len(self.x), 1))
        else:
            self.n = _normals(self.kind, g, self.x)
        self.linear = None
        if self.kind in ("cylinder", "cone"):
            from .feature_distance import surface_distance

            model = _Axial(self.kind, SimpleNamespace(**arr))
            h = 1e-6
            d0 = surface_distance(self.kind, model.geometry(model.p0), self.x)
            jac = np.zeros((len(self.x), len(model.p0)))
            for k in range(len(model.p0)):
                e = np.zeros(len(model.p0))
                e[k] = h
                jac[:, k] = (surface_distance(self.kind, model.geometry(model.p0 + e), self.x) - d0) / h
            self.linear = (model, np.linalg.pinv(jac, rcond=1e-10))
        from .feature_distance import surface_distance

        self.form, _, self.nu = sampling_form(self.kind, surface_distance(self.kind, g, self.x), sources, len(self.x))
        self.start = SimpleNamespace(**arr)

    def moved(self, dx: np.ndarray) -> Any:
        """The feature with its hits moved by ``dx`` (n x 3) and refitted."""
        from .uncertainty import _refit

        g = dict(self.f.geometry)
        if self.linear is not None:
            model, pinv = self.linear
            dp = -pinv @ np.einsum("ij,ij->i", self.n, dx)
            new = model.geometry(model.p0 + dp)
        else:
            fit = _refit(self.kind, self.x + dx, self.start)
            new = fit.geometry()
        for key, v in new.items():
            v = np.asarray(v, float)
            if key in ("normal", "direction") and key in g and float(v @ np.asarray(g[key], float)) < 0:
                v = -v  # the same sense as the feature's (a refitted plane's normal has no side)
            g[key] = v.tolist() if v.ndim else float(v)
        return replace(self.f, geometry=g, points=self.x + dx)


def involved(d: dict[str, Any], datums: dict[str, dict]) -> list[int]:
    """The ids of the toleranced feature and of the datum features of the frame, the toleranced one first."""
    ids = [int(d["feature"])]
    for label in d.get("datums") or []:
        for part in str(label).split("-"):
            dd = datums.get(part)
            if dd is not None and int(dd["feature"]) not in ids:
                ids.append(int(dd["feature"]))
    return ids


def gdt_uncertainty(d: dict[str, Any], datums: dict[str, dict], feats: dict[int, Any], value: float,
                    evaluate_one: Callable[..., Any], mesh: Any = None, pose: Any = None) -> dict[str, Any]:
    """``{"U": mm, "k": k, "u_c": mm, "terms": {source: mm}}`` of the evaluated ``value`` of definition ``d``, or
    ``{"why": reason}`` when it has none; ``evaluate_one``: cmm.metrology.gdt_eval.evaluate_one (its caller)."""
    ch = d.get("characteristic", "")
    if "composite" in d:
        return {"why": "no uncertainty: a composite position's tiers are not propagated"}
    if ch.startswith("profile"):
        return {"why": "no uncertainty: a profile is evaluated after a best fit of its points to the CAD mesh, "
                       "which is not propagated"}
    ids = involved(d, datums)
    parts: list[tuple[int, _Moving]] = []
    sources = None
    for i, fid in enumerate(ids):
        f = feats.get(fid)
        if f is None:
            return {"why": f"no uncertainty: feature {fid} is not measured"}
        budget = getattr(f, "budget", None)
        role = "the toleranced feature" if i == 0 else f"datum feature {f.name}"
        if not budget or f.kind not in BUDGET_KINDS or not len(f.points):
            return {"why": f"no uncertainty: {role} has no uncertainty budget (a least-squares fit of a plane, "
                           "circle, sphere, cylinder, cone or point has one)"}
        if sources is None:
            sources = Sources.from_dict(budget.get("inputs"))
        parts.append((fid, _Moving(f, sources)))
    assert sources is not None
    src = sources
    x = np.vstack([m.x for _, m in parts])
    n = np.vstack([m.n for _, m in parts])
    spans = np.cumsum([0] + [len(m.x) for _, m in parts])

    def value_at(dx: np.ndarray) -> float:
        moved = dict(feats)
        for j, (fid, m) in enumerate(parts):
            moved[fid] = m.moved(dx[spans[j]:spans[j + 1]])
        return float(evaluate_one(d, datums, moved, mesh, pose).value)

    def change(dx: np.ndarray) -> tuple[float, float]:
        """(the linear change of the value, the length of the deviation's change) for the displacement ``dx``:
        from the value at +dx and -dx, |delta|^2 = (v+^2 + v-^2) / 2 - v^2, exact both for a value linear in
        the errors and for the length of a deviation vector (v = |dev + delta|), whatever delta's direction."""
        vp, vm = value_at(dx), value_at(-dx)
        return (vp - vm) / 2.0, math.sqrt(max(0.0, (vp * vp + vm * vm) / 2.0 - value * value))

    along = lambda pattern: pattern[:, None] * n  # noqa: E731 - a displacement along each hit's normal
    systematic: dict[str, list[np.ndarray]] = {"probe qualification": [src.u_tip * along(np.ones(len(x)))]}
    if src.pretravel_u:
        from .compensation import pretravel_basis

        keys = tuple(k for k in src.pretravel_u if k != "const")
        basis = pretravel_basis(-n, keys)
        mean = src.pretravel_mean or {}
        systematic["probe direction"] = [src.pretravel_u[k] * along(basis[:, i] - mean.get(k, 0.0))
                                         for i, k in enumerate(keys)]
    else:
        phi = np.arctan2(-n[:, 1], -n[:, 0])
        horizontal = n[:, 0] ** 2 + n[:, 1] ** 2
        systematic["probe lobing"] = [src.lobing / math.sqrt(2.0) * along(horizontal * f(3 * phi))
                                      for f in (np.cos, np.sin)]
        systematic["probe Z/XY"] = [src.z_xy * along(horizontal - n[:, 2] ** 2)]
    rel = x - (x.mean(axis=0) if src.reference is None else np.asarray(src.reference, float))
    su, qu = src.machine_scale_u(), src.machine_squareness_u()
    scale, square = [], []
    for k in range(3):
        m = np.zeros_like(x)
        m[:, k] = su * rel[:, k]
        scale.append(m)
    for a, b in ((0, 1), (0, 2), (1, 2)):
        m = np.zeros_like(x)
        m[:, a] = qu * rel[:, b]
        square.append(m)
    systematic["machine scale"], systematic["machine squareness"] = scale, square
    systematic["thermal"] = [src.thermal_u() * rel]
    both: dict[str, tuple[float, float]] = {}  # term -> (u linear, u of the deviation's length)
    dofs: dict[str, float] = {}

    def add(name: str, changes: list[tuple[float, float]]) -> None:
        both[name] = (math.sqrt(sum(a * a for a, _ in changes)), math.sqrt(sum(b * b for _, b in changes)))

    try:
        for source, pats in systematic.items():
            add(source, [change(p) for p in pats])
        one = np.zeros((len(x), 3))

        def hit(i: int, size: float) -> tuple[float, float]:
            dx = one.copy()
            dx[i] = size * n[i]
            return change(dx)

        add("scatter", [hit(i, src.repeatability) for i in range(len(x))])
        own = ch in ON_GEOMETRY or (ch in ("parallelism", "perpendicularity", "angularity") and parts[0][1].kind != "plane")
        for j, (fid, m) in enumerate(parts):
            if j == 0 and not own:
                continue
            add(f"sampling {m.f.name}", [hit(i, m.form) for i in range(spans[j], spans[j + 1])])
            dofs[f"sampling {m.f.name}"] = m.nu + PRIOR_DOF  # the residuals' degrees of freedom and the prior's
    except Exception as exc:  # noqa: BLE001 - a moved set the evaluation refuses: no uncertainty, said why
        return {"why": f"no uncertainty: the tolerance could not be re-evaluated on the moved hits ({exc})"}

    def expanded(which: int) -> tuple[float, float, dict[str, float]]:
        terms = {t: v[which] for t, v in both.items()}
        uc = math.sqrt(sum(v * v for v in terms.values()))
        ws = sum(terms[t] ** 4 / nu for t, nu in dofs.items())
        return coverage_factor(uc ** 4 / ws if ws > 0 and uc > 0 else math.inf), uc, terms

    # a value more than U from zero, U from the deviation's lengths (a position 20 um off with U 6 um): the linear
    # propagation; nearer zero (a perpendicularity of 1 um against 1 um errors) the value's error can take the
    # whole deviation's error in any direction (the linear change sees only its part along the deviation read):
    # its length bounds it. (Deciding on the linear U instead covered a perpendicularity whose true value is 0
    # only 88 % on the simulator: a measured value large by chance then took the smaller, linear U.)
    k, uc, terms = expanded(1)
    if value > k * uc:
        k, uc, terms = expanded(0)
    return {"U": k * uc, "k": k, "u_c": uc, "terms": terms,
            "note": "from the budgets' sources moved through the feature's and the datums' fits and the zone's "
                    "evaluation: sources common to the set-up at once, scatter and sampling hit by hit"}

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

A composite position's rows (each feature's pattern-locating tier, the pattern's feature-relating tier) are
propagated together (:func:`row_uncertainties`): every feature of the pattern and every datum feature moves, each
row's value is re-evaluated and takes its own U.

A profile's points move as they are (no fit of their own: the profile's best fit to the CAD mesh is inside the
evaluation repeated for every moved set), each along the mesh's normal at its closest point, with the sources of
a budget of the frame's features (the station's defaults when none has one). Near zero a zone of the
toleranced feature's own hits (a profile, a form, a runout) is set by the extremes of its hits' errors, not by the
change of the hit that happens to be the extreme: twice the 95.45 % point of the largest of n hit scatters takes
the lengths' place for its own hits.

Refused, with the reason: a feature or datum feature without a budget (not a least-squares plane, circle,
sphere, cylinder, cone or point; a profile's own points need none), a profile without the mesh and pose or of
more than PROFILE_MAX_HITS points (each hit repeats the best fit to the mesh).
"""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np

from .uncertainty import COVERAGE, K_COVERAGE, PRIOR_DOF, Sources, coverage_factor, sampling_form

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


LARGEST_DRAWS = 4000  # Monte Carlo draws for the U of a value that is the largest of several (fixed seed)


def _largest_of(changes: np.ndarray) -> float:
    """The 95.45 % point of the largest |error| of several values (a position at each end of an axis) whose
    linear changes per independent pattern (rows, at its standard uncertainty) are ``changes``. The largest of
    several values moves with whichever is largest after the errors: where two ends are about level (an axis
    square to its datum) that is the larger of the two ends' errors, biased up, which one end's linear U misses
    (the boss's position to A|B, both ends 4.5 um off: 94.5 % covered in 1000 trials); |max(a + e) - max(a)| <=
    max |e| bounds it, whichever end is largest."""
    changes = changes[np.abs(changes).max(axis=1) > 1e-15]  # patterns that move none (another feature's hits)
    rng = np.random.default_rng(0)
    e = rng.standard_normal((LARGEST_DRAWS, len(changes))) @ changes
    return float(np.quantile(np.abs(e).max(axis=1), COVERAGE))


class _Points:
    """A profile's toleranced feature: its hits move and the profile takes them as they are (its own best fit
    to the CAD mesh is inside the evaluation that is repeated); each hit's normal the mesh's at its closest
    point."""

    def __init__(self, f: Any, mesh: Any, pose: Any) -> None:
        from .mesh import closest_points
        from .transform import as_pose, invert

        self.f, self.kind = f, f.kind
        self.x = np.asarray(f.points, float).reshape(-1, 3)
        t = as_pose(pose)
        to_part = invert(t)
        self.n = closest_points(mesh, self.x @ to_part[:3, :3].T + to_part[:3, 3]).normals @ t[:3, :3].T
        self.form, self.nu = 0.0, 0  # its form under the hits is what a profile measures: no sampling term

    def moved(self, dx: np.ndarray) -> Any:
        return replace(self.f, points=self.x + dx)


PROFILE_MAX_HITS = 60  # a profile's U re-evaluates it (a best fit to the mesh) 2 x its hits + about 50 times


def involved(d: dict[str, Any], datums: dict[str, dict]) -> list[int]:
    """The ids of the toleranced feature (a composite's pattern) and of the datum features of the frame, the
    toleranced one first."""
    ids = [int(d["feature"])] + [int(x) for x in d.get("pattern") or [] if int(x) != int(d["feature"])]
    for label in d.get("datums") or []:
        for part in str(label).split("-"):
            dd = datums.get(part)
            if dd is not None and int(dd["feature"]) not in ids:
                ids.append(int(dd["feature"]))
    return ids


def gdt_uncertainty(d: dict[str, Any], datums: dict[str, dict], feats: dict[int, Any], value: float,
                    evaluate_one: Callable[..., Any], mesh: Any = None, pose: Any = None) -> dict[str, Any]:
    """``{"U": mm, "k": k, "u_c": mm, "terms": {source: mm}}`` of the evaluated ``value`` of definition ``d``, or
    ``{"why": reason}`` when it has none; ``evaluate_one``: cmm.metrology.gdt_eval.evaluate_one (its caller; for
    a composite position its first row, the first feature's pattern-locating tier)."""
    return row_uncertainties(d, datums, feats, [value], lambda *a: [evaluate_one(*a)], mesh, pose)[0]


def row_uncertainties(d: dict[str, Any], datums: dict[str, dict], feats: dict[int, Any], values: list[float],
                      evaluate_values: Callable[..., list[Any]], mesh: Any = None, pose: Any = None,
                      own: bool | None = None) -> list[dict[str, Any]]:
    """The uncertainty (as :func:`gdt_uncertainty`) of each row's value of definition ``d``: one row, or a
    composite position's (each feature's pattern-locating tier and the pattern's feature-relating tier), all
    propagated through the same moved hits; ``evaluate_values(d, datums, feats, mesh, pose)``: the rows'
    values (numbers, or GdtResults whose ``parts`` are the values each is the largest of). ``own``: whether the toleranced feature's sampling counts (its fitted geometry is what the value
    stands on), for another caller's values (a DMIS tolerance); by default from the characteristic."""
    ch = d.get("characteristic", "")
    rows = len(values)
    refused = lambda why: [{"why": why}] * rows  # noqa: E731
    profile = ch.startswith("profile")
    ids = involved(d, datums)
    toleranced = 1 + len([x for x in d.get("pattern") or [] if int(x) != int(d["feature"])])
    parts: list[tuple[int, Any]] = []
    budgets = [getattr(feats.get(fid), "budget", None) for fid in ids]
    # the set-up's sources: the toleranced feature's budget's, a profile's (its points need no fit of their own)
    # from a datum feature's budget or, with none, the station's defaults
    inputs = next((b.get("inputs") for b in budgets if b), None)
    src = Sources.from_dict(inputs) if inputs else Sources()
    for i, fid in enumerate(ids):
        f = feats.get(fid)
        if f is None:
            return refused(f"no uncertainty: feature {fid} is not measured")
        if profile and i == 0:
            n_hits = len(np.asarray(f.points).reshape(-1, 3))
            if mesh is None or pose is None or n_hits < 3:
                return refused("no uncertainty: a profile needs its points, the CAD mesh and the part's pose")
            if n_hits > PROFILE_MAX_HITS:
                return refused(f"no uncertainty: a profile of {n_hits} points (more than {PROFILE_MAX_HITS}) is not "
                               "propagated: each of its hits would repeat the best fit to the CAD mesh")
            parts.append((fid, _Points(f, mesh, pose)))
            continue
        budget = budgets[i]
        role = ("the toleranced feature" if toleranced == 1 else f"feature {f.name} of the pattern") if i < toleranced \
            else f"datum feature {f.name}"
        if not budget or f.kind not in BUDGET_KINDS or not len(f.points):
            return refused(f"no uncertainty: {role} has no uncertainty budget (a least-squares fit of a plane, "
                           "circle, sphere, cylinder, cone or point has one)")
        parts.append((fid, _Moving(f, src)))
    x = np.vstack([m.x for _, m in parts])
    n = np.vstack([m.n for _, m in parts])
    spans = np.cumsum([0] + [len(m.x) for _, m in parts])

    def flat(items: list[Any]) -> tuple[list[float], list[float]]:
        """The rows' values and, after them, the values each row's is the largest of (GdtResult.parts)."""
        vals = [float(getattr(it, "value", it)) for it in items]
        return vals, [float(p) for it in items for p in (getattr(it, "parts", ()) or ())]

    try:
        base = evaluate_values(d, datums, feats, mesh, pose)
        base_parts = flat(base)[1]
        counts = [len(getattr(it, "parts", ()) or ()) for it in base]
    except Exception as exc:  # noqa: BLE001 - the definition does not evaluate: no uncertainty, said why
        return refused(f"no uncertainty: the tolerance could not be evaluated ({exc})")
    value = np.asarray(list(values) + base_parts, float)
    part_of = np.cumsum([rows] + counts)  # row r's parts: value[part_of[r]:part_of[r + 1]]

    def value_at(dx: np.ndarray) -> np.ndarray:
        moved = dict(feats)
        for j, (fid, m) in enumerate(parts):
            moved[fid] = m.moved(dx[spans[j]:spans[j + 1]])
        vals, more = flat(evaluate_values(d, datums, moved, mesh, pose))
        out = np.asarray(vals + more, float)
        if out.shape != value.shape:
            raise ValueError(f"{len(out)} values on the moved hits, {len(value)} measured")
        return out

    def change(dx: np.ndarray, lengths: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(the linear change of each value, the length of its deviation's change) for the displacement ``dx``:
        from the value at +dx and -dx, |delta|^2 = (v+^2 + v-^2) / 2 - v^2, exact both for a value linear in
        the errors and for the length of a deviation vector (v = |dev + delta|), whatever delta's direction.
        A value that is the largest of several lengths (a position checked at both ends of an axis) has a kink
        where the largest changes end: across it that second difference takes the ends' gap, not |delta|^2 (the
        boss's position to A|B got U / RMS error 3.0 from it). Where it is positive the one-sided second
        differences (0, dx, 2dx and 0, -dx, -2dx) are taken too and the smallest kept: a side without the kink
        gives the active end's |delta|^2 exactly, and a kink only adds to the side that has it."""
        vp, vm = value_at(dx), value_at(-dx)
        sq = (vp * vp + vm * vm) / 2.0 - value * value
        if lengths and np.any(sq > 0):
            vp2, vm2 = value_at(2 * dx), value_at(-2 * dx)
            sq = np.minimum(sq, np.minimum((vp2 * vp2 - 2 * vp * vp + value * value) / 2.0,
                                           (vm2 * vm2 - 2 * vm * vm + value * value) / 2.0))
        return (vp - vm) / 2.0, np.sqrt(np.maximum(0.0, sq))

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
    both: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # term -> (u linear, u of the deviation's length) per row
    dofs: dict[str, float] = {}

    independent: list[np.ndarray] = []  # every pattern's linear changes, each an independent standard error

    def add(name: str, changes: list[tuple[np.ndarray, np.ndarray]]) -> None:
        both[name] = (np.sqrt(sum(a * a for a, _ in changes)), np.sqrt(sum(b * b for _, b in changes)))
        independent.extend(a for a, _ in changes)

    try:
        for source, pats in systematic.items():
            add(source, [change(p) for p in pats])
        # each hit moved once along its normal: its scatter and its sampling are the same displacement at two
        # sizes, and both changes (the linear one and the deviation's length) scale with the size
        step = np.concatenate([np.full(len(m.x), max(src.repeatability, m.form, 1e-6)) for _, m in parts])
        if own is None:
            own = ch in ON_GEOMETRY or (ch in ("parallelism", "perpendicularity", "angularity")
                                        and parts[0][1].kind != "plane")
        n_own = int(spans[toleranced])  # the toleranced feature's hits come first
        per_hit = []
        for i in range(len(x)):
            dx = np.zeros((len(x), 3))
            dx[i] = step[i] * n[i]
            per_hit.append(change(dx, lengths=own or i >= n_own))  # a zone's own hits: see below
        add("scatter", [(a * src.repeatability / step[i], b * src.repeatability / step[i])
                        for i, (a, b) in enumerate(per_hit)])
        if not own:
            # near zero a zone of the feature's own hits (the range of their distances: a form, a runout; a profile:
            # twice their largest distance) read from n hits is set by the extremes of n scatters, not by the
            # change of the hit that happens to be the extreme: its error is bounded by twice the largest hit error,
            # whose 95.45 % point (n independent hits) takes the lengths' place, as a standard uncertainty of half
            # of it. (The hit-by-hit lengths covered a flatness of 30 hits whose true value is 0 85 % of the time,
            # a profile's none; the range's own 95.45 % point, smaller, let values read large by chance take the
            # linear U: a flatness of 0.85 um 83 % covered, against 95 % with this bound.)
            from scipy.stats import norm

            rest = sum((per_hit[i][1] * src.repeatability / step[i]) ** 2 for i in range(n_own, len(x)))
            bound = float(norm.ppf((1.0 + COVERAGE ** (1.0 / n_own)) / 2.0)) * src.repeatability
            both["scatter"] = (both["scatter"][0], np.sqrt(rest + bound ** 2) * np.ones(rows))
        for j, (fid, m) in enumerate(parts):
            if j < toleranced and not own:
                continue
            add(f"sampling {m.f.name}", [(per_hit[i][0] * m.form / step[i], per_hit[i][1] * m.form / step[i])
                                         for i in range(spans[j], spans[j + 1])])
            dofs[f"sampling {m.f.name}"] = m.nu + PRIOR_DOF  # the residuals' degrees of freedom and the prior's
    except Exception as exc:  # noqa: BLE001 - a moved set the evaluation refuses: no uncertainty, said why
        return refused(f"no uncertainty: the tolerance could not be re-evaluated on the moved hits ({exc})")

    def expanded(row: int, which: int) -> tuple[float, float, dict[str, float]]:
        terms = {t: float(v[which][row]) for t, v in both.items()}
        uc = math.sqrt(sum(v * v for v in terms.values()))
        ws = sum(terms[t] ** 4 / nu for t, nu in dofs.items())
        return coverage_factor(uc ** 4 / ws if ws > 0 and uc > 0 else math.inf), uc, terms

    # a value more than U from zero, U from the deviation's lengths (a position 20 um off with U 6 um): the linear
    # propagation; nearer zero (a perpendicularity of 1 um against 1 um errors) the value's error can take the
    # whole deviation's error in any direction (the linear change sees only its part along the deviation read):
    # its length bounds it. (Deciding on the linear U instead covered a perpendicularity whose true value is 0
    # only 88 % on the simulator: a measured value large by chance then took the smaller, linear U.)
    out = []
    for row in range(rows):
        k, uc, terms = expanded(row, 1)
        big = k * uc
        if value[row] > k * uc:
            k, uc, terms = expanded(row, 0)
            big = k * uc
            if part_of[row + 1] - part_of[row] > 1:
                big = max(big, k / K_COVERAGE * _largest_of(np.array(independent)[:, part_of[row]:part_of[row + 1]]))
        out.append({"U": big, "k": big / uc if uc > 0 else k, "u_c": uc, "terms": terms,
                    "note": "from the budgets' sources moved through the feature's and the datums' fits and the "
                            "zone's evaluation: sources common to the set-up at once, scatter and sampling hit by "
                            "hit" + ("" if inputs else " (the station's default sources: no feature has a budget)")})
    return out

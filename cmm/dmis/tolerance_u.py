"""The expanded uncertainty of a DMIS tolerance's output (``TA(..) = TOL/..``), as a ``$$`` comment beside it.

The same propagation as the station's geometric tolerances (:mod:`cmm.metrology.uncertainty_gdt`): the hits of
FA(..) and of its DAT(..) features (or of the second feature of a DISTB / ANGLB) move by each source of their
budgets, the features are refitted and the DMIS tolerance evaluated again (:func:`cmm.dmis.tolerances.evaluate`,
DMIS's own definition of each word). A size (DIAM, RAD) and the fit's form of a kind without a minimum-zone form
take the feature budget's own U. No U, and the comment says why, where a feature has no budget (a constructed
feature, another criterion than least squares) or the value cannot be re-evaluated.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..metrology.gdt_eval import MeasuredFeature
from ..metrology.uncertainty_gdt import row_uncertainties
from .features import Actual
from .tolerances import FORM, GDT_FORM, SIZE, Evaluation, evaluate

TWO = ("DISTB", "ANGLB")
ZONE_OF_OWN_HITS = ("FLAT", "STRGHT", "CIRLTY", "CYLCTY", "PROFS", "PROFL", "RUNOUT")  # the hits' own zone


def _budget(model: Any, a: Actual) -> dict[str, Any] | None:
    f = model.features.get(a.feature_id) if a.feature_id is not None else None
    return getattr(f, "budget", None) if f is not None else None


def tolerance_u(ev: Evaluation, features: list[Actual], datums: dict[str, Actual], frame: np.ndarray,
                sizes: dict[str, tuple[float, float]], model: Any) -> dict[str, Any]:
    """``{"U": mm or deg, "k": k}`` of the evaluated tolerance ``ev`` or ``{"why": reason}``."""
    tol, a = ev.tolerance, features[0]
    w = tol.word
    b = _budget(model, a)
    if w in SIZE or (w in FORM and (GDT_FORM.get((w, a.kind)) is None or a.hit_points is None)):
        key = "diameter" if w in SIZE else "form"
        if not b or key not in (b.get("U") or {}):
            return {"why": f"FA({a.label}) has no uncertainty budget with its {key}"}
        return {"U": float(b["U"][key]) / (2.0 if w == "RAD" else 1.0), "k": float((b.get("k") or {}).get(key, 2.0))}
    others = [features[1]] if w in TWO else [datums[n] for n in tol.datums[:3] if n in datums]
    everyone = [a, *others]
    feats = {}
    for k, x in enumerate(everyone):
        pts = np.zeros((0, 3)) if x.hit_points is None else np.asarray(x.hit_points, float).reshape(-1, 3)
        feats[k] = MeasuredFeature(f"FA({x.label})", x.kind, dict(x.geometry), None, pts, budget=_budget(model, x))
    letters = [chr(ord("A") + k) for k in range(len(others))]
    d = {"characteristic": f"TOL/{w}", "feature": 0, "datums": letters}
    defs = {x: {"label": x, "feature": k + 1} for k, x in enumerate(letters)}

    def value(_d: Any, _defs: Any, moved: dict[int, MeasuredFeature], *_: Any) -> list[float]:
        acts = [replace(x, geometry=dict(moved[k].geometry), hit_points=np.asarray(moved[k].points))
                for k, x in enumerate(everyone)]
        dats = dict(datums)
        if w not in TWO:
            dats.update({n: acts[k + 1] for k, n in enumerate(n for n in tol.datums[:3] if n in datums)})
        return [evaluate(tol, acts[:2] if w in TWO else acts[:1], dats, frame, sizes).value]

    # the value stands on the fitted geometry (a position, an axis's orientation, a distance) unless it is the
    # zone of the feature's own hits (form, profile, runout, a plane's orientation): then their form is measured
    own = w not in ZONE_OF_OWN_HITS and not (w in ("PARLEL", "PERPEND", "ANGLR") and a.kind == "plane")
    (u,) = row_uncertainties(d, defs, feats, [abs(ev.value)] if w in TWO else [ev.value], value, own=own)
    return u


def tolerance_u_line(ev: Evaluation, features: list[Actual], datums: dict[str, Actual], frame: np.ndarray,
                     sizes: dict[str, tuple[float, float]], model: Any, scale: float) -> str:
    """``$$ TA(label): U (95 %) 0.00123 k=2.05``, in the program's units (an ANGLB in degrees), or the reason
    there is none."""
    try:
        u = tolerance_u(ev, features, datums, frame, sizes, model)
    except Exception as exc:  # noqa: BLE001 - the output goes on; the comment says why there is no U
        u = {"why": f"it could not be propagated ({exc})"}
    label = ev.tolerance.label
    if "U" not in u:
        why = str(u.get("why", "")).removeprefix("no uncertainty: ")
        return f"$$ TA({label}): no U: {why}"
    unit = 1.0 if ev.tolerance.word == "ANGLB" else scale
    return f"$$ TA({label}): U (95 %) {u['U'] / unit:.5f} k={u['k']:.2f}"

"""The station's feature fit from probed hits: fit the pre-travel-corrected tip centres, then offset by the tip
radius (points: the compensated point; lines: the tip centres' line moved a radius across it towards the face).
The live measurement model and a recorded session's re-evaluation fit the same way with it."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from . import fit_criteria
from .features import FitResult
from .probe_offset import offset_feature


def fit_hits(kind: str, method: str, centres: Any, approach: Any, points: Any, settings: Any,
             nominal: Any = None) -> FitResult:
    """The station's feature fit: fit the pre-travel-corrected tip centres, then offset by the tip radius.

    A nominal (e.g. the feature a mesh pick suggested, or a program's) seeds the fit: with few points a
    short cylinder, say, has other axes that fit nearly as well, and the nominal picks the right one.
    """
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    approach = np.asarray(approach, dtype=np.float64).reshape(-1, 3)
    if kind == "point":
        return fit_criteria.fit("point", np.asarray(points, dtype=np.float64).reshape(-1, 3), method)
    centres = centres - settings.pretravel(approach)[:, None] * approach
    result = fit_criteria.fit(kind, centres, method, nominal=_centre_start(nominal, kind))
    if kind != "line":
        return offset_feature(result, centres, approach, settings.tip_radius)
    # a line is probed on a face from one side: the tip centres' line moved onto the surface, by the tip radius
    # along the probing direction across the line (the contact lies a radius along the approach from the centre)
    u = np.asarray(result.direction, dtype=np.float64)
    a = approach.mean(axis=0)
    across = a - (a @ u) * u
    if np.linalg.norm(across) < 0.5:  # probed from opposite sides: no one side to move it to; the centres' line
        return result
    return replace(result, point=result.point + settings.tip_radius * across / np.linalg.norm(across))


def fit_hit_records(kind: str, method: str, hits: Any, settings: Any, nominal: Any = None) -> FitResult:
    """``fit_hits`` for hit records (anything with .machine, .approach and .point)."""
    return fit_hits(kind, method, [h.machine for h in hits], [h.approach for h in hits], [h.point for h in hits],
                    settings, nominal)


def _centre_start(nominal: Any, kind: str) -> dict | None:
    """Start values for a fit to tip centres from a nominal surface feature of the same kind.

    Positions and directions carry over; sizes do not (tip centres sit a radius off the surface),
    so the fit takes its size from the data.
    """
    if nominal is None or getattr(nominal, "kind", kind) != kind:
        return None
    params = getattr(nominal, "params", nominal)
    return {k: v for k, v in dict(params).items() if k not in ("radius", "minor_radius", "kind")}

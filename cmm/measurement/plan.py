"""Auto-measure on a measurement model: a planned feature probed hit by hit and fitted.

:func:`plan_at_pick` turns a click on the part into a :class:`~cmm.metrology.hit_plan.HitPlan`
(feature kind, hits, approaches, clearance plane; :func:`plan_targets` gives what the control core previews);
:func:`run_plan` probes the hits one after the other (the first over the
clearance plane, the others straight or over the feature's hop height where
the control core's rails prove it free of the part) and fits the feature
against the CAD nominal. A failed hit
stops the run and says which one; the hits already taken stay recorded.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..metrology.hit_plan import HitPlan, PlanError, plan_feature
from ..metrology.pick import suggest_feature


class PlanCancelled(PlanError):
    """The operator cancelled the run (the ``cancel`` verb): it ended between hits; the hits taken stay recorded."""

    cancelled = True


def plan_at_pick(model: Any, face_id: int, *, n: int | None = None) -> HitPlan:
    """The measurement proposed for the part face ``face_id``."""
    part = model.part
    if part is None:
        raise PlanError("load a part before planning a measurement")
    suggestion = suggest_feature(part.mesh, int(face_id))  # part coordinates
    return plan_feature(part.mesh, part.pose, suggestion.feature, suggestion.face_ids, n=n,
                        tip_radius=float(model.prober.settings.tip_radius))


def plan_targets(plan: HitPlan) -> list[tuple[np.ndarray, np.ndarray, float, float | None]]:
    """(nominal point, approach, clearance Z, hop Z) of every planned hit, machine coordinates, in the order
    :func:`run_plan` probes them: what the control core's ``probe_paths`` previews. The first hit has no hop
    height (it arrives over the clearance plane), the others the plan's."""
    return [(np.asarray(p, float), np.asarray(u, float), float(plan.clearance_z),
             None if k == 0 or plan.hop_z is None else float(plan.hop_z))
            for k, (p, u) in enumerate(zip(plan.points, plan.approaches))]


def run_plan(model: Any, plan: HitPlan, *, name: str | None = None, method: str = "ls",
             progress: Callable[[int, int], None] | None = None, timeout: float = 120.0,
             cancelled: Callable[[], bool] = lambda: False, client: Any = None) -> Any:
    """Probe every planned hit (as ``client``, through the control core), then fit the feature with the
    plan's nominal. Returns the Feature."""
    ids: list[int] = []
    for k, (p, u, cz, hop) in enumerate(plan_targets(plan)):
        if cancelled():
            raise PlanCancelled(f"cancelled after {k} of {len(plan)} hits; the hits taken stay recorded")
        hit = model.probe(p, u, clearance_z=cz, client=client, hop_z=hop).wait(timeout)
        ids.append(model.hit_id(hit))
        if progress is not None:
            progress(k + 1, len(plan))
    return model.fit_feature(plan.kind, ids, method, name, plan.nominal)

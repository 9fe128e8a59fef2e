"""Re-evaluate a recorded session from its raw hits: the raw counts are the truth.

For every hit: counts -> machine mm through the axis configuration and
geometry correction recorded in the session's ``start`` event, then
compensation with the given :class:`ProbeSettings` (tip radius + pre-travel
model). Every feature is refitted with its recorded kind and hits and the
chosen method (default: the recorded one), exactly as the station fits:
fit the pre-travel-corrected tip centres, then offset by the tip radius
(points: the compensated point; lines: the tip centres' line moved a radius across it towards the face).

The result is a new in-memory :class:`Session` whose events are the
original ones with hits and features replaced; its ``start`` event carries
``derived_from`` naming the original. ``write_session`` stores it as a new
session.

A DMIS run's tolerance evaluations (its ``dmis_tolerances`` event,
:mod:`cmm.session.qif_dmis`) are recomputed on the refitted features by
``tolerances`` (the front ends pass :func:`cmm.dmis.replay.reevaluate_event`,
which runs the program again on the refitted hits: the sessions do not import
the DMIS package); without it the event is copied, and its document says that
it leaves those characteristics out.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

import numpy as np

from ..journal.records import FeatureRecord, HitRecord
from ..journal.session import Session
from ..metrology.features import FitError
from ..metrology.fit_hits import fit_hit_records


def recompute_hits(session: Session, settings: Any) -> dict[int, HitRecord]:
    """Every hit ever recorded (active or deleted), recomputed from its counts."""
    recs = {int(e["id"]): HitRecord.from_event(e) for e in session.events if e.get("kind") == "hit"}
    if not recs:
        return {}
    ids = list(recs)
    counts = np.array([recs[i].counts for i in ids], dtype=np.float64)
    machine = session.counts_to_mm(counts)
    approach = np.array([recs[i].approach for i in ids], dtype=np.float64)
    normals = [recs[i].normal for i in ids]
    points = settings.compensate(machine, approach)
    for k, n in enumerate(normals):
        if n is not None:
            points[k] = settings.compensate(machine[k], approach[k], np.asarray(n))
    out = {}
    for k, i in enumerate(ids):
        out[i] = replace(recs[i], machine=tuple(float(x) for x in machine[k]), point=tuple(float(x) for x in points[k]))
    return out


# (the event, the refitted features by id so far, every hit recomputed, feature id -> why it was not refitted)
# -> the event's new fields
Tolerances = Callable[[dict, dict[int, FeatureRecord], dict[int, HitRecord], dict[int, str]], dict]


def reevaluate(session: Session, settings: Any = None, *, method: str | None = None,
               methods: dict[str, str] | None = None, name: str | None = None,
               progress: Callable[[int, int], None] | None = None, tolerances: Tolerances | None = None) -> Session:
    """A new session evaluated from ``session``'s raw hits.

    ``settings``: the ProbeSettings to compensate with (default: the recorded
    ones). ``method`` refits every feature with that criterion; ``methods``
    maps feature names to criteria (wins over ``method``); otherwise each
    feature keeps its recorded method. A feature that cannot be refitted
    (e.g. a method not available for its kind) becomes an ``error`` event.
    ``tolerances``: recomputes a ``dmis_tolerances`` event (see the module's docstring).
    """
    from .qif_dmis import EVENT

    settings = settings or session.probe_settings()
    hits = recompute_hits(session, settings)
    methods = methods or {}
    events: list[dict] = []
    refitted: dict[int, FeatureRecord] = {}
    failed: dict[int, str] = {}
    n = len(session.events)
    for i, e in enumerate(session.events):
        kind = e.get("kind")
        head = {"seq": e.get("seq"), "time": e.get("time"), "kind": kind}
        if kind == "start":
            events.append({**e, "tip_radius": settings.tip_radius, "pretravel": dict(settings.pretravel.coefficients),
                           "derived_from": {"session": session.name, "how": "re-evaluation from raw counts",
                                            "recorded_tip_radius": e.get("tip_radius"),
                                            "recorded_pretravel": e.get("pretravel"), "method": method,
                                            "methods": methods or None}})
        elif kind == "hit":
            events.append({**head, **hits[int(e["id"])].to_event()})
        elif kind == "feature":
            rec = FeatureRecord.from_event(e)
            fmethod = methods.get(e.get("name", ""), method or rec.method)
            recs = [hits[h] for h in rec.hit_ids if h in hits]
            try:
                if len(recs) != len(rec.hit_ids):
                    raise FitError(f"hits {[h for h in rec.hit_ids if h not in hits]} are not in the journal")
                result = fit_hit_records(rec.kind, fmethod, recs, settings, rec.nominal_feature())
            except (FitError, ValueError) as exc:
                events.append({**head, "kind": "error", "source": "reevaluate",
                               "message": f"feature {e.get('name')!r} could not be refitted: {exc}"})
                failed[rec.id] = f"{rec.name} could not be refitted: {exc}"
                refitted.pop(rec.id, None)
                continue
            refit = FeatureRecord.of(result, id=rec.id, name=rec.name, hit_ids=rec.hit_ids, kind=rec.kind,
                                     nominal=rec.nominal, tolerance=rec.tolerance, probe=rec.probe)
            if "budget" in rec.fit:  # the uncertainty budget of the refitted hits (its terms' reference kept)
                from ..metrology.uncertainty import Sources, feature_budget

                recorded = rec.fit.get("budget") or {}
                ref = recorded.get("reference")
                budget = feature_budget(rec.kind, fmethod, np.array([h.point for h in recs], float).reshape(-1, 3),
                                        result, Sources.from_dict(recorded.get("inputs"), reference=ref))
                if budget is not None:
                    refit.fit["budget"] = budget
            events.append({**head, **refit.to_event()})
            refitted[rec.id] = refit
            failed.pop(rec.id, None)
        elif kind == EVENT and tolerances is not None:
            events.append({**head, **tolerances(e, dict(refitted), hits, dict(failed))})
        else:
            events.append(dict(e))
        if progress is not None and (i % 1000 == 0 or i == n - 1):
            progress(i + 1, n)
    return Session.from_events(events, name or f"{session.name}-reevaluated", None)

"""A DMIS run's tolerance evaluations, kept in its session so that every QIF document of the session carries them.

The station's report has no row for some DMIS tolerances (orientation, distances and angles between features,
profiles, runout, concentricity): their values exist only in the run's evaluations. At the end of a DMIS run the
executor records them as one ``dmis_tolerances`` event (:func:`record`); :func:`session_evaluations` reads them back
from a recorded session, so ``cmm sessions export --qif`` and the Report tab's QIF button write the same
characteristics as ``cmm run --qif`` does. Older sessions (without the event) give none.

The event also keeps what re-evaluating the session needs to run the program again (``replay``: its text, the
hits in the order it took them, the operator's answers, the alignments' outcomes, the items it recalled). A
session re-evaluated from raw counts (:mod:`cmm.session.reevaluate`) gets the event recomputed on its refitted
features by the DMIS executor (``cmm.dmis.replay``, a front end's: the sessions never import the DMIS package),
marked ``reevaluated``, with the evaluations the replay could not give in ``left_out`` (each with why);
:func:`left_out` says in one sentence which characteristics a document leaves out and why.

The journal's fold ignores the event kind (it is kept in the session's events).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

EVENT = "dmis_tolerances"
# DMIS tolerance words the station's report has no row for -> the characteristic name qif_map types them by
DMIS_ONLY = {"PARLEL": "parallelism", "PERPEND": "perpendicularity", "ANGLR": "angularity", "DISTB": "distance",
             "ANGLB": "angle", "PROFS": "profile of a surface", "PROFL": "profile of a line",
             "RUNOUT": "circular runout", "CONCEN": "concentricity"}


@dataclass(frozen=True)
class RecordedTolerance:
    """The parts of a DMIS ``TOL/`` statement a QIF characteristic needs (as :class:`cmm.dmis.tolerances.Tolerance`)."""

    label: str
    word: str
    lower: float = 0.0
    upper: float = 0.0
    nominal: float | None = None
    datums: list[str] = field(default_factory=list)
    options: list[str] = field(default_factory=list)
    material: str = ""


@dataclass(frozen=True)
class RecordedEvaluation:
    """A recorded tolerance evaluation (as :class:`cmm.dmis.tolerances.Evaluation`)."""

    tolerance: RecordedTolerance
    value: float
    intol: bool
    features: list[str]
    bonus: float = 0.0
    note: str = ""


def _finite(v: Any) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def to_records(evaluations: Any) -> list[dict[str, Any]]:
    """The evaluations as plain JSON (the event's ``evaluations``); one whose value is not a number is left out."""
    out = []
    for ev in evaluations or ():
        t = ev.tolerance
        value = _finite(ev.value)
        if value is None:
            continue
        out.append({"label": str(t.label), "word": str(t.word), "lower": _finite(t.lower) or 0.0,
                    "upper": _finite(t.upper) or 0.0, "nominal": _finite(t.nominal),
                    "datums": [str(x) for x in t.datums], "options": [str(x) for x in t.options],
                    "material": str(getattr(t, "material", "") or ""), "value": value, "intol": bool(ev.intol),
                    "features": [str(x) for x in ev.features], "bonus": _finite(ev.bonus) or 0.0,
                    "note": str(ev.note or "")})
    return out


def record(model: Any, program: str, evaluations: Any, replay: dict[str, Any] | None = None) -> None:
    """Record a finished DMIS run's evaluations in the model's session (nothing when there are none), with what
    its re-evaluation replays (``replay``, JSON; None: not kept). A journal that refuses the event is told in the
    operator's log; the run stands."""
    recs = to_records(evaluations)
    if not recs:
        return
    try:
        model.record(EVENT, program=str(program), evaluations=recs, **({"replay": replay} if replay else {}))
    except Exception as exc:  # noqa: BLE001 - the QIF extras are help; the measurement stands without them
        log = getattr(model, "log", None)
        if log is not None:
            log("error", f"the DMIS tolerances of {program!r} were not kept in the session: {exc}")


def from_records(recs: Any) -> list[RecordedEvaluation]:
    out = []
    for r in recs or ():
        t = RecordedTolerance(str(r["label"]), str(r["word"]), float(r.get("lower") or 0.0),
                              float(r.get("upper") or 0.0), None if r.get("nominal") is None else float(r["nominal"]),
                              list(r.get("datums") or []), list(r.get("options") or []), str(r.get("material") or ""))
        out.append(RecordedEvaluation(t, float(r["value"]), bool(r["intol"]), list(r.get("features") or []),
                                      float(r.get("bonus") or 0.0), str(r.get("note") or "")))
    return out


def _last(session: Any) -> tuple[dict | None, bool]:
    """(the last DMIS tolerance event of ``session`` or None, whether the session is re-evaluated from counts)."""
    last, derived = None, False
    for event in getattr(session, "events", None) or ():
        if event.get("kind") == "start" and event.get("derived_from"):
            derived = True
        if event.get("kind") == EVENT:
            last = event
    return last, derived


def session_evaluations(session: Any) -> list[RecordedEvaluation]:
    """The DMIS tolerance evaluations recorded in ``session`` (of its last DMIS run that had any), or []. A session
    re-evaluated from raw counts (its start says ``derived_from``) gives those recomputed on its refitted features
    (an event marked ``reevaluated``); the original run's values, evaluated on the original fits, never."""
    last, derived = _last(session)
    if last is None or (derived and not last.get("reevaluated")):
        return []
    return from_records(last.get("evaluations"))


def left_out(session: Any) -> str:
    """One sentence saying which DMIS-only characteristics (:data:`DMIS_ONLY`) of the session's last DMIS run its
    QIF document leaves out and why ("": none)."""
    last, derived = _last(session)
    if last is None or not derived:
        return ""

    def names(recs: Any) -> str:
        return ", ".join(f"T({r['label']})" for r in recs)

    if not last.get("reevaluated"):
        recs = [r for r in last.get("evaluations") or () if r.get("word") in DMIS_ONLY]
        return (f"The DMIS tolerances {names(recs)} of {last.get('program')!r} are left out: this session was "
                "re-evaluated without running the program again, and their recorded values are the original "
                "fits'.") if recs else ""
    gone = [r for r in last.get("left_out") or () if r.get("word") in DMIS_ONLY]
    if not gone:
        return ""
    whys = sorted({str(r.get("why") or "not evaluated") for r in gone})
    return (f"The DMIS tolerances {names(gone)} of {last.get('program')!r} are left out: "
            + "; ".join(w.rstrip(".") for w in whys) + ".")

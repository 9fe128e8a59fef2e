"""A DMIS run's tolerances re-evaluated on a session's refitted features: the program run again on its hits.

A DMIS run keeps in its session (the ``dmis_tolerances`` event, :mod:`cmm.session.qif_dmis`) the program's text,
the hits in the order it took them, the operator's TEXT/QUERY answers, whether each alignment moved the part and
the items it recalled from earlier programs. :func:`reevaluate_event` (the ``tolerances`` of
:func:`cmm.session.reevaluate.reevaluate`) runs the program again through the same
:class:`~cmm.dmis.executor.Executor` on a target that moves nothing: each PTMEAS (or manual MEAS) takes the run's
next hit, recomputed from its counts, and each MEAS's fit is the session's refitted feature of those hits. So the
alignments (and the nominals they move with the part), the constructions and every tolerance are evaluated as the
run did, on the refitted geometry. What cannot be run again is left out, each with why.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..session.qif_dmis import EVENT, to_records
from .check import check
from .executor import Executor
from .run_state import DmisError

# the keys of a feature event's fit that are not its geometry (FitResult.summary() and the model's additions)
NOT_GEOMETRY = ("n_points", "form", "sigma", "uncertainty", "warnings", "proof", "alternative", "budget")
OLD = ("the run was recorded before DMIS runs kept their program and hits in the session, so it cannot be run "
       "again")


class _Result:
    """A refitted feature's fit as the executor reads one: its geometry, form and better-fitting alternative."""

    def __init__(self, fit: dict[str, Any]) -> None:
        self.form = float(fit.get("form") or 0.0)
        self.alternative = fit.get("alternative") or None
        self._geometry = {k: v for k, v in fit.items() if k not in NOT_GEOMETRY}

    def geometry(self) -> dict[str, Any]:
        return dict(self._geometry)


class _Fitted:
    def __init__(self, record: Any) -> None:
        self.id = record.id
        self.result = _Result(record.fit)


class _Model:
    """The measurement model as the replay shows it: the recomputed hits; no live features to tolerance."""

    def __init__(self, hits: dict[int, Any]) -> None:
        self.hits = hits
        self.features: dict[int, Any] = {}
        self.datums: dict[str, Any] = {}

    def log(self, level: str, text: str) -> None:
        pass


class _Recalled:
    """The items the run recalled from earlier programs, as it recalled them (SAVE keeps nothing)."""

    def __init__(self, items: dict[str, Any]) -> None:
        self.items = items

    def recall(self, key: str) -> tuple[Any, str] | None:
        from .saved import decode

        data = self.items.get(key)
        return None if data is None else (decode(key, data), "the run being re-evaluated")

    def keep(self, key: str, value: Any, program: str) -> None:
        pass


class ReplayTarget:
    """A DMIS target that hands the executor the run's hits and the session's refitted features."""

    def __init__(self, replay: dict[str, Any], features: dict[int, Any], hits: dict[int, Any],
                 failed: dict[int, str]) -> None:
        self.model = _Model(hits)
        self._ids = [int(h) for h in replay.get("hit_ids") or ()]
        self.total = len(self._ids)
        self._taken = 0
        self._answers = [str(a) for a in replay.get("answers") or ()]
        self._aligned = [bool(a) for a in replay.get("aligned") or ()]
        self._recalled = _Recalled(dict(replay.get("recalled") or {}))
        self._features = features
        self._failed = failed

    def left(self) -> int:
        """How many of the run's hits the replay has not taken."""
        return self.total - self._taken

    def _take(self, n: int) -> list[int]:
        if self._taken + n > len(self._ids):
            raise DmisError(f"the program takes more than the run's {len(self._ids)} hits")
        out = self._ids[self._taken:self._taken + n]
        self._taken += n
        return out

    def probe(self, point: np.ndarray, approach: np.ndarray, **_: Any) -> int:
        return self._take(1)[0]

    def manual_hits(self, prompt: str, n: int, guides: list) -> list[int]:
        return self._take(n)

    def fit(self, kind: str, hit_ids: list[int], name: str, nominal: Any) -> Any:
        ids = tuple(int(h) for h in hit_ids)
        fits = [r for r in self._features.values() if r.hit_ids == ids and r.kind == kind]
        if fits:  # the run's feature of those hits (named as the program's label)
            return _Fitted(next((r for r in fits if r.name == name), fits[0]))
        why = next((m for m in self._failed.values() if m.startswith(f"{name} ")), None)
        raise ValueError(why or f"the session has no refitted {kind} of its hits {list(ids)}")

    def align(self, measured: np.ndarray, nominal: np.ndarray, points: np.ndarray, name: str) -> str:
        if not self._aligned:
            raise DmisError(f"{name}: the run did not record this alignment")
        if not self._aligned.pop(0):
            raise ValueError(f"{name} did not move the part in the run either")
        return f"{name} moves the part as in the run"

    def ask(self, prompt: str, *, answer: bool) -> str:
        if not answer:
            return ""
        if not self._answers:
            raise DmisError(f"{prompt.split(':')[0]}: the run did not record the operator's answer")
        return self._answers.pop(0)

    def saved_items(self) -> _Recalled:
        return self._recalled

    def position(self) -> np.ndarray:
        return np.zeros(3)

    def move(self, target: np.ndarray, speed: float | None) -> None:
        pass

    def note(self, text: str) -> None:
        pass

    def tell(self, text: str) -> None:
        pass

    def hold(self, done: Any) -> None:
        pass

    def set_tolerance(self, feature_id: int, tolerance: dict[str, float]) -> None:
        pass

    def set_nominal(self, feature_id: int, nominal: Any) -> None:
        pass

    def define_datum(self, label: str, feature_id: int) -> None:
        pass

    def define_position(self, *args: Any, **kw: Any) -> None:
        pass

    def run_end(self, series: str, **_: Any) -> None:
        pass  # the run's trend and records are the run's, not its replay's

    def probes(self) -> None:
        return None

    def select_probe(self, name: str) -> str:
        return ""

    tip_radius = nominal_tip_diameter = 0.0
    probing_speed = positioning_speed = float("inf")
    probe_distances = (2.0, 3.0, 2.0)


class _Replay(Executor):
    def do_snslct(self, s: Any) -> None:
        """The sensor the run selected: its probe was checked then, and its hits are recorded."""
        name = self.labels(s)[0].name
        if name not in self.sensors:
            raise self.fail(s, f"S({name}) is not defined (S({name}) = SNSDEF/PROBE, ...)")
        self.sensor = name


def replay(program: str, replay: dict[str, Any], features: dict[int, Any], hits: dict[int, Any],
           failed: dict[int, str]) -> tuple[list[Any], str]:
    """(the evaluations of the program run again on the refitted features, in order; why it stopped short, or
    "")."""
    stmts, problems = check(str(replay.get("text") or ""))
    if problems:
        return [], f"the program does not pass its check ({problems[0]})"
    target = ReplayTarget(replay, features, hits, failed)
    executor = _Replay(stmts, target, name=program)  # type: ignore[arg-type]
    try:
        executor._run()  # the statements only: the run's journal notes, trend and records are the run's
    except DmisError as exc:
        return executor.result.evaluations, f"running the program again on the refitted features stopped at {exc}"
    if target.left():
        return [], (f"running the program again took {target.total - target.left()} of the run's {target.total} "
                    "hits, so it did not follow the run")
    return executor.result.evaluations, ""


def _gone(rec: dict[str, Any], why: str) -> dict[str, Any]:
    return {"label": rec.get("label"), "word": rec.get("word"), "features": rec.get("features") or [], "why": why}


def reevaluate_event(event: dict[str, Any], features: dict[int, Any], hits: dict[int, Any],
                     failed: dict[int, str]) -> dict[str, Any]:
    """A ``dmis_tolerances`` event recomputed on the refitted ``features`` (id -> FeatureRecord) and ``hits`` (id ->
    HitRecord, recomputed from counts; ``failed``: feature id -> why it was not refitted): the evaluations the
    replay gives, marked ``reevaluated``, and in ``left_out`` the run's others with why."""
    program = str(event.get("program") or "program")
    original = list(event.get("evaluations") or ())
    data = event.get("replay") or {}
    out: dict[str, Any] = {"kind": EVENT, "program": program, "reevaluated": True,
                           **({"replay": data} if data else {})}
    if not data.get("text"):
        why = str(data.get("refused") or OLD)
        return {**out, "evaluations": [], "left_out": [_gone(r, why) for r in original]}
    evaluations, why = replay(program, data, features, hits, failed)
    recs = to_records(evaluations)
    kept, gone, j = [], [], 0
    for r in original:  # the replay gives the run's evaluations in the run's order (up to where it stopped)
        key = (r.get("label"), list(r.get("features") or ()))
        k = next((x for x in range(j, len(recs)) if (recs[x]["label"], recs[x]["features"]) == key), None)
        if k is None:
            gone.append(_gone(r, why or "its value is not a number on the refitted features"))
        else:
            kept.append(recs[k])
            j = k + 1
    return {**out, "evaluations": kept, "left_out": gone}

"""Routines: a taught measurement program as an ordered list of steps, edited and run on every part.

A routine is a program file (:mod:`cmm.session.program`, format ``cmm-program/2``) whose ``[[steps]]`` list
the order of work, like PC-DMIS's edit window or CALYPSO's characteristic list::

    [[steps]]
    kind = "align"              # 3-2-1 from three feature steps (planes) of the routine
    name = "alignment"
    datums = ["TOP", "FRONT", "LEFT"]
    manual = true               # the operator takes 3-2-1 hits by hand first (prompted), then automatic

    [[steps]]
    kind = "feature"            # a [[features]] entry, by name: its hits, nominal, tolerance, method
    name = "bore"
    probe = "T1"                # optional: the probe (stylus) the step measures with; changed to before it

    [[steps]]
    kind = "construct"
    name = "bore-boss"
    operation = "distance"      # intersection, distance, angle, midpoint
    of = ["bore", "boss"]

    [[steps]]
    kind = "report"
    name = "report"

:func:`teach_routine` makes one from a session (its features, its last 3-2-1 alignment, its constructions);
:class:`Routine` edits it (rename, reorder, insert, delete, nominal, tolerance, clearance);
:class:`RoutineRun` runs it on the next part: the alignment first (manual hits prompted on screen, then the
datum features measured automatically), every step with a progress count, pause / resume / skip / cancel,
and the part's results in a session of their own. A step that stops on a fault (unexpected contact, link fault,
E-STOP) stops the run there; after Reset, :meth:`RoutineRun.resume_after_fault` retracts to the clearance height
through the command API's rails, discards the hits the stopped step had taken (deleted: they stay in the
journal) and runs that step again and the rest, in the same part session; :meth:`RoutineRun.restart` discards
everything the run measured and starts again from the first step.
"""

from __future__ import annotations

import threading
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..metrology.align import AlignmentError
from ..metrology.characteristics import DEFAULT_TOLERANCE
from ..metrology.fit_ls import fit_plane
from ..metrology.hops import with_hops
from ..metrology.pick import NominalFeature
from ..metrology.transform import invert
from ..session.program import Program, ProgramError, check, machine_targets, teach, to_toml
from .alignment import AlignmentResult, align_321, align_features, apply, datum_frame

STEP_KINDS = ("align", "feature", "construct", "report")
MANUAL_HITS = (3, 2, 1)  # 3-2-1: hits on the primary, secondary and tertiary datum
CONSTRUCTIONS = ("intersection", "distance", "angle", "midpoint")


class RoutineError(ProgramError):
    """A routine that cannot be edited or run as asked, in an operator's words."""


def _feature_step(name: str, probe: str = "") -> dict[str, Any]:
    """A feature step; ``probe`` names the probe it measures with when one probe took all its hits."""
    step: dict[str, Any] = {"kind": "feature", "name": name}
    if probe and "+" not in probe:
        step["probe"] = probe
    return step


class Routine:
    """The ordered steps of a program, with the edits the Routine view offers."""

    def __init__(self, program: Program) -> None:
        self.program = program
        if not program.steps:
            program.steps = [_feature_step(f.name) for f in program.features]
        self.validate()

    @property
    def name(self) -> str:
        return self.program.name

    @property
    def steps(self) -> list[dict[str, Any]]:
        return self.program.steps

    def text(self) -> str:
        return to_toml(self.program)

    def save(self, path: str | Path) -> Path:
        p = Path(path)
        p.write_text(self.text(), encoding="utf-8")
        return p

    # --- what a step is ------------------------------------------------------------------

    def feature(self, name: str) -> Any:
        try:
            return self.program.feature(name)
        except KeyError:
            raise RoutineError(f"the routine has no feature {name!r}") from None

    def describe(self, index: int) -> str:
        s = self.steps[index]
        skip = (f" [{s['probe']}]" if s.get("probe") else "") + (" (skipped)" if s.get("skip") else "")
        if s["kind"] == "align":
            how = "manual hits, then automatic" if s.get("manual") else "automatic"
            return f"{index + 1}. align 3-2-1: {' | '.join(s['datums'])} ({how}){skip}"
        if s["kind"] == "feature":
            f = self.feature(s["name"])
            return f"{index + 1}. {f.name}: {f.kind}, {len(f.hits)} hits, {f.method}{skip}"
        if s["kind"] == "construct":
            return f"{index + 1}. {s['name']}: {s['operation']} of {' and '.join(s['of'])}{skip}"
        return f"{index + 1}. {s['name']}: report{skip}"

    def lines(self) -> list[str]:
        return [self.describe(i) for i in range(len(self.steps))]

    def settings(self, index: int) -> dict[str, str]:
        """What an operator edits on a feature step, as the edit fields write it (part mm): ``tolerance`` (size
        form location), ``clearance`` (the highest of its hits'), ``nominal`` (name=value ...), ``hits`` (ids in
        order); {} for any other step."""
        s = self.steps[index]
        if s["kind"] != "feature":
            return {}
        f = self.feature(s["name"])
        t = {**DEFAULT_TOLERANCE, **(f.tolerance or {})}  # a key the feature lacks is the default, never 0
        by_id = {h.id: h for h in self.program.hits}
        clear = max((by_id[i].clearance_z for i in f.hits if i in by_id), default=float("nan"))

        def value(v: Any) -> str:
            return " ".join(f"{float(x):g}" for x in v) if isinstance(v, (list, tuple)) else f"{float(v):g}"

        nominal = " ".join(f"{k}={value(v)}" for k, v in (f.nominal or {}).items()
                           if k != "kind" and isinstance(v, (int, float, list, tuple)))
        return {"tolerance": " ".join(f"{float(t.get(k, 0.0)):g}" for k in ("size", "form", "location")),
                "clearance": f"{clear:g}", "nominal": nominal, "hits": " ".join(map(str, f.hits))}

    def measured_features(self) -> list[str]:
        """The features a run probes, in its order: an alignment's datums where it stands (always), a feature
        step unless it was measured already; skipped steps left out."""
        order: list[str] = []
        for s in self.steps:
            if s.get("skip"):
                continue
            if s["kind"] == "align":
                order += list(s["datums"])
            elif s["kind"] == "feature" and s["name"] not in order:
                order.append(s["name"])
        return order

    def targets(self, pose: Any) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
        """(feature, machine point, machine approach, clearance Z) of every hit a run probes, in its order, for the
        part at ``pose``: what a path preview draws (the run's alignment may move the later ones)."""
        by_id = {h.id: t for h, *t in machine_targets(self.program, np.asarray(pose, float))}
        return [(name, *by_id[hid]) for name in self.measured_features() for hid in self.feature(name).hits]

    def validate(self) -> None:
        """Refuse steps that name what the routine does not have, before anything moves."""
        names = [s.get("name") for s in self.steps]
        if len(set(names)) != len(names):
            raise RoutineError("two steps have the same name: rename one")
        features = {f.name for f in self.program.features}
        earlier: set[str] = set()
        for k, s in enumerate(self.steps, 1):
            kind = s.get("kind")
            if kind not in STEP_KINDS:
                raise RoutineError(f"step {k}: unknown kind {kind!r}; choose one of {', '.join(STEP_KINDS)}")
            if not isinstance(s.get("name"), str) or not s["name"].strip():
                raise RoutineError(f"step {k} needs a name")
            if "probe" in s and s["probe"] is not None and (not isinstance(s["probe"], str) or not s["probe"].strip()):
                raise RoutineError(f"step {k} ({s['name']}): the probe must be a probe's name")
            if kind == "feature" and s["name"] not in features:
                raise RoutineError(f"step {k} measures {s['name']!r}, which is not a feature of the routine")
            if kind == "align":
                datums = s.get("datums")
                if not isinstance(datums, list) or len(datums) != 3 or len(set(datums)) != 3:
                    raise RoutineError(f"step {k}: a 3-2-1 alignment needs three different datum features")
                for d in datums:
                    if d not in features:
                        raise RoutineError(f"step {k}: the datum {d!r} is not a feature of the routine")
                    if self.feature(d).kind != "plane":
                        raise RoutineError(f"step {k}: the datum {d!r} must be a plane for a 3-2-1 alignment")
                earlier.update(datums)
            if kind == "construct":
                if s.get("operation") not in CONSTRUCTIONS:
                    raise RoutineError(f"step {k}: construction must be one of {', '.join(CONSTRUCTIONS)}")
                of = s.get("of")
                if not isinstance(of, list) or len(of) != 2:
                    raise RoutineError(f"step {k}: a construction needs two features")
                missing = [n for n in of if n not in earlier]
                if missing:
                    raise RoutineError(f"step {k} ({s['name']}) uses {', '.join(missing)} before it is measured: "
                                       "move the step after them")
            earlier.add(s["name"])

    # --- edits ----------------------------------------------------------------------------

    def _edit(self, change: Callable[[], None]) -> None:
        before = [dict(s) for s in self.steps], [(f.name, f.tolerance, f.nominal) for f in self.program.features]
        change()
        try:
            self.validate()
        except RoutineError:
            self.program.steps[:] = before[0]
            for f, (name, tol, nom) in zip(self.program.features, before[1]):
                f.name, f.tolerance, f.nominal = name, tol, nom
            raise

    def rename(self, index: int, name: str) -> None:
        name = name.strip()
        if not name:
            raise RoutineError("a step needs a name")
        step = self.steps[index]
        old = step["name"]

        def change() -> None:
            if step["kind"] == "feature":
                self.feature(old).name = name
                for s in self.steps:
                    for key in ("datums", "of"):
                        if key in s:
                            s[key] = [name if n == old else n for n in s[key]]
                for d in [*self.program.datums, *self.program.gdt]:  # the taught datums and tolerances follow
                    if d.get("feature") == old:
                        d["feature"] = name
                    if d.get("pattern"):
                        d["pattern"] = [name if n == old else n for n in d["pattern"]]
            step["name"] = name

        self._edit(change)

    def move(self, index: int, delta: int) -> int:
        """Move a step up (-1) or down (+1); returns its new index."""
        new = min(max(index + delta, 0), len(self.steps) - 1)

        def change() -> None:
            self.steps.insert(new, self.steps.pop(index))

        self._edit(change)
        return new

    def delete(self, index: int) -> None:
        self._edit(lambda: self.steps.pop(index))

    def insert(self, index: int, step: dict[str, Any]) -> None:
        self._edit(lambda: self.steps.insert(index, dict(step)))

    def set_skip(self, index: int, skip: bool) -> None:
        self._edit(lambda: self.steps[index].update(skip=bool(skip) or None))

    def set_tolerance(self, name: str, **tolerance: float) -> None:
        f = self.feature(name)
        for k, v in tolerance.items():
            if not np.isfinite(v) or v < 0:
                raise RoutineError(f"{name}: the {k} tolerance must be a positive number of mm, not {v}")
        f.tolerance.update({k: float(v) for k, v in tolerance.items()})

    def set_nominal(self, name: str, **params: Any) -> None:
        """Change nominal parameters (part coordinates), e.g. ``radius=15.0`` or ``point=[30, 40, 0]``; all are
        checked before any is changed."""
        f = self.feature(name)
        if not f.nominal:
            raise RoutineError(f"{name} has no nominal to edit")
        new = {}
        for k, v in params.items():
            if k not in f.nominal or k == "kind":
                raise RoutineError(f"{name}: its nominal has no {k!r} (it has "
                                   f"{', '.join(n for n in f.nominal if n != 'kind')})")
            try:
                arr = np.asarray(v, float)
            except (TypeError, ValueError):
                arr = np.array(np.nan)
            if not np.all(np.isfinite(arr)) or arr.shape != np.asarray(f.nominal[k], float).shape:
                raise RoutineError(f"{name}: {k} must be like {f.nominal[k]!r}, not {v!r}")
            if k == "radius" and float(arr) <= 0:
                raise RoutineError(f"{name}: the radius must be more than 0 mm, not {float(arr):g}")
            new[k] = arr.tolist() if arr.ndim else float(arr)
        f.nominal.update(new)

    def set_hits(self, name: str, ids: list[int]) -> None:
        """The feature's hit plan: which of the routine's hits it takes, in that order (drop or reorder hits)."""
        f = self.feature(name)
        known = {h.id for h in self.program.hits}
        ids = [int(i) for i in ids]
        missing = [i for i in ids if i not in known]
        if missing:
            raise RoutineError(f"{name}: the routine has no hit {', '.join(map(str, missing))}")
        if len(set(ids)) != len(ids):
            raise RoutineError(f"{name}: a hit is listed twice")
        from ..metrology.fit_ls import MIN_POINTS

        need = MIN_POINTS.get(f.kind, 1)
        if len(ids) < need:
            raise RoutineError(f"{name}: a {f.kind} needs at least {need} hits, not {len(ids)}")
        f.hits = ids

    def set_hit(self, hid: int, point: Any = None, approach: Any = None) -> None:
        """Move one planned hit: its nominal surface point and/or approach direction (part coordinates)."""
        hit = next((h for h in self.program.hits if h.id == int(hid)), None)
        if hit is None:
            raise RoutineError(f"the routine has no hit {hid}")
        p = hit.point if point is None else np.asarray(point, float)
        u = hit.approach if approach is None else np.asarray(approach, float)
        p, u = np.asarray(p, float), np.asarray(u, float)
        if p.shape != (3,) or u.shape != (3,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(u))):
            raise RoutineError(f"hit {hid}: a point and a direction are three numbers each (X Y Z)")
        if np.linalg.norm(u) < 1e-9:
            raise RoutineError(f"hit {hid}: the approach direction is zero")
        if p[2] > hit.clearance_z:
            raise RoutineError(f"hit {hid}: Z {p[2]:g} is above its clearance height {hit.clearance_z:g}: "
                               "raise the clearance first")
        hit.point = tuple(float(x) for x in p)  # type: ignore[assignment]
        hit.approach = tuple(float(x) for x in u / np.linalg.norm(u))  # type: ignore[assignment]

    def set_manual(self, index: int, manual: bool) -> None:
        """An alignment step with (True) or without the operator's manual 3-2-1 hits first."""
        if self.steps[index]["kind"] != "align":
            raise RoutineError(f"{self.steps[index]['name']} is not an alignment step")
        self._edit(lambda: self.steps[index].update(manual=bool(manual) or None))

    def set_probe(self, index: int, probe: str | None) -> None:
        """The probe a step measures with (None or '': whatever probe is in use)."""
        probe = (probe or "").strip() or None
        self._edit(lambda: self.steps[index].update(probe=probe))

    def set_clearance(self, name: str, clearance_z: float) -> None:
        """The part Z every hit of the feature climbs to before moving to the next."""
        f = self.feature(name)
        if not np.isfinite(clearance_z):
            raise RoutineError(f"{name}: the clearance height must be a number of mm")
        ids = set(f.hits)
        hits = [h for h in self.program.hits if h.id in ids]
        low = next((h for h in hits if clearance_z < h.point[2]), None)
        if low is not None:  # checked for every hit before any changes: a refused edit changes nothing
            raise RoutineError(f"{name}: the clearance Z {clearance_z:g} mm is below hit {low.id} "
                               f"(Z {low.point[2]:.3f} in the part); nothing was changed")
        for h in hits:
            h.clearance_z = float(clearance_z)


def teach_routine(session: Any, *, name: str | None = None, part_mesh: Any = None,
                  part_nominals: dict[str, Any] | None = None, manual_alignment: bool = True) -> Routine:
    """A routine from what the operator did in ``session``: its last 3-2-1 alignment first (with its datum
    features), then every feature and construction in the order they were made, then a report."""
    program = teach(session, name=name, part_mesh=part_mesh, part_nominals=part_nominals)
    st = session.state
    steps: list[dict[str, Any]] = []
    alignment = next((a for a in reversed(st.alignments) if a.method == "3-2-1" and a.info.get("names")), None)
    taught = {f.name for f in program.features}
    if alignment is not None and all(n in taught for n in alignment.info["names"]):
        steps.append({"kind": "align", "name": "alignment", "datums": list(alignment.info["names"]),
                      "manual": bool(manual_alignment)})
    names = {f.id: f.name for f in st.features.values()}
    probes = {f.name: f.probe or "" for f in st.features.values()}
    if alignment is not None and steps:  # the datums' probe, when one probe took them all
        used = {probes.get(n, "") for n in steps[0]["datums"]}
        if len(used) == 1 and "" not in used and "+" not in next(iter(used)):
            steps[0]["probe"] = next(iter(used))
    # fitted and constructed features share one id counter: their ids are the order they were made in
    made: list[tuple[int, dict[str, Any]]] = [(f.id, _feature_step(f.name, probes.get(f.name, "")))
                                              for f in st.features.values() if f.name in taught]
    for cid, c in st.constructed.items():
        ops = [names.get(i) for i in c.operands]
        if c.operation in CONSTRUCTIONS and len(ops) == 2 and all(ops):
            names[cid] = c.name
            step = {"kind": "construct", "name": c.name, "operation": c.operation, "of": ops}
            if c.tolerance:  # the construction's own tolerance (a distance's +- location, an angle's ...)
                step["tolerance"] = {k: float(v) for k, v in c.tolerance.items()}
            if (c.result or {}).get("projection", "").startswith("axis to axis, 3-D"):  # taken in 3-D: again so
                step["three_d"] = True
            made.append((cid, step))
    steps += [s for _seq, s in sorted(made, key=lambda t: t[0])]
    steps.append({"kind": "report", "name": "report"})
    program.steps = steps
    return Routine(program)


# ------------------------------------------------------------------------------------- preview


def run_order(routine: Routine, *, start: int = 0, done: Any = (), manual_taken: bool = False) -> list[tuple[str, str]]:
    """What a run does from step ``start`` on, in order: ('hand', prompt) for each group of hits the operator
    takes by hand (a manual alignment's), ('feature', name) for each feature measured automatically (an
    alignment's datums where it stands); skipped steps, features in ``done`` and features measured earlier in
    the run left out."""
    order: list[tuple[str, str]] = []
    seen = set(done)
    for s in routine.steps[start:]:
        if s.get("skip"):
            continue
        names: list[str] = []
        if s["kind"] == "align":
            if s.get("manual") and not manual_taken:
                order += [("hand", f"{n} hit{'s' if n > 1 else ''} by hand on {d}")
                          for d, n in zip(s["datums"], MANUAL_HITS)]
                manual_taken = True
            names = list(s["datums"])
        elif s["kind"] == "feature":
            names = [s["name"]]
        for n in names:
            if n not in seen:
                seen.add(n)
                order.append(("feature", n))
    return order


@dataclass
class RoutinePath:
    """The path a run of a routine will take (machine mm), for a preview before it runs: ``cycles`` (the control
    core's :class:`~cmm.machine.probing.CyclePath`) in run order, the feature each measures, the hits the
    operator takes by hand before cycle ``k`` (``hand[k]``: the alignment's prompts; the path after them starts
    over the next automatic hit, since the tip is where the hand left it), and ``lead``, the corners of a
    resume's retract (the back-off after a contact, up to the clearance height) before the first cycle."""

    cycles: list[Any]
    features: list[str]
    hand: dict[int, list[str]] = field(default_factory=dict)
    lead: list[np.ndarray] = field(default_factory=list)
    tail: list[np.ndarray] = field(default_factory=list)  # the run's end: from the last retract up to the clearance plane

    def text(self) -> str:
        """The hand-taken hits and the resume's retract, in words (the path itself is drawn)."""
        words = []
        if self.lead:
            words.append(f"first the retract: back off and up to Z {float(self.lead[-1][2]):.1f} mm (machine)")
        for k, prompts in sorted(self.hand.items()):
            where = f"before hit {k + 1}" if k else "first"
            words.append(f"{where}: {', '.join(prompts)} (the path goes on over hit {k + 1} from where the hand "
                         "leaves the tip)")
        if self.tail:
            words.append(f"at the end: up to the clearance plane, Z {float(self.tail[-1][2]):.1f} mm (machine)")
        return "; ".join(words)


def routine_path(routine: Routine, controller: Any, pose: Any, run: "RoutineRun | None" = None, *,
                 mesh: Any = None) -> RoutinePath:
    """The path a run of ``routine`` on the part at ``pose`` takes, from the control core (``probe_paths``,
    ``move_legs``: the rails and probing cycle the run executes): from where the tip is now (after an unexpected
    contact: backing off first), a manual alignment's hand hits named where they come, then the alignment's
    datums and every feature. ``mesh`` is the part's (the run hops between a feature's hits over it; without it
    the preview takes every hit over its clearance height). With ``run`` stopped on a fault: its resume (the
    retract, then the stopped step again and the rest). The run's alignment moves the hits after it by what it finds; with the part where
    ``pose`` says, the run passes every corner."""
    resume = run is not None and run.can_resume
    order = run.remaining() if resume else run_order(routine)
    by_id = {h.id: t for h, *t in machine_targets(routine.program, np.asarray(pose, float))}
    out = RoutinePath([], [])
    start = here = None
    if resume:
        goal = run.retract_target()  # type: ignore[union-attr]
        if goal is not None:
            here = np.asarray(controller.frame_position("machine"), float)
            out.lead = [np.asarray(q, float) for q in controller.move_legs(goal)]
            start = out.lead[-1]
    hand: list[str] = []
    for kind, what in order:
        if kind == "hand":
            hand.append(what)
            continue
        targets = with_hops([by_id[hid] for hid in routine.feature(what).hits], mesh, pose, controller.tip_radius)
        if hand:  # after the hand hits: from over the first automatic hit's pre-hit point
            first = controller.probe_paths(targets[:1], start=out.cycles[-1].retract if out.cycles else start)[0]
            start = first.rapid[-2] if len(first.rapid) > 1 else first.pre
            out.hand[len(out.cycles)] = hand
            hand = []
        elif out.cycles:
            start = out.cycles[-1].retract
        cycles = controller.probe_paths(targets, start=start)
        out.cycles += cycles
        out.features += [what] * len(cycles)
    if hand:
        out.hand[len(out.cycles)] = hand
    if out.lead and out.cycles and 0 not in out.hand:  # the retract's corners lead the first cycle's rapid
        c0 = out.cycles[0]
        out.cycles[0] = replace(c0, start=here, rapid=(*out.lead, *c0.rapid))
    if out.cycles:  # the run ends at the clearance plane (cmm.measurement.run_end)
        from .run_end import clearance_target

        end = np.asarray(out.cycles[-1].retract, float)
        top = clearance_target(controller, end)
        out.tail = [] if top is None else [end, top]
    return out


# ------------------------------------------------------------------------------------- run


@dataclass
class RunProgress:
    step: int = 0  # index of the step running
    steps: int = 0
    hits: int = 0  # hits taken so far
    total_hits: int = 0
    state: str = "ready"  # ready, waiting (for the operator), running, paused, done, failed, cancelled
    message: str = ""
    prompt: str = ""  # what the operator must do now (manual alignment hits)
    results: dict[str, Any] = field(default_factory=dict)  # step name -> feature / constructed feature
    session: Any = None  # the part's session (path or name)
    part: Any = None  # the trends record of the finished run (cmm.session.trends.PartResult), when recorded


class RoutineCancelled(RoutineError):
    """The operator cancelled the run (the ``cancel`` verb or the tab's Cancel); the hits taken stay recorded."""

    cancelled = True


class RoutineRun:
    """One run of a routine on the next part. ``run()`` blocks (call it from a job thread); ``pause``,
    ``resume``, ``skip`` and ``cancel`` act between hits from any thread. After a step stopped on a fault
    (state ``failed``, ``faulted`` its index), ``resume_after_fault()`` or ``restart()`` (blocking, from a job
    thread) carry on in the same part session; ``cancel()`` ends it."""

    def __init__(self, routine: Routine, model: Any, controller: Any = None, *, client: Any = None,
                 part_name: str | None = None, on_progress: Callable[[RunProgress], None] | None = None,
                 timeout: float = 120.0, change_probe: Callable[[str], Any] | None = None) -> None:
        self.routine = routine
        self.model = model
        self.controller = controller
        self.client = client
        self.part_name = part_name
        self.on_progress = on_progress
        self.timeout = timeout
        self.change_probe = change_probe  # makes a named probe the one in use (the calibration service's)
        self.progress = RunProgress(steps=len(routine.steps), total_hits=self._total_hits())
        self._go = threading.Event()
        self._go.set()
        self._skip = False
        self._cancel = False
        self._stopped = threading.Event()  # set by cancel: ends the waits for the operator at once
        self._fids: dict[str, int] = {}  # feature name -> the model's feature id for this part
        self._partial: list[int] = []  # hits of the feature being measured, not fitted yet
        self._taken: list[int] = []  # every hit this run kept (fitted into a feature)
        self._manual: list[list[int]] | None = None  # the manual 3-2-1 hits, once all were taken
        self.faulted: int | None = None  # index of the step a fault stopped
        self.discarded: list[int] = []  # hits of stopped steps, deleted (they stay in the journal)
        self._hit_map: dict[int, int] = {}  # program hit id -> this run's hit id
        self._gdt_done = False  # the taught datums and geometric tolerances are defined once per run

    def _total_hits(self) -> int:
        r = self.routine
        measured = {n for s in r.steps if not s.get("skip")
                    for n in (s["datums"] if s["kind"] == "align" else [s["name"]] if s["kind"] == "feature" else [])}
        return sum(len(r.feature(n).hits) for n in measured)

    # --- operator's controls -------------------------------------------------------------

    def pause(self) -> None:
        self._go.clear()
        self._tell(state="paused", message="paused after the hit in progress: Resume to go on")

    def resume(self) -> bool:
        """Go on after a pause; False when the run was not paused."""
        self._go.set()
        if self.progress.state == "paused":
            self._tell(state="running", message="resumed")
            return True
        return False

    def skip(self) -> None:
        """Leave the step in progress after its current hit (its feature is not fitted)."""
        self._skip = True
        self._go.set()

    def cancel(self) -> None:
        self._cancel = True
        self._stopped.set()
        self._go.set()
        if self.progress.state == "failed":  # stopped on a fault: nothing runs to see the flag
            self.model.note(f"routine {self.routine.name!r} cancelled after the fault at step {self.faulted + 1}"
                            if self.faulted is not None else f"routine {self.routine.name!r} cancelled")
            self._tell(state="cancelled", message="cancelled after the fault; the hits taken stay recorded",
                       prompt="")

    def _tell(self, **changes: Any) -> None:
        for k, v in changes.items():
            setattr(self.progress, k, v)
        if self.on_progress is not None:
            try:
                self.on_progress(self.progress)
            except Exception:  # noqa: BLE001 - a closed page must not stop the run
                pass

    def _between_hits(self) -> None:
        while not self._go.wait(0.05):
            if self._cancel:
                break
        if self._cancel:
            raise RoutineCancelled("the routine was cancelled by the operator; the hits taken stay recorded")

    # --- the run --------------------------------------------------------------------------

    def run(self, manual_hits: Callable[[str, int], list[int]] | None = None) -> RunProgress:
        """Run every step. ``manual_hits(prompt, n)`` returns the ids of n hits the operator took by hand when
        the alignment asks for them (default: wait for n new hits in the model, the prompt shown meanwhile)."""
        model, routine = self.model, self.routine
        routine.validate()
        check(routine.program, model.part, None, None)
        name = f"{routine.name} {self.part_name}" if self.part_name else routine.name
        self.progress.session = model.new_part(name)  # this part's tree and report: its own rows only
        model.record("routine", name=routine.name, text=routine.text(), part=self.part_name)
        self._tell(state="running", message=f"routine {routine.name!r} started")
        return self._steps_from(0, manual_hits)

    @property
    def can_resume(self) -> bool:
        return self.progress.state == "failed" and self.faulted is not None and not self._cancel

    def resume_after_fault(self, manual_hits: Callable[[str, int], list[int]] | None = None) -> RunProgress:
        """After a fault (and Reset): retract to the clearance height, discard the stopped step's hits, run that
        step again and the rest, in the same part session."""
        if not self.can_resume:
            raise RoutineError("there is no stopped step to resume: the routine did not stop on a fault")
        step = self.faulted
        assert step is not None
        self._retract()
        self._discard(self._partial, f"step {step + 1} stopped by the fault")
        self._partial = []
        self.model.note(f"routine {self.routine.name!r} resumed from step {step + 1}")
        self._tell(state="running", message=f"resumed from step {step + 1}", prompt="")
        return self._steps_from(step, manual_hits)

    def restart(self, manual_hits: Callable[[str, int], list[int]] | None = None) -> RunProgress:
        """After a fault (and Reset): retract, discard everything this run measured (hits and features deleted,
        still in the journal) and run the routine again from its first step, in the same part session."""
        if not self.can_resume:
            raise RoutineError("there is no stopped run to restart: the routine did not stop on a fault")
        self._retract()
        for fid in self._fids.values():
            try:
                self.model.delete_feature(fid)
            except Exception:  # noqa: BLE001 - a feature the operator deleted meanwhile
                pass
        self._discard(self._taken + self._partial, "the routine restarted")
        self._fids.clear()
        self._hit_map.clear()
        self._gdt_done = False
        self._taken, self._partial, self._manual = [], [], None
        self.progress.results.clear()
        self.model.note(f"routine {self.routine.name!r} restarted from step 1")
        self._tell(state="running", message="restarted from step 1", hits=0, prompt="")
        return self._steps_from(0, manual_hits)

    def _discard(self, ids: list[int], why: str) -> None:
        """Delete hits (a 'hit_deleted' event each: the journal keeps them) and say why."""
        gone = [h for h in ids if h in self.model.hits]
        for h in gone:
            self.model.delete_hit(h)
        if gone:
            self.discarded += gone
            self.model.record("routine_discarded", hit_ids=gone, reason=why)
            self.model.note(f"routine {self.routine.name!r}: hits {', '.join(map(str, gone))} discarded ({why})")
            self._tell(hits=max(0, self.progress.hits - len(gone)))

    def _retract(self) -> None:
        """Straight up to the clearance height through the command API (its rails back off a contact first)."""
        c = self.controller
        if c is None:
            return
        mode = str(getattr(c.state.mode, "value", ""))
        if mode in ("fault", "e-stopped"):
            raise RoutineError(f"the machine is {'in fault' if mode == 'fault' else 'emergency stopped'}: "
                               "press Reset, then resume")
        self._wait_standing()
        target = self.retract_target()
        if target is None:
            return
        answer = c.commands.call(self.client, "move", {"target": [float(x) for x in target],
                                                        "frame": "machine", "path": "clearance"},
                                 wait=True, timeout=self.timeout)
        if not answer.ok:
            raise RoutineError(f"the retract to the clearance height failed: {answer.error['message']}")
        self.model.note(f"routine {self.routine.name!r}: retracted to the clearance height Z {target[2]:.3f}")

    def retract_target(self) -> np.ndarray | None:
        """Where a resume's retract goes (machine mm): straight above the tip at the part's clearance height (or
        where the tip is, when higher); None without a controller or a reported position."""
        here = None if self.controller is None else self.controller.frame_position("machine")
        if here is None:
            return None
        z = max(float(here[2]), float(self.model.clearance_z()) if self.model.part is not None else float(here[2]))
        return np.array([float(here[0]), float(here[1]), z])

    def remaining(self) -> list[tuple[str, str]]:
        """What a resume after the fault does, in order (see :func:`run_order`)."""
        start = self.faulted if self.faulted is not None else 0
        return run_order(self.routine, start=start, done=set(self._fids), manual_taken=self._manual is not None)

    def _steps_from(self, start: int, manual_hits: Callable[[str, int], list[int]] | None) -> RunProgress:
        model, routine = self.model, self.routine
        self.faulted = None
        jobs = getattr(self.controller, "jobs", None)  # the control core's running jobs: the cancel, pause, resume
        # and skip_step verbs reach this run through them
        try:
            with nullcontext() if jobs is None else jobs.running(f"routine {routine.name!r}", self.cancel,
                                                                 pause=self.pause, resume=self.resume, skip=self.skip):
                for i in range(start, len(routine.steps)):
                    step = routine.steps[i]
                    self.progress.step = i
                    if step.get("skip"):
                        continue
                    self._skip = False
                    self._tell(message=routine.describe(i))
                    if step["kind"] in ("align", "feature"):
                        self._use_probe(step)
                    if step["kind"] == "align":
                        self._align(step, manual_hits or self._wait_for_hits)
                    elif step["kind"] == "feature":
                        if step["name"] not in self._fids:
                            self._in_job(f"measure {step['name']}", lambda s=step: self._measure(s["name"]))
                    elif step["kind"] == "construct":
                        self._construct(step)
                    else:
                        self._define_gdt()
                        self.progress.results[step["name"]] = self._report()
                self._define_gdt()  # a routine without a report step still evaluates its tolerances
        except RoutineCancelled as exc:
            self._tell(state="cancelled", message=str(exc), prompt="")
            model.note(f"routine {routine.name!r} cancelled")
            raise
        except Exception as exc:
            self.faulted = self.progress.step
            name = routine.steps[self.faulted]["name"]
            self._tell(state="failed", message=f"step {self.faulted + 1} ({name}) stopped: {exc}", prompt="")
            model.note(f"routine {routine.name!r} stopped at step {self.faulted + 1} ({name}): {exc}")
            raise
        self._end_at_clearance()
        model.note(f"routine {routine.name!r} finished")
        self.progress.part = self._record_trend()
        self._tell(state="done", step=len(routine.steps), message=f"routine {routine.name!r} done", prompt="")
        return self.progress

    def _record_trend(self) -> Any:
        """The finished run as a part of the routine's series, when the model records trends: the characteristics
        of the features it measured and constructed (sizes, positions, form, distances) and of the part's
        geometric tolerances, with the part's name as its serial (see :func:`.program.record_trend`)."""
        from ..session.trends import feature_values, measured
        from .program import record_trend

        model = self.model
        if getattr(model, "trends", None) is None:
            return None
        records = {**model.features, **model.constructed}
        values = {m.name: m for m in feature_values(records[fid].record() for fid in self._fids.values()
                                                    if fid in records)}
        for _d, c in model.gdt_characteristics() if model.gdt else []:
            m = measured(c)
            if m is not None:
                values.setdefault(m.name, m)  # a name given twice counts once: the part's record refuses twins
        return record_trend(model, self.routine.name, values=list(values.values()), serial=self.part_name or "")

    def _use_probe(self, step: dict[str, Any]) -> None:
        """Change to the probe the step names, before it moves."""
        want = step.get("probe")
        if not want or want == getattr(self.model, "probe_name", ""):
            return
        if self.change_probe is None:
            raise RoutineError(f"{step['name']} measures with probe {want} but {self.model.probe_name or 'another'} "
                               "is in use: change the probe, or clear the step's probe")
        self._wait_standing()
        self.change_probe(want)
        self.model.note(f"routine {self.routine.name!r}: probe {want} for {step['name']}")

    def _wait_standing(self) -> None:
        """The operator's last manual hit may still be retracting: wait until the machine stands (30 s at most)."""
        if self.controller is None:
            return
        for _ in range(300):
            if str(getattr(self.controller.state.mode, "value", "")) not in ("moving", "probing", "jogging"):
                break
            self._stopped.wait(0.1)

    def _in_job(self, what: str, fn: Callable[[], Any]) -> Any:
        if self.controller is None:
            return fn()
        self._wait_standing()
        return self.controller.run_job(self.client, f"routine {self.routine.name!r}: {what}", fn, cancel=self.cancel)

    def _measure(self, name: str) -> Any:
        """Probe a feature's hits (part coordinates through the current alignment) and fit it."""
        model, program = self.model, self.routine.program
        f = self.routine.feature(name)
        pose = np.asarray(model.part.pose, float)
        by_id = {h.id: t for h, *t in machine_targets(program, pose)}
        self._partial = ids = []
        part = model.part
        targets = with_hops([by_id[hid] for hid in f.hits], part.mesh, pose, float(model.prober.settings.tip_radius))
        for p, u, cz, hop in targets:
            self._between_hits()
            if self._skip:
                self.model.note(f"{name} skipped by the operator after {len(ids)} of {len(f.hits)} hits")
                self._partial = []
                return None
            hit = model.probe(p, u, clearance_z=cz, client=self.client, hop_z=hop).wait(self.timeout)
            ids.append(model.hit_id(hit))
            self._hit_map[f.hits[len(ids) - 1]] = ids[-1]  # program hit id -> this part's (datum targets)
            self._tell(hits=self.progress.hits + 1)
        nominal = None
        if f.nominal:
            nominal = NominalFeature(f.nominal["kind"],
                                     {k: v for k, v in f.nominal.items() if k != "kind"}).transformed(pose)
        feature = model.fit_feature(f.kind, ids, f.method, f.name, nominal, tolerance=f.tolerance)
        self._taken += ids
        self._partial = []
        self._fids[name] = feature.id
        self.progress.results[name] = feature
        return feature

    def _construct(self, step: dict[str, Any]) -> None:
        a, b = (self._fids.get(n) for n in step["of"])
        if a is None or b is None:
            self.model.note(f"{step['name']} not constructed: {' or '.join(step['of'])} was not measured")
            return
        c = self.model.construct_feature(step["operation"], a, b, step["name"], tolerance=step.get("tolerance"),
                                         three_d=bool(step.get("three_d")))
        self._fids[step["name"]] = c.id
        self.progress.results[step["name"]] = c

    def _end_at_clearance(self) -> None:
        """The run ends with the tip at the clearance plane (the last hit retracts only a few mm): the next run's
        first move starts clear of the part."""
        if self.controller is None:
            return
        from .run_end import end_at_clearance

        try:
            z = end_at_clearance(self.controller, self.client, self.timeout)
        except Exception as exc:  # noqa: BLE001 - the part's results stand; the climb's refusal is told
            text = f"routine {self.routine.name!r}: the climb to the clearance plane at its end failed: {exc}"
            self.model.note(text)
            self._tell(message=text)
            return
        if z is not None:
            self.model.note(f"routine {self.routine.name!r}: ended at the clearance plane, machine Z {z:.3f}")

    def _define_gdt(self) -> None:
        """The taught datums and geometric tolerances (A|B|C, modifiers, composite tiers ...) on the features this
        part's run measured; once per run. What cannot be defined (a skipped feature) is a note, not a failure."""
        program = self.routine.program
        if self._gdt_done or not (program.datums or program.gdt):
            return
        self._gdt_done = True
        from .program_gdt import define

        for text in define(self.model, program.datums, program.gdt, dict(self._fids), dict(self._hit_map)):
            self.model.note(f"routine {self.routine.name!r}: {text}")

    def _report(self) -> Any:
        """The part's report (HTML beside its session journal); the journal holds everything up to here."""
        from ..session.report import write_report
        from ..session.store import open_session

        path = self.progress.session
        if not isinstance(path, Path):
            self.model.note("report step: the session is in a database; make its report with cmm report")
            return None
        part = self.model.part
        return write_report(open_session(path), path.with_suffix(".html"),
                            mesh=None if part is None else part.mesh, title=f"{self.routine.name} {self.part_name or ''}".strip())

    # --- alignment --------------------------------------------------------------------------

    def _wait_for_hits(self, prompt: str, n: int) -> list[int]:
        """The default for manual hits: show ``prompt`` and wait until the operator has taken ``n`` hits."""
        start = set(self.model.hits)
        self._tell(state="waiting", prompt=prompt)
        while True:
            new = [h for h in self.model.hits if h not in start]
            if len(new) >= n:
                self._tell(state="running", prompt="")
                return new[:n]
            if self._cancel:
                raise RoutineCancelled("the routine was cancelled while waiting for manual hits")
            if self.progress.prompt != f"{prompt}: {len(new)} of {n} taken":
                self._tell(prompt=f"{prompt}: {len(new)} of {n} taken")
            self._stopped.wait(0.1)  # a person's pace: look again in a tenth of a second

    def _align(self, step: dict[str, Any], manual_hits: Callable[[str, int], list[int]]) -> None:
        """Manual 3-2-1 hits (when the step says so), then the three datums measured and the part aligned. Run
        again after a fault, it keeps the manual hits and the datums measured before the fault."""
        model = self.model
        datums = step["datums"]
        if step.get("manual") and self._manual is None:
            ids = []
            for what, datum, n in zip(("primary", "secondary", "tertiary"), datums, MANUAL_HITS):
                self._between_hits()
                got = manual_hits(f"Take {n} hit{'s' if n > 1 else ''} by hand on {datum} ({what} datum)", n)
                if len(got) != n:
                    raise RoutineError(f"the manual alignment needs {n} hits on {datum}, got {len(got)}")
                ids.append(got)
            apply(model, self._manual_321(datums, ids))
            self._manual = ids
            self._taken += [h for g in ids for h in g]
            model.note("manual 3-2-1 alignment from 6 hits taken by hand")
        fids = []
        for d in datums:
            if d not in self._fids:
                self._in_job(f"measure {d}", lambda d=d: self._measure(d))
            if d not in self._fids:
                raise RoutineError(f"the alignment needs {d}, which was skipped")
            fids.append(self._fids[d])
        apply(model, align_features(model, *fids))

    def _manual_321(self, datums: list[str], ids: list[list[int]]) -> AlignmentResult:
        """The pose from 3 hits on the primary plane, 2 on the secondary and 1 on the tertiary, against the
        three planes' nominals (part coordinates)."""
        model = self.model
        pose = np.asarray(model.part.pose, float)
        nominal = []
        for d in datums:
            nom = self.routine.feature(d).nominal
            if not nom or nom.get("kind") != "plane":
                raise RoutineError(f"the manual alignment needs the nominal plane of {d}")
            nominal.append(("plane", {"point": nom["point"], "normal": nom["normal"]}))
        pts = [np.array([model.hits[h].point for h in group], float) for group in ids]
        R = pose[:3, :3]
        n0 = np.asarray(fit_plane(pts[0]).normal, float)
        n0 = n0 if n0 @ (R @ np.asarray(nominal[0][1]["normal"], float)) >= 0 else -n0
        line_dir = pts[1][1] - pts[1][0]
        if np.linalg.norm(line_dir) < 1.0:
            raise RoutineError(f"the two hits on {datums[1]} are less than 1 mm apart: take them further apart")
        n_ter = R @ np.asarray(nominal[2][1]["normal"], float)
        measured = (("plane", {"point": pts[0].mean(axis=0), "normal": n0}),
                    ("line", {"point": pts[1][0], "direction": line_dir}),
                    ("plane", {"point": pts[2][0], "normal": n_ter}))
        try:
            p0, nz, lp, ld, q = datum_frame(*measured)
            nom = datum_frame(*nominal)
            ld = ld if ld @ (R @ nom[3]) >= 0 else -ld
            new = align_321(p0, nz, lp, ld, q) @ invert(align_321(*nom))
        except AlignmentError as exc:
            raise RoutineError(f"the manual alignment failed: {exc}") from None
        return AlignmentResult("3-2-1 manual", new, {}, {"hit_ids": [h for g in ids for h in g],
                                                          "names": list(datums)})

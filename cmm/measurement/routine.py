"""Routines: a taught measurement program as an ordered list of steps, edited and run on every part.

A routine is a program file (:mod:`cmm.program.toml_program`, format ``cmm-program/2``) whose ``[[steps]]`` list
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
:class:`~cmm.measurement.routine_run.RoutineRun` runs it on the next part: the alignment first (manual hits prompted on screen, then the
datum features measured automatically), every step with a progress count, pause / resume / skip / cancel,
and the part's results in a session of their own. A step that stops on a fault (unexpected contact, link fault,
E-STOP) stops the run there; after Reset, :meth:`~cmm.measurement.routine_run.RoutineRun.resume_after_fault` retracts to the clearance height
through the command API's rails, discards the hits the stopped step had taken (deleted: they stay in the
journal) and runs that step again and the rest, in the same part session; :meth:`~cmm.measurement.routine_run.RoutineRun.restart` discards
everything the run measured and starts again from the first step. The preview of a run's path is
:mod:`cmm.measurement.routine_path`.
"""


from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..metrology.characteristics import DEFAULT_TOLERANCE
from ..program.toml_program import Program, ProgramError, machine_targets, teach, to_toml

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

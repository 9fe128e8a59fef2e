"""Running a routine on the next part: the alignment first (manual hits prompted on screen, then the datum
features measured automatically), every step with a progress count, pause / resume / skip / cancel between
hits, a step stopped on a fault resumed after Reset or the whole run restarted, and the part's results in a
session of their own (see :mod:`cmm.measurement.routine` for what a routine is)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..metrology.align import AlignmentError
from ..metrology.fit_ls import fit_plane
from ..metrology.hops import with_hops
from ..metrology.pick import NominalFeature
from ..metrology.transform import invert
from ..program.runner import RunProgress, StepRunner
from ..program.toml_program import check, machine_targets
from .alignment import AlignmentResult, align_321, datum_frame
from .routine import MANUAL_HITS, Routine, RoutineError
from .routine_host import RoutineHost
from .routine_path import run_order


__all__ = ["RoutineCancelled", "RoutineRun", "RunProgress"]


class RoutineCancelled(RoutineError):
    """The operator cancelled the run (the ``cancel`` verb or the tab's Cancel); the hits taken stay recorded."""

    cancelled = True


class RoutineRun:
    """One run of a routine on the next part: the routine's steps on the part programs' one runner
    (:class:`cmm.program.runner.StepRunner`: its state, progress and controls). ``run()`` blocks (call it from a job
    thread); ``pause``, ``resume``, ``skip`` and ``cancel`` act between hits from any thread. After a step stopped on
    a fault (state ``failed``, ``faulted`` its index), ``resume_after_fault()`` or ``restart()`` (blocking, from a
    job thread) carry on in the same part session; ``cancel()`` ends it.

    ``host`` is all the run gets of the station (:class:`~cmm.measurement.routine_host.RoutineHost`: the part,
    its hits and fits, the journal, the machine); the ``run_routine`` verb hands it one acting for its caller."""

    def __init__(self, routine: Routine, host: RoutineHost, *, part_name: str | None = None,
                 on_progress: Callable[[RunProgress], None] | None = None, timeout: float = 120.0) -> None:
        self.routine = routine
        self.host = host
        self.part_name = part_name
        self.timeout = timeout
        self.runner = StepRunner(steps=len(routine.steps), total_hits=self._total_hits(), on_progress=on_progress)
        self._manual_hits: Callable[[str, int], list[int]] | None = None  # how the operator's hits are taken
        self._fids: dict[str, int] = {}  # feature name -> its feature id for this part
        self._partial: list[int] = []  # hits of the feature being measured, not fitted yet
        self._taken: list[int] = []  # every hit this run kept (fitted into a feature)
        self._manual: list[list[int]] | None = None  # the manual 3-2-1 hits, once all were taken
        self.discarded: list[int] = []  # hits of stopped steps, deleted (they stay in the journal)
        self._hit_map: dict[int, int] = {}  # program hit id -> this run's hit id
        self._gdt_done = False  # the taught datums and geometric tolerances are defined once per run

    def _total_hits(self) -> int:
        r = self.routine
        measured = {n for s in r.steps if not s.get("skip")
                    for n in (s["datums"] if s["kind"] == "align" else [s["name"]] if s["kind"] == "feature" else [])}
        return sum(len(r.feature(n).hits) for n in measured)

    # --- the runner's state and the operator's controls ------------------------------------------

    @property
    def progress(self) -> RunProgress:
        return self.runner.progress

    @property
    def faulted(self) -> int | None:
        return self.runner.faulted

    @property
    def on_progress(self) -> Callable[[RunProgress], None] | None:
        return self.runner.on_progress

    @on_progress.setter
    def on_progress(self, fn: Callable[[RunProgress], None] | None) -> None:
        self.runner.on_progress = fn

    def pause(self) -> bool:
        return self.runner.pause()

    def resume(self) -> bool:
        """Go on after a pause; False when the run was not paused."""
        return self.runner.resume()

    def skip(self) -> bool:
        """Leave the step in progress after its current hit (its feature is not fitted)."""
        return self.runner.skip()

    def cancel(self) -> None:
        faulted, stopped = self.faulted, self.progress.state == "failed"
        self.runner.cancel()
        if stopped:  # stopped on a fault: nothing ran to see the flag
            self.host.note(f"routine {self.routine.name!r} cancelled after the fault at step {faulted + 1}"
                            if faulted is not None else f"routine {self.routine.name!r} cancelled")

    def _tell(self, **changes: Any) -> None:
        self.runner.tell(**changes)

    def _between_hits(self) -> None:
        if not self.runner.hold():
            raise RoutineCancelled("the routine was cancelled by the operator; the hits taken stay recorded")

    # --- the run --------------------------------------------------------------------------

    def run(self, manual_hits: Callable[[str, int], list[int]] | None = None) -> RunProgress:
        """Run every step. ``manual_hits(prompt, n)`` returns the ids of n hits the operator took by hand when
        the alignment asks for them (default: wait for n new hits, the prompt shown meanwhile)."""
        host, routine = self.host, self.routine
        routine.validate()
        check(routine.program, host.part(), None, None)
        name = f"{routine.name} {self.part_name}" if self.part_name else routine.name
        self.progress.session = host.new_part(name)  # this part's tree and report: its own rows only
        host.record("routine", name=routine.name, text=routine.text(), part=self.part_name)
        self._tell(state="running", message=f"routine {routine.name!r} started")
        return self._steps_from(0, manual_hits)

    @property
    def can_resume(self) -> bool:
        return self.runner.can_resume

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
        self.host.note(f"routine {self.routine.name!r} resumed from step {step + 1}")
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
                self.host.delete_feature(fid)
            except Exception:  # noqa: BLE001 - a feature the operator deleted meanwhile
                pass
        self._discard(self._taken + self._partial, "the routine restarted")
        self._fids.clear()
        self._hit_map.clear()
        self._gdt_done = False
        self._taken, self._partial, self._manual = [], [], None
        self.progress.results.clear()
        self.host.note(f"routine {self.routine.name!r} restarted from step 1")
        self._tell(state="running", message="restarted from step 1", hits=0, prompt="")
        return self._steps_from(0, manual_hits)

    def _discard(self, ids: list[int], why: str) -> None:
        """Delete hits (a 'hit_deleted' event each: the journal keeps them) and say why."""
        hits = self.host.hits()
        gone = [h for h in ids if h in hits]
        for h in gone:
            self.host.delete_hit(h)
        if gone:
            self.discarded += gone
            self.host.record("routine_discarded", hit_ids=gone, reason=why)
            self.host.note(f"routine {self.routine.name!r}: hits {', '.join(map(str, gone))} discarded ({why})")
            self._tell(hits=max(0, self.progress.hits - len(gone)))

    def _retract(self) -> None:
        """Straight up to the clearance height through the command API (its rails back off a contact first)."""
        mode = self.host.mode()
        if mode in ("fault", "e-stopped"):
            raise RoutineError(f"the machine is {'in fault' if mode == 'fault' else 'emergency stopped'}: "
                               "press Reset, then resume")
        self._wait_standing()
        target = self.retract_target()
        if target is None:
            return
        try:
            self.host.move_up(target, self.timeout)
        except RoutineError as exc:
            raise RoutineError(f"the retract to the clearance height failed: {exc}") from None
        self.host.note(f"routine {self.routine.name!r}: retracted to the clearance height Z {target[2]:.3f}")

    def retract_target(self) -> np.ndarray | None:
        """Where a resume's retract goes (machine mm): straight above the tip at the part's clearance height (or
        where the tip is, when higher); None without a reported position."""
        here = self.host.position()
        if here is None:
            return None
        z = max(float(here[2]), self.host.clearance_z() if self.host.part() is not None else float(here[2]))
        return np.array([float(here[0]), float(here[1]), z])

    def remaining(self) -> list[tuple[str, str]]:
        """What a resume after the fault does, in order (see :func:`run_order`)."""
        start = self.faulted if self.faulted is not None else 0
        return run_order(self.routine, start=start, done=set(self._fids), manual_taken=self._manual is not None)

    def _steps_from(self, start: int, manual_hits: Callable[[str, int], list[int]] | None) -> RunProgress:
        self._manual_hits = manual_hits
        host, routine = self.host, self.routine
        controls = self.runner.controls()
        description = f"routine {routine.name!r}"
        self.runner.wait = host.wait  # a pause inside the machine loop keeps the loop serving STOP
        try:  # a running job: the cancel, pause, resume and skip_step verbs reach this run
            with host.running(description, self.cancel, pause=controls["pause"], resume=controls["resume"],
                              skip=controls["skip"]):
                # the job query: hits taken of the hits planned, what the run does now
                self.runner.report = lambda p: host.report(description, p.hits, p.total_hits, p.message)
                self.runner.update()
                self.runner.run_steps(start, self._step, skipped=lambda i: bool(routine.steps[i].get("skip")),
                                      describe=routine.describe)
                self._define_gdt()  # a routine without a report step still evaluates its tolerances
        except RoutineCancelled as exc:
            self._tell(state="cancelled", message=str(exc), prompt="")
            host.note(f"routine {routine.name!r} cancelled")
            self._notify_stopped(exc)
            raise
        except Exception as exc:
            name = routine.steps[self.progress.step]["name"]
            k = self.runner.fail(f"step {self.progress.step + 1} ({name}) stopped: {exc}")
            host.note(f"routine {routine.name!r} stopped at step {k + 1} ({name}): {exc}")
            self._notify_stopped(f"step {k + 1} ({name}): {exc}")
            raise
        self._end_at_clearance()
        host.note(f"routine {routine.name!r} finished")
        self.progress.part = self._record_trend()
        self.runner.finish(f"routine {routine.name!r} done")
        return self.progress

    def _step(self, i: int) -> None:
        """One step of the routine: an alignment, a feature, a construction or the report."""
        step = self.routine.steps[i]
        if step["kind"] in ("align", "feature"):
            self._use_probe(step)
        if step["kind"] == "align":
            self._align(step, self._manual_hits or self._wait_for_hits)
        elif step["kind"] == "feature":
            if step["name"] not in self._fids:
                self._in_job(f"measure {step['name']}", lambda s=step: self._measure(s["name"]))
        elif step["kind"] == "construct":
            self._construct(step)
        else:
            self._define_gdt()
            self.progress.results[step["name"]] = self._report()

    def _record_trend(self) -> Any:
        """The finished run as a part of the routine's series, when the station records trends: the
        characteristics of the features it measured and constructed (sizes, positions, form, distances) and of
        the part's geometric tolerances, with the part's name as its serial."""
        return self.host.record_part(self.routine.name, list(self._fids.values()), self.part_name or "")

    def _notify_stopped(self, reason: Any) -> None:
        """The run's early end to whoever is notified (cmm.session.notify); never raises."""
        self.host.run_stopped(self.routine.name, reason, self.part_name or "")

    def _use_probe(self, step: dict[str, Any]) -> None:
        """Change to the probe the step names, before it moves."""
        want = step.get("probe")
        in_use = self.host.probe_name()
        if not want or want == in_use:
            return
        self._wait_standing()
        if not self.host.select_probe(want):
            raise RoutineError(f"{step['name']} measures with probe {want} but {in_use or 'another'} "
                               "is in use: change the probe, or clear the step's probe")
        self.host.note(f"routine {self.routine.name!r}: probe {want} for {step['name']}")

    def _wait_standing(self) -> None:
        """The operator's last manual hit may still be retracting: wait until the machine stands (30 s at most)."""
        for _ in range(300):
            if self.host.mode() not in ("moving", "probing", "jogging"):
                break
            self.runner.sleep(0.1)

    def _in_job(self, what: str, fn: Callable[[], Any]) -> Any:
        self._wait_standing()
        return self.host.run_job(f"routine {self.routine.name!r}: {what}", fn, cancel=self.cancel)

    def _measure(self, name: str) -> Any:
        """Probe a feature's hits (part coordinates through the current alignment) and fit it."""
        host, program = self.host, self.routine.program
        f = self.routine.feature(name)
        part = host.part()
        pose = np.asarray(part.pose, float)
        by_id = {h.id: t for h, *t in machine_targets(program, pose)}
        self._partial = ids = []
        targets = with_hops([by_id[hid] for hid in f.hits], part.mesh, pose, host.tip_radius())
        for p, u, cz, hop in targets:
            self._between_hits()
            if self.runner.skip_asked:
                host.note(f"{name} skipped by the operator after {len(ids)} of {len(f.hits)} hits")
                self._partial = []
                return None
            ids.append(host.probe(p, u, cz, hop, self.timeout))
            self._hit_map[f.hits[len(ids) - 1]] = ids[-1]  # program hit id -> this part's (datum targets)
            self._tell(hits=self.progress.hits + 1)
        nominal = None
        if f.nominal:
            nominal = NominalFeature(f.nominal["kind"],
                                     {k: v for k, v in f.nominal.items() if k != "kind"}).transformed(pose)
        feature = host.fit(f.kind, ids, f.method, f.name, nominal, f.tolerance)
        self._taken += ids
        self._partial = []
        self._fids[name] = feature.id
        self.progress.results[name] = feature
        return feature

    def _construct(self, step: dict[str, Any]) -> None:
        a, b = (self._fids.get(n) for n in step["of"])
        if a is None or b is None:
            self.host.note(f"{step['name']} not constructed: {' or '.join(step['of'])} was not measured")
            return
        c = self.host.construct(step["operation"], a, b, step["name"], step.get("tolerance"),
                                bool(step.get("three_d")))
        self._fids[step["name"]] = c.id
        self.progress.results[step["name"]] = c

    def _end_at_clearance(self) -> None:
        """The run ends with the tip at the clearance plane (the last hit retracts only a few mm): the next run's
        first move starts clear of the part (:mod:`cmm.measurement.run_end`)."""
        try:
            z = self.host.end_at_clearance(self.timeout)
        except Exception as exc:  # noqa: BLE001 - the part's results stand; the climb's refusal is told
            text = f"routine {self.routine.name!r}: the climb to the clearance plane at its end failed: {exc}"
            self.host.note(text)
            self._tell(message=text)
            return
        if z is not None:
            self.host.note(f"routine {self.routine.name!r}: ended at the clearance plane, machine Z {z:.3f}")

    def _define_gdt(self) -> None:
        """The taught datums and geometric tolerances (A|B|C, modifiers, composite tiers ...) on the features this
        part's run measured; once per run. What cannot be defined (a skipped feature) is a note, not a failure."""
        program = self.routine.program
        if self._gdt_done or not (program.datums or program.gdt):
            return
        self._gdt_done = True
        for text in self.host.define_tolerances(program.datums, program.gdt, dict(self._fids), dict(self._hit_map)):
            self.host.note(f"routine {self.routine.name!r}: {text}")

    def _report(self) -> Any:
        """The part's report (HTML beside its session journal); the journal holds everything up to here."""
        path = self.progress.session
        if not isinstance(path, Path):
            self.host.note("report step: the session is in a database; make its report with cmm report")
            return None
        return self.host.write_report(path, f"{self.routine.name} {self.part_name or ''}".strip())

    # --- alignment --------------------------------------------------------------------------

    def _wait_for_hits(self, prompt: str, n: int) -> list[int]:
        """The default for manual hits: show ``prompt`` and wait until the operator has taken ``n`` hits."""
        start = set(self.host.hits())
        self._tell(state="waiting", prompt=prompt)
        while True:
            new = [h for h in self.host.hits() if h not in start]
            if len(new) >= n:
                self._tell(state="running", prompt="")
                return new[:n]
            if self.runner.cancelled:
                raise RoutineCancelled("the routine was cancelled while waiting for manual hits")
            if self.progress.prompt != f"{prompt}: {len(new)} of {n} taken":
                self._tell(prompt=f"{prompt}: {len(new)} of {n} taken")
            self.runner.sleep(0.1)  # a person's pace: look again in a tenth of a second

    def _align(self, step: dict[str, Any], manual_hits: Callable[[str, int], list[int]]) -> None:
        """Manual 3-2-1 hits (when the step says so), then the three datums measured and the part aligned. Run
        again after a fault, it keeps the manual hits and the datums measured before the fault."""
        host = self.host
        datums = step["datums"]
        if step.get("manual") and self._manual is None:
            ids = []
            for what, datum, n in zip(("primary", "secondary", "tertiary"), datums, MANUAL_HITS):
                self._between_hits()
                got = manual_hits(f"Take {n} hit{'s' if n > 1 else ''} by hand on {datum} ({what} datum)", n)
                if len(got) != n:
                    raise RoutineError(f"the manual alignment needs {n} hits on {datum}, got {len(got)}")
                ids.append(got)
            host.apply_alignment(self._manual_321(datums, ids))
            self._manual = ids
            self._taken += [h for g in ids for h in g]
            host.note("manual 3-2-1 alignment from 6 hits taken by hand")
        fids = []
        for d in datums:
            if d not in self._fids:
                self._in_job(f"measure {d}", lambda d=d: self._measure(d))
            if d not in self._fids:
                raise RoutineError(f"the alignment needs {d}, which was skipped")
            fids.append(self._fids[d])
        host.align_features(*fids)

    def _manual_321(self, datums: list[str], ids: list[list[int]]) -> AlignmentResult:
        """The pose from 3 hits on the primary plane, 2 on the secondary and 1 on the tertiary, against the
        three planes' nominals (part coordinates)."""
        pose = np.asarray(self.host.part().pose, float)
        nominal = []
        for d in datums:
            nom = self.routine.feature(d).nominal
            if not nom or nom.get("kind") != "plane":
                raise RoutineError(f"the manual alignment needs the nominal plane of {d}")
            nominal.append(("plane", {"point": nom["point"], "normal": nom["normal"]}))
        hits = self.host.hits()
        pts = [np.array([hits[h].point for h in group], float) for group in ids]
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

"""The path a run of a routine will take, for a preview before it runs: the order of work from any step
(:func:`run_order`), and the probing cycles, hand-taken hits, a resume's retract and the run's end at the
clearance plane (:func:`routine_path`), from the control core's rails and probing cycle."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..metrology.hops import with_hops
from ..program.toml_program import machine_targets
from .routine import MANUAL_HITS, Routine


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


def routine_path(routine: Routine, controller: Any, pose: Any, run: Any = None, *,
                 mesh: Any = None) -> RoutinePath:
    """The path a run of ``routine`` on the part at ``pose`` takes, from the control core (``probe_paths``,
    ``move_legs``: the rails and probing cycle the run executes): from where the tip is now (after an unexpected
    contact: backing off first), a manual alignment's hand hits named where they come, then the alignment's
    datums and every feature. ``mesh`` is the part's (the run hops between a feature's hits over it; without it
    the preview takes every hit over its clearance height). With ``run`` (a
    :class:`~cmm.measurement.routine_run.RoutineRun`) stopped on a fault: its resume (the retract, then the stopped
    step again and the rest). The run's alignment moves the hits after it by what it finds; with the part where
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
        top = clearance_target(controller.commands, end)
        out.tail = [] if top is None else [end, top]
    return out

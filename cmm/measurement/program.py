"""Run a taught measurement program (:mod:`cmm.program.toml_program`) on a measurement model.

:func:`run_program` checks the program against the loaded part and the machine's travel BEFORE anything moves
(:func:`cmm.program.toml_program.check`), then probes every hit through the model and fits the features with their recorded kind, method, nominal and tolerance. On the station a front end runs it
as a job of the control core (:func:`run_on`), so it holds the machine like any other command. When the model
records trends (``model.trends``, :class:`cmm.session.trends.Trends`), the run is a part of the program's
series: every characteristic of its features, with the part's ``serial``.

A feature's first hit arrives over its clearance height; its later hits (the program's consecutive hits of one
feature) hop as the routine runner's do (:func:`hop_targets`, :func:`cmm.metrology.hops.with_hops`): straight
where the control core's rails prove the line free of the part mesh, else over the feature's local top, else
over the clearance height. A model without rails (:func:`cmm.measurement.recording.record`) takes every hit
over its clearance height.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import groupby
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..metrology.hops import with_hops
from ..metrology.pick import NominalFeature
from ..program.runner import StepRunner
from ..program.toml_program import Program, ProgramError, check, load, machine_targets
from .model import Feature, MeasurementModel


class ProgramCancelled(ProgramError):
    """The operator cancelled the run (the ``cancel`` verb) before its next hit; the hits taken stay recorded."""

    cancelled = True


@dataclass
class ProgramRun:
    program: Program
    hit_ids: dict[int, int]  # program hit id -> session hit id
    features: dict[str, Feature]  # name -> the fitted feature
    part: Any = None  # the trends record (cmm.session.trends.PartResult) when the model records trends


def hop_targets(program: Program, pose: Any, mesh: Any, tip_radius: float) -> list[tuple]:
    """(hit, machine point, approach, clearance Z, hop Z or None) for every hit in the program's order: each run of
    consecutive hits of one feature gets its hop heights as the routine runner's (:func:`with_hops`: None for
    the first, the feature's local top for the others); a hit of no feature, or without ``mesh``, none."""
    owner: dict[int, str] = {}
    for f in program.features:
        for i in f.hits:
            owner.setdefault(i, f.name)
    out: list[tuple] = []
    targets = machine_targets(program, np.asarray(pose, float))
    for _, run in groupby(targets, key=lambda t: owner.get(t[0].id, f"#{t[0].id}")):
        run = list(run)
        out += [(t[0], *h) for t, h in zip(run, with_hops([t[1:] for t in run], mesh, pose, tip_radius))]
    return out


def run_program(program: Program, model: MeasurementModel, part_pose: Any = None, *,
                progress: Callable[[int, int], None] | None = None, timeout: float = 120.0,
                serial: str = "", cancelled: Callable[[], bool] = lambda: False, hops: bool = True) -> ProgramRun:
    """Run ``program`` on ``model`` with the part at ``part_pose`` (part -> machine; default: the model's
    current part pose, i.e. its last alignment). ``cancelled()`` is asked before every hit: when it says so the
    run ends there (ProgramError), the hits taken stay recorded. A feature's later hits hop within it
    (:func:`hop_targets`); ``hops=False`` takes every hit over its clearance height."""
    if not isinstance(model, MeasurementModel):
        raise TypeError(f"a program runs on a measurement model, not on {type(model).__name__}")
    part = model.part
    pose = np.asarray(part_pose if part_pose is not None else (None if part is None else part.pose), dtype=np.float64)
    check(program, part, pose, model.machine, model.prober.settings.tip_radius)
    model.note(f"program {program.name!r} started ({len(program.hits)} hits, {len(program.features)} features)")
    ids: dict[int, int] = {}
    targets = hop_targets(program, pose, part.mesh if hops else None, float(model.prober.settings.tip_radius))
    for k, (h, p, u, cz, hop) in enumerate(targets):
        if cancelled():
            model.note(f"program {program.name!r} cancelled after {k} of {len(targets)} hits")
            raise ProgramCancelled(f"program {program.name!r} cancelled after {k} of {len(targets)} hits; "
                               "the hits taken stay recorded")
        hit = model.probe(p, u, clearance_z=cz, hop_z=hop).wait(timeout)
        ids[h.id] = model.hit_id(hit)
        if progress is not None:
            progress(k + 1, len(targets))
    feats = {}
    for f in program.features:
        nominal = None
        if f.nominal:
            nominal = NominalFeature(f.nominal["kind"], {k: v for k, v in f.nominal.items() if k != "kind"}).transformed(pose)
        feats[f.name] = model.fit_feature(f.kind, [ids[i] for i in f.hits], f.method, f.name, nominal,
                                          tolerance=f.tolerance)
    model.note(f"program {program.name!r} finished")
    return ProgramRun(program, ids, feats, record_trend(model, program.name, feats.values(), serial=serial))


def tell_stopped(model: Any, series: str, reason: Any, serial: str = "") -> None:
    """Tell the model's notifier (if it has one) that a run of ``series`` stopped early, and why; never raises (the
    run's own error stands)."""
    notifier = getattr(model, "notifier", None)  # cmm.session.notify's Notifier, when the station notifies
    if notifier is not None:
        try:
            notifier.run_stopped(model, series, reason, serial)
        except Exception:  # noqa: BLE001 - a notification never hides the run's error
            pass


def record_trend(model: MeasurementModel, series: str, features: Any = (), *, values: Any = (), serial: str = "",
                 run_id: str | None = None) -> Any:
    """Record a finished run as a part of ``series`` in ``model.trends`` (None when the model records no trends):
    the characteristics of its fitted ``features`` and any other ``values``
    (:class:`cmm.metrology.measured.Measured`, e.g. :func:`cmm.session.trends.tolerance_values` of a DMIS run). A
    trend that cannot be written is noted in the session and the operator's log; the measurement stands."""
    from ..metrology.measured import TrendError, feature_values

    notifier = getattr(model, "notifier", None)  # cmm.session.notify: the run's end to a webhook / MQTT
    if notifier is not None:
        try:
            notifier.run_end(model, series, feature_values(f.record() for f in features) + list(values), serial)
        except Exception as exc:  # noqa: BLE001 - a notification never spoils the run
            model.log("error", f"the end of the run was not notified: {exc}")
    trends = getattr(model, "trends", None)
    if trends is None:
        return None
    try:
        part = trends.record_part(series, feature_values(f.record() for f in features) + list(values), serial=serial,
                                  run_id=run_id)
    except (TrendError, OSError) as exc:
        text = f"the run was not added to the trends of {series!r}: {exc}"
        model.log("error", text)
        model.note(text)
        return None
    # the session says which series it is a part of (its report can then include that series' charts)
    model.record("trend", series=part.series, run_id=part.run_id, station=part.station)
    return part


def run_on(controller: Any, model: MeasurementModel, program: Program | str | Path, part_pose: Any = None,
           client: Any = None, serial: str = "") -> ProgramRun:
    """Run a program (or the program file at that path) as a job of the control core: it holds the machine
    for the whole run, as ``client``; the ``cancel`` verb ends it before its next hit."""
    prog = load(program) if isinstance(program, (str, Path)) else program
    description = f"program {prog.name!r}"
    # the part programs' one runner: the cancel verb ends the run before its next hit, pause holds it there (the
    # machine loop serving STOP), resume goes on; each hit taken is its progress (the job query)
    runner = StepRunner(steps=len(prog.hits), total_hits=len(prog.hits),
                        wait=getattr(controller, "wait_event", None))
    jobs = getattr(controller, "jobs", None)
    if jobs is not None:
        runner.report = lambda p: jobs.report(description, p.hits, p.total_hits, f"hit {p.hits} of {p.total_hits}")
    return controller.run_job(client, description, lambda: run_program(
        prog, model, part_pose, serial=serial, cancelled=lambda: not runner.hold(),
        progress=lambda k, n: runner.hit_taken()), cancel=runner.cancel, pause=runner.pause, resume=runner.resume)

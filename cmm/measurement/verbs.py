"""The measurement's verbs of the command API, registered where the measurement lives: fit, construct, nominal,
datum, GD&T, align, auto-measure, programs and routines, and the session journal's new session, new part, note
and record_event. Only the control holder changes the measurement (a note in the journal: the holder or a local
client); the long verbs (auto-measure, programs, routines) register with the control core's running jobs while
they run, so the ``cancel`` verb ends them between hits from any front end.

The control core is reached by its duck-typed surface only (``check_access``, ``jobs.running``, ``commands``):
this package sits beside the control layer, not over it; the composition root (:mod:`cmm.station`) calls
:func:`register_measurement_verbs` once it has built both.
"""

from __future__ import annotations

import threading
from typing import Any

from ..metrology.pick import NominalFeature
from . import alignment
from .errors import INFO_FIELDS, MeasurementError
from .plan import plan_at_pick, run_plan
from .program import run_on
from .routine_host import RoutineHost, StationRoutineHost
from .run_end import end_at_clearance

# the journal events a front end may write itself (record_event); everything else the model records as it changes
# a part program's end, which its runner tells (cmm.dmis.runner): data {"series", "values", "event"} (its trend
# values, its own journal event) or {"series", "stopped"} (why it stopped early, for the notifier)
RUN_ENDS = ("program_end", "program_stopped")
JOURNAL_EVENTS = ("routine_saved", *RUN_ENDS)


def register_measurement_verbs(controller: Any, measurement: Any, calibration: Any = None) -> None:
    """Register the measurement verbs on ``controller.commands`` for ``measurement`` (the live model);
    ``calibration`` (the calibration service) given: a routine step's probe is selected with the select_probe
    verb."""

    def holder(fn: Any) -> Any:
        def verb(client: Any, **params: Any) -> Any:
            controller.check_access(client, "measure")
            return fn(**params)
        return verb

    def fit(kind: str, hits: list[int], method: str = "ls", name: str | None = None, nominal: Any = None,
            tolerance: Any = None) -> Any:
        return measurement.fit_feature(kind, [int(h) for h in hits], method, name, nominal, tolerance)

    def align(primary: int | None = None, secondary: int | None = None, tertiary: int | None = None,
              hits: list[int] | None = None, measured: Any = None, nominal: Any = None, points: Any = None,
              name: str = "") -> Any:
        if measured is not None or nominal is not None:  # a program's datum system (DMIS DATSET ...)
            if measured is None or nominal is None or points is None:
                raise MeasurementError("align from a program's datum system needs measured, nominal and points")
            result = alignment.align_program_frame(measurement, measured, nominal, points, name)
        elif hits is not None:
            result = alignment.best_fit_hits(measurement, [int(h) for h in hits])
        elif None not in (primary, secondary, tertiary):
            result = alignment.align_features(measurement, int(primary), int(secondary), int(tertiary))
        else:
            raise MeasurementError("align needs three features (primary, secondary, tertiary) or hits for a best fit")
        alignment.apply(measurement, result)
        return result

    def construct(operation: str, a: int, b: int, name: str | None = None, tolerance: Any = None,
                  three_d: bool = False) -> Any:
        return measurement.construct_feature(operation, int(a), int(b), name, tolerance, three_d)

    def nominal_from_dict(d: Any) -> NominalFeature:
        """A nominal sent as JSON: {"kind": plane | sphere | cylinder | cone, "point" / "center", "normal" /
        "direction", "radius" ...} (the form a feature's summary shows)."""
        if not isinstance(d, dict) or "kind" not in d:
            raise MeasurementError("a nominal is given as its kind and parameters, e.g. "
                               "{kind: cylinder, point: [x, y, z], direction: [0, 0, 1], radius: 5}")
        try:
            return NominalFeature(str(d["kind"]), {k: v for k, v in d.items() if k != "kind"})
        except (TypeError, ValueError) as exc:
            raise MeasurementError(f"the nominal cannot be used: {exc}") from None

    def set_nominal(feature: int, nominal: Any = None, tolerance: Any = None) -> Any:
        if nominal is not None and not isinstance(nominal, NominalFeature):
            nominal = nominal_from_dict(nominal)
        return measurement.set_feature_nominal(int(feature), nominal, tolerance)

    def define_gdt(characteristic: str, feature: int, tolerance: float, datums: Any = "", material: str = "",
                   angle: float | None = None, direction: str = "radial", pattern: Any = None,
                   composite: dict | None = None, name: str | None = None,
                   datum_modifiers: dict[str, str] | None = None, offset: float = 0.0) -> Any:
        extra: dict[str, Any] = {}
        if composite is not None:
            extra = {"pattern": [int(f) for f in pattern or []], "composite": composite}
        return measurement.define_gdt(characteristic, int(feature), tolerance, datums, material=material,
                                      angle=angle, direction=direction, name=name, datum_modifiers=datum_modifiers,
                                      offset=offset or 0.0, **extra)

    def auto_measure(client: Any, plan: Any = None, face: int | None = None, n: int | None = None,
                     name: str | None = None, method: str = "ls", progress: Any = None) -> Any:
        controller.check_access(client, "measure")
        if plan is None:
            if face is None:
                raise MeasurementError("auto-measure needs a plan or the part face to plan on")
            plan = plan_at_pick(measurement, int(face), n=n)
        stop = threading.Event()  # the cancel verb sets it; the plan looks between its hits
        cancel, cancelled = stop.set, stop.is_set

        def work() -> Any:
            feature = run_plan(measurement, plan, name=name, method=method, progress=progress, cancelled=cancelled,
                               client=client)
            try:  # the run ends at the clearance plane (cmm.measurement.run_end); the feature stands either way
                end_at_clearance(controller.commands, client)
            except Exception as exc:  # noqa: BLE001 - told in the journal, in words
                measurement.note(f"auto-measure: the climb to the clearance plane at its end failed: {exc}")
            return feature
        # a run like the others: a STOP ends it as "auto-measure of ... ended by the operator's STOP: ..."
        return controller.run_beside(client, f"auto-measure of {name or 'the ' + plan.kind}", work, cancel=cancel,
                                     action="measure")

    def program(client: Any, path: Any, serial: str = "") -> Any:
        return run_on(controller, measurement, path, client=client, serial=serial)

    cmds = controller.commands
    REQUIRED = cmds.REQUIRED  # noqa: N806 - the API's marker of a parameter that must be given
    cmds.register("measure_feature", holder(fit), {"kind": REQUIRED, "hits": REQUIRED, "method": "ls", "name": None,
                                                   "nominal": None, "tolerance": None},
                  "fit a feature (plane, circle, sphere, cylinder, cone, line...) to hits by id")
    cmds.register("construct", holder(construct), {"operation": REQUIRED, "a": REQUIRED, "b": REQUIRED, "name": None,
                                                   "tolerance": None, "three_d": False},
                  "construct a feature from features a and b (distance, angle, intersection, midpoint ...)")
    cmds.register("undo", holder(measurement.undo), {}, "undo the last hit added or deleted")
    cmds.register("delete_hit", holder(lambda hit: measurement.delete_hit(int(hit))), {"hit": REQUIRED},
                  "delete a hit by id (undo brings it back)")
    cmds.register("delete_feature", holder(lambda feature: measurement.delete_feature(int(feature))),
                  {"feature": REQUIRED}, "delete a feature (or a construction) by id")
    cmds.register("refit_feature", holder(lambda feature, hits: measurement.refit_feature(int(feature),
                                                                                        [int(h) for h in hits])),
                  {"feature": REQUIRED, "hits": REQUIRED},
                  "fit a feature again to other hits (one removed or re-taken); its name, nominal and tolerance stay")
    cmds.register("set_nominal", holder(set_nominal), {"feature": REQUIRED, "nominal": None, "tolerance": None},
                  "a feature's nominal ({kind, point / center, normal / direction, radius ...} or a CAD pick's) "
                  "and/or its tolerances ({size, form, location, position, angle}); journalled as a new fit event")
    cmds.register("define_datum", holder(lambda label, feature, modifier="", targets=None: measurement.define_datum(
                      str(label), int(feature), modifier, None if targets is None else list(targets))),
                  {"label": REQUIRED, "feature": REQUIRED, "modifier": "", "targets": None},
                  "make a fitted feature datum label (A, B ...), RFS or MMB / LMB, or established by targets: hit "
                  "ids, a target area {area: [hit ids]} or line {line: [hit ids]}")
    cmds.register("define_gdt", holder(define_gdt),
                  {"characteristic": REQUIRED, "feature": REQUIRED, "tolerance": REQUIRED, "datums": "",
                   "material": "", "angle": None, "direction": "radial", "pattern": None, "composite": None,
                   "name": None, "datum_modifiers": None, "offset": 0.0},
                  "a geometric tolerance on a feature against datums \"A|B|C\" (a composite position: pattern "
                  "feature ids and composite {tolerance, datums}; datum_modifiers {label: MMB | LMB} as this frame "
                  "references them; offset: a profile's unequally disposed zone, mm, ISO 1101 UZ, + outside the "
                  "material); evaluated at once, refused in words when it cannot be; returns (definition, "
                  "characteristic)")
    cmds.register("delete_gdt", holder(lambda gdt: measurement.delete_gdt(int(gdt))), {"gdt": REQUIRED},
                  "delete a geometric tolerance by id")
    cmds.register("set_info", holder(lambda **fields: measurement.set_info(**fields)),
                  {k: None for k in INFO_FIELDS},
                  "the report header: " + ", ".join(INFO_FIELDS) + " (temperature in deg C); only the fields given change")
    cmds.register("align", holder(align), {"primary": None, "secondary": None, "tertiary": None, "hits": None,
                                           "measured": None, "nominal": None, "points": None, "name": ""},
                  "align the part: 3-2-1 from three features, a best fit of hits to the CAD, or a program's datum "
                  "system (measured and nominal 4x4, program -> machine; points: its datums' hits, checked on the part)")
    cmds.register("auto_measure", auto_measure, {"plan": None, "face": None, "n": None, "name": None, "method": "ls",
                                                 "progress": None},
                  "probe a planned feature hit by hit over the clearance plane and fit it (plan: in process; "
                  "else face: the part face id to plan on, n hits per ring); cancel ends it after the hit in progress")
    cmds.register("run_program", program, {"path": REQUIRED, "serial": ""},
                  "run a measurement program file (the machine is the program's until it ends; cancel ends it "
                  "after the hit in progress)")
    def routine_host(client: Any) -> RoutineHost:
        """What a routine's run gets of this station, acting as ``client``: a step's probe is selected with the
        select_probe verb when there is a calibration service."""
        return StationRoutineHost(measurement, controller, client, select_probes=calibration is not None)

    def routine(client: Any, run: Any, manual_hits: Any = None, action: str = "run") -> Any:
        controller.check_access(client, "measure")
        run.host = routine_host(client)  # its jobs are this client's; the cancel verb ends it
        go = {"run": run.run, "resume": run.resume_after_fault, "restart": run.restart}.get(action)
        if go is None:
            raise MeasurementError(f"run_routine: action must be run, resume or restart, not {action!r}")
        return go(manual_hits)

    def new_session(client: Any, name: str | None = None) -> Any:
        controller.check_access(client, "measure")
        return measurement.new_session(None if name in (None, "") else name)

    def new_part(client: Any, name: str | None = None) -> Any:
        controller.check_access(client, "measure")
        return measurement.new_part(None if name in (None, "") else name)

    def note(client: Any, text: Any) -> None:
        controller.check_access(client, "record")
        measurement.note(str(text))

    def record_event(client: Any, kind: str, data: dict | None = None) -> None:
        controller.check_access(client, "record")
        if kind not in JOURNAL_EVENTS:
            raise MeasurementError(f"a front end records only {', '.join(JOURNAL_EVENTS)} events in the journal, not "
                               f"{kind!r} (hits, features and alignments are the measurement verbs')")
        if data is not None and not (isinstance(data, dict) and all(isinstance(k, str) for k in data)):
            raise MeasurementError(f"record_event: data must be named fields (a JSON object), got {type(data).__name__}")
        if kind in RUN_ENDS:
            return run_end(**(data or {}))
        measurement.record(kind, **(data or {}))

    cmds.register("new_session", new_session, {"name": None},
                  "close the live session journal and record a new one (name: letters, digits, '.', '_', '-' or "
                  "spaces; none: a time stamp) with a start event (configuration, calibration); the control holder "
                  "only; returns its path or store name")
    cmds.register("new_part", new_part, {"name": None},
                  "the next part of a series (a program run again): a new session as new_session, and the previous "
                  "part's hits, features, datums and tolerances put away (they stay in its journal); the control "
                  "holder only; returns its path or store name")
    cmds.register("note", note, {"text": REQUIRED},
                  "a note in the session journal (the report lists it): notes are part of the record, so only the "
                  "control holder or a client at the station's own computer (or the station) writes them, never "
                  "an anonymous observer")
    cmds.register("record_event", record_event, {"kind": REQUIRED, "data": None},
                  "an event of a front end in the session journal: kind " + ", ".join(JOURNAL_EVENTS) + " with its "
                  "data {name: value} (in process, a part program's end: program_end {series, values, event} records "
                  "its trend and its event and tells the notifier, program_stopped {series, stopped} tells why it "
                  "stopped); hits, features and alignments only through their verbs; who may: as note")
    def new_routine_run(client: Any, routine: Any, part_name: str | None = None, on_progress: Any = None) -> Any:
        from .routine_run import RoutineRun

        return RoutineRun(routine, routine_host(client), part_name=part_name, on_progress=on_progress)

    def teach(client: Any, name: str | None = None, manual_alignment: bool = True) -> Any:
        from ..journal.store import open_session
        from .routine import teach_routine

        journal = measurement.journal
        if journal is None or not hasattr(journal, "path"):
            raise MeasurementError("this session has no journal file to teach from")
        part = measurement.part
        return teach_routine(open_session(journal.path), name=name or None, manual_alignment=manual_alignment,
                             part_mesh=None if part is None else part.mesh,
                             part_nominals=None if part is None else part.nominal_features)

    def preview(client: Any, routine: Any, run: Any = None) -> Any:
        from .routine_path import routine_path

        part = measurement.part
        if part is None:
            raise MeasurementError("load the routine's part first")
        return routine_path(routine, controller, part.pose, run, mesh=part.mesh)

    def run_end(series: str, values: Any = None, event: Any = None, stopped: Any = None, serial: str = "") -> Any:
        """A part program's end (record_event's program_end / program_stopped): its trend values (the run a part
        of the series, the notifier told) and its own journal event (kind, data), or why it stopped early."""
        from .program import record_trend, tell_stopped

        notifier = getattr(measurement, "notifier", None)
        if stopped is not None:  # an early end: told to the notifier (never raises; the run's error stands)
            tell_stopped(measurement, series, stopped, serial)
            return None
        part = None
        if values is not None:
            part = record_trend(measurement, series, values=list(values), serial=serial)
        elif notifier is not None:  # nothing to trend: the run's end is still told
            try:
                notifier.run_end(measurement, series, [])
            except Exception as exc:  # noqa: BLE001 - a notification never spoils the run
                measurement.log("error", f"the end of the run was not notified: {exc}")
        if event is not None:
            kind, data = event
            try:
                measurement.record(kind, **data)
            except Exception as exc:  # noqa: BLE001 - the extras are help; the measurement stands without them
                measurement.log("error", f"the {kind} of {series!r} were not kept in the session: {exc}")
        return part

    cmds.register("new_routine_run", new_routine_run, {"routine": REQUIRED, "part_name": None, "on_progress": None},
                  "in process: a run of a routine on the next part (its progress, pause / resume / skip, its recovery "
                  "after a fault), not started and changing nothing: run_routine runs it", query=True)
    cmds.register("teach_routine", teach, {"name": None, "manual_alignment": True},
                  "in process: a routine taught from the live session's journal (its last 3-2-1 alignment, features, "
                  "constructions and a report step), on the part loaded; changes nothing", query=True)
    cmds.register("routine_path", preview, {"routine": REQUIRED, "run": None},
                  "in process: the path a run of the routine takes on the part where the model has it (the probing "
                  "cycles, the hand-taken hits, a stopped run's resume: run), from the control core's rails",
                  query=True)
    cmds.register("run_routine", routine, {"run": REQUIRED, "manual_hits": None, "action": "run"},
                  "in process: run a routine on the next part (a RoutineRun: pause / resume / skip on it), or after "
                  "a fault resume it from the stopped step (retract, the step again) or restart it; cancel ends it "
                  "between hits")

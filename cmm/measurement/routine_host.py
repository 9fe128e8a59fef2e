"""What a routine's run needs of the station, and nothing more: :class:`RoutineHost`.

A :class:`~cmm.measurement.routine_run.RoutineRun` gets this narrow protocol, never the measurement model or the
control core themselves (as the I++ executor gets its :class:`cmm.ippdme.backend.Backend` and the calibration
service its :class:`cmm.calibration.service.CalibrationHost`): the part and its hits, the fits and the session
journal it writes, and the machine it moves, each an operation named for what the run does with it.
:class:`StationRoutineHost` is the one implementation, over the live measurement model and the control core,
acting as one client of the command API; :func:`cmm.measurement.verbs.register_measurement_verbs` builds it for
the ``new_routine_run`` and ``run_routine`` verbs.
"""

from __future__ import annotations

import threading
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol

import numpy as np

from .alignment import AlignmentResult, align_features, apply
from .routine import RoutineError


class RoutineHost(Protocol):
    """The station as a routine's run sees it. Machine positions in machine mm (tip centre)."""

    # --- the part, its hits and features ---------------------------------------------------------

    def part(self) -> Any:
        """The part loaded (its ``pose``, part -> machine, and ``mesh``); None without one."""

    def probe_name(self) -> str:
        """The probe in use ("" when none is named)."""

    def tip_radius(self) -> float:
        """The radius (mm) of the tip in use: a feature's hits hop over the part by it."""

    def clearance_z(self) -> float:
        """The part's clearance height (machine Z)."""

    def hits(self) -> Mapping[int, Any]:
        """The hits of this part by id (each with its ``point``)."""

    def probe(self, point: Any, approach: Any, clearance_z: float | None, hop_z: float | None,
              timeout: float) -> int:
        """Take one programmed hit (over the clearance height, hopping at ``hop_z``); its id once recorded."""

    def fit(self, kind: str, hits: list[int], method: str, name: str, nominal: Any, tolerance: Any) -> Any:
        """Fit a feature to hits (its nominal and tolerance given); the fitted feature (``id``)."""

    def construct(self, operation: str, a: int, b: int, name: str, tolerance: Any, three_d: bool) -> Any:
        """Construct a feature from features a and b; the construction (``id``)."""

    def delete_hit(self, hit: int) -> None:
        """Delete a hit (the journal keeps it)."""

    def delete_feature(self, feature: int) -> None:
        """Delete a feature or a construction (the journal keeps it)."""

    def align_features(self, primary: int, secondary: int, tertiary: int) -> None:
        """Align the part 3-2-1 on three fitted features."""

    def apply_alignment(self, result: AlignmentResult) -> None:
        """Align the part as ``result`` says (a manual 3-2-1 the run worked out)."""

    def define_tolerances(self, datums: list[dict], gdts: list[dict], features: dict[str, int],
                          hits: dict[int, int]) -> list[str]:
        """The routine's datums and geometric tolerances on this part's features (name -> id; program hit id ->
        hit id: datum targets); what could not be defined, in words."""

    # --- the session journal, the report, the trends -----------------------------------------------

    def new_part(self, name: str) -> Any:
        """A new session for the next part (the previous part's results put away); its path or store name."""

    def note(self, text: str) -> None:
        """A note in the session journal."""

    def record(self, kind: str, **data: Any) -> None:
        """An event of the run in the session journal."""

    def write_report(self, session: Path, title: str) -> Any:
        """The part's report beside its journal; None (and a note saying so) when this station writes none."""

    def record_part(self, series: str, features: list[int], serial: str) -> Any:
        """The finished run as a part of ``series`` (its features' and tolerances' values, ``serial`` its name)
        when the station keeps trends or notifies; None otherwise."""

    def run_stopped(self, series: str, reason: Any, serial: str) -> None:
        """Tell whoever is notified that the run stopped early; never raises."""

    # --- the machine -------------------------------------------------------------------------------

    def mode(self) -> str:
        """The machine's mode: "idle", "moving", "probing", "jogging", "fault", "e-stopped" ..."""

    def position(self) -> np.ndarray | None:
        """Where the tip is (None: no sample yet)."""

    def move_up(self, target: Any, timeout: float) -> None:
        """Move to ``target`` over the clearance path (a contact backed off first); RoutineError when refused
        or failed."""

    def end_at_clearance(self, timeout: float) -> float | None:
        """Climb to the clearance plane after the run (:func:`cmm.measurement.run_end.end_at_clearance`): the
        machine Z reached, None when nothing moved; raises when the climb is refused or fails."""

    def run_job(self, description: str, work: Callable[[], Any], cancel: Callable[[], None]) -> Any:
        """Run ``work`` in the machine loop with the machine to itself (``cancel``: the cancel verb's); its
        result."""

    def running(self, description: str, cancel: Callable[[], None], *, pause: Callable[[], Any],
                resume: Callable[[], Any], skip: Callable[[], Any]) -> AbstractContextManager[Any]:
        """While the block runs, the run is a running job: the cancel, pause, resume and skip_step verbs reach
        it."""

    def report(self, description: str, done: int, total: int, step: str) -> None:
        """How far the running job is (hits taken of the hits planned, what it does now), for the job query."""

    def wait(self, event: threading.Event, timeout: float) -> bool:
        """Wait for ``event`` (a pause); inside the machine loop the loop goes on serving STOP meanwhile."""

    def select_probe(self, name: str) -> bool:
        """Make the named probe the one in use; False when this station selects no probes."""


class StationRoutineHost:
    """The :class:`RoutineHost` of a station: its measurement ``model`` and its control core ``controller``,
    acting as ``client`` of the command API (moves, jobs, the probe selected, waits and the machine's state go
    through its verbs and queries, so the access policy and the motion rails apply). ``select_probes``: the
    station has a calibration service, whose ``select_probe`` verb changes the probe in use."""

    def __init__(self, model: Any, controller: Any, client: Any = None, *, select_probes: bool = False) -> None:
        self._model = model
        self._api = controller.commands
        # the registry of running jobs: a routine registers itself there for its whole run and holds no machine
        # meanwhile (each feature is a run_job of its own); no verb does that without a run_beside's refusal and
        # its STOP wording, which a routine reports its own way
        self._jobs = controller.jobs
        self.client = client
        self._select_probes = select_probes

    # --- the part, its hits and features ---------------------------------------------------------

    def part(self) -> Any:
        return self._model.part

    def probe_name(self) -> str:
        return getattr(self._model, "probe_name", "") or ""

    def tip_radius(self) -> float:
        return float(self._model.prober.settings.tip_radius)

    def clearance_z(self) -> float:
        return float(self._model.clearance_z())

    def hits(self) -> Mapping[int, Any]:
        return self._model.hits

    def probe(self, point: Any, approach: Any, clearance_z: float | None, hop_z: float | None,
              timeout: float) -> int:
        model = self._model
        hit = model.probe(point, approach, clearance_z=clearance_z, client=self.client, hop_z=hop_z).wait(timeout)
        return model.hit_id(hit)

    def fit(self, kind: str, hits: list[int], method: str, name: str, nominal: Any, tolerance: Any) -> Any:
        return self._model.fit_feature(kind, hits, method, name, nominal, tolerance=tolerance)

    def construct(self, operation: str, a: int, b: int, name: str, tolerance: Any, three_d: bool) -> Any:
        return self._model.construct_feature(operation, a, b, name, tolerance=tolerance, three_d=three_d)

    def delete_hit(self, hit: int) -> None:
        self._model.delete_hit(hit)

    def delete_feature(self, feature: int) -> None:
        self._model.delete_feature(feature)

    def align_features(self, primary: int, secondary: int, tertiary: int) -> None:
        apply(self._model, align_features(self._model, primary, secondary, tertiary))

    def apply_alignment(self, result: AlignmentResult) -> None:
        apply(self._model, result)

    def define_tolerances(self, datums: list[dict], gdts: list[dict], features: dict[str, int],
                          hits: dict[int, int]) -> list[str]:
        from .program_gdt import define

        return list(define(self._model, datums, gdts, features, hits))

    # --- the session journal, the report, the trends -----------------------------------------------

    def new_part(self, name: str) -> Any:
        return self._model.new_part(name)

    def note(self, text: str) -> None:
        self._model.note(text)

    def record(self, kind: str, **data: Any) -> None:
        self._model.record(kind, **data)

    def write_report(self, session: Path, title: str) -> Any:
        model = self._model
        reporter = getattr(model, "reporter", None)  # cmm.session.report.write_part_report on a station
        if reporter is None:
            model.note("report step: this measurement model writes no reports; make its report with cmm report")
            return None
        part = model.part
        return reporter(session, mesh=None if part is None else part.mesh, title=title)

    def record_part(self, series: str, features: list[int], serial: str) -> Any:
        from ..metrology.measured import feature_values, measured
        from .program import record_trend

        model = self._model
        if getattr(model, "trends", None) is None and getattr(model, "notifier", None) is None:
            return None  # nobody to tell: no trends, no notifications
        records = {**model.features, **model.constructed}
        values = {m.name: m for m in feature_values(records[fid].record() for fid in features if fid in records)}
        for _d, c in model.gdt_characteristics() if model.gdt else []:
            m = measured(c)
            if m is not None:
                values.setdefault(m.name, m)  # a name given twice counts once: the part's record refuses twins
        return record_trend(model, series, values=list(values.values()), serial=serial)

    def run_stopped(self, series: str, reason: Any, serial: str) -> None:
        from .program import tell_stopped

        tell_stopped(self._model, series, reason, serial)

    # --- the machine, through the command API as the run's client ---------------------------------

    def mode(self) -> str:
        state = self._api.invoke(self.client, "state")
        return str(getattr(state.mode, "value", state.mode))

    def position(self) -> np.ndarray | None:
        here = self._api.invoke(self.client, "position", frame="machine")
        return None if here is None else np.asarray(here, float)

    def move_up(self, target: Any, timeout: float) -> None:
        try:
            self._api.invoke(self.client, "move", target=[float(x) for x in target], frame="machine",
                             path="clearance").wait(timeout)
        except Exception as exc:  # noqa: BLE001 - a refusal, a contact, a stop: the run's error in the API's words
            raise RoutineError(str(exc) or type(exc).__name__) from exc

    def end_at_clearance(self, timeout: float) -> float | None:
        from .run_end import end_at_clearance

        return end_at_clearance(self._api, self.client, timeout)

    def run_job(self, description: str, work: Callable[[], Any], cancel: Callable[[], None]) -> Any:
        return self._api.invoke(self.client, "run_job", description=description, work=lambda _job: work(),
                                cancel=cancel)

    def running(self, description: str, cancel: Callable[[], None], *, pause: Callable[[], Any],
                resume: Callable[[], Any], skip: Callable[[], Any]) -> AbstractContextManager[Any]:
        return self._jobs.running(description, cancel, pause=pause, resume=resume, skip=skip)

    def report(self, description: str, done: int, total: int, step: str) -> None:
        self._jobs.report(description, done, total, step)

    def wait(self, event: threading.Event, timeout: float) -> bool:
        return self._api.invoke(self.client, "loop_wait", event=event, timeout=timeout)

    def select_probe(self, name: str) -> bool:
        if not self._select_probes:
            return False
        self._api.invoke(self.client, "select_probe", name=name)  # as the page's Use this probe does
        return True

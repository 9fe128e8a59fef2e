"""The measurement model: the part, its hits and features, undo, constructions, alignment and the session journal.

One :class:`MeasurementModel` per station (``station.measurement``) and one per headless recording
(:func:`cmm.measurement.recording.record`): hits arrive through :meth:`MeasurementModel.add_hit` (the control
core's hit recorder, or the prober's listener), are journalled (fsync'ed / committed) before anyone is shown
them, and features are fitted from them the same way everywhere: fit the pre-travel-corrected tip centres, then
offset by the tip radius (:func:`cmm.metrology.fit_hits.fit_hit_records`, which re-evaluation uses too).

Probing goes through the ``probe`` callable the owner gives (the station: its control core; headless: the
prober). Listeners (:meth:`subscribe`) get 'hit', 'hits', 'feature', 'features', 'part', 'info' and the machine
events the owner passes to :meth:`machine_event` (which the journal records). Thread-safe: front ends call it
from several threads; hits are journalled on the control core's dispatcher thread.
"""

from __future__ import annotations

import contextlib
import functools

import json
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..journal.records import ConstructedRecord, FeatureRecord, HitRecord
from ..journal.session import file_sha256, machine_snapshot, mesh_sha256
from ..journal.state import SessionState
from ..journal.store import check_name, is_url
from ..journal.writer import Journal, encode_event
from ..metrology.features import FitError, FitResult
from ..metrology.fit_hits import fit_hit_records
from ..metrology.mesh import signed_deviation
from ..metrology.pick import FeatureSuggestion, NominalFeature, PickResult, pick, suggest_feature

from .session_files import clean_info, construct_pair, open_journal, start_event
from .tolerancing import Tolerancing
from .errors import FEATURE_KINDS, INFO_FIELDS, MeasurementError  # noqa: F401 - front ends import them there
TOLERANCE_KEYS = ("size", "form", "location", "position", "angle", "size_lower", "size_upper")
# the diameter's own limits (deviations from the nominal, mm; a DMIS TOL/DIAM, -0.01, 0.05): any sign
SIZE_LIMITS = ("size_lower", "size_upper")
# machine events the journal records, and which of them as errors
MACHINE_EVENTS = ("contact", "deadman", "limit", "error", "estop", "fault", "stop", "reset", "reconnect")
MACHINE_ERRORS = ("contact", "error", "fault", "estop")


@dataclass
class Part:
    name: str
    mesh: Any  # trimesh.Trimesh in part coordinates
    pose: np.ndarray  # part -> machine (the station's belief; alignment refines it)
    nominal_features: dict[str, NominalFeature] = field(default_factory=dict)
    sha256: str | None = None  # content hash; the mesh's when not given
    setup: np.ndarray | None = None  # part -> machine at the nominal set-up (the pose it was loaded with)

    def __post_init__(self) -> None:
        if self.setup is None and self.pose is not None:
            self.setup = np.array(self.pose, dtype=np.float64, copy=True)
        if self.sha256 is None and self.mesh is not None:
            self.sha256 = mesh_sha256(self.mesh)


@dataclass
class Feature:
    """A fitted feature as the model holds it: the whole fit (``result``: residuals, covariance, the
    better-fitting alternative) and its nominal as a :class:`NominalFeature`. What is recorded of it is its
    :meth:`record`, the :class:`~cmm.journal.records.FeatureRecord` the journal, the report, replay and
    re-evaluation read."""

    id: int
    name: str
    kind: str
    method: str
    hit_ids: list[int]
    result: FitResult
    nominal: NominalFeature | None = None
    tolerance: dict[str, float] | None = None  # {"size", "form", "location", "position"}: DEFAULT_TOLERANCE otherwise
    budget: dict[str, Any] | None = None  # the uncertainty budget (cmm.metrology.uncertainty.feature_budget)

    def record(self, probe: str | None = None) -> FeatureRecord:
        """The feature as journalled (``probe``: the probe(s) that took its hits)."""
        rec = FeatureRecord.of(self.result, id=self.id, name=self.name, hit_ids=self.hit_ids,
                               nominal=None if self.nominal is None else self.nominal.to_dict(),
                               tolerance=self.tolerance, probe=probe)
        if self.budget is not None:
            rec.fit["budget"] = self.budget  # U, k per value and its terms, kept with the fit
        return rec


@dataclass
class ConstructedFeature:
    """A feature constructed from two others (intersection, distance, angle, mid-point); what is recorded of it
    is its :meth:`record` (:class:`~cmm.journal.records.ConstructedRecord`)."""

    id: int
    name: str
    operation: str
    operands: tuple[int, int]
    result: Any  # cmm.metrology.construct.Constructed
    nominal: Any = None  # the same construction on the operands' nominals (Constructed) or None
    tolerance: dict[str, float] | None = None

    def record(self) -> ConstructedRecord:
        return ConstructedRecord(self.id, 0, self.name, self.operation, tuple(self.operands), self.result.summary(),
                                 None if self.nominal is None else self.nominal.summary(), self.tolerance)


def check_tolerance(tolerance: dict[str, float] | None) -> dict[str, float] | None:
    """Validate a feature tolerance: known keys, positive finite mm (degrees for ``angle``)."""
    if tolerance is None:
        return None
    out: dict[str, float] = {}
    for k, v in tolerance.items():
        if k not in TOLERANCE_KEYS:
            raise MeasurementError(f"unknown tolerance {k!r}; use {', '.join(TOLERANCE_KEYS)}")
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise MeasurementError(f"the {k} tolerance must be a number, got {v!r}") from None
        if k in SIZE_LIMITS:
            if not abs(x) < 1e3:
                raise MeasurementError(f"the {k} limit must be a number of mm, got {v!r}")
        elif not (x > 0 and x < 1e3):
            raise MeasurementError(f"the {k} tolerance must be a positive number, got {v!r}")
        out[k] = x
    if "size_lower" in out and "size_upper" in out and not out["size_lower"] < out["size_upper"]:
        raise MeasurementError(f"the size's lower limit {out['size_lower']:g} must be below its upper limit "
                               f"{out['size_upper']:g}")
    return out


class MeasurementModel:
    """Hits, features and the session journal of one measuring set-up.

    ``machine`` is read for the configuration, the travel limits and the geometry correction, ``prober`` for the
    probe settings (tip radius, pre-travel), both live: a calibration applied later counts. ``probe(point,
    approach, clearance_z, client[, hop_z=])`` takes a programmed hit and returns a status whose ``wait()`` gives
    the hit;
    ``start_fields()`` adds to each session's ``start`` event (port, calibration).

    Every event the model journals is folded into :attr:`state` (:class:`~cmm.journal.state.SessionState`,
    the fold replay and re-evaluation make of a journal file), journal open or not: the hits (``hits``,
    ``deleted``), datums, geometric tolerances, report header and notes are read from it. The live fitted and
    constructed features (``features``, ``constructed``) keep their whole fits beside their records in the fold.
    """

    def __init__(self, machine: Any, prober: Any, probe: Callable[..., Any], *, part: Part | None = None,
                 session_dir: str | Path = "sessions", start_fields: Callable[[], dict[str, Any]] = dict,
                 lock: Any = None) -> None:
        self.machine = machine
        self.prober = prober
        self.config = machine.config
        self._probe = probe
        self._start_fields = start_fields
        self.lock = lock if lock is not None else threading.RLock()
        self.part = part
        self.state = SessionState()  # the fold of the events journalled (see new_part)
        self._undo: list[tuple[str, int]] = []
        self.features: dict[int, Feature] = {}
        self.constructed: dict[int, ConstructedFeature] = {}
        self.tolerancing = Tolerancing(self)  # datums and geometric tolerances
        self._next_hit = 1
        self._next_feature = 1
        self.last_hit: Any = None
        self.probe_name = ""  # the probe (stylus) in use: journalled with every hit and feature
        self.hit_probes: dict[int, str] = {}  # hit id -> the probe that took it
        self.events: list[tuple[float, str, str]] = []  # (time, kind, message) for the UI
        self._listeners: list[Callable[[str, Any], None]] = []
        self.holder_name: Callable[[], str | None] | None = None  # who holds control, for every record (``by``)
        self.session_dir = session_dir if is_url(session_dir) else Path(session_dir)  # or a postgresql:// URL
        self.journal: Any = None
        # the pose in force came from an alignment (the page's frame label). Not the fold's ``aligned``: that one
        # starts again with each part of a series (new_part), whose hits wait for that part's own alignment
        self.aligned = False
        self.alignment_name = ""  # the alignment in force, as the operator knows it ("3-2-1 TOP/FRONT/LEFT")
        self.trends: Any = None  # cmm.session.trends.Trends: each program run is recorded there as a part
        # writes a part's report beside its session journal (journal path, mesh=, title=) -> the report's path: a
        # routine's report step (the station gives cmm.session.report.write_part_report)
        self.reporter: Callable[..., Any] | None = None
        self._on_close: list[Callable[[], None]] = []

    @property
    def hits(self) -> dict[int, HitRecord]:
        """The active hits by id, in recording order (the fold's)."""
        return self.state.hits

    @property
    def deleted(self) -> dict[int, HitRecord]:
        """The deleted hits by id (undo or restore brings them back)."""
        return self.state.deleted_hits

    @property
    def datums(self) -> dict[str, dict[str, Any]]:
        """Datum definitions by label (:mod:`cmm.metrology.gdt_eval`)."""
        return self.state.datums

    @property
    def gdt(self) -> dict[int, dict[str, Any]]:
        """Geometric tolerance definitions by id."""
        return self.state.gdt

    @property
    def info(self) -> dict[str, Any]:
        """The report header: part number, drawing, operator, temperature ..."""
        return self.state.info

    # --- events -------------------------------------------------------------------

    def subscribe(self, fn: Callable[[str, Any], None]) -> Callable[[], None]:
        """Events: 'hit', 'hits', 'feature', 'features', 'part', 'info', plus the machine events the owner
        passes on ('mode', 'fault', 'stop', 'estop', 'contact', 'deadman', 'limit', 'homed', 'error' ...).
        Returns the function that ends the subscription (a page that closes, a wizard done with its hits)."""
        self._listeners.append(fn)
        return functools.partial(_discard, self._listeners, fn)

    def machine_event(self, kind: str, info: Any) -> None:
        """A control core event: journalled (stops, faults, contacts ...) and passed to the listeners."""
        if kind == "hit" and isinstance(info, dict):
            return  # the control core's hit event: add_hit has notified already, with the hit id
        if kind in MACHINE_EVENTS:
            from ..journal.wording import event_text

            text = event_text(kind, info)
            self.events.append((time.time(), kind, text))
            try:
                self.record("error" if kind in MACHINE_ERRORS else "event", source=f"machine:{kind}", message=text)
            except Exception:  # noqa: BLE001 - the session may be closing or the disk full; the event is still shown
                pass
        self._notify(kind, info)

    def use_probe(self, name: str) -> None:
        """The probe (stylus) in use from now on: its name is journalled with every hit and feature."""
        self.probe_name = str(name or "")

    def log(self, kind: str, message: str) -> None:
        """A line for the operator's event log (not journalled)."""
        self.events.append((time.time(), kind, message))

    def _notify(self, kind: str, info: Any) -> None:
        for fn in list(self._listeners):
            try:
                fn(kind, info)
            except Exception as exc:  # a broken listener must not stop the machine
                self.events.append((time.time(), "error", f"listener failed: {exc}"))

    # --- session -------------------------------------------------------------------

    def new_session(self, name: str | None = None) -> Path | str:
        """Open a new session journal (in ``session_dir``) with a ``start`` event: configuration and calibration.
        What was measured stays (the fold goes on; the new journal has it from its start on)."""
        return self._open_session(name, fresh=False)

    def _open_session(self, name: str | None, fresh: bool) -> Path | str:
        """A new journal; ``fresh``: the fold starts again with its ``start`` event (the report header kept)."""
        stamp = time.strftime("session-%Y%m%d-%H%M%S")
        name = stamp if name is None else check_name(name)  # whatever the caller: no "../x", no absolute paths
        with self.lock:
            if self.journal is not None:
                self.journal.close()
            self.journal, path = open_journal(self.session_dir, name, stamp)
            info = dict(self.info)
            if fresh:
                self.state = SessionState()
            self._start(self.journal, **self._start_fields())
            if info:
                self._append(self.journal, "info", **info)
            return path

    def new_part(self, name: str | None = None) -> Path | str:
        """A new session for the next part of a series (a DMIS program run again): its own journal, and the
        previous part's hits, features, datums and geometric tolerances put away (they stay in its journal), so
        this part's tree, characteristics and report have its own rows only. Ids go on counting."""
        with self.lock:
            path = self._open_session(name, fresh=True)  # hits, datums and tolerances: the fold starts again
            self._undo.clear()
            self.features.clear()
            self.constructed.clear()
            self.tolerancing.cache = None
            self.hit_probes.clear()
            self.last_hit = None
        self._notify("hits", None)
        self._notify("features", None)
        return path

    def record_into(self, writer: Any, **start: Any) -> None:
        """Journal into ``writer`` (a store's session writer), beginning with its ``start`` event."""
        with self.lock:
            self.journal = writer
            self._start(writer, **start)

    def _start(self, writer: Any, **start: Any) -> None:
        snapshot = machine_snapshot(self.config, self.machine.correction, self.prober.settings)
        self._append(writer, "start", **start_event(snapshot, self.part, start))

    def record(self, kind: str, **data: Any) -> None:
        """An event: in the session journal if one is open, and folded into :attr:`state` either way. With
        :attr:`holder_name` set (a station with users), each event says who held control (``by``)."""
        if self.holder_name is not None and "by" not in data:
            name = self.holder_name()
            if name:
                data["by"] = name
        with self.lock:
            self._append(self.journal, kind, **data)

    def _append(self, writer: Any, kind: str, **data: Any) -> dict:
        """Journal an event with ``writer`` (None: no journal) and fold it, as a reader of the journal gets it
        (lists, plain numbers), into :attr:`state`: the live state is the fold of the journal. An event the
        journal refuses (a disk full, a number that is not finite) is not folded."""
        if writer is not None:
            event = writer.append(kind, **data)
        else:
            event = {"seq": self.state.seq + 1, "time": time.time(), "kind": kind, **data}
        event = json.loads(encode_event(event))
        self.state.apply(event)
        return event

    def note(self, text: str) -> None:
        self.record("note", text=text)

    def set_info(self, **fields: Any) -> dict[str, Any]:
        """Report header fields (part_number, drawing, operator, machine_name, temperature in deg C, remarks)."""
        clean = clean_info(fields)
        with self.lock:
            self.record("info", **clean)
        self._notify("info", dict(self.info))
        return dict(self.info)

    def on_close(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` when the model closes, before its journal closes (detach a hit listener)."""
        self._on_close.append(fn)

    def close(self) -> None:
        for fn in self._on_close:
            fn()
        if self.journal is not None:
            self.journal.close()

    # --- part -------------------------------------------------------------------

    def load_part(self, path: str | Path, pose: np.ndarray | None = None, mesh: Any = None) -> Part:
        """The part ``path`` (a mesh or a CAD file; ``mesh``: that file already read) at ``pose`` (part -> machine)."""
        from ..metrology.mesh import load_part

        mesh = load_part(path) if mesh is None else mesh
        mesh.metadata["sha256"], mesh.metadata["path"] = file_sha256(path), str(Path(path).resolve())
        with self.lock:
            self.part = Part(Path(path).name, mesh, np.eye(4) if pose is None else np.asarray(pose, float))
            self.aligned = False
            self.record("part", name=self.part.name, pose=self.part.pose, sha256=mesh.metadata["sha256"],
                        path=mesh.metadata["path"])
        self._notify("part", self.part)
        return self.part

    def pick(self, origin: Any, direction: Any) -> tuple[PickResult, NominalFeature | None] | None:
        """Ray pick on the part: hit point and normal (machine coordinates) and a suggested nominal feature."""
        picked = self.pick_region(origin, direction)
        if picked is None:
            return None
        hit, suggestion = picked
        return hit, suggestion.feature if suggestion is not None else None

    def pick_region(self, origin: Any, direction: Any) -> tuple[PickResult, FeatureSuggestion | None] | None:
        """Ray pick on the part: the hit (machine coordinates) and the feature suggested for the surface it hit, with
        that surface's mesh faces (``face_ids``); None for the suggestion when none could be made."""
        if self.part is None:
            raise MeasurementError("no part is loaded")
        hit = pick(self.part.mesh, self.part.pose, origin, direction)
        if hit is None:
            return None
        try:
            suggestion = suggest_feature(self.part.mesh, hit.face_id, self.part.pose)
        except Exception:  # noqa: BLE001 - a suggestion is optional help
            suggestion = None
        return hit, suggestion

    def set_alignment(self, pose: Any, method: str = "manual", **info: Any) -> None:
        """Adopt a part -> machine pose from an alignment (3-2-1, best fit) and record it."""
        if self.part is None:
            raise MeasurementError("load a part before aligning it")
        with self.lock:
            self.part.pose = np.asarray(pose, dtype=np.float64).reshape(4, 4)
            self.aligned = True
            names = info.get("names") or ()
            self.alignment_name = f"{method} {'/'.join(str(n) for n in names)}".strip()
            self.record("alignment", pose=self.part.pose, method=method, **info)
        self._notify("part", self.part)

    def above_point(self, point: Any, normal: Any, clearance: float | None = None) -> np.ndarray:
        """The tip position ``clearance`` mm above a surface point along its normal."""
        clearance = self.config.probe.approach_distance + self.prober.settings.tip_radius if clearance is None else clearance
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        return np.asarray(point, float) + clearance * n

    def clearance_z(self, margin: float = 10.0) -> float:
        """A height that clears the part (its top + ``margin``), or the present height without a part."""
        if self.part is None:
            return float(self.machine.position[2])
        corners = np.array([[x, y, z] for x in self.part.mesh.bounds[:, 0] for y in self.part.mesh.bounds[:, 1]
                            for z in self.part.mesh.bounds[:, 2]])
        top = float((corners @ self.part.pose[:3, :3].T + self.part.pose[:3, 3])[:, 2].max())
        return min(top + margin + self.prober.settings.tip_radius, self.config.axis("z").max)

    # --- hits -----------------------------------------------------------------------

    def probe(self, point: Any, approach: Any, clearance_z: float | None = None, client: Any = None,
              hop_z: float | None = None) -> Any:
        """Programmed hit at a surface point; ``approach`` points into the surface. The rapid climbs to
        ``clearance_z`` (default: clear of the part) before it crosses; with ``hop_z`` it may go straight or over
        that lower height where the control core's rails prove it free of the part."""
        if clearance_z is None and self.part is not None:
            clearance_z = self.clearance_z()
        if hop_z is None:
            return self._probe(point, approach, clearance_z, client)
        return self._probe(point, approach, clearance_z, client, hop_z=hop_z)

    def probe_here(self, point: Any, normal: Any, client: Any = None) -> Any:
        """Probe a picked point along its (outward) mesh normal, via the clearance height."""
        return self.probe(point, -np.asarray(normal, float), client=client)

    def add_hit(self, hit: Any) -> int:
        """Record a hit: journalled before anyone is shown it; returns its session id. The model keeps it as a
        :class:`~cmm.journal.records.HitRecord` (the probe's hit with its id) the fold makes of the event, the
        record replay rebuilds."""
        with self.lock:
            hid = self._next_hit
            self._next_hit += 1
            self.record("hit", **HitRecord.of(hit, hid).to_event(), probe=self.probe_name, probe_data=self.probe_data())
            self.hit_probes[hid] = self.probe_name
            record = self.hits[hid]  # on disk before anyone is shown it
            self.last_hit = record
            self._undo.append(("add", hid))
        self._notify("hit", (hid, record))
        return hid

    def probe_data(self) -> dict[str, Any]:
        """The probe data in force now, as each hit journals it (:mod:`cmm.session.probe_used`): the tip radius,
        the pre-travel model and the date of the qualification they came from ("" never qualified)."""
        settings = self.prober.settings
        try:
            fields = self._start_fields()
        except Exception:  # noqa: BLE001 - a status that cannot be read: the radius and the model still go
            fields = {}
        cal = fields.get("calibration") if isinstance(fields.get("calibration"), dict) else None
        # None: no calibration service (a headless recording): the start snapshot's word stands
        qualified = None if cal is None else str((cal.get("probe") or {}).get("date") or "")
        return {"tip_radius": float(settings.tip_radius), "pretravel": settings.pretravel.describe(),
                "qualified": qualified}

    def hit_id(self, hit: Any) -> int:
        """The session id of a recorded hit (the record, or the probe's hit it was recorded from)."""
        if isinstance(hit, HitRecord):
            return hit.id
        key = (hit.time, tuple(hit.counts), tuple(hit.machine))
        with self.lock:
            for hid in reversed(list(self.hits)):
                h = self.hits[hid]
                if (h.time, tuple(h.counts), tuple(h.machine)) == key:
                    return hid
        raise MeasurementError("the hit was not recorded")

    def delete_hit(self, hid: int) -> None:
        with self.lock:
            if hid not in self.hits:
                raise MeasurementError(f"there is no hit {hid}")
            self.record("hit_deleted", id=hid)
            self._undo.append(("delete", hid))
        self._notify("hits", None)

    def undo(self) -> str:
        """Undo the last hit added or deleted."""
        with self.lock:
            if not self._undo:
                raise MeasurementError("nothing to undo")
            action, hid = self._undo[-1]
            if action == "add":
                self.record("hit_deleted", id=hid, undo=True)
                message = f"removed hit {hid}"
            else:
                self.record("hit_restored", id=hid, undo=True)
                message = f"restored hit {hid}"
            self._undo.pop()  # journalled: undone
        self._notify("hits", None)
        return message

    def hit_deviations(self) -> dict[int, float]:
        """Signed deviation of each compensated hit from the part mesh (+ = material outside nominal)."""
        with self.lock:
            items = list(self.hits.items())
        if self.part is None or not items:
            return {}
        result = signed_deviation(self.part.mesh, np.array([h.point for _, h in items]), self.part.pose)
        return {hid: float(d) for (hid, _), d in zip(items, result.deviations)}

    # --- features ----------------------------------------------------------------

    def fit_feature(self, kind: str, hit_ids: list[int], method: str = "ls", name: str | None = None,
                    nominal: NominalFeature | None = None, tolerance: dict[str, float] | None = None,
                    *, feature_id: int | None = None) -> Feature:
        """Fit a feature to hits: fit the pre-travel-corrected tip centres, then offset by the tip radius.

        Without a ``nominal`` the part's CAD surface the hits lie on gives it
        (:func:`cmm.metrology.nominal_match.nominal_for_points`). ``feature_id``
        refits an existing feature in place (a hit deleted or re-taken).
        """
        tolerance = check_tolerance(tolerance)
        if kind not in FEATURE_KINDS:
            raise MeasurementError(f"unknown feature kind {kind!r}; choose one of {', '.join(FEATURE_KINDS)}")
        with self.lock:
            missing = [h for h in hit_ids if h not in self.hits]
            if missing:
                raise MeasurementError(f"no hits with ids {missing}")
            hits = [self.hits[h] for h in hit_ids]
        part = self.part
        if nominal is None and part is not None:
            from ..metrology.nominal_match import nominal_for_points

            try:
                nominal = nominal_for_points(part.mesh, part.pose, [h.point for h in hits], kind)
            except Exception:  # noqa: BLE001 - a nominal is help; the fit stands without one
                nominal = None
        try:
            result = fit_hit_records(kind, method, hits, self.prober.settings, nominal)
        except FitError as exc:
            raise MeasurementError(str(exc)) from None
        from ..metrology.uncertainty import feature_budget
        from ..metrology.uncertainty_inputs import model_sources

        origin = None if part is None else tuple(np.asarray(part.pose, float)[:3, 3])
        budget = feature_budget(kind, method, np.array([h.point for h in hits], float).reshape(-1, 3), result,
                                model_sources(self, origin))
        with self.lock:
            if feature_id is None:
                fid = self._next_feature
                self._next_feature += 1
            else:
                fid = feature_id
            feature = Feature(fid, name or f"{kind} {fid}", kind, method, list(hit_ids), result, nominal, tolerance,
                              budget)
            self._record_feature(feature)
            self.features[fid] = feature
        self._notify("feature", feature)
        return feature

    def feature_probe(self, feature: Any) -> str:
        """The probe(s) whose hits a feature was fitted to ("T1", or "T1+T2" for hits of several tips)."""
        names = sorted({self.hit_probes.get(h, "") for h in getattr(feature, "hit_ids", ())} - {""})
        return "+".join(names)

    def _record_feature(self, feature: Feature) -> None:
        self.record("feature", **feature.record(self.feature_probe(feature)).to_event())

    def refit_feature(self, fid: int, hit_ids: list[int]) -> Feature:
        """Fit feature ``fid`` again to other hits (one deleted or re-taken); keeps its name, nominal, tolerance."""
        with self.lock:
            f = self.features.get(fid)
            if f is None:
                raise MeasurementError(f"there is no feature {fid}")
        return self.fit_feature(f.kind, list(hit_ids), f.method, f.name, f.nominal, f.tolerance, feature_id=fid)

    def set_feature_nominal(self, fid: int, nominal: NominalFeature | None = None,
                            tolerance: dict[str, float] | None = None) -> Feature:
        """Edit a feature's nominal and/or tolerance (typed or from a CAD pick); recorded as a new fit event."""
        tolerance = check_tolerance(tolerance)
        with self.lock:
            f = self.features.get(fid)
            if f is None:
                raise MeasurementError(f"there is no feature {fid}")
            if nominal is not None:
                f.nominal = nominal
            if tolerance is not None:
                f.tolerance = {**(f.tolerance or {}), **tolerance}
            self._record_feature(f)
        self._notify("feature", f)
        return f

    def construct_feature(self, operation: str, a: int, b: int, name: str | None = None,
                          tolerance: dict[str, float] | None = None, three_d: bool = False) -> ConstructedFeature:
        """Construct a feature from features ``a`` and ``b`` (see :mod:`cmm.metrology.construct`): distances
        between parallel axes along the alignment's Z in its XY plane, or in 3-D with ``three_d``."""
        tolerance = check_tolerance(tolerance)
        with self.lock:
            fa, fb = self.features.get(a), self.features.get(b)
            if fa is None or fb is None:
                raise MeasurementError(f"there is no feature {a if fa is None else b}")
            if a == b:
                raise MeasurementError("a construction needs two different features")
            # the alignment's Z in machine coordinates (the nominal set-up's without an alignment)
            workplane = None if self.part is None else np.asarray(self.part.pose, float)[:3, 2]
        result, nominal = construct_pair(operation, fa, fb, workplane, three_d)
        with self.lock:
            fid = self._next_feature
            self._next_feature += 1
            feature = ConstructedFeature(fid, name or f"{operation} {fa.name} / {fb.name}", operation, (a, b), result,
                                         nominal, tolerance)
            self.record("constructed", **feature.record().to_event())
            self.constructed[fid] = feature
        self._notify("feature", feature)
        return feature

    # --- datums and geometric tolerances (ISO 1101 / ASME Y14.5): cmm.measurement.tolerancing --------------

    def measured_features(self) -> dict[int, Any]:
        """The fitted features as :class:`cmm.metrology.gdt_eval.MeasuredFeature` (geometry, nominal, points)."""
        return self.tolerancing.measured_features()

    def gdt_characteristics(self, definitions: list[dict[str, Any]] | None = None) -> list[tuple[dict, Any]]:
        """(definition, Characteristic) of every geometric tolerance (or of ``definitions``)."""
        return self.tolerancing.gdt_characteristics(definitions)

    def define_datum(self, label: str, feature_id: int, modifier: str = "", targets: Any = None) -> dict[str, Any]:
        """Make feature ``feature_id`` datum ``label`` (:meth:`Tolerancing.define_datum`); journalled."""
        return self.tolerancing.define_datum(label, feature_id, modifier, targets)

    def define_gdt(self, characteristic: str, feature_id: int, tolerance: float, datums: Any = (),
                   **options: Any) -> tuple[dict[str, Any], Any]:
        """Define (or with ``gdt_id`` replace) a geometric tolerance (:meth:`Tolerancing.define_gdt`);
        journalled; returns (definition, its first Characteristic)."""
        return self.tolerancing.define_gdt(characteristic, feature_id, tolerance, datums, **options)

    def delete_gdt(self, gid: int) -> None:
        self.tolerancing.delete_gdt(gid)

    def delete_feature(self, fid: int) -> None:
        with self.lock:
            if fid not in self.constructed and fid not in self.features:
                raise MeasurementError(f"there is no feature {fid}")
            self.record("feature_deleted", id=fid)
            self.constructed.pop(fid, None)
            self.features.pop(fid, None)
        self._notify("features", None)


def _discard(items: list[Any], item: Any) -> None:
    """Remove ``item`` from ``items`` if it is there (a subscription ended twice is ended once)."""
    with contextlib.suppress(ValueError):
        items.remove(item)

"""A measurement session rebuilt from its journal events.

Event kinds (every event also has ``seq``, ``time`` and ``kind``):

- ``start``: the machine and probe snapshot the session was recorded with:
  ``config`` (file name), ``port``, ``tip_radius``, ``pretravel`` (model
  coefficients), ``part``/``part_pose``/``part_sha256`` and, since format 2,
  ``format``, ``calibration`` (the records in force: ``probe`` / ``machine``
  each with ``date`` and their figures, or None), ``axes`` (name, counts_per_mm, direction, home, min, max per
  axis), ``correction`` (scale_ppm, squareness_urad), ``probe`` (the
  configured probe) and ``speeds``; a derived session adds ``derived_from``.
- ``part``: ``name``, ``pose`` (4x4 part -> machine), ``sha256``, ``path``.
- ``alignment``: ``pose`` (4x4 part -> machine), ``method``, optional
  ``rms``, ``max_residual``, ``hit_ids``.
- ``hit``: ``id``, ``counts`` (raw latched encoder counts, the truth),
  ``machine`` (tip centre mm), ``approach``, ``speed``, ``hit_time``,
  ``point`` (compensated surface point), ``mode``, optional ``normal``.
- ``hit_deleted`` / ``hit_restored``: ``id`` (and ``undo``).
- ``feature``: ``id``, ``name``, ``feature_kind``, ``method``, ``hit_ids``,
  the fit summary (``n_points``, ``form``, ``sigma`` and geometry such as
  ``point``, ``normal``, ``center``, ``radius``, ``diameter``...), ``nominal``
  (machine coordinates), optional ``tolerance`` ({"size", "form", "location"}) and ``probe`` (the probe(s)
  that took its hits). :class:`FeatureRecord` reads and writes it.
- ``constructed``: ``id``, ``name``, ``operation`` (intersection, distance,
  angle, midpoint), ``operands`` (feature ids), ``result`` and ``nominal``
  ({"kind": point/line/distance/angle, geometry or ``value``}), ``tolerance``.
- ``feature_deleted``: ``id`` (a fitted or constructed feature).
- ``datum``: ``label`` (A, B ...), ``feature`` (its datum feature's id, None: the label is removed),
  ``modifier`` ("", "MMB", "LMB").
- ``gdt``: a geometric tolerance (feature control frame): ``id``, ``name``, ``characteristic``, ``feature``,
  ``tolerance``, ``datums`` (labels in precedence order), ``material``, ``angle``, ``direction``
  (see :mod:`cmm.metrology.gdt_eval`); ``gdt_deleted``: ``id``. Later events with the same id replace it.
- ``info``: the report header an operator filled in: any of ``part_number``,
  ``drawing``, ``operator``, ``machine_name``, ``temperature`` (deg C), ``remarks``;
  later events update earlier ones.
- ``note``: ``text``. ``error``: ``message`` and ``source`` (e.g. "machine:limit").
- ``program``: ``name``, ``sha256`` of a program that ran (``status``).

Unknown kinds are kept in ``events`` and otherwise ignored, so newer
journals open in older readers.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from typing import Any, Iterable

import numpy as np

from ..machine.probing import Hit
from ..metrology.characteristics import DEFAULT_TOLERANCE, Characteristic, characteristics, constructed_characteristics

FORMAT = 2


@dataclass(frozen=True)
class HitRecord(Hit):
    """A recorded hit: the probe's :class:`~cmm.machine.probing.Hit` with its session id and journal position.
    The one hit type: the measurement model keeps these, replay and re-evaluation rebuild them from the journal."""

    id: int = 0
    seq: int = 0

    @classmethod
    def from_event(cls, e: dict) -> "HitRecord":
        return cls(counts=tuple(int(c) for c in e["counts"]), machine=tuple(e["machine"]),  # type: ignore[arg-type]
                   approach=tuple(e["approach"]), speed=float(e.get("speed", 0.0)),  # type: ignore[arg-type]
                   time=float(e.get("hit_time", e.get("time", 0.0))), point=tuple(e["point"]),  # type: ignore[arg-type]
                   mode=e.get("mode", "programmed"), normal=None if e.get("normal") is None else tuple(e["normal"]),  # type: ignore[arg-type]
                   id=int(e["id"]), seq=int(e.get("seq", 0)))

    @classmethod
    def of(cls, hit: Hit, id: int, seq: int = 0) -> "HitRecord":
        """The probe's hit as recorded under session id ``id``."""
        return cls(counts=hit.counts, machine=hit.machine, approach=hit.approach, speed=hit.speed, time=hit.time,
                   point=hit.point, mode=hit.mode, normal=hit.normal, id=int(id), seq=int(seq))

    def to_event(self) -> dict:
        return {"id": self.id, "counts": list(self.counts), "machine": list(self.machine),
                "approach": list(self.approach), "speed": self.speed, "hit_time": self.time,
                "point": list(self.point), "mode": self.mode, "normal": None if self.normal is None else list(self.normal)}


_FEATURE_META = ("seq", "time", "recorded_time", "kind", "id", "name", "feature_kind", "method", "hit_ids", "nominal",
                 "tolerance", "probe")


@dataclass(frozen=True)
class FeatureRecord:
    """A fitted feature as the journal records it: the one feature type of the report, replay and re-evaluation.

    The measurement model's live :class:`cmm.measurement.model.Feature` (which keeps the whole fit: residuals,
    covariance, the better-fitting alternative) gives its record with ``Feature.record()``; the model journals
    ``record.to_event()`` and replay rebuilds it with :meth:`from_event`, so both sides read the same fields.
    """

    id: int
    seq: int
    name: str
    kind: str
    method: str
    hit_ids: tuple[int, ...]
    fit: dict[str, Any]  # n_points, form, sigma and the geometry (diameter, center, ...): FitResult.summary()
    nominal: dict[str, Any] | None = None  # NominalFeature.to_dict() in machine coordinates
    tolerance: dict[str, float] | None = None
    probe: str | None = None  # the probe(s) whose hits it was fitted to ("T1", "T1+T2"); None: not recorded

    @classmethod
    def of(cls, result: Any, *, id: int, name: str, hit_ids: Iterable[int], kind: str | None = None,
           nominal: dict[str, Any] | None = None, tolerance: dict[str, float] | None = None,
           probe: str | None = None, seq: int = 0) -> "FeatureRecord":
        """The record of a fit (a :class:`cmm.metrology.features.FitResult`); ``kind``: the fit's own
        unless given."""
        fit = result.summary()
        fit_kind, method = fit.pop("kind"), fit.pop("method")
        return cls(int(id), int(seq), str(name), kind or fit_kind, method, tuple(int(h) for h in hit_ids), fit,
                   nominal, tolerance, probe)

    @classmethod
    def from_event(cls, e: dict) -> "FeatureRecord":
        fit = {k: v for k, v in e.items() if k not in _FEATURE_META}
        return cls(int(e["id"]), int(e.get("seq", 0)), str(e.get("name", f"feature {e['id']}")),
                   str(e.get("feature_kind", "")), str(e.get("method", "ls")), tuple(int(h) for h in e.get("hit_ids", ())),
                   fit, e.get("nominal"), e.get("tolerance"), e.get("probe"))

    def to_event(self) -> dict:
        """The ``feature`` event's fields (without seq, time, kind)."""
        out = {"id": self.id, "name": self.name, "hit_ids": list(self.hit_ids), "feature_kind": self.kind,
               "method": self.method, **self.fit, "nominal": self.nominal}
        if self.tolerance is not None:
            out["tolerance"] = self.tolerance
        if self.probe is not None:
            out["probe"] = self.probe
        return out

    def nominal_feature(self) -> Any:
        """The nominal it was fitted with as a :class:`cmm.metrology.pick.NominalFeature` (its start values), or
        None."""
        if not self.nominal or "kind" not in self.nominal:
            return None
        from ..metrology.pick import NominalFeature

        return NominalFeature(self.nominal["kind"], {k: v for k, v in self.nominal.items() if k != "kind"})

    def characteristics(self, tolerance: dict[str, float] | None = None) -> list[Characteristic]:
        """Its toleranced characteristics (:func:`cmm.metrology.characteristics.characteristics`), as the
        report, the trends and the feature tree show them, at ``tolerance`` (its own when not given; over the
        defaults)."""
        return characteristics(self.name, self.kind, self.fit, self.nominal,
                               self.tolerance if tolerance is None else tolerance)

    def measured(self, hits: dict[int, Any], tolerance: dict[str, float] | None = None) -> Any:
        """The feature as geometric tolerances evaluate it (:class:`cmm.metrology.gdt_eval.MeasuredFeature`),
        with the points of its hits among ``hits`` (id -> hit, deleted ones too: a feature keeps its hits);
        ``tolerance``: its own when not given, over the defaults (the size's limits)."""
        from ..metrology.gdt_eval import MeasuredFeature

        pts = np.array([hits[h].point for h in self.hit_ids if h in hits], float).reshape(-1, 3)
        tol = {**DEFAULT_TOLERANCE, **((self.tolerance if tolerance is None else tolerance) or {})}
        return MeasuredFeature(self.name, self.kind, self.fit, self.nominal, pts, float(tol["size"]),
                               tuple(h for h in self.hit_ids if h in hits), tol.get("size_lower"),
                               tol.get("size_upper"))


@dataclass(frozen=True)
class ConstructedRecord:
    """A constructed feature as the journal records it (``constructed`` events): the live
    :class:`cmm.measurement.model.ConstructedFeature` gives it with ``record()``, replay rebuilds it."""

    id: int
    seq: int
    name: str
    operation: str  # intersection, distance, angle, midpoint (cmm.metrology.construct)
    operands: tuple[int, ...]  # the feature ids it was constructed from
    result: dict[str, Any]  # Constructed.summary(): {"kind": point/line/distance/angle, geometry or "value"}
    nominal: dict[str, Any] | None = None  # the same construction on the operands' nominals
    tolerance: dict[str, float] | None = None

    @classmethod
    def from_event(cls, e: dict) -> "ConstructedRecord":
        return cls(int(e["id"]), int(e.get("seq", 0)), str(e.get("name", f"construction {e['id']}")),
                   str(e.get("operation", "")), tuple(int(i) for i in e.get("operands", ())), e.get("result") or {},
                   e.get("nominal"), e.get("tolerance"))

    def to_event(self) -> dict:
        """The ``constructed`` event's fields (without seq, time, kind)."""
        return {"id": self.id, "name": self.name, "operation": self.operation, "operands": list(self.operands),
                "result": self.result, "nominal": self.nominal, "tolerance": self.tolerance}

    def characteristics(self, tolerance: dict[str, float] | None = None) -> list[Characteristic]:
        """Its toleranced characteristics (:func:`cmm.metrology.characteristics.constructed_characteristics`) at
        ``tolerance`` (its own when not given; over the defaults)."""
        return constructed_characteristics(self.name, self.result, self.nominal,
                                           self.tolerance if tolerance is None else tolerance)


@dataclass(frozen=True)
class PartRef:
    name: str
    sha256: str | None
    pose: tuple[tuple[float, ...], ...]
    path: str | None = None

    @property
    def pose_array(self) -> np.ndarray:
        return np.array(self.pose, dtype=np.float64)


@dataclass(frozen=True)
class AlignmentRecord:
    seq: int
    method: str
    pose: tuple[tuple[float, ...], ...]
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def pose_array(self) -> np.ndarray:
        return np.array(self.pose, dtype=np.float64)


def _pose(value: Any) -> tuple[tuple[float, ...], ...] | None:
    if value is None:
        return None
    a = np.asarray(value, dtype=np.float64).reshape(4, 4)
    return tuple(tuple(float(x) for x in row) for row in a)


@dataclass
class SessionState:
    """What was known after a given event: the scrubber's view of a session."""

    index: int = -1  # index of the last applied event in the event list (-1: none yet)
    seq: int = 0
    time: float | None = None
    hits: dict[int, HitRecord] = field(default_factory=dict)  # active hits by id, in recording order
    deleted_hits: dict[int, HitRecord] = field(default_factory=dict)
    features: dict[int, FeatureRecord] = field(default_factory=dict)
    part: PartRef | None = None
    part_pose: tuple[tuple[float, ...], ...] | None = None  # the current part -> machine pose (alignment)
    alignments: list[AlignmentRecord] = field(default_factory=list)
    notes: list[tuple[int, str]] = field(default_factory=list)  # (seq, text)
    errors: list[tuple[int, str]] = field(default_factory=list)
    # part pose per hit: the alignment in force when it was taken; hits taken before the first
    # alignment of a part get that alignment (it is the best knowledge of where that part is)
    hit_pose: dict[int, tuple[tuple[float, ...], ...] | None] = field(default_factory=dict)
    unaligned: list[int] = field(default_factory=list)
    aligned: bool = False  # an alignment was made since the part was (re)loaded
    info: dict[str, Any] = field(default_factory=dict)  # report header fields (``info`` events)
    constructed: dict[int, ConstructedRecord] = field(default_factory=dict)  # constructed features by id
    datums: dict[str, dict] = field(default_factory=dict)  # ``datum`` definitions by label
    gdt: dict[int, dict] = field(default_factory=dict)  # ``gdt`` definitions by id
    last_event: dict | None = None

    def copy(self) -> "SessionState":
        """An independent copy (records are immutable, so shallow container copies suffice)."""
        return replace(self, hits=dict(self.hits), deleted_hits=dict(self.deleted_hits), features=dict(self.features),
                       alignments=list(self.alignments), notes=list(self.notes), errors=list(self.errors),
                       hit_pose=dict(self.hit_pose), unaligned=list(self.unaligned), info=dict(self.info),
                       constructed=dict(self.constructed), datums=dict(self.datums), gdt=dict(self.gdt))

    @property
    def pose_array(self) -> np.ndarray | None:
        return None if self.part_pose is None else np.array(self.part_pose, dtype=np.float64)

    @property
    def alignment(self) -> AlignmentRecord | None:
        return self.alignments[-1] if self.alignments else None

    def points(self, ids: Iterable[int] | None = None) -> np.ndarray:
        """Compensated points (n x 3, machine mm) of the active hits (or of ``ids``)."""
        recs = self.hits.values() if ids is None else [self.hits.get(i) or self.deleted_hits[i] for i in ids]
        return np.array([h.point for h in recs], dtype=np.float64).reshape(-1, 3)

    def apply(self, event: dict, index: int | None = None) -> None:
        kind = event.get("kind")
        self.index = self.index + 1 if index is None else index
        self.seq = int(event.get("seq", self.seq + 1))
        self.time = event.get("time", self.time)
        self.last_event = event
        if kind == "start":
            if event.get("part") is not None:
                self.part = PartRef(str(event["part"]), event.get("part_sha256"), _pose(event.get("part_pose")) or _pose(np.eye(4)),  # type: ignore[arg-type]
                                    event.get("part_path"))
            self.part_pose = _pose(event.get("part_pose"))
        elif kind == "part":
            pose = _pose(event.get("pose")) or _pose(np.eye(4))
            self.part = PartRef(str(event.get("name")), event.get("sha256"), pose, event.get("path"))  # type: ignore[arg-type]
            self.part_pose = pose
            self.unaligned = []
            self.aligned = False
        elif kind == "alignment":
            pose = _pose(event["pose"])
            info = {k: v for k, v in event.items() if k not in ("seq", "time", "kind", "pose", "method")}
            self.alignments.append(AlignmentRecord(self.seq, str(event.get("method", "manual")), pose, info))  # type: ignore[arg-type]
            self.part_pose = pose
            for hid in self.unaligned:
                self.hit_pose[hid] = pose
            self.unaligned = []
            self.aligned = True
        elif kind == "hit":
            rec = HitRecord.from_event(event)
            self.hits[rec.id] = rec
            self.deleted_hits.pop(rec.id, None)
            self.hit_pose[rec.id] = self.part_pose
            if not self.aligned:
                self.unaligned.append(rec.id)
        elif kind == "hit_deleted":
            hid = int(event["id"])
            if hid in self.hits:
                self.deleted_hits[hid] = self.hits.pop(hid)
        elif kind == "hit_restored":
            hid = int(event["id"])
            if hid in self.deleted_hits:
                self.hits[hid] = self.deleted_hits.pop(hid)
                self.hits = dict(sorted(self.hits.items()))
        elif kind == "feature":
            rec = FeatureRecord.from_event(event)
            self.features[rec.id] = rec
        elif kind == "constructed":
            rec_c = ConstructedRecord.from_event(event)
            self.constructed[rec_c.id] = rec_c
        elif kind == "feature_deleted":
            self.features.pop(int(event["id"]), None)
            self.constructed.pop(int(event["id"]), None)
        elif kind == "datum":
            label = str(event.get("label", ""))
            if event.get("feature") is None:
                self.datums.pop(label, None)
            else:
                self.datums[label] = {k: v for k, v in event.items() if k not in ("seq", "time", "kind")}
        elif kind == "gdt":
            self.gdt[int(event["id"])] = {k: v for k, v in event.items() if k not in ("seq", "time", "kind")}
        elif kind == "gdt_deleted":
            self.gdt.pop(int(event["id"]), None)
        elif kind == "info":
            self.info.update({k: v for k, v in event.items() if k not in ("seq", "time", "kind")})
        elif kind == "note":
            self.notes.append((self.seq, str(event.get("text", ""))))
        elif kind == "error":
            self.errors.append((self.seq, str(event.get("message", ""))))


@dataclass
class Session:
    """A whole session: its events, the final state and the recorded configuration."""

    name: str
    events: list[dict]
    damage: str | None = None
    state: SessionState = field(default_factory=SessionState)

    @classmethod
    def from_events(cls, events: list[dict], name: str = "session", damage: str | None = None) -> "Session":
        state = SessionState()
        for i, e in enumerate(events):
            state.apply(e, i)
        return cls(name, list(events), damage, state)

    # --- recorded configuration ------------------------------------------------

    @property
    def start(self) -> dict:
        for e in self.events:
            if e.get("kind") == "start":
                return e
        return {}

    @property
    def hits(self) -> dict[int, HitRecord]:
        return self.state.hits

    @property
    def features(self) -> dict[int, FeatureRecord]:
        return self.state.features

    @property
    def part(self) -> PartRef | None:
        return self.state.part

    @property
    def derived_from(self) -> dict | None:
        return self.start.get("derived_from")

    def axes(self) -> list[dict]:
        """Per-axis counts -> mm configuration as recorded (older journals: the shipped default, with a warning)."""
        axes = self.start.get("axes")
        if axes:
            return axes
        from ..machine.config import load

        cfg = load()
        return [axis_snapshot(a) for a in cfg.axes]

    @property
    def warnings(self) -> list[str]:
        out = []
        if self.damage:
            out.append(self.damage)
        if self.events and not self.start.get("axes"):
            out.append("this journal does not record the axis configuration; "
                       "counts are converted with the shipped default machine.toml")
        return out

    def correction(self) -> dict:
        return self.start.get("correction") or {"scale_ppm": [0.0, 0.0, 0.0], "squareness_urad": [0.0, 0.0, 0.0]}

    def probe_settings(self) -> Any:
        """The ProbeSettings (tip radius + pre-travel model) the session was recorded with."""
        from ..machine.probing import ProbeSettings
        from ..metrology.compensation import PretravelModel

        s = self.start
        return ProbeSettings(float(s.get("tip_radius", 1.0)), PretravelModel(dict(s.get("pretravel") or {})))

    def counts_to_mm(self, counts: Any) -> np.ndarray:
        """Raw counts (n x 3) -> machine mm through the recorded axis config and geometry correction."""
        return counts_to_mm(counts, self.axes(), self.correction())

    def summary(self) -> dict[str, Any]:
        s = self.state
        return {"name": self.name, "events": len(self.events), "hits": len(s.hits), "deleted_hits": len(s.deleted_hits),
                "features": len(s.features), "alignments": len(s.alignments), "notes": len(s.notes),
                "errors": len(s.errors), "part": None if s.part is None else s.part.name,
                "part_sha256": None if s.part is None else s.part.sha256,
                "started": self.events[0].get("time") if self.events else None,
                "ended": self.events[-1].get("time") if self.events else None,
                "derived_from": self.derived_from, "damage": self.damage}


# --- snapshots and helpers used by the measurement model --------------------


def axis_snapshot(axis: Any) -> dict:
    return {"name": axis.name, "counts_per_mm": axis.counts_per_mm, "direction": axis.direction,
            "home": axis.home, "min": axis.min, "max": axis.max}


def machine_snapshot(config: Any, correction: Any = None, settings: Any = None) -> dict:
    """The configuration + calibration fields of a ``start`` event (JSON-ready)."""
    out: dict[str, Any] = {
        "format": FORMAT,
        "config": config.source,
        "axes": [axis_snapshot(a) for a in config.axes],
        "probe": {k: getattr(config.probe, k) for k in ("input", "active_level", "tip_radius", "pretravel",
                                                        "approach_distance", "search_distance", "retract_distance")},
        "speeds": {k: getattr(config.speeds, k) for k in ("positioning", "probing")},
    }
    if correction is not None:
        out["correction"] = {"scale_ppm": list(correction.scale_ppm), "squareness_urad": list(correction.squareness_urad)}
    if settings is not None:
        out["tip_radius"] = settings.tip_radius
        out["pretravel"] = dict(settings.pretravel.coefficients)
    return out


def counts_to_mm(counts: Any, axes: list[dict], correction: dict | None = None) -> np.ndarray:
    from ..machine.geometry import geometry_matrix

    c = np.atleast_2d(np.asarray(counts, dtype=np.float64))
    readings = np.column_stack([a["home"] + c[:, i] / (a["counts_per_mm"] * a["direction"]) for i, a in enumerate(axes)])
    if correction and (any(correction.get("scale_ppm", ())) or any(correction.get("squareness_urad", ()))):
        m = geometry_matrix(tuple(correction["scale_ppm"]), tuple(correction["squareness_urad"]))
        readings = readings @ m.T
    return readings


def mesh_sha256(mesh: Any) -> str:
    """Content hash of a mesh: the file's sha256 if it was loaded from a file
    (``mesh.metadata['sha256']``), else sha256 of its float64 vertices and int64 faces."""
    meta = getattr(mesh, "metadata", None) or {}
    if meta.get("sha256"):
        return str(meta["sha256"])
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.vertices, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype="<i8").tobytes())
    return h.hexdigest()


def file_sha256(path: Any) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()

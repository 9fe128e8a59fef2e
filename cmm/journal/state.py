"""The fold of a session journal's events: what was known after each event (:class:`SessionState`).

The live measurement model (:class:`cmm.measurement.model.MeasurementModel`) folds every event it journals
into its own state with :meth:`SessionState.apply`; replay, re-evaluation, the report and the scrubber fold a
journal file's events (:class:`cmm.journal.session.Session`) with the same ``apply``, so an event means one thing.

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
  ``point`` (compensated surface point), ``mode``, optional ``normal`` and ``probe`` (the stylus).
- ``hit_deleted`` / ``hit_restored``: ``id`` (and ``undo``).
- ``feature``: ``id``, ``name``, ``feature_kind``, ``method``, ``hit_ids``,
  the fit summary (``n_points``, ``form``, ``sigma`` and geometry such as
  ``point``, ``normal``, ``center``, ``radius``, ``diameter``...), ``nominal``
  (machine coordinates), optional ``tolerance`` ({"size", "form", "location"}) and ``probe`` (the probe(s)
  that took its hits). :class:`~cmm.journal.records.FeatureRecord` reads and writes it.
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

Unknown kinds are kept in a session file's ``events`` and otherwise ignored by the fold, so newer
journals open in older readers.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Iterable

import numpy as np

from .records import AlignmentRecord, ConstructedRecord, FeatureRecord, HitRecord, PartRef


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

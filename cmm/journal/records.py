"""The records the session journal's events hold: hits, fitted and constructed features, the part, alignments.

Each record reads its event (``from_event``) and, where the measurement model journals it, writes it
(``to_event``), so the live model, replay, re-evaluation and the report read the same fields. The fold of the
events into these records is :class:`cmm.journal.state.SessionState`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from ..machine.probing import Hit
from ..metrology.characteristics import DEFAULT_TOLERANCE, Characteristic, characteristics, constructed_characteristics


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
                 "tolerance", "probe", "by")  # by: the person who held control (a station with users)


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
        out = characteristics(self.name, self.kind, self.fit, self.nominal,
                              self.tolerance if tolerance is None else tolerance)
        from dataclasses import replace

        expanded = (self.fit.get("budget") or {}).get("U")
        if not expanded:
            why = (f"no uncertainty: the budget is defined for least-squares fits only (this one: {self.method})"
                   if self.method != "ls" else f"no uncertainty: no budget for this {self.kind} (too few hits, or "
                                               "recorded before the station kept one)")
            return [replace(c, uncertainty_why=why) for c in out]
        from ..metrology.uncertainty import characteristic_k, characteristic_u

        budget = self.fit.get("budget")
        out = [replace(c, uncertainty=characteristic_u(c.name, expanded), uncertainty_k=characteristic_k(c.name, budget))
               for c in out]
        return [c if c.uncertainty is not None else
                replace(c, uncertainty_why=f"no uncertainty: the budget has no term for the {c.name}") for c in out]

    def measured(self, hits: dict[int, Any], tolerance: dict[str, float] | None = None) -> Any:
        """The feature as geometric tolerances evaluate it (:class:`cmm.metrology.gdt_eval.MeasuredFeature`),
        with the points of its hits among ``hits`` (id -> hit, deleted ones too: a feature keeps its hits);
        ``tolerance``: its own when not given, over the defaults (the size's limits)."""
        from ..metrology.gdt_eval import MeasuredFeature

        pts = np.array([hits[h].point for h in self.hit_ids if h in hits], float).reshape(-1, 3)
        tol = {**DEFAULT_TOLERANCE, **((self.tolerance if tolerance is None else tolerance) or {})}
        return MeasuredFeature(self.name, self.kind, self.fit, self.nominal, pts, float(tol["size"]),
                               tuple(h for h in self.hit_ids if h in hits), tol.get("size_lower"),
                               tol.get("size_upper"), self.fit.get("alternative") or None,
                               self.fit.get("budget") or None)


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

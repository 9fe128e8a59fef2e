"""A session journal file: its events, their fold (:class:`cmm.journal.state.SessionState`) and the
configuration it was recorded with (the ``start`` event); the snapshot helpers the measurement model writes the
``start`` event with. The event kinds are listed in :mod:`cmm.journal.state`.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..machine.config import AxisConfig, counts_to_mm, load
from ..machine.geometry import GeometryCorrection
from .records import FeatureRecord, HitRecord, PartRef
from .state import SessionState

FORMAT = 2


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
        return [a.snapshot() for a in load().axes]

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
        c = self.correction()
        return counts_to_mm(np.atleast_2d(np.asarray(counts, dtype=np.float64)),
                            [AxisConfig.from_snapshot(a) for a in self.axes()],
                            GeometryCorrection(tuple(c.get("scale_ppm") or (0.0, 0.0, 0.0)),
                                               tuple(c.get("squareness_urad") or (0.0, 0.0, 0.0))))

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


def machine_snapshot(config: Any, correction: Any = None, settings: Any = None) -> dict:
    """The configuration + calibration fields of a ``start`` event (JSON-ready)."""
    out: dict[str, Any] = {
        "format": FORMAT,
        "config": config.source,
        "axes": [a.snapshot() for a in config.axes],
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

"""Read-only queries of the measurement model for every front end (the OPC UA server, scripts): snapshots that
change nothing, registered on the command API beside the measurement verbs (``query=True``: open to every
client, anonymous observers too)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class ModelSnapshot:
    """The measurement model at one moment, copied under the model's lock: its hits (id -> HitRecord), the hits
    deleted (undo brings them back), fitted features and constructions (id -> the model's feature
    objects, as a copy of the dicts under the lock gave them), the part and the last hit. Front ends draw from it and never take the lock
    themselves; an in-process query (the objects are the model's records, not JSON)."""

    hits: dict[int, Any] = field(default_factory=dict)
    deleted: dict[int, Any] = field(default_factory=dict)
    features: dict[int, Any] = field(default_factory=dict)
    constructed: dict[int, Any] = field(default_factory=dict)
    part: Any = None
    last_hit: Any = None

    def hit_or_deleted(self) -> dict[int, Any]:
        """Every hit by id, the deleted ones too (a feature's hits that were deleted after its fit)."""
        return {**self.deleted, **self.hits}

    def named(self) -> list[tuple[int, str]]:
        """(id, name) of every feature and construction, by id."""
        return sorted([(fid, f.name) for fid, f in self.features.items()]
                      + [(fid, c.name) for fid, c in self.constructed.items()])


def snapshot(measurement: Any) -> ModelSnapshot:
    """A :class:`ModelSnapshot` of ``measurement``, taken under its lock (the one place that lock is taken for a
    reader outside the model)."""
    with measurement.lock:
        return ModelSnapshot(dict(measurement.hits), dict(measurement.deleted), dict(measurement.features),
                             dict(measurement.constructed), measurement.part, measurement.last_hit)


def register_queries(api: Any, measurement: Any, calibration: Any = None) -> None:
    """``part``: the part loaded; ``probe_in_use``: the probe in use; ``characteristics``: the session's toleranced
    characteristics; ``report_info``: the report header."""

    def probe(client: Any) -> dict[str, Any]:
        row: dict[str, Any] = {}
        if calibration is not None:
            try:
                row = next((r for r in calibration.probes() if r["selected"]), {})
            except Exception:  # noqa: BLE001 - an unreadable probe list: the probe in use is still named
                row = {}
        radius = row.get("tip_radius")
        status = "not qualified" if radius is None else ("expired" if row.get("expired") else "qualified")
        return {"name": measurement.probe_name or row.get("name", ""), "tip_diameter": row.get("tip_diameter"),
                "tip_radius": radius, "qualified_on": row.get("qualified_on", ""), "status": status}

    def characteristics(client: Any) -> list[dict[str, Any]]:
        from ..metrology.measured import feature_values

        with measurement.lock:
            records = [f.record() for f in measurement.features.values()]
        out = []
        for m in feature_values(records):
            out.append({"name": m.name, "value": m.value, "nominal": m.nominal, "lower": m.lower, "upper": m.upper,
                        "unit": m.unit, "ok": m.ok})
        return out

    def part(client: Any) -> dict[str, Any] | None:
        p = measurement.part  # one attribute read: the page asks five times a second and never waits on the lock
        if p is None:
            return None
        cad = p.mesh.metadata.get("cad")  # a CAD part's B-rep model (cmm.cad.CadModel)
        path = p.mesh.metadata.get("path")
        return {"name": p.name, "pose": [[float(v) for v in row] for row in p.pose],
                "description": cad.summary() if cad is not None else f"{p.name}: a mesh of {len(p.mesh.faces)} triangles",
                "path": None if path is None else str(path)}

    api.register("part", part, {},
                 "None without a part; else its name, pose (4x4 part -> machine, where the station believes it lies), "
                 "description (a CAD part's faces, or the mesh's triangles) and the file it was loaded from (path)",
                 query=True)
    api.register("model", lambda client: snapshot(measurement), {},
                 "in process: the measurement model at this moment (hits, deleted hits, features, constructions, "
                 "the part, the last hit), copied under the model's lock; front ends draw from it", query=True)
    api.register("probe_in_use", probe, {}, "the probe in use: name, tip diameter and qualified radius (mm), the date "
                 "of its qualification and its status: qualified, expired or not qualified", query=True)
    api.register("characteristics", characteristics, {},
                 "the live session's toleranced characteristics (as the report lists them): name, value, "
                 "nominal, lower and upper limits, unit and ok (None: no limit)", query=True)
    api.register("report_info", lambda client: dict(measurement.info), {},
                 "the report header (part number, drawing, operator, machine name, temperature, remarks)", query=True)

"""Read-only queries of the measurement model for every front end (the OPC UA server, scripts): snapshots that
change nothing, registered on the command API beside the measurement verbs (``query=True``: open to every
client, anonymous observers too)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
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
    datums: dict[str, Any] = field(default_factory=dict)  # label -> the datum's definition (its feature id ...)

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
                             dict(measurement.constructed), measurement.part, measurement.last_hit,
                             dict(measurement.datums))


def register_queries(api: Any, measurement: Any, calibration: Any = None) -> None:
    """``probe_in_use``: the probe in use; ``characteristics``: the session's toleranced characteristics; ``report_info``:
    the report header."""

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

    def probing_setup(client: Any) -> dict[str, Any]:
        cfg = measurement.config
        probes = None
        if calibration is not None and getattr(calibration, "directory", None) is not None:
            probes = [{"name": r["name"], "tip_diameter": float(r["tip_diameter"]), "selected": bool(r["selected"]),
                       "qualified": r["tip_radius"] is not None and not r.get("expired"),
                       "qualified_diameters": [] if r["tip_radius"] is None else [2.0 * float(r["tip_radius"])]}
                      for r in calibration.probes()]
        speed = float(calibration.qualified_probing_speed) if calibration is not None else float(cfg.speeds.probing)
        folder = getattr(measurement, "session_dir", None)
        return {"tip_radius": float(measurement.prober.settings.tip_radius),
                "nominal_tip_diameter": 2.0 * float(cfg.probe.tip_radius),
                "approach_distance": float(cfg.probe.approach_distance),
                "search_distance": float(cfg.probe.search_distance),
                "retract_distance": float(cfg.probe.retract_distance),
                "positioning_speed": float(cfg.speeds.positioning), "probing_speed": speed,
                "probe_name": measurement.probe_name or "", "probes": probes,
                # the sessions folder (None: the sessions are in a database), and where they are (a folder or URL)
                "session_dir": str(folder) if isinstance(folder, Path) else None,
                "sessions": None if folder is None else str(folder)}

    api.register("model", lambda client: snapshot(measurement), {},
                 "in process: the measurement model at this moment (hits, deleted hits, features, constructions, "
                 "the part, the last hit), copied under the model's lock; front ends draw from it", query=True)
    api.register("probe_in_use", probe, {}, "the probe in use: name, tip diameter and qualified radius (mm), the date "
                 "of its qualification and its status: qualified, expired or not qualified", query=True)
    api.register("characteristics", characteristics, {},
                 "the live session's toleranced characteristics (as the report lists them): name, value, "
                 "nominal, lower and upper limits, unit and ok (None: no limit)", query=True)
    api.register("probing_setup", probing_setup, {},
                 "what a part program measures with: the tip radius in use and the configured tip diameter (mm), "
                 "the approach, search and retract distances (mm), the positioning and qualified probing speeds "
                 "(mm/s), the probe in use, the probe list (name, tip_diameter, selected, qualified, "
                 "qualified_diameters; None without a calibration folder) and the sessions folder", query=True)
    api.register("report_info", lambda client: dict(measurement.info), {},
                 "the report header (part number, drawing, operator, machine name, temperature, remarks)", query=True)

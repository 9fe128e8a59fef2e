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
    aligned: bool = False  # the pose in force came from an alignment
    alignment_name: str = ""  # that alignment as the operator knows it ("3-2-1 TOP/FRONT/LEFT")
    datums: dict[str, Any] = field(default_factory=dict)  # datum definitions by label
    info: dict[str, Any] = field(default_factory=dict)  # the report header
    probe_name: str = ""  # the probe in use
    state: Any = None  # the session's fold (a new part of a series starts another): identity only, never changed

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
                             bool(measurement.aligned), str(measurement.alignment_name or ""),
                             dict(measurement.datums), dict(measurement.info), str(measurement.probe_name or ""),
                             measurement.state)


def register_queries(api: Any, measurement: Any, calibration: Any = None) -> None:
    """``part``: the part loaded; ``probe_in_use``: the probe in use; ``characteristics``: the session's toleranced
    characteristics; ``report_info``: the report header; ``model``: the model now; what the page computes from it
    without changing it (deviations, the pick, a proposed plan, an alignment previewed); in process, the model's
    events."""

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
    api.register("part_frame", lambda client: ModelSnapshot(
                     part=measurement.part, aligned=bool(measurement.aligned),
                     alignment_name=str(measurement.alignment_name or ""), probe_name=str(measurement.probe_name or ""),
                     state=measurement.state), {},
                 "in process: the part, the alignment in force and the probe in use (a ModelSnapshot without the "
                 "hits, the features and the lock): what the frame labels and the pick show at their rate",
                 query=True)
    api.register("part_alignment", lambda client: {
                     "part": None if measurement.part is None else str(measurement.part.name),
                     "aligned": bool(measurement.aligned), "alignment": str(measurement.alignment_name or ""),
                     "probe": str(measurement.probe_name or "")}, {},
                 "part_frame as JSON (what the status bar subscribes to): the part's name (None without a part), "
                 "aligned (the pose in force came from an alignment), the alignment's name and the probe in use",
                 query=True)

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
    register_model_reads(api, measurement)


def register_model_reads(api: Any, measurement: Any) -> None:
    """The reads the page makes of the model besides its snapshot: each computes from the model, changes nothing."""
    from . import alignment
    from .align_wizard import AlignWizard
    from .plan import plan_at_pick

    REQUIRED = api.REQUIRED  # noqa: N806 - the API's marker of a parameter that must be given

    def upload_status(client: Any) -> str:
        upload = getattr(measurement.journal, "upload_status", None)
        return upload() if callable(upload) else ""

    def align_preview(client: Any, primary: int | None = None, secondary: int | None = None,
                      tertiary: int | None = None, hits: list[int] | None = None) -> Any:
        if hits is not None:
            return alignment.best_fit_hits(measurement, [int(h) for h in hits])
        if None in (primary, secondary, tertiary):
            raise ValueError("an alignment needs three features (primary, secondary, tertiary) or hits")
        return alignment.align_features(measurement, int(primary), int(secondary), int(tertiary))

    def wizard(client: Any, kind: str, invoke: Any, on_change: Any = None, elements: Any = None) -> Any:
        return AlignWizard(measurement, invoke, kind, on_change=on_change, elements=elements)

    api.register("hit_deviations", lambda client: measurement.hit_deviations(), {},
                 "hit id -> its signed deviation from the part's surface (mm, + = material outside the nominal)",
                 query=True)
    api.register("probe_data", lambda client: {**measurement.probe_data(), "name": measurement.probe_name}, {},
                 "the probe data the next hit uses, as each hit journals it: tip radius, pre-travel model, the date "
                 "of the qualification they came from; and the probe's name", query=True)
    api.register("above_point", lambda client, point, normal, clearance=None: measurement.above_point(
                     point, normal, clearance), {"point": REQUIRED, "normal": REQUIRED, "clearance": None},
                 "the tip position clearance mm (default: approach distance + tip radius) out from a surface point "
                 "along its normal (machine mm)", query=True)
    api.register("clearance_z", lambda client, margin=10.0: measurement.clearance_z(margin), {"margin": 10.0},
                 "a machine Z that clears the part (its top + margin), or the present height without a part",
                 query=True)
    api.register("pick", lambda client, origin, direction: measurement.pick_region(origin, direction),
                 {"origin": REQUIRED, "direction": REQUIRED},
                 "in process: a ray pick on the part (machine mm): the point hit and the feature suggested for its "
                 "surface with its faces, or None for a miss", query=True)
    api.register("plan_at_pick", lambda client, face, n=None: plan_at_pick(measurement, int(face), n=n),
                 {"face": REQUIRED, "n": None},
                 "in process: the measurement proposed for the part's face (feature, hits, paths): what auto_measure "
                 "would run", query=True)
    api.register("align_preview", align_preview, {"primary": None, "secondary": None, "tertiary": None, "hits": None},
                 "in process: an alignment computed (3-2-1 from three features, or a best fit of hits), not applied: "
                 "the align verb applies it", query=True)
    api.register("gdt_characteristics", lambda client: measurement.gdt_characteristics(), {},
                 "in process: (definition, characteristic) of every geometric tolerance, evaluated as the report "
                 "does", query=True)
    api.register("upload_status", upload_status, {},
                 "the shop database's words when it is offline (\"database offline, N events waiting\"), else empty",
                 query=True)
    api.register("watch_model", lambda client, on_event: measurement.subscribe(on_event), {"on_event": REQUIRED},
                 "in process: on_event(kind, info) for every change of the model ('hit', 'hits', 'feature', "
                 "'features', 'part', 'info') and every machine event it passes on; returns the function that ends it",
                 query=True)
    api.register("align_wizard", wizard, {"kind": REQUIRED, "invoke": REQUIRED, "on_change": None, "elements": None},
                 "in process: a prompted alignment of kind on the model's part (cmm.measurement.align_wizard); it "
                 "counts the model's hits and sends its verbs through invoke(verb, **params)", query=True)

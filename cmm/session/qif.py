"""QIF 3 Results (ISO 23952, QIF 3.0.0) of a recorded session: what a shop's quality system reads.

One document per session (a routine run, a DMIS run, an auto-measure, a session re-evaluated: every run is a
session), with:

- ``QPId`` of the document (a UUID derived from the session's name and its last event, so exporting the same
  session twice gives the same QPId; a re-evaluated session is another session, another QPId), and
  ``ThisResultsInstanceQPId`` for the results;
- the station as the ``MeasurementDevice`` (every characteristic names it), the program
  (``InspectionProgram``), the operator (``InspectionOperator``), start and end of the inspection, the session
  name as ``ReportNumber`` and the HTML report as an ``ExternalFileReference`` when one is given;
- the part (``Product/PartSet/Part``: its name, part number and drawing, the CAD file as a ``DigitalModel``
  with its SHA-256, and the nominals of the features that came from CAD in ``FeatureNominalIds``);
- the datums (``DatumDefinitions``, with the features they are defined on) and a datum reference frame per
  geometric tolerance's datum list;
- every fitted feature: definition, nominal (the CAD / program nominal; a feature without one has its measured
  geometry as nominal, said in its description), item and measurement (the actuals);
- every characteristic of the station's report (the feature table, the constructed distances and angles, the
  geometric tolerances), the same :class:`~cmm.metrology.characteristics.Characteristic` values the report and
  its CSV show: definition (tolerance), nominal (target), item (which features, which station) and measurement
  (actual value, status PASS / FAIL / INDETERMINATE for "check" / NOT_ANALYZED without a nominal, and the
  expanded uncertainty U with its coverage factor k, see :mod:`cmm.session.qif_map`), and the overall status.

Coordinates are in the part's coordinate system (the CAD model's) when the session has a part pose, else in
machine coordinates; lengths mm, angles degrees (``FileUnits``).

Written with the standard library's ElementTree; the tests validate every document they write against the QIF
3.0.0 schemas with lxml.
"""

from __future__ import annotations

import math
import re
import socket
import time
import uuid
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from ..journal.session import Session
from ..metrology.characteristics import Characteristic, verdict
from .gdt_session import session_gdt
from .qif_dmis import DMIS_ONLY
from .qif_map import (FEATURE_TYPES, ORIENTATION, QIF_NS, WITH_ZONE_SHAPE, coverage_factor, expanded_uncertainty,
                      qif_type, status)
from .report import _constructed_rows, _tolerances

APPLICATION = "cmm station"
_PROGRAM_NOTE = re.compile(r"^(?:DMIS program|routine) '(.+?)' started")


class QifError(RuntimeError):
    """A QIF document that cannot be written, in words."""


def _num(v: float) -> str:
    """A decimal as xs:decimal takes it (no exponent), to the last bit of the double."""
    v = float(v)
    if not math.isfinite(v):
        raise QifError(f"a value to write is not a number ({v})")
    if v == 0:
        return "0"
    return np.format_float_positional(v, unique=True, trim="-")


def _vec(v: Any) -> str:
    return " ".join(_num(x) for x in np.asarray(v, float).reshape(3))


def _iso(t: float | None) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(t if t else time.time()))


class _Doc:
    """Element building with the QIF namespace and the document's id counter."""

    def __init__(self) -> None:
        ET.register_namespace("", QIF_NS)
        self.next_id = 0

    def id(self) -> str:
        self.next_id += 1
        return str(self.next_id)

    @staticmethod
    def el(parent: ET.Element | None, tag: str, text: Any = None, **attrib: str) -> ET.Element:
        name = f"{{{QIF_NS}}}{tag}"
        e = ET.Element(name, attrib) if parent is None else ET.SubElement(parent, name, attrib)
        if text is not None:
            e.text = text if isinstance(text, str) else _num(text)
        return e

    def ids(self, parent: ET.Element, tag: str, ids: list[str]) -> ET.Element:
        box = self.el(parent, tag, n=str(len(ids)))
        for i in ids:
            self.el(box, "Id", i)
        return box


def recorded_program(session: Session) -> str:
    """The program the session ran: the routine it records (a ``routine`` event), else from its notes ("DMIS
    program 'x.dmi' started"), or ""."""
    for event in session.events or ():
        if event.get("kind") == "routine" and event.get("name"):
            return str(event["name"])
    for _seq, text in session.state.notes:
        m = _PROGRAM_NOTE.match(text)
        if m:
            return m.group(1)
    return ""


def session_qpid(session: Session) -> str:
    last = session.events[-1] if session.events else {}
    key = f"cmm-session:{session.name}:{last.get('seq', 0)}:{last.get('time', 0)}"
    return str(uuid.uuid5(uuid.NAMESPACE_URL, key))


class _Frame:
    """Machine coordinates -> the part's (CAD) coordinates, when the session has a part pose."""

    def __init__(self, pose: Any) -> None:
        self.pose = None if pose is None else np.asarray(pose, float)

    def point(self, p: Any) -> np.ndarray:
        p = np.asarray(p, float).reshape(3)
        return p if self.pose is None else self.pose[:3, :3].T @ (p - self.pose[:3, 3])

    def vector(self, v: Any) -> np.ndarray:
        v = np.asarray(v, float).reshape(3)
        v = v / (np.linalg.norm(v) or 1.0)
        return v if self.pose is None else self.pose[:3, :3].T @ v


def _geometry(kind: str, g: dict, frame: _Frame) -> dict[str, Any]:
    """The QIF elements of a feature's geometry (nominal or actual), in the part's frame."""
    out: dict[str, Any] = {}
    loc = next((g[k] for k in ("center", "point", "apex") if g.get(k) is not None), None)
    if kind in ("cylinder", "cone"):
        point = g.get("point") if g.get("point") is not None else g.get("apex")
        axis = g.get("direction")
        if point is not None and axis is not None:
            out["Axis"] = (frame.point(point), frame.vector(axis))
    elif loc is not None:
        out["Location"] = frame.point(loc)
    vec = g.get("normal") if g.get("normal") is not None else g.get("direction")
    if kind in ("plane", "circle") and vec is not None:
        out["Normal"] = frame.vector(vec)
    if kind == "line" and vec is not None:
        out["Direction"] = frame.vector(vec)
    if g.get("radius") is not None:
        out["Diameter"] = 2.0 * float(g["radius"])
    if kind == "cone" and g.get("half_angle") is not None:
        out["HalfAngle"] = math.degrees(float(g["half_angle"]))
        if g.get("apex") is not None and g.get("point") is not None:  # the diameter at the location point
            out["Diameter"] = 2.0 * float(np.linalg.norm(np.subtract(g["point"], g["apex"]))) * math.tan(
                float(g["half_angle"]))
    return out


def _write_geometry(d: _Doc, parent: ET.Element, geo: dict[str, Any], kind: str, actual: bool) -> None:
    if "Axis" in geo:
        ax = d.el(parent, "Axis")
        d.el(ax, "AxisPoint", _vec(geo["Axis"][0]))
        d.el(ax, "Direction", _vec(geo["Axis"][1]))
    if "Location" in geo:
        d.el(parent, "Location", _vec(geo["Location"]))
    if "Normal" in geo:
        d.el(parent, "Normal", _vec(geo["Normal"]))
    if "Direction" in geo:
        d.el(parent, "Direction", _vec(geo["Direction"]))
    if actual and "Diameter" in geo and kind in ("circle", "cylinder", "sphere"):
        d.el(parent, "Diameter", geo["Diameter"])


def _nominal_ok(kind: str, nominal: dict | None) -> bool:
    from ..metrology.characteristics import COMPARABLE

    return bool(nominal) and nominal.get("kind") in COMPARABLE.get(kind, ()) + (kind,)


def _characteristic_rows(session: Session, program: Any, default_tolerance: float | None, mesh: Any
                         ) -> list[tuple[str, Any, Characteristic]]:
    """(owner kind, owner, Characteristic): the report's rows, in the report's order."""
    tols = _tolerances(session, program, default_tolerance)
    rows: list[tuple[str, Any, Characteristic]] = []
    for fid, f in session.state.features.items():
        rows += [("feature", f, c) for c in f.characteristics(tols[fid])]
    for rec, cs in _constructed_rows(session, default_tolerance):
        rows += [("constructed", rec, c) for c in cs]
    for dfn, c in session_gdt(session, mesh, tols):
        rows.append(("gdt", dfn, c))
    return rows


def qif_document(session: Session, *, program: Any = None, default_tolerance: float | None = None, mesh: Any = None,
                 program_name: str | None = None, operator: str | None = None, station: str | None = None,
                 report: str | None = None, dmis: Any = None) -> ET.ElementTree:
    """The session as a QIF 3 Results document (see the module docstring). ``dmis``: a DMIS run's tolerance
    evaluations (:class:`cmm.dmis.tolerances.Evaluation`; None: the ones recorded in the session,
    :func:`cmm.session.qif_dmis.session_evaluations`), whose characteristics the report has no row for
    (orientation, distances and angles between features, profiles, runout, concentricity) are added after the
    report's, named ``<features> <word> T(<label>)``, with the DMIS output's value and INTOL / OUTOL; those a
    re-evaluated session leaves out are said in a ``NotedEvent`` (:func:`cmm.session.qif_dmis.left_out`)."""
    gone = ""  # the DMIS-only characteristics a re-evaluated session's document leaves out, and why
    if dmis is None:
        from .qif_dmis import left_out, session_evaluations

        dmis, gone = session_evaluations(session), left_out(session)
    d = _Doc()
    st = session.state
    info = st.info
    frame = _Frame(st.part_pose)
    root = d.el(None, "QIFDocument", versionQIF="3.0.0", idMax="0")
    d.el(root, "QPId", session_qpid(session))
    ver = d.el(root, "Version")
    d.el(ver, "TimeCreated", _iso(time.time()))
    head = d.el(root, "Header")
    app = d.el(head, "Application")
    d.el(app, "Name", APPLICATION)
    d.el(app, "Organization", "CMM station project")
    std = d.el(root, "StandardsDefinitions", n="1")
    standard_id = d.id()
    se = d.el(std, "Standard", id=standard_id)
    d.el(d.el(se, "Organization"), "StandardsOrganizationEnum", "ISO")
    d.el(se, "Designator", "1101")  # the station's geometric tolerances: ISO 1101 (and ASME Y14.5 alike)
    d.el(se, "Year", "2017")
    units = d.el(d.el(root, "FileUnits"), "PrimaryUnits")
    ang = d.el(units, "AngularUnit")
    d.el(ang, "SIUnitName", "radian")
    d.el(ang, "UnitName", "degree")
    d.el(d.el(ang, "UnitConversion"), "Factor", "0.017453292519943295")
    lin = d.el(units, "LinearUnit")
    d.el(lin, "SIUnitName", "meter")
    d.el(lin, "UnitName", "mm")
    d.el(d.el(lin, "UnitConversion"), "Factor", "0.001")

    rows = _characteristic_rows(session, program, default_tolerance, mesh) + _dmis_rows(dmis)
    features = st.features
    # ids, reserved up front so that datums and the part can refer to features written later
    fids = {fid: {k: d.id() for k in ("definition", "nominal", "item", "measurement")} for fid in features}

    # --- datums and their reference frames
    datum_ids: dict[str, str] = {}
    if st.datums:
        box = d.el(root, "DatumDefinitions", n=str(len(st.datums)))
        for label, dd in sorted(st.datums.items()):
            datum_ids[label] = d.id()
            e = d.el(box, "DatumDefinition", id=datum_ids[label])
            d.el(e, "DatumLabel", label)
            fid = dd.get("feature")
            if fid is not None and int(fid) in fids:
                d.ids(e, "FeatureNominalIds", [fids[int(fid)]["nominal"]])
    drf_ids: dict[tuple, str] = {}
    frames = []
    for kind, owner, c in rows:
        refs = _refs(kind, c)
        labels = [_label(lab)[0] for ref in refs for lab in ref.split("-")]
        if refs and all(lab in datum_ids for lab in labels) and refs not in drf_ids:
            drf_ids[refs] = d.id()
            frames.append((refs, owner))
    if frames:
        box = d.el(root, "DatumReferenceFrames", n=str(len(frames)))
        for refs, owner in frames:
            e = d.el(box, "DatumReferenceFrame", id=drf_ids[refs])
            ds = d.el(e, "Datums", n=str(len(refs)))
            mods = (owner.get("datum_modifiers") or {}) if isinstance(owner, dict) else {}
            for k, ref in enumerate(refs):
                datum = d.el(ds, "Datum")
                labels = ref.split("-")
                compound = None if len(labels) == 1 else d.el(datum, "CompoundDatum", n=str(len(labels)))
                for seq, lab in enumerate(labels, 1):
                    inner = None if compound is None else d.el(compound, "Datum")
                    simple = d.el(datum if inner is None else inner, "SimpleDatum")
                    lab, own = _label(lab)
                    d.el(simple, "DatumDefinitionId", datum_ids[lab])
                    mod = own or mods.get(lab) or (st.datums.get(lab) or {}).get("modifier") or ""
                    d.el(simple, "MaterialModifier", {"MMB": "MAXIMUM", "LMB": "LEAST"}.get(mod, "NONE"))
                    d.el(simple, "ReferencedComponent", "ACTUAL")
                    if inner is not None:
                        d.el(inner, "SequenceNumber", str(seq))
                prec = d.el(datum, "Precedence")
                d.el(prec, "PrecedenceEnum", ("PRIMARY", "SECONDARY", "TERTIARY")[k] if k < 3 else "PRIMARY")

    # --- the station
    station_name = station or str(info.get("machine_name") or "") or socket.gethostname()
    device_id = d.id()
    res = d.el(root, "MeasurementResources")
    devs = d.el(res, "MeasurementDevices", n="1")
    dev = d.el(devs, "MeasurementDevice", id=device_id)
    d.el(dev, "Name", _token(station_name))
    start = session.start
    d.el(dev, "Description", f"CMM station; machine link {start.get('port', '?')}; configuration "
                             f"{start.get('config', '?')}")

    # --- the part
    part = st.part
    from_cad = [fid for fid, f in features.items() if _nominal_ok(f.kind, f.nominal)]
    prod = d.el(root, "Product")
    parts = d.el(prod, "PartSet", n="1")
    part_id = d.id()
    pe = d.el(parts, "Part", id=part_id)
    part_name = part.name if part is not None else str(info.get("part_number") or session.name)
    pattrs = [_attr_str(d, "PartName", part_name)]
    if part is not None and part.sha256:
        pattrs.append(_attr_str(d, "ModelSHA256", part.sha256))  # the CAD mesh the nominals came from
    d.el(pe, "Attributes", n=str(len(pattrs))).extend(pattrs)
    if info.get("part_number"):
        d.el(pe, "ModelNumber", str(info["part_number"]))
    if part is not None and from_cad:
        d.ids(pe, "FeatureNominalIds", [fids[fid]["nominal"] for fid in from_cad])
    if part is not None or info.get("drawing"):
        ext_items = []
        if info.get("drawing"):
            ext_items.append(("drawing", str(info["drawing"])))
        if part is not None:
            ext_items.append(("model", part))
        ext = d.el(pe, "DefinitionExternal", id=d.id(), n=str(len(ext_items)))
        for what, val in ext_items:
            if what == "drawing":
                dr = d.el(ext, "PrintedDrawing", id=d.id())
                d.el(dr, "Name", val)
                d.el(dr, "DrawingNumber", val)
            else:
                dm = d.el(ext, "DigitalModel", id=d.id())
                d.el(dm, "Name", val.name)
                fe = d.el(dm, "File")
                d.el(fe, "Name", str(val.path or val.name))
                d.el(d.el(fe, "Format"), "OtherDigitalModelFormat",
                     Path(str(val.path or "")).suffix.lstrip(".").upper() or "MESH")
    comps = d.el(prod, "ComponentSet", n="1")
    comp_id = d.id()
    ce = d.el(comps, "Component", id=comp_id)
    d.el(d.el(ce, "Part"), "Id", part_id)
    paths = d.el(prod, "AsmPaths", n="1")
    path_id = d.id()
    ap = d.el(paths, "AsmPath", id=path_id)
    d.ids(ap, "ComponentIds", [comp_id])

    # --- features
    if features:
        fs = d.el(root, "Features")
        defs = d.el(fs, "FeatureDefinitions", n=str(len(features)))
        noms = d.el(fs, "FeatureNominals", n=str(len(features)))
        items = d.el(fs, "FeatureItems", n=str(len(features)))
        for fid, f in features.items():
            t = FEATURE_TYPES.get(f.kind, "Point")
            ids = fids[fid]
            has_nominal = _nominal_ok(f.kind, f.nominal)
            nom_geo = _geometry(f.kind, f.nominal if has_nominal else f.fit, frame)
            act_geo = _geometry(f.kind, f.fit, frame)
            de = d.el(defs, f"{t}FeatureDefinition", id=ids["definition"])
            if f.kind in ("circle", "cylinder", "sphere", "cone"):
                inner = (f.nominal or {}).get("inner")
                side = "NOT_APPLICABLE" if inner is None else ("INTERNAL" if inner else "EXTERNAL")
                d.el(de, "InternalExternal", side)
                d.el(de, "Diameter", nom_geo.get("Diameter", act_geo.get("Diameter", 0.0)))
                if f.kind == "cone":
                    d.el(de, "HalfAngle", nom_geo.get("HalfAngle", act_geo.get("HalfAngle", 0.0)))
            ne = d.el(noms, f"{t}FeatureNominal", id=ids["nominal"])
            if not has_nominal:
                d.el(ne, "Attributes", n="1").append(_attr_str(d, "NominalSource",
                                                               "none given: the measured geometry stands in"))
            d.el(ne, "Name", _token(f.name))
            d.el(ne, "FeatureDefinitionId", ids["definition"])
            _write_geometry(d, ne, nom_geo, f.kind, actual=False)
            ie = d.el(items, f"{t}FeatureItem", id=ids["item"])
            d.el(ie, "FeatureNominalId", ids["nominal"])
            d.el(ie, "FeatureName", _token(f.name))
            det = d.el(d.el(d.el(ie, "DeterminationMode"), "Checked"), "CheckDetails")
            d.el(det, "Measured")

    # --- characteristics
    crow = []
    for kind, owner, c in rows:
        ref_fids = _owner_features(kind, owner, features)
        feature_kind = features[ref_fids[0]].kind if ref_fids else ""
        if kind == "gdt":
            qt, family = qif_type(str(owner.get("characteristic", c.name)), feature_kind)
        elif kind == "dmis":
            qt, family = qif_type(c.name.split(f" {owner.tolerance.word} ")[0], feature_kind)
        else:
            qt, family = qif_type(c.name, feature_kind)
        crow.append((kind, owner, c, ref_fids, qt, family,
                     {k: d.id() for k in ("definition", "nominal", "item", "measurement")}))
    if crow:
        cs = d.el(root, "Characteristics")
        d.el(cs, "FormalStandardId", standard_id)
        defs = d.el(cs, "CharacteristicDefinitions", n=str(len(crow)))
        noms = d.el(cs, "CharacteristicNominals", n=str(len(crow)))
        items = d.el(cs, "CharacteristicItems", n=str(len(crow)))
        for k, (kind, owner, c, ref_fids, qt, family, ids) in enumerate(crow, 1):
            _char_definition(d, defs, qt, family, kind, owner, c, ids, drf_ids,
                             features[ref_fids[0]].kind if ref_fids else "")
            ne = d.el(noms, f"{qt}CharacteristicNominal", id=ids["nominal"])
            d.el(ne, "CharacteristicDefinitionId", ids["definition"])
            if ref_fids:
                d.ids(ne, "FeatureNominalIds", [fids[f]["nominal"] for f in ref_fids])
            d.el(ne, "Name", _token(f"{c.feature} {c.name}"))
            if qt == "LineProfile":  # the normal of the section the profile's points lie in
                d.el(ne, "Vector", _vec(_section_normal(session, ref_fids, frame)))
            if qt in ("DistanceBetween", "AngleBetween"):
                if c.nominal is not None:
                    d.el(ne, "TargetValue", c.nominal)
                d.el(ne, "AnalysisMode", "THREEDIMENSIONAL")
            elif family in ("limits", "angular", "user") and c.nominal is not None:
                d.el(ne, "TargetValue", c.nominal)
            ie = d.el(items, f"{qt}CharacteristicItem", id=ids["item"])
            d.el(ie, "Name", _token(f"{c.feature} {c.name}"))
            des = d.el(ie, "CharacteristicDesignator")
            d.el(des, "Designator", str(k))
            d.el(des, "UUID", str(uuid.uuid5(uuid.UUID(session_qpid(session)), f"{k}:{c.feature}:{c.name}")))
            if ref_fids:
                d.ids(ie, "FeatureItemIds", [fids[f]["item"] for f in ref_fids])
            d.ids(ie, "MeasurementDeviceIds", [device_id])
            d.el(ie, "CharacteristicNominalId", ids["nominal"])

    # --- results
    chars = [c for _k, _o, c in rows]
    overall, _failed, _missing = verdict(chars)
    results = d.el(root, "Results")
    mset = d.el(results, "MeasurementResultsSet", n="1")
    mr = d.el(mset, "MeasurementResults", id=d.id())
    tr = d.el(mr, "InspectionTraceability")
    d.el(tr, "ReportNumber", session.name)
    if gone:  # said in the document, not silently missing
        noted = d.el(d.el(tr, "NotedEvents", n="1"), "NotedEvent", id=d.id())
        d.el(noted, "Description", gone)
        d.el(noted, "SequenceNumber", "1")
    t0 = session.events[0].get("time") if session.events else None
    t1 = session.events[-1].get("time") if session.events else None
    if t0:
        d.el(tr, "InspectionStart", _iso(t0))
    if t1:
        d.el(tr, "InspectionEnd", _iso(t1))
    prog = program_name if program_name is not None else recorded_program(session)
    if prog:
        ip = d.el(tr, "InspectionProgram")
        d.el(d.el(ip, "File"), "Name", prog)
        d.el(ip, "Description", "DMIS part program" if prog.lower().endswith((".dmi", ".dms")) else "station routine")
        d.el(ip, "FormalStandardId", standard_id)
        d.el(d.el(ip, "Author"), "Name", "not recorded")  # required by QIF; the session does not say who wrote it
    who = operator if operator is not None else str(info.get("operator") or "")
    if who:
        d.el(d.el(tr, "InspectionOperator"), "Name", who)
    d.el(tr, "ReportPreparationDate", _iso(time.time()))
    d.el(mr, "ThisResultsInstanceQPId", str(uuid.uuid5(uuid.UUID(session_qpid(session)), "results")))
    if report:
        refs = d.el(mr, "ExternalFileReferences", n="1")
        ref = d.el(refs, "ExternalFileReference")
        d.el(ref, "URI", str(report))
        d.el(d.el(ref, "FileSpec"), "OtherFileSpec", "HTML")
        d.el(ref, "Description", "the station's inspection report")
    if features:
        mf = d.el(mr, "MeasuredFeatures", n=str(len(features)))
        for fid, f in features.items():
            t = FEATURE_TYPES.get(f.kind, "Point")
            me = d.el(mf, f"{t}FeatureMeasurement", id=fids[fid]["measurement"])
            d.el(me, "FeatureItemId", fids[fid]["item"])
            _write_geometry(d, me, _geometry(f.kind, f.fit, frame), f.kind, actual=True)
            if f.kind == "cone" and f.fit.get("half_angle") is not None:
                d.el(me, "HalfAngle", math.degrees(float(f.fit["half_angle"])))
    if crow:
        mc = d.el(mr, "MeasuredCharacteristics")
        cm = d.el(mc, "CharacteristicMeasurements", n=str(len(crow)))
        for kind, owner, c, ref_fids, qt, family, ids in crow:
            fit = features[ref_fids[0]].fit if kind == "feature" and ref_fids else None
            u = expanded_uncertainty(c, fit)
            k = coverage_factor(c)
            me = d.el(cm, f"{qt}CharacteristicMeasurement", id=ids["measurement"])
            attrs = []
            if u is not None:
                attrs.append(_attr_d(d, "ExpandedUncertainty", u))
                attrs.append(_attr_d(d, "CoverageFactor", k))
            if c.check:
                attrs.append(_attr_str(d, "Check", c.check))
            if kind == "gdt" and "composite" not in owner and str(owner.get("material") or "") in ("MMC", "LMC"):
                attrs.append(_attr_d(d, "AllowedWithBonus", c.upper))
            if attrs:
                box = d.el(me, "Attributes", n=str(len(attrs)))
                box.extend(attrs)
            if c.note:
                d.el(me, "Description", c.note)
            d.el(d.el(me, "Status"), "CharacteristicStatusEnum",
                 ("PASS" if owner.intol else "FAIL") if kind == "dmis" else status(c))
            d.el(me, "CharacteristicItemId", ids["item"])
            if ref_fids:
                d.ids(me, "FeatureMeasurementIds", [fids[f]["measurement"] for f in ref_fids])
            d.ids(me, "MeasurementDeviceIds", [device_id])
            if c.actual is not None:
                v = d.el(me, "Value", c.actual)
                if u is not None:
                    v.set("combinedUncertainty", _num(u / k))
                    v.set("meanError", "0")
    d.el(d.el(mr, "InspectionStatus"), "InspectionStatusEnum",
         {"PASS": "PASS", "FAIL": "FAIL"}.get(overall, "UNKNOWN"))
    acs = d.el(d.el(results, "ActualComponentSets", n="1"), "ActualComponentSet", n="1")
    ac = d.el(acs, "ActualComponent", id=d.id())
    d.el(d.el(ac, "Status"), "InspectionStatusEnum", {"PASS": "PASS", "FAIL": "FAIL"}.get(overall, "UNKNOWN"))
    d.el(ac, "AsmPathId", path_id)
    root.set("idMax", str(d.next_id))
    return ET.ElementTree(root)


def _token(s: str) -> str:
    return " ".join(str(s).split()) or "-"


def _attr_str(d: _Doc, name: str, value: str) -> ET.Element:
    return d.el(None, "AttributeStr", name=name, value=str(value))


def _attr_d(d: _Doc, name: str, value: float) -> ET.Element:
    return d.el(None, "AttributeD1", name=name, value=_num(value))


def _label(token: str) -> tuple[str, str]:
    """A datum reference's label and modifier: "G(M)" -> ("G", "MMB"), "A" -> ("A", "")."""
    m = re.match(r"^\s*([A-Za-z]+)\s*(?:\((M|L)\))?", token)
    if m is None:
        return token.strip(), ""
    return m.group(1), {"M": "MMB", "L": "LMB"}.get(m.group(2) or "", "")


def _refs(kind: str, c: Characteristic) -> tuple[str, ...]:
    """A geometric tolerance's datum references in precedence order ("A", "B", "E-F"), from its row."""
    return tuple(x.strip() for x in c.datums.split("|") if x.strip()) if kind in ("gdt", "dmis") and c.datums else ()


def _dmis_rows(evaluations: Any) -> list[tuple[str, Any, Characteristic]]:
    rows: list[tuple[str, Any, Characteristic]] = []
    for ev in evaluations or ():
        t = ev.tolerance
        kind = DMIS_ONLY.get(t.word)
        if kind is None:
            continue
        if t.word == "RUNOUT" and "TOTAL" in t.options:
            kind = "total runout"
        feature = "-".join(ev.features)
        unit = "deg" if t.word in ("ANGLB", "ANGLR") and kind != "angularity" else "mm"
        if t.word in ("DISTB", "ANGLB"):  # the value is the deviation from the nominal distance / angle
            nominal = float(t.nominal or 0.0)
            c = Characteristic(feature, f"{kind} {t.word} T({t.label})", nominal, nominal + float(ev.value),
                               float(t.upper), float(t.lower), unit=unit, note=ev.note)
        else:  # a zone
            c = Characteristic(feature, f"{kind} {t.word} T({t.label})", 0.0, float(ev.value),
                               float(t.upper) + float(ev.bonus), 0.0, note=ev.note, datums="|".join(t.datums))
        rows.append(("dmis", ev, c))
    return rows


def _owner_features(kind: str, owner: Any, features: dict) -> list[int]:
    if kind == "feature":
        return [owner.id] if owner.id in features else []
    if kind == "constructed":
        return [i for i in owner.operands if i in features]
    if kind == "dmis":
        by_name = {f.name: fid for fid, f in features.items()}
        return [by_name[n] for n in owner.features if n in by_name]
    fid = owner.get("feature")
    return [int(fid)] if fid is not None and int(fid) in features else []


def _char_definition(d: _Doc, parent: ET.Element, qt: str, family: str, kind: str, owner: Any, c: Characteristic,
                     ids: dict, drf_ids: dict, feature_kind: str = "") -> None:
    de = d.el(parent, f"{qt}CharacteristicDefinition", id=ids["definition"])
    if c.tolerance_text:
        d.el(de, "Description", f"{c.name}: {c.tolerance_text}")
    if family in ("limits", "angular", "user"):
        tol = d.el(de, "Tolerance")
        d.el(tol, "MaxValue", c.upper)
        d.el(tol, "MinValue", c.lower)
        d.el(tol, "DefinedAsLimit", "false")
        if qt.startswith("UserDefined"):
            d.el(de, "WhatToMeasure", c.name)
        return
    # zone tolerances: the stated zone (a bonus at MMC / LMC is in c.upper; the stated one in the definition)
    material = {"MMC": "MAXIMUM", "LMC": "LEAST"}.get(str(owner.get("material") or "").upper(), "NONE") \
        if kind == "gdt" and "composite" not in owner else "NONE"
    # at MMC / LMC the stated zone (the bonus the actual size gives is the measurement's AllowedWithBonus);
    # otherwise the zone allowed (a composite frame's lower tier has its own)
    stated = float(owner.get("tolerance") or c.upper) if material != "NONE" else c.upper
    d.el(de, "ToleranceValue", stated)
    refs = _refs(kind, c)
    if qt == "Position":
        if refs in drf_ids:
            d.el(de, "DatumReferenceFrameId", drf_ids[refs])
        d.el(de, "MaterialCondition", material)
        spherical = feature_kind == "sphere" and (kind != "gdt" or "3D" in str(owner.get("direction") or ""))
        d.el(d.el(de, "ZoneShape"), "SphericalZone" if spherical else "DiametricalZone")
        return
    if qt in ORIENTATION or qt in ("CircularRunout", "TotalRunout", "Concentricity", "Coaxiality",
                                   "SurfaceProfile", "LineProfile"):
        if refs in drf_ids:
            d.el(de, "DatumReferenceFrameId", drf_ids[refs])
    if qt in ORIENTATION or qt == "Straightness":
        d.el(de, "MaterialCondition", material)
    if qt in WITH_ZONE_SHAPE:
        _zone_shape(d, de, qt, "⌀" in c.tolerance_text)


def _zone_shape(d: _Doc, de: ET.Element, qt: str, diametral: bool) -> None:
    z = d.el(de, "ZoneShape")
    if qt in ("Concentricity", "Coaxiality") or diametral:
        d.el(z, "DiametricalZone")
    else:
        d.el(z, "NonDiametricalZone" if qt == "Straightness" else "PlanarZone")


def _section_normal(session: Session, fids: list[int], frame: _Frame) -> np.ndarray:
    """The least-squares plane normal of a feature's hit points (a line profile's section), in the part's frame."""
    st = session.state
    hits = {**st.deleted_hits, **st.hits}
    pts = np.array([hits[h].point for f in fids for h in st.features[f].hit_ids if h in hits], float).reshape(-1, 3)
    if len(pts) < 3:
        return frame.vector([0.0, 0.0, 1.0])
    n = np.linalg.svd(pts - pts.mean(axis=0))[2][-1]
    return frame.vector(n if n[np.argmax(np.abs(n))] > 0 else -n)


def write_qif(session: Session, path: str | Path, **kw: Any) -> Path:
    """Write the session's QIF 3 Results document to ``path`` (UTF-8 XML); returns the path."""
    p = Path(path)
    tree = qif_document(session, **kw)
    ET.indent(tree, space="  ")
    p.parent.mkdir(parents=True, exist_ok=True)
    tree.write(p, encoding="UTF-8", xml_declaration=True)
    return p


def qif_bytes(session: Session, **kw: Any) -> bytes:
    tree = qif_document(session, **kw)
    ET.indent(tree, space="  ")
    return ET.tostring(tree.getroot(), encoding="UTF-8", xml_declaration=True)

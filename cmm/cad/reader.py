"""Read STEP (AP203, AP214, AP242) and IGES files with OpenCASCADE (the ``cadquery-ocp`` wheel, module ``OCP``).

:func:`read_cad` returns a :class:`cmm.cad.model.CadModel`: every B-rep face with its exact surface, and a
triangulation tagged with faces. Lengths are converted to millimetres by the readers (an inch file comes in
x 25.4); assemblies are flattened with their placements. Free-form faces that are in fact planes, cylinders,
cones, spheres or tori (IGES exporters write planes as B-spline surfaces and cylinders as surfaces of
revolution) are recognised as such within ``RECOGNISE_TOL``. A file the readers cannot use raises
:class:`CadError` with one sentence.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .freeform import face_brep
from .model import FREE_FORM, CadError, CadFace, CadModel, assign_groups

CAD_EXTENSIONS = (".step", ".stp", ".iges", ".igs")
DEFLECTION = 0.01  # mm, the triangulation's chordal error
ANGULAR = 0.5  # rad, the largest angle between neighbouring facets (the chordal error governs on all but tiny radii)
RECOGNISE_TOL = 1e-6  # mm: a free-form surface this close to an analytic one is taken as that surface

_SCHEMAS = (("AP242", "AP242"), ("MANAGED_MODEL_BASED_3D", "AP242"), ("AUTOMOTIVE_DESIGN", "AP214"),
            ("CONFIG_CONTROL_DESIGN", "AP203"), ("AP203", "AP203"), ("AP214", "AP214"))


def read_cad(path: str | Path, deflection: float = DEFLECTION, angular: float = ANGULAR) -> CadModel:
    """The CAD model of a STEP or IGES file (mm, the file's frame)."""
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in CAD_EXTENSIONS:
        raise CadError(f"cannot read '{p.name}': '{ext or '(no extension)'}' is not a CAD format the station reads "
                       f"({', '.join(CAD_EXTENSIONS)})")
    if not p.is_file():
        raise CadError(f"CAD file '{p}' does not exist")
    fmt = "STEP" if ext in (".step", ".stp") else "IGES"
    head = p.read_bytes()[:4096].decode("latin-1", "replace")
    schema = ""
    if fmt == "STEP":
        if not head.lstrip().startswith("ISO-10303-21"):
            raise CadError(f"'{p.name}' is not a STEP file: it does not begin with ISO-10303-21 (empty, truncated "
                           "or another format)")
        m = re.search(r"FILE_SCHEMA\s*\(\s*\(\s*'([^']*)'", head, re.I)
        name = (m.group(1) if m else "").upper()
        schema = next((ap for key, ap in _SCHEMAS if key in name), name.split(" ")[0] if name else "")
    elif len(head) < 80 or head[72] != "S":
        raise CadError(f"'{p.name}' is not an IGES file: its first line is not an 80-column start record")
    _quiet()
    shape, unit = _read_shape(p, fmt)
    shape = _solidify(shape)
    return _build(shape, p.name, fmt, unit, schema, deflection, angular)


def _quiet() -> None:
    """OpenCASCADE's readers print statistics on stdout: only failures get through."""
    from OCP.Message import Message, Message_Gravity

    for printer in Message.DefaultMessenger_s().Printers():
        printer.SetTraceLevel(Message_Gravity.Message_Fail)


def _read_shape(p: Path, fmt: str):
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Message import Message_ProgressRange

    if fmt == "STEP":
        from OCP.STEPControl import STEPControl_Reader

        reader = STEPControl_Reader()
    else:
        from OCP.IGESControl import IGESControl_Reader

        reader = IGESControl_Reader()
    status = reader.ReadFile(str(p))
    if status != IFSelect_RetDone:
        raise CadError(f"'{p.name}' is broken or not a valid {fmt} file (the {fmt} reader could not parse it)")
    unit = _file_unit(reader, fmt, p)
    try:
        reader.TransferRoots(Message_ProgressRange())
        shape = reader.OneShape()
    except Exception as exc:  # noqa: BLE001 - OCCT raises Standard_Failure subclasses
        raise CadError(f"'{p.name}' could not be turned into geometry ({exc})") from exc
    if shape is None or shape.IsNull():
        raise CadError(f"'{p.name}' holds no solid, shell or surface the {fmt} reader could transfer")
    return shape, unit


_SI_PREFIX = {"": "m", ".MILLI.": "mm", ".CENTI.": "cm", ".MICRO.": "um", ".KILO.": "km", ".DECI.": "dm"}


def _step_unit(p: Path) -> str:
    """The length unit a STEP file declares (the reader converts to mm whatever it is)."""
    text = p.read_bytes().decode("latin-1", "replace")
    m = re.search(r"CONVERSION_BASED_UNIT\s*\(\s*'([^']*)'[^;]*LENGTH_UNIT", text, re.I)
    if m:
        return m.group(1).strip().lower()
    m = re.search(r"LENGTH_UNIT\s*\(\s*\)[^;]*SI_UNIT\s*\(\s*([.A-Z$]*)\s*,\s*\.METRE\.", text, re.I)
    return _SI_PREFIX.get(m.group(1).replace("$", "").upper(), "mm") if m else "mm"


def _file_unit(reader, fmt: str, p: Path) -> str:
    try:
        if fmt == "STEP":
            return _step_unit(p)
        name = reader.IGESModel().GlobalSection().UnitName().ToCString().strip().lower()
        return {"in": "inch", "inch": "inch", "ft": "foot"}.get(name, name or "mm")
    except Exception:  # noqa: BLE001 - the unit is information only: the readers convert anyway
        return "mm"


def _solidify(shape):
    """Loose faces (IGES has no solids) sewn into shells, and closed shells made solids, so that every face knows
    its material side."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing
    from OCP.ShapeFix import ShapeFix_Solid
    from OCP.TopAbs import TopAbs_SHELL, TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    if TopExp_Explorer(shape, TopAbs_SOLID).More():
        return shape
    sewing = BRepBuilderAPI_Sewing(1e-3)
    sewing.Add(shape)
    sewing.Perform()
    sewn = sewing.SewedShape()
    ex = TopExp_Explorer(sewn, TopAbs_SHELL)
    from OCP.BRep import BRep_Builder
    from OCP.TopoDS import TopoDS_Compound

    out, builder, any_solid = TopoDS_Compound(), BRep_Builder(), False
    builder.MakeCompound(out)
    while ex.More():
        shell = TopoDS.Shell(ex.Current())
        if shell.Closed() or _closed(shell):
            builder.Add(out, ShapeFix_Solid().SolidFromShell(shell))
            any_solid = True
        else:
            builder.Add(out, shell)
        ex.Next()
    return out if any_solid else sewn


def _closed(shell) -> bool:
    from OCP.BRepCheck import BRepCheck_Shell, BRepCheck_Status

    try:
        return BRepCheck_Shell(shell).Closed() == BRepCheck_Status.BRepCheck_NoError
    except Exception:  # noqa: BLE001
        return False


def _bodies(shape):
    """(name, [faces]) per solid, then one entry for faces that belong to no solid."""
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    out = []
    ex = TopExp_Explorer(shape, TopAbs_SOLID)
    while ex.More():
        faces = []
        fx = TopExp_Explorer(ex.Current(), TopAbs_FACE)
        while fx.More():
            faces.append(TopoDS.Face(fx.Current()))
            fx.Next()
        out.append((f"solid {len(out) + 1}", faces))
        ex.Next()
    loose = []
    fx = TopExp_Explorer(shape, TopAbs_FACE, TopAbs_SOLID)
    while fx.More():
        loose.append(TopoDS.Face(fx.Current()))
        fx.Next()
    if loose:
        out.append(("surfaces", loose))
    return out


def _build(shape, name: str, fmt: str, unit: str, schema: str, deflection: float, angular: float) -> CadModel:
    from OCP.BRepMesh import BRepMesh_IncrementalMesh

    BRepMesh_IncrementalMesh(shape, deflection, False, angular, True)
    bodies = _bodies(shape)
    if not any(faces for _, faces in bodies):
        raise CadError(f"'{name}' holds no surfaces (only points, curves or empty products)")
    verts, tris, owner, faces = [], [], [], []
    offset = 0
    for b, (_, body_faces) in enumerate(bodies):
        for face in body_faces:
            mesh = _triangulate(face)
            if mesh is None:
                continue
            v, t = mesh
            kind, params, source = _surface(face)
            if kind == FREE_FORM:  # its exact surface for projections (cmm.cad.freeform), as plain text
                params["brep"] = face_brep(face)
            index = len(faces)
            f = CadFace(index, kind, params, +1, b, source=source)
            f.sense = _sense(f, v, t)
            corners = v[t]
            f.area = float(0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                                         corners[:, 2] - corners[:, 0]), axis=1).sum())
            f.bounds = np.array([v.min(axis=0), v.max(axis=0)])
            faces.append(f)
            verts.append(v)
            tris.append(t + offset)
            owner.append(np.full(len(t), index, dtype=np.int64))
            offset += len(v)
    if not faces:
        raise CadError(f"'{name}' could not be triangulated: its faces have no valid boundaries")
    vertices, triangles = _merge(np.concatenate(verts), np.concatenate(tris))
    owners = np.concatenate(owner)
    # a triangle whose corners merged (at a sphere's pole) has no area: drop it
    keep = (triangles[:, 0] != triangles[:, 1]) & (triangles[:, 1] != triangles[:, 2]) & (triangles[:, 0] != triangles[:, 2])
    triangles, owners = triangles[keep], owners[keep]
    model = CadModel(name, fmt, unit, faces, vertices, triangles, owners,
                     bodies=[n for n, _ in bodies], deflection=deflection, schema=schema)
    assign_groups(model)
    return model


def _triangulate(face):
    """(vertices (n, 3), triangles (m, 3)) of a face's triangulation, wound out of the material."""
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_REVERSED
    from OCP.TopLoc import TopLoc_Location

    loc = TopLoc_Location()
    tri = BRep_Tool.Triangulation_s(face, loc)
    if tri is None or tri.NbTriangles() == 0:
        return None
    n, m = tri.NbNodes(), tri.NbTriangles()
    v = np.array([tri.Node(i).Coord() for i in range(1, n + 1)], dtype=np.float64).reshape(n, 3)
    t = np.array([tri.Triangle(i).Get() for i in range(1, m + 1)], dtype=np.int64).reshape(m, 3) - 1
    if not loc.IsIdentity():  # an assembly's placement: one matrix for all the nodes
        trsf = loc.Transformation()
        rot = np.array([[trsf.Value(r, c) for c in (1, 2, 3)] for r in (1, 2, 3)])
        shift = np.array([trsf.Value(r, 4) for r in (1, 2, 3)])
        v = v @ rot.T + shift
    if face.Orientation() == TopAbs_REVERSED:
        t = t[:, ::-1]
    return v, t


def _xyz(p) -> np.ndarray:
    return np.array([p.X(), p.Y(), p.Z()], dtype=np.float64)


def _surface(face) -> tuple[str, dict, str]:
    """The face's surface: (kind, params, the file's surface type when it was recognised as analytic)."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.GeomAbs import GeomAbs_SurfaceType as T
    from OCP.GeomAdaptor import GeomAdaptor_Surface

    adaptor = BRepAdaptor_Surface(face)
    kind = adaptor.GetType()
    source = ""
    if kind not in (T.GeomAbs_Plane, T.GeomAbs_Cylinder, T.GeomAbs_Cone, T.GeomAbs_Sphere, T.GeomAbs_Torus):
        try:
            from OCP.GeomConvert import GeomConvert_SurfToAnaSurf

            conv = GeomConvert_SurfToAnaSurf(BRep_Tool.Surface_s(face))
            analytic = conv.ConvertToAnalytical(RECOGNISE_TOL)
        except Exception:  # noqa: BLE001 - recognition is best effort: the face stays free-form
            analytic = None
        if analytic is None:
            return FREE_FORM, {"type": str(kind).rsplit("_", 1)[-1]}, ""
        source = str(kind).rsplit("_", 1)[-1]
        adaptor = GeomAdaptor_Surface(analytic)
        kind = adaptor.GetType()
    if kind == T.GeomAbs_Plane:
        ax = adaptor.Plane().Position()
        return "plane", {"origin": _xyz(ax.Location()), "normal": _xyz(ax.Direction())}, source
    if kind == T.GeomAbs_Cylinder:
        c = adaptor.Cylinder()
        ax = c.Position()
        return "cylinder", {"origin": _xyz(ax.Location()), "axis": _xyz(ax.Direction()),
                            "radius": float(c.Radius())}, source
    if kind == T.GeomAbs_Sphere:
        s = adaptor.Sphere()
        return "sphere", {"center": _xyz(s.Location()), "radius": float(s.Radius())}, source
    if kind == T.GeomAbs_Torus:
        t = adaptor.Torus()
        ax = t.Position()
        return "torus", {"center": _xyz(ax.Location()), "axis": _xyz(ax.Direction()),
                         "major_radius": float(t.MajorRadius()), "minor_radius": float(t.MinorRadius())}, source
    if kind == T.GeomAbs_Cone:
        c = adaptor.Cone()
        ax = c.Position()
        axis = _xyz(ax.Direction())
        semi = float(c.SemiAngle())  # signed: the radius grows along +axis when positive
        apex = _xyz(c.Apex())
        if semi < 0:
            axis, semi = -axis, -semi
        return "cone", {"apex": apex, "axis": axis, "half_angle": semi}, source
    return FREE_FORM, {"type": str(kind).rsplit("_", 1)[-1]}, ""


def _sense(face: CadFace, v: np.ndarray, t: np.ndarray) -> int:
    """+1 when the surface's natural normal agrees with the triangles' outward normals, else -1."""
    if not face.analytic:
        return 1
    from .surfaces import project

    corners = v[t]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])  # area-weighted
    _, _, natural = project(face.kind, face.params, corners.mean(axis=1))
    return 1 if float(np.einsum("ij,ij->", normals, natural)) >= 0 else -1


def _merge(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices shared by neighbouring faces (the same edge nodes) merged, so the triangulation is connected."""
    key = np.round(vertices / 1e-7).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return vertices[first], inverse.reshape(-1)[triangles]

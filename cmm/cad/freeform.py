"""Exact projection of points onto free-form faces (B-spline, Bezier, extruded, revolved, offset surfaces).

An analytic face's surface is a few numbers (:mod:`cmm.cad.surfaces`); a free-form one is kept as the face's BREP
text (OpenCASCADE's own format, its placement applied) in ``CadFace.params["brep"]``, so the model still pickles
and copies as plain data (the simulator runs in a process of its own). The first projection onto a face in a
process reads it back and keeps OpenCASCADE's point projection (``GeomAPI_ProjectPointOnSurf``, over the face's
parameter range) for the next ones.
"""

from __future__ import annotations

import os
import tempfile
import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
_CACHE: dict[int, Any] = {}  # hash of a face's BREP text -> (surface, projector, lock)
_LOCK = threading.Lock()


def face_brep(face: Any) -> str:
    """The BREP text of an OpenCASCADE face (with its location), as :func:`project` reads it back."""
    from OCP.BRepTools import BRepTools

    fd, path = tempfile.mkstemp(suffix=".brep")
    os.close(fd)
    try:
        BRepTools.Write_s(face, path)
        with open(path, encoding="ascii", errors="replace") as fh:
            return fh.read()
    finally:
        os.unlink(path)


def _projector(text: str) -> Any:
    key = hash(text)
    with _LOCK:
        got = _CACHE.get(key)
    if got is not None:
        return got
    from OCP.BRep import BRep_Builder, BRep_Tool
    from OCP.BRepTools import BRepTools
    from OCP.Extrema import Extrema_ExtAlgo
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS, TopoDS_Shape

    fd, path = tempfile.mkstemp(suffix=".brep")
    try:
        with os.fdopen(fd, "w", encoding="ascii") as fh:
            fh.write(text)
        shape = TopoDS_Shape()
        BRepTools.Read_s(shape, path, BRep_Builder())
    finally:
        os.unlink(path)
    explorer = TopExp_Explorer(shape, TopAbs_FACE)
    face = TopoDS.Face(explorer.Current()) if explorer.More() else TopoDS.Face(shape)
    surface = BRep_Tool.Surface_s(face)  # the face's location applied
    umin, umax, vmin, vmax = BRepTools.UVBounds_s(face)
    projector = GeomAPI_ProjectPointOnSurf()
    projector.Init(surface, umin, umax, vmin, vmax, Extrema_ExtAlgo.Extrema_ExtAlgo_Grad)
    got = (surface, projector, threading.Lock())
    with _LOCK:
        _CACHE[key] = got
    return got


def project(params: dict[str, Any], points: Array, outward: Array) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
    """Foot points, signed distances (+ on the ``outward`` side: the triangulation's outward normals near each
    point) and outward unit normals of ``points`` (n, 3) on a free-form face's exact surface, and which points it
    projected (a point the projection cannot place keeps NaN)."""
    from OCP.gp import gp_Pnt, gp_Vec

    points = np.asarray(points, float).reshape(-1, 3)
    n = len(points)
    foot = np.full((n, 3), np.nan)
    normal = np.full((n, 3), np.nan)
    dist = np.full(n, np.nan)
    ok = np.zeros(n, dtype=bool)
    text = params.get("brep")
    if not text:
        return foot, dist, normal, ok
    surface, projector, lock = _projector(text)
    p, du, dv = gp_Pnt(), gp_Vec(), gp_Vec()
    with lock:
        for i, q in enumerate(points):
            projector.Perform(gp_Pnt(*map(float, q)))
            if not projector.IsDone() or projector.NbPoints() == 0:
                continue
            u, v = projector.LowerDistanceParameters()
            surface.D1(u, v, p, du, dv)
            nat = np.cross([du.X(), du.Y(), du.Z()], [dv.X(), dv.Y(), dv.Z()])
            length = float(np.linalg.norm(nat))
            if length < 1e-12:  # a degenerate point (a pole): no normal to sign the distance by
                continue
            nat /= length
            if float(nat @ outward[i]) < 0:
                nat = -nat
            f = np.array([p.X(), p.Y(), p.Z()])
            foot[i], normal[i], dist[i], ok[i] = f, nat, float((q - f) @ nat), True
    return foot, dist, normal, ok

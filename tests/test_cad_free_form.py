"""Free-form faces measured on their exact surface: an elliptic cylinder (an ellipse extruded, a surface no analytic
kind describes), 40 x 20 mm across, 30 mm high. A point a known distance d out along the ellipse's normal is d from
the surface exactly (d below the smallest radius of curvature); the triangulation alone is off by up to its chordal
error. The simulator's contacts and the deviations both go through ``CadModel.refine``."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

import cad_support as cs

pytest.importorskip("OCP")

from cmm.cad import FREE_FORM, read_cad  # noqa: E402
from cmm.metrology.mesh import closest_points  # noqa: E402

A, B, H = 20.0, 10.0, 30.0  # semi-axes along X and Y, height (mm)


@pytest.fixture(scope="module")
def elliptic(tmp_path_factory):
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeWire
    from OCP.BRepPrimAPI import BRepPrimAPI_MakePrism
    from OCP.gp import gp_Ax2, gp_Dir, gp_Elips, gp_Pnt, gp_Vec

    edge = BRepBuilderAPI_MakeEdge(gp_Elips(gp_Ax2(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1), gp_Dir(1, 0, 0)), A, B)).Edge()
    face = BRepBuilderAPI_MakeFace(BRepBuilderAPI_MakeWire(edge).Wire()).Face()
    solid = BRepPrimAPI_MakePrism(face, gp_Vec(0, 0, H)).Shape()
    path = cs.write_step(solid, tmp_path_factory.mktemp("free-form") / "elliptic.stp")
    return read_cad(path)


def _offset_points(distances):
    """Points d out from the ellipse along its outward normal, at angles around it, at mid height."""
    t = np.linspace(0.1, 2 * math.pi, len(distances), endpoint=False)
    on = np.stack([A * np.cos(t), B * np.sin(t), np.full_like(t, H / 2)], axis=1)
    n = np.stack([np.cos(t) / A, np.sin(t) / B, np.zeros_like(t)], axis=1)
    n /= np.linalg.norm(n, axis=1)[:, None]
    return on + np.asarray(distances)[:, None] * n, on, n


def test_the_side_of_an_elliptic_cylinder_is_measured_on_its_exact_surface(elliptic):
    (side,) = [f for f in elliptic.faces if f.kind == FREE_FORM]
    assert "brep" in side.params
    d = np.array([0.5, -0.5, 0.05, -0.05, 1.0, 0.2, -1.0, 0.0] * 4)  # + outside the material
    points, on, n = _offset_points(d)
    mesh = elliptic.mesh()
    got = closest_points(mesh, points)  # the deviations' closest points (metrology.mesh)
    np.testing.assert_allclose(got.distances, np.abs(d), atol=1e-7)
    foot_ok = np.abs(d) > 0  # a point on the surface has no direction to compare
    np.testing.assert_allclose(got.points[foot_ok], on[foot_ok], atol=1e-6)
    np.testing.assert_allclose(got.normals, n, atol=1e-6)
    # the triangulation alone: off by up to its chordal error (the exact surface is what changed the answer)
    tri_d = np.linalg.norm(points - np.asarray(mesh.nearest.on_surface(points)[0]), axis=1)
    assert np.max(np.abs(tri_d - np.abs(d))) > 1e-4
    # signed, as the simulator's contacts take it; the model still pickles (the simulator's process)
    copy = pickle.loads(pickle.dumps(elliptic))
    tris = mesh.nearest.on_surface(points)[2]
    foot, signed, normal, exact = copy.refine(points, tris, mesh.nearest.on_surface(points)[0])
    assert exact.all()
    np.testing.assert_allclose(signed, d, atol=1e-7)
    np.testing.assert_allclose(normal, n, atol=1e-6)


def test_the_simulators_contacts_on_a_free_form_face_are_exact(elliptic):
    """The simulator's part (its probe world), placed turned and moved: the distance from the tip's centre to the
    part it reads is the exact one, in machine coordinates."""
    from cmm.sim.cmm_sim import pose_matrix
    from cmm.sim.probe_world import MeshObstacle

    pose = pose_matrix((200.0, 150.0, 5.0), rz_deg=25.0)
    surface = MeshObstacle(elliptic.mesh(), pose)
    d = np.array([0.3, 0.8, 0.05, 0.6])
    points, _, n = _offset_points(d)
    for p, dist, normal in zip(points, d, n):
        machine = (pose @ np.append(p, 1.0))[:3]
        got, out = surface.query(machine)
        assert got == pytest.approx(dist, abs=1e-7)
        np.testing.assert_allclose(out, pose[:3, :3] @ normal, atol=1e-6)

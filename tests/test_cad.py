"""CAD in with exact surfaces (cmm.cad): STEP and IGES read with OpenCASCADE, every face with its exact surface;
picks, nominals, hit plans and deviations take the exact surface, not a fit to triangles.

The NIST simple part is read in place from ../shared/cad (never copied): a 100 x 100 x 50 block with a blind D50
hole 25 deep at (50, 50) opening in the top face. Other geometry is written here with OpenCASCADE
(tests/cad_support.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import cad_support as cs
from shared_refs import shared_path
from cmm.cad import CadError, cad_for_mesh, read_cad
from cmm.measurement.plan import plan_at_pick
from cmm.metrology.hit_plan import plan_feature
from cmm.metrology.mesh import MeshError, load_part, signed_deviation
from cmm.metrology.pick import pick, suggest_feature

SHARED = shared_path("cad")  # NIST's part, read in place
STP, IGS = SHARED / "ipp_simple.stp", SHARED / "ipp_simple.igs"


@pytest.fixture(scope="module")
def nist():
    return read_cad(STP)


@pytest.fixture(scope="module")
def nist_mesh():
    return load_part(STP)


def _faces(model, kind):
    return [f for f in model.faces if f.kind == kind]


def test_nist_step_faces_are_the_exact_block_and_hole(nist):
    assert nist.format == "STEP" and nist.schema == "AP203" and nist.unit == "mm"
    assert nist.counts() == {"plane": 7, "cylinder": 1}
    assert len(nist.bodies) == 1
    (hole,) = _faces(nist, "cylinder")
    assert hole.params["radius"] == 25.0 and hole.sense == -1  # a bore: the material is outside the radius
    np.testing.assert_allclose(hole.params["origin"][:2], [50, 50], atol=1e-12)
    np.testing.assert_allclose(abs(hole.params["axis"] @ [0, 0, 1]), 1.0, atol=1e-15)
    np.testing.assert_allclose(hole.bounds[:, 2], [25.0, 50.0], atol=1e-9)
    # outward normals: six block sides, and the hole's bottom looking up (+Z) out of the material at z 25
    outward = {tuple(np.round(f.sense * f.params["normal"], 12)): float(f.sense * f.params["normal"] @ f.params["origin"])
               for f in _faces(nist, "plane") if abs(f.params["normal"][2]) < 1 or f.bounds[0, 2] != 25.0}
    assert outward[(0.0, 0.0, 1.0)] == 50.0 and outward[(0.0, 0.0, -1.0)] == 0.0
    assert outward[(1.0, 0.0, 0.0)] == 100.0 and outward[(-1.0, 0.0, 0.0)] == 0.0
    bottom = [f for f in _faces(nist, "plane") if np.allclose(f.bounds[:, 2], 25.0)]
    assert len(bottom) == 1 and np.allclose(bottom[0].sense * bottom[0].params["normal"], [0, 0, 1])
    np.testing.assert_allclose(nist.vertices.min(axis=0), [0, 0, 0], atol=1e-9)
    np.testing.assert_allclose(nist.vertices.max(axis=0), [100, 100, 50], atol=1e-9)
    mesh = nist.mesh()
    assert mesh.is_watertight
    exact_volume = 100 * 100 * 50 - math.pi * 25**2 * 25
    assert mesh.volume == pytest.approx(exact_volume, abs=20.0)  # chords cut the hole a little smaller


def test_nist_iges_free_form_faces_are_recognised_as_planes_and_one_cylinder():
    model = read_cad(IGS)
    assert model.format == "IGES" and model.unit == "mm"
    assert model.counts() == {"plane": 7, "cylinder": 2}  # the hole comes as two halves (surfaces of revolution)
    halves = _faces(model, "cylinder")
    assert {f.source for f in halves} == {"SurfaceOfRevolution"}
    assert all(f.source == "BSplineSurface" for f in _faces(model, "plane"))
    assert halves[0].group == halves[1].group  # one feature: a pick on either half gives the whole bore
    for f in halves:
        assert f.params["radius"] == pytest.approx(25.0, abs=1e-9) and f.sense == -1
    # the IGES frame differs from the STEP's: the top face is at z 0, the block below it
    np.testing.assert_allclose(model.vertices.min(axis=0), [0, 0, -50], atol=1e-6)
    np.testing.assert_allclose(model.vertices.max(axis=0), [100, 100, 0], atol=1e-6)
    mesh = model.mesh()
    assert mesh.is_watertight  # the loose IGES faces were sewn into a solid
    kind, params, tris = model.nominal(halves[0].index)
    assert kind == "cylinder" and params["bore"] and params["length"] == pytest.approx(25.0, abs=1e-6)
    assert set(model.tri_face[tris]) == {halves[0].index, halves[1].index}


def test_pick_on_the_drawn_part_maps_to_its_exact_face(nist_mesh):
    cad = cad_for_mesh(nist_mesh)
    pose = np.eye(4)
    pose[:3, 3] = (200.0, 100.0, 0.0)
    hit = pick(nist_mesh, pose, (250.0, 150.0, 40.0), (1.0, 0.3, 0.0))  # from the hole's axis onto its wall
    assert cad.face_of(hit.face_id).kind == "cylinder"
    assert math.hypot(hit.point[0] - 250.0, hit.point[1] - 150.0) == pytest.approx(25.0, abs=1e-9)
    suggestion = suggest_feature(nist_mesh, hit.face_id, pose)
    f = suggestion.feature
    assert f.kind == "cylinder" and f.params["bore"]
    assert abs(f.params["radius"] - 25.0) <= 1e-9
    np.testing.assert_allclose(f.params["point"], [250.0, 150.0, 37.5], atol=1e-9)
    assert f.params["length"] == pytest.approx(25.0, abs=1e-9)


def test_a_picked_fillet_is_its_exact_cylinder_where_the_mesh_fit_was_a_plane(tmp_path):
    path = cs.write_step(cs.filleted_box(7.5), tmp_path / "fillet.step")
    mesh = load_part(path)
    cad = cad_for_mesh(mesh)
    (fillet,) = _faces(cad, "cylinder")
    tri = int(cad.triangles_of([fillet.index])[0])
    f = suggest_feature(mesh, tri).feature
    assert f.kind == "cylinder" and not f.params["bore"]
    assert abs(2 * f.params["radius"] - 15.0) <= 1e-9
    np.testing.assert_allclose(f.params["point"][:2], [52.5, 32.5], atol=1e-9)
    plain = mesh.copy()
    plain.metadata.pop("cad")
    fitted = suggest_feature(plain, tri).feature  # the triangles' smooth region runs into both tangent planes
    assert fitted.kind != "cylinder" or abs(2 * fitted.params["radius"] - 15.0) > 1e-3


def test_box_with_sphere_and_cone_types_and_a_cone_fit_that_was_off(tmp_path):
    path = cs.write_step(cs.box_with_sphere_and_cone(), tmp_path / "box.stp")
    mesh = load_part(path)
    cad = cad_for_mesh(mesh)
    assert cad.counts() == {"plane": 7, "sphere": 1, "cone": 1}
    assert mesh.is_watertight  # the triangles that collapse at the sphere's pole are gone
    (sphere,) = _faces(cad, "sphere")
    (cone,) = _faces(cad, "cone")
    s = suggest_feature(mesh, int(cad.triangles_of([sphere.index])[0])).feature
    assert s.kind == "sphere" and abs(s.params["radius"] - 10.0) <= 1e-9 and not s.params["bore"]
    np.testing.assert_allclose(s.params["center"], [20, 20, 15], atol=1e-9)
    tri = int(cad.triangles_of([cone.index])[0])
    c = suggest_feature(mesh, tri).feature
    assert c.kind == "cone" and abs(c.params["half_angle"] - math.atan(0.5)) <= 1e-12
    np.testing.assert_allclose(c.params["apex"], [45, 20, 36], atol=1e-9)
    np.testing.assert_allclose(c.params["direction"], [0, 0, -1], atol=1e-12)
    plain = mesh.copy()
    plain.metadata.pop("cad")
    fitted = suggest_feature(plain, tri).feature  # the facets make a pyramid: its apex and angle are off
    assert fitted.kind == "cone" and abs(fitted.params["half_angle"] - math.atan(0.5)) > 1e-5


def test_an_inch_file_comes_in_millimetres(tmp_path):
    path = cs.write_step(cs.box_with_sphere_and_cone(), tmp_path / "inch.stp", unit="INCH")
    assert "CONVERSION_BASED_UNIT('INCH'" in path.read_text()
    model = read_cad(path)
    assert model.unit == "inch"
    np.testing.assert_allclose(model.vertices.max(axis=0), [60, 40, 28], atol=1e-6)  # mm, not inches
    (sphere,) = _faces(model, "sphere")
    assert sphere.params["radius"] == pytest.approx(10.0, abs=1e-9)


def test_an_inch_iges_comes_in_millimetres(tmp_path):
    from OCP.IGESControl import IGESControl_Writer

    writer = IGESControl_Writer("IN", 1)  # the file's coordinates in inches, its global section says INCH
    writer.AddShape(cs.box_with_sphere_and_cone())
    writer.ComputeModel()
    path = tmp_path / "inch.igs"
    assert writer.Write(str(path))
    assert "4HINCH" in path.read_text()
    model = read_cad(path)
    assert model.unit == "inch"
    np.testing.assert_allclose(model.vertices.max(axis=0), [60, 40, 28], atol=1e-6)  # mm, not inches
    (sphere,) = _faces(model, "sphere")
    assert sphere.params["radius"] == pytest.approx(10.0, abs=1e-6)


@pytest.mark.parametrize("schema, ap", [("AP203", "AP203"), ("AP214IS", "AP214"), ("AP242DIS", "AP242")])
def test_every_step_schema_is_read(tmp_path, schema, ap):
    path = cs.write_step(cs.filleted_box(7.5), tmp_path / f"{schema}.stp", schema=schema)
    model = read_cad(path)
    assert model.schema == ap and model.counts() == {"plane": 6, "cylinder": 1}
    (fillet,) = _faces(model, "cylinder")
    assert fillet.params["radius"] == pytest.approx(7.5, abs=1e-12) and fillet.sense == 1


def test_an_assembly_is_flattened_with_its_placements(tmp_path):
    model = read_cad(cs.bolt_assembly(tmp_path / "assembly.step"))
    assert len(model.bodies) == 3  # the plate twice and the pin
    holes = sorted((f for f in _faces(model, "cylinder") if f.sense < 0), key=lambda f: f.params["origin"][1])
    assert [round(f.params["radius"], 9) for f in holes] == [5.0, 5.0]
    # the second plate: turned 90° about (25, 15) and lifted 10 mm, its hole moves from (15, 15) to (25, 5)
    np.testing.assert_allclose(holes[0].params["origin"][:2], [25, 5], atol=1e-9)
    np.testing.assert_allclose(holes[1].params["origin"][:2], [15, 15], atol=1e-9)
    assert holes[0].bounds[0, 2] == pytest.approx(10.0, abs=1e-9)
    (pin,) = [f for f in _faces(model, "cylinder") if f.sense > 0]
    assert pin.params["radius"] == pytest.approx(4.0, abs=1e-12) and pin.body != holes[0].body


@pytest.mark.parametrize("name, content, words", [
    ("broken.stp", "ISO-10303-21;\nHEADER;\nFILE_SCHEMA(('AP203'));\nENDSEC;\nDATA;\n#1=GARBAGE(", "is broken or not a valid STEP file"),
    ("empty.step", "", "is not a STEP file"),
    ("mesh.stp", "solid x\nendsolid x\n", "is not a STEP file"),
    ("short.igs", "not an iges file\n", "is not an IGES file"),
])
def test_a_broken_file_gets_one_sentence(tmp_path, name, content, words):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(MeshError) as err:
        load_part(path)
    message = str(err.value)
    assert words in message and name in message
    assert "\n" not in message and "Traceback" not in message


def test_a_step_without_surfaces_is_refused(tmp_path):
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
    from OCP.gp import gp_Pnt

    path = cs.write_step(BRepBuilderAPI_MakeVertex(gp_Pnt(1, 2, 3)).Shape(), tmp_path / "point.stp")
    with pytest.raises(CadError, match="holds no"):
        read_cad(path)


def test_deviations_use_the_exact_distance_on_analytic_faces(nist_mesh):
    rng = np.random.default_rng(3)
    angles = rng.uniform(0, 2 * math.pi, 200)
    depth = rng.uniform(27.0, 48.0, 200)
    offset = rng.uniform(-0.02, 0.02, 200)  # + inside the hole = outside the material
    radial = np.c_[np.cos(angles), np.sin(angles), np.zeros(200)]
    points = np.array([50.0, 50.0, 0.0]) + (25.0 - offset)[:, None] * radial + depth[:, None] * [0, 0, 1]
    exact = signed_deviation(nist_mesh, points)
    np.testing.assert_allclose(exact.deviations, offset, atol=1e-12)
    np.testing.assert_allclose(np.hypot(exact.closest_points[:, 0] - 50, exact.closest_points[:, 1] - 50), 25.0,
                               atol=1e-12)
    plain = nist_mesh.copy()
    plain.metadata.pop("cad")
    chords = signed_deviation(plain, points).deviations - offset
    assert np.abs(chords).max() > 1e-3  # the triangles are chords: up to the 0.01 mm deflection off


def test_a_hit_plan_on_a_cad_pick_takes_the_exact_bore(nist_mesh):
    cad = cad_for_mesh(nist_mesh)
    (hole,) = _faces(cad, "cylinder")
    suggestion = suggest_feature(nist_mesh, int(cad.triangles_of([hole.index])[0]))
    plan = plan_feature(nist_mesh, np.eye(4), suggestion.feature, suggestion.face_ids)
    assert plan.kind == "cylinder" and plan.nominal.params["radius"] == 25.0
    r = np.hypot(plan.points[:, 0] - 50, plan.points[:, 1] - 50)
    np.testing.assert_allclose(r, 25.0, atol=1e-12)  # on the exact bore, not on its chords
    assert (plan.points[:, 2] > 25.0).all() and (plan.points[:, 2] < 50.0).all()


class _Model:
    """What plan_at_pick reads of a measurement model: the part and the probe's tip radius."""

    def __init__(self, mesh, pose):
        from types import SimpleNamespace

        from cmm.measurement.model import Part

        self.part = Part("ipp_simple.stp", mesh, pose)
        self.prober = SimpleNamespace(settings=SimpleNamespace(tip_radius=1.0))


def test_auto_measure_plan_at_a_pick_on_the_hole_bottom(nist_mesh):
    pose = np.eye(4)
    pose[:3, 3] = (100.0, 80.0, 0.0)
    hit = pick(nist_mesh, pose, (140.0, 140.0, 100.0), (0, 0, -1))  # down the hole onto its bottom
    assert cad_for_mesh(nist_mesh).face_of(hit.face_id).kind == "plane"
    assert hit.point[2] == 25.0
    plan = plan_at_pick(_Model(nist_mesh, pose), hit.face_id)
    assert plan.kind == "plane"
    np.testing.assert_allclose(plan.nominal.params["normal"], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(plan.points[:, 2], 25.0, atol=1e-12)


def test_a_point_above_the_hole_is_measured_to_the_rim_not_to_the_plane_around_it(nist_mesh):
    # 3 mm above the top face and 0.3 mm in from the hole's rim: the rim is nearest (the plane under the point is the
    # hole's opening, not material); a foot accepted on the top plane's exact surface would read 3.000
    point = np.array([[50.0 + 25.0 - 0.3, 50.0, 53.0]])
    deviation = signed_deviation(nist_mesh, point).deviations[0]
    assert deviation == pytest.approx(math.hypot(3.0, 0.3), abs=2e-3)

"""Any part on the simulated table: ``--part FILE --part-pose X,Y,Z[,RZ]``. The simulated world holds the CAD part
with its probe contacts on the exact surfaces, the station uses the same file as its nominal CAD, and a part that
would collide with the reference sphere or leave the table is refused with a sentence."""

from __future__ import annotations

import math

import numpy as np
import pytest

import session_support as sup
from shared_refs import shared_path
from cmm.cad import cad_for_mesh
from cmm.cli import main
from cmm.metrology.mesh import load_part
from cmm.sim.cmm_sim import CmmSimSettings, pose_matrix
from cmm.sim.placement import PlacementError, parse_pose
from cmm.sim.probe_world import MeshObstacle, ProbeModel
from cmm.station import Station

STP = shared_path("cad", "ipp_simple.stp")  # read in place, never copied
pytestmark = pytest.mark.skipif(not STP.is_file(), reason=f"the reference part {STP} is not here (set CMM_SHARED)")
POSE = pose_matrix((150.0, 120.0, 0.0), rz_deg=30.0)


@pytest.fixture(scope="module")
def station(module_stations):
    """The station on the in-process simulator (virtual clock) with the NIST part at POSE, homed. Its probe has no
    3-lobed pre-travel (the station's compensation of the lobes leaves about a micrometre on a circle, whatever the
    part): what the hits show is the geometry."""
    settings = CmmSimSettings(probe=ProbeModel(pretravel_lobe=0.0))
    return module_stations.probing("cad", part_path=STP, part_pose=POSE, sim_settings=settings)


def test_the_simulated_contacts_are_on_the_exact_surfaces():
    mesh = load_part(STP)
    exact = MeshObstacle(mesh, POSE)
    chords = MeshObstacle(_plain(mesh), POSE)
    rng = np.random.default_rng(5)
    worst_exact = worst_chords = 0.0
    for a, z, gap in zip(rng.uniform(0, 2 * math.pi, 60), rng.uniform(28, 47, 60), rng.uniform(0.9, 1.1, 60)):
        local = np.array([50 + (25 - gap) * math.cos(a), 50 + (25 - gap) * math.sin(a), z])  # in the hole
        p = sup.to_machine(POSE, local)
        d, n = exact.query(p)
        worst_exact = max(worst_exact, abs(d - gap))
        np.testing.assert_allclose(n, sup.dir_to_machine(POSE, [-math.cos(a), -math.sin(a), 0]), atol=1e-12)
        worst_chords = max(worst_chords, abs(chords.query(p)[0] - gap))
    assert worst_exact < 1e-9
    assert worst_chords > 1e-3  # against the triangles alone the tip would stop up to the 0.01 mm deflection early


def _plain(mesh):
    plain = mesh.copy()
    plain.metadata.pop("cad")
    return plain


def test_the_station_uses_the_part_file_as_its_nominal_cad(station):
    part = station.measurement.part
    assert part.name == "ipp_simple.stp"
    assert cad_for_mesh(part.mesh) is not None and cad_for_mesh(station.sim.part_mesh) is not None
    np.testing.assert_allclose(part.pose, POSE, atol=1e-12)  # the part is where --part-pose says
    np.testing.assert_allclose(station.sim.settings.part_pose, POSE, atol=1e-12)


def test_a_bore_measured_on_the_simulated_part_is_within_a_micrometre_of_the_cad(station):
    m = station.measurement
    ids = []
    for a in np.radians([10, 82, 154, 226, 298]):
        n = np.array([math.cos(a), math.sin(a), 0.0])
        target = sup.to_machine(POSE, np.array([50.0, 50.0, 40.0]) + 25.0 * n)
        hit = m.probe(target, sup.dir_to_machine(POSE, n), clearance_z=m.clearance_z()).wait(120)
        ids.append(m.hit_id(hit))
    feature = m.fit_feature("circle", ids)
    nominal = feature.nominal  # from the CAD face the hits lie on: the exact bore
    assert nominal.kind == "cylinder" and nominal.params["radius"] == 25.0
    centre = sup.to_machine(POSE, [50.0, 50.0, 40.0])
    assert abs(feature.result.radius - 25.0) < 1e-3
    assert np.linalg.norm(feature.result.center[:2] - centre[:2]) < 1e-3


def test_the_hole_bottom_plane_is_within_a_micrometre(station):
    m = station.measurement
    ids = []
    for x, y in ((40, 45), (60, 48), (50, 62)):
        target = sup.to_machine(POSE, [x, y, 25.0])
        hit = m.probe(target, [0, 0, -1], clearance_z=m.clearance_z()).wait(120)
        ids.append(m.hit_id(hit))
    deviations = m.hit_deviations()
    assert all(abs(deviations[i]) < 1e-6 for i in ids)  # a nanometre: the contacts are on the exact plane
    plane = m.fit_feature("plane", ids)
    assert plane.nominal.kind == "plane" and abs(plane.nominal.params["point"][2] - 25.0) < 1e-12


def test_the_next_part_is_moved_and_turned_and_refused_off_the_table(station):
    moved = pose_matrix((200.0, 150.0, 0.0), rz_deg=-15.0)
    station.place_sim_part(moved)
    np.testing.assert_allclose(station.sim.settings.part_pose, moved)
    np.testing.assert_allclose(station.measurement.part.pose, POSE)  # the station believes the set-up until aligned
    with pytest.raises(PlacementError, match="would leave the table"):
        station.place_sim_part(pose_matrix((460.0, 150.0, 0.0)))
    with pytest.raises(PlacementError, match="reference sphere"):
        station.place_sim_part(pose_matrix((330.0, 230.0, 0.0)))
    np.testing.assert_allclose(station.sim.settings.part_pose, moved)  # a refused placement leaves the part alone
    station.place_sim_part(POSE)


@pytest.mark.parametrize("pose, words", [
    ("360,260,0", "would stand in the reference sphere or its stem"),
    ("290,200,0", "come within 6.0 mm of"),
    ("450,100,0", "would leave the table"),
    ("100,100,5", "would float 5.000 mm above the table"),
    ("100,100", "--part-pose needs X,Y,Z or X,Y,Z,RZ"),
])
def test_a_part_that_collides_or_leaves_the_table_is_refused_with_a_sentence(pose, words):
    with pytest.raises(PlacementError) as err:
        Station(port="sim://?cmm=1", part_path=STP, part_pose=parse_pose(pose))
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("command", [
    ["sim", "--cmm", "--tcp", "127.0.0.1:0"],
    ["serve", "--http-port", "0"],
    ["run", "prog.dms"],
    ["calibrate", "probe"],
])
def test_every_front_end_refuses_a_bad_placement_before_anything_moves(tmp_path, monkeypatch, capsys, command):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "prog.dms").write_text("FILNAM/'x'\nUNITS/MM, ANGDEC\nGOTO/100,100,200\nENDFIL\n")
    code = main(command + ["--part", str(STP), "--part-pose", "350,250,0"])
    err = capsys.readouterr().err
    assert code != 0
    assert "reference sphere" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_a_broken_part_file_is_one_sentence_on_the_command_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "part.step").write_text("ISO-10303-21;\nDATA;\n#1=NONSENSE(;\n")
    (tmp_path / "prog.dms").write_text("FILNAM/'x'\nUNITS/MM, ANGDEC\nENDFIL\n")
    assert main(["run", "prog.dms", "--part", "part.step"]) == 2
    err = capsys.readouterr().err.strip()
    assert "part.step" in err and "not a valid STEP file" in err and len(err.splitlines()) == 1

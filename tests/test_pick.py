"""Ray picks on a posed mesh and feature suggestion on the sample part."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cmm.metrology.pick import NominalFeature, pick, suggest_feature
from cmm.metrology.transform import apply_points, apply_vectors, make_pose, rotation_about_axis
from cmm.sim.sample_part import sample_part

POSE = make_pose(rotation_about_axis((0.3, 1.0, -0.2), np.radians(25.0)), (800.0, 450.0, -120.0))


@pytest.fixture(scope="module")
def part():
    return sample_part()


def _pick_part(part, origin, direction, pose=POSE):
    """Pick with a ray given in part coordinates, sent in machine coordinates."""
    mesh, _ = part
    return pick(mesh, pose, apply_points(pose, origin), 7.5 * apply_vectors(pose, direction))


def test_pick_box_posed():
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    origin = apply_points(POSE, [1.0, 2.0, 50.0])
    hit = pick(box, POSE, origin, apply_vectors(POSE, [0.0, 0.0, -3.0]))
    np.testing.assert_allclose(hit.point, apply_points(POSE, [1.0, 2.0, 5.0]), atol=1e-9)
    np.testing.assert_allclose(hit.normal, POSE[:3, 2], atol=1e-12)
    assert hit.distance == pytest.approx(45.0)


def test_pick_nearest_hit_and_misses(part):
    # straight down through the top face: the top (z 40) is hit, not the bottom
    hit = _pick_part(part, [10.0, 10.0, 100.0], [0.0, 0.0, -1.0])
    np.testing.assert_allclose(hit.point, apply_points(POSE, [10.0, 10.0, 40.0]), atol=1e-9)
    assert _pick_part(part, [10.0, 10.0, 100.0], [0.0, 0.0, 1.0]) is None  # pointing away
    assert _pick_part(part, [30.0, 40.0, 100.0], [0.0, 0.0, -1.0]) is None  # down the through bore


def test_pick_curved_normal(part):
    # horizontal ray at the boss: hits the boss side with a radial normal
    hit = _pick_part(part, [70.0, -50.0, 47.0], [0.0, 1.0, 0.0])
    local = np.linalg.solve(POSE[:3, :3], hit.point - POSE[:3, 3])
    assert local[1] == pytest.approx(12.0, abs=2e-3)  # radius 10 minus chordal error
    np.testing.assert_allclose(np.linalg.solve(POSE[:3, :3], hit.normal), [0, -1, 0], atol=0.02)


@pytest.mark.parametrize(
    "name, origin, direction",
    [
        ("top_plane", [10.0, 10.0, 100.0], [0.0, 0.0, -1.0]),
        ("bore", [30.0, 40.0, 20.0], [1.0, 0.3, 0.0]),
        ("boss", [70.0, -50.0, 47.0], [0.0, 1.0, 0.0]),
        ("dome", [71.0, 57.0, 100.0], [0.0, 0.0, -1.0]),
        ("cone", [100.0, -50.0, 45.0], [0.0, 1.0, 0.0]),
        ("boss_top", [71.0, 22.0, 100.0], [0.0, 0.0, -1.0]),
    ],
)
def test_suggest_matches_nominal(part, name, origin, direction):
    mesh, features = part
    hit = _pick_part(part, origin, direction)
    suggestion = suggest_feature(mesh, hit.face_id, POSE)
    got, want = suggestion.feature, features[name].transformed(POSE)
    assert got.kind == want.kind
    g, w = got.params, want.params
    if got.kind == "plane":
        np.testing.assert_allclose(g["normal"], w["normal"], atol=1e-9)
        assert abs((g["point"] - w["point"]) @ w["normal"]) < 1e-9
    elif got.kind == "cylinder":
        assert g["radius"] == pytest.approx(w["radius"], abs=1e-9)
        assert g["bore"] == w["bore"]
        assert abs(g["direction"] @ w["direction"]) == pytest.approx(1.0, abs=1e-12)
        offset = g["point"] - w["point"]
        assert np.linalg.norm(offset - (offset @ w["direction"]) * w["direction"]) < 1e-9
    elif got.kind == "sphere":  # cap edge vertices sit on chords: micrometre level
        assert g["radius"] == pytest.approx(w["radius"], abs=1e-3)
        np.testing.assert_allclose(g["center"], w["center"], atol=1e-3)
        assert g["bore"] is False
    elif got.kind == "cone":
        np.testing.assert_allclose(g["apex"], w["apex"], atol=1e-6)
        np.testing.assert_allclose(g["direction"], w["direction"], atol=1e-9)
        assert g["half_angle"] == pytest.approx(w["half_angle"], abs=1e-9)
        assert g["bore"] is False
    assert suggestion.max_residual < 5e-3


def test_suggest_sphere_cavity_and_conical_hole():
    block = trimesh.creation.box(extents=(60.0, 60.0, 30.0))
    cavity = trimesh.creation.icosphere(subdivisions=4, radius=8.0)
    hole = trimesh.creation.cone(radius=10.0, height=20.0, sections=128)  # apex up at z 20
    hole.apply_translation((-20.0, 0.0, 0.0))
    from cmm.sim.sample_part import _boolean  # double-precision booleans

    mesh = _boolean(block, [cavity, hole], "difference")
    inside = pick(mesh, None, [0.0, 0.0, 0.0], [1.0, 0.2, 0.1])
    s = suggest_feature(mesh, inside.face_id).feature
    assert s.kind == "sphere" and s.params["bore"] is True
    assert s.params["radius"] == pytest.approx(8.0, abs=1e-6)
    cone_hit = pick(mesh, None, [-20.0, 0.0, 10.0], [1.0, 0.0, 0.0])
    c = suggest_feature(mesh, cone_hit.face_id).feature
    assert c.kind == "cone" and c.params["bore"] is True
    np.testing.assert_allclose(c.params["apex"], [-20.0, 0.0, 20.0], atol=1e-9)
    assert c.params["half_angle"] == pytest.approx(np.arctan(0.5), abs=1e-12)


def test_nominal_feature_round_trip():
    f = NominalFeature("cylinder", {"point": [1, 2, 3], "direction": [0, 0, 1], "radius": 2, "bore": True})
    d = f.to_dict()
    assert d == {"kind": "cylinder", "point": [1.0, 2.0, 3.0], "direction": [0.0, 0.0, 1.0], "radius": 2.0, "bore": True}
    with pytest.raises(ValueError, match="unknown feature kind"):
        NominalFeature("torus-ish", {})


def test_suggest_bad_face(part):
    with pytest.raises(ValueError, match="does not exist"):
        suggest_feature(part[0], 10**9)

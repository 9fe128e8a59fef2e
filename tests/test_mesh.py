"""Mesh loading (all formats, error cases) and signed deviation on known geometry."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

from cmm.metrology.mesh import MESH_EXTENSIONS, MeshError, MeshWarning, load_part, signed_deviation
from cmm.metrology.transform import make_pose, rotation_about_axis

# a pose far from the origin: 1000 mm away, rotated about a skew axis
POSE = make_pose(rotation_about_axis((1.0, -2.0, 0.5), np.radians(37.0)), (1000.0, -750.0, 420.0))


def _posed(points):
    return np.asarray(points, dtype=np.float64) @ POSE[:3, :3].T + POSE[:3, 3]


@pytest.fixture(scope="module")
def box():
    return trimesh.creation.box(extents=(40.0, 20.0, 10.0))  # centred at the origin


@pytest.mark.parametrize("ext", MESH_EXTENSIONS)  # CAD formats: tests/test_cad.py
def test_every_format_round_trips(tmp_path, ext, box):
    path = tmp_path / f"part{ext}"
    box.export(path)
    mesh = load_part(path)
    assert mesh.vertices.dtype == np.float64
    assert len(mesh.faces) == 12
    assert mesh.metadata["watertight"]
    assert mesh.volume == pytest.approx(8000.0, rel=1e-6)


def test_ascii_stl_and_scene_flattening(tmp_path, box):
    path = tmp_path / "ascii.stl"
    path.write_text(trimesh.exchange.stl.export_stl_ascii(box))
    assert len(load_part(path).faces) == 12
    # a two-node GLB scene flattens into one mesh with node transforms applied
    other = box.copy()
    other.apply_translation((100.0, 0.0, 0.0))
    scene = trimesh.Scene([box, other])
    glb = tmp_path / "scene.glb"
    scene.export(glb)
    mesh = load_part(glb)
    assert len(mesh.faces) == 24
    assert mesh.bounds[1, 0] == pytest.approx(120.0)


def test_unsupported_extension_lists_supported(tmp_path):
    path = tmp_path / "part.x_t"  # Parasolid: not read (STEP and IGES are, tests/test_cad.py)
    path.write_text("**ABCDEFGHIJKLMNOPQRSTUVWXYZ")
    with pytest.raises(MeshError, match=r"unsupported mesh format '\.x_t'.*\.step.*\.igs.*\.stl.*\.3mf"):
        load_part(path)


def test_missing_file(tmp_path):
    with pytest.raises(MeshError, match="does not exist"):
        load_part(tmp_path / "nope.stl")


@pytest.mark.parametrize("ext", [".3mf", ".glb", ".ply", ".off"])
def test_broken_file_names_the_file(tmp_path, ext):
    path = tmp_path / f"broken{ext}"
    path.write_bytes(b"\x00\x01garbage\xff" * 7)
    with pytest.raises(MeshError, match=f"broken{ext}"):
        load_part(path)


def test_empty_mesh(tmp_path):
    path = tmp_path / "empty.obj"
    path.write_text("# no geometry\n")
    with pytest.raises(MeshError, match="no triangles"):
        load_part(path)


def test_non_finite_vertices(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="NaN or infinite"):
        load_part(path)


def test_open_mesh_warns_and_flags(tmp_path, box):
    open_box = box.copy()
    open_box.update_faces(np.arange(10))  # drop two triangles
    path = tmp_path / "open.stl"
    open_box.export(path)
    with pytest.warns(MeshWarning, match="not watertight"):
        mesh = load_part(path)
    assert mesh.metadata["watertight"] is False


def test_box_deviation_known_offsets_posed(box):
    # points at known offsets along face normals, on faces, edges and corners
    local = np.array(
        [
            [5.0, 3.0, 5.0 + 0.25],  # above +z face
            [5.0, 3.0, 5.0 - 0.25],  # below +z face (inside)
            [-20.0 - 1.5, 2.0, -1.0],  # outside -x face
            [12.0, 10.0 - 0.001, 0.0],  # just inside +y face
            [20.0 + 3.0, 10.0 + 4.0, 0.0],  # outside near an edge: distance 5
            [20.0 + 1.0, 10.0 + 2.0, 5.0 + 2.0],  # outside near a corner: distance 3
            [0.0, 0.0, 0.0],  # centre: 5 inside
        ]
    )
    expected = np.array([0.25, -0.25, 1.5, -0.001, 5.0, 3.0, -5.0])
    result = signed_deviation(box, _posed(local), POSE)
    np.testing.assert_allclose(result.deviations, expected, rtol=0, atol=1e-9)
    # closest points come back in machine coordinates
    np.testing.assert_allclose(result.closest_points[0], _posed([5.0, 3.0, 5.0]), atol=1e-9)
    np.testing.assert_allclose(result.normals[0], POSE[:3, 2], atol=1e-12)
    assert result.min == pytest.approx(-5.0) and result.max == pytest.approx(5.0)
    assert result.rms == pytest.approx(np.sqrt(np.mean(expected**2)))


def test_box_deviation_matches_analytic_field(box):
    rng = np.random.default_rng(0)
    local = rng.uniform((-30, -15, -10), (30, 15, 10), size=(2000, 3))
    q = np.abs(local) - (20.0, 10.0, 5.0)
    exact = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    result = signed_deviation(box, _posed(local), POSE)
    np.testing.assert_allclose(result.deviations, exact, rtol=0, atol=1e-9)
    # trimesh's own convention is the opposite sign
    theirs = trimesh.proximity.signed_distance(box, local[:50])
    np.testing.assert_allclose(result.deviations[:50], -theirs, atol=1e-9)


def test_sphere_deviation_sign_and_size():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=10.0)
    directions = trimesh.unitize(np.random.default_rng(1).normal(size=(200, 3)))
    offsets = np.linspace(-2.0, 2.0, 200)
    result = signed_deviation(sphere, _posed(directions * (10.0 + offsets)[:, None]), POSE)
    # faceted sphere: the facets sit up to ~0.02 mm inside the true radius
    np.testing.assert_allclose(result.deviations, offsets, atol=0.03)
    assert np.all(np.sign(result.deviations[np.abs(offsets) > 0.05]) == np.sign(offsets[np.abs(offsets) > 0.05]))


def test_deviation_rejects_bad_input(box):
    with pytest.raises(MeshError, match="NaN"):
        signed_deviation(box, [[0.0, np.nan, 0.0]])
    with pytest.raises(ValueError, match="4x4"):
        signed_deviation(box, [[0.0, 0.0, 0.0]], np.eye(3))


def test_load_warning_free_for_closed_mesh(tmp_path, box):
    path = tmp_path / "closed.stl"
    box.export(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_part(path)


# ---------------------------------------------------------------- libigl engine, chunks, progress


@pytest.fixture(scope="module")
def fine_sphere():
    return trimesh.creation.icosphere(subdivisions=4, radius=20.0)  # 5,120 faces


def _near_surface(mesh, n, seed):
    pts, faces = trimesh.sample.sample_surface(mesh, n, seed=seed)
    off = np.random.default_rng(seed).uniform(-0.5, 0.5, n)
    return pts + off[:, None] * mesh.face_normals[faces]


def test_same_results_as_igl_signed_distance(fine_sphere):
    """Float64 agreement with libigl's own signed_distance (same sign convention)."""
    import igl

    local = _near_surface(fine_sphere, 3000, seed=5)
    res = signed_deviation(fine_sphere, _posed(local), POSE)
    s, _, c, _ = igl.signed_distance(local, np.asarray(fine_sphere.vertices, np.float64),
                                     np.asarray(fine_sphere.faces, np.int64),
                                     sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
    np.testing.assert_allclose(res.deviations, s, atol=1e-12, rtol=0)
    np.testing.assert_allclose(res.closest_points, _posed(c), atol=1e-9, rtol=0)
    # + = outside the material: points pushed outward along the normal are positive
    r = np.linalg.norm(local, axis=1)
    assert np.all(res.deviations[r > 20.05] > 0) and np.all(res.deviations[r < 19.9] < 0)


def test_chunked_run_reports_progress_and_matches(fine_sphere, monkeypatch):
    from cmm.metrology import mesh as mesh_mod

    pts = _posed(_near_surface(fine_sphere, 1000, seed=6))
    whole = signed_deviation(fine_sphere, pts, POSE)
    monkeypatch.setattr(mesh_mod, "CHUNK", 128)
    calls = []
    chunked = signed_deviation(fine_sphere, pts, POSE, progress=lambda done, total: calls.append((done, total)))
    assert np.array_equal(chunked.deviations, whole.deviations)
    assert np.array_equal(chunked.closest_points, whole.closest_points)
    assert calls[0] == (128, 1000) and calls[-1] == (1000, 1000) and len(calls) == 8

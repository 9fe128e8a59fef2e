"""Meshes as they come: an STL (float32 vertices) of a part turned and placed about 400 mm out
gives the same form-only profile and best fit as the float64 mesh (within 0.1 um); before, the fit slid along the
face on the float32 facets' 1e-5 mm unevenness (128.9 mm instead of 0.0018)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cmm.metrology import gdt
from cmm.metrology.align import best_fit
from cmm.metrology.mesh import load_part
from cmm.metrology.transform import apply_points, make_pose, rotation_about_axis

PLACED = make_pose(rotation_about_axis([0.3, 0.5, 1.0], np.radians(37.0)), (412.3, 387.9, 405.1))


@pytest.fixture
def meshes(tmp_path):
    box = trimesh.creation.box(extents=(40, 30, 20), transform=make_pose(None, (20, 15, 10))).subdivide().subdivide()
    box.apply_transform(PLACED)
    path = tmp_path / "part.stl"
    box.export(path)  # binary STL: float32 vertices
    m32 = load_part(path)
    assert np.abs(np.asarray(m32.vertices) - np.asarray(m32.vertices, np.float32).astype(np.float64)).max() == 0
    return box, m32


def test_form_only_profile_on_a_float32_stl_far_out(meshes):
    box, m32 = meshes
    rng = np.random.default_rng(3)
    top = np.c_[rng.uniform(2, 38, 40), rng.uniform(2, 28, 40), 20 + rng.uniform(-0.001, 0.001, 40)]
    pts = apply_points(PLACED, top)
    exact = gdt.profile("profile of a surface", pts, box, np.eye(4), 0.05).value
    assert exact == pytest.approx(0.0018226693, abs=1e-8)
    assert gdt.profile("profile of a surface", pts, m32, np.eye(4), 0.05).value == pytest.approx(exact, abs=1e-4)


def test_best_fit_on_a_float32_stl_far_out(meshes):
    box, m32 = meshes
    rng = np.random.default_rng(4)
    local = np.r_[np.c_[rng.uniform(2, 38, 20), rng.uniform(2, 28, 20), np.full(20, 20.0)],
                  np.c_[np.full(10, 40.0), rng.uniform(2, 28, 10), rng.uniform(2, 18, 10)],
                  np.c_[rng.uniform(2, 38, 10), np.zeros(10), rng.uniform(2, 18, 10)]]
    moved = make_pose(rotation_about_axis([0, 0, 1], np.radians(0.2)), (0.1, -0.05, 0.02))
    pts = apply_points(moved, apply_points(PLACED, local))
    a = best_fit(box, pts)
    b = best_fit(m32, pts)
    assert np.abs(apply_points(a.transform, local[:5]) - apply_points(b.transform, local[:5])).max() < 1e-4
    assert b.rms < 1e-4

"""3-2-1 alignment and point-to-plane ICP best fit."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cmm.metrology.align import AlignmentError, align_321, best_fit
from cmm.metrology.transform import apply_points, apply_vectors, invert, make_pose, rotation_about_axis
from cmm.sim.sample_part import sample_part

TRUE = make_pose(rotation_about_axis((0.2, -0.4, 1.0), np.radians(123.0)), (612.5, -88.25, 1030.0))


def test_321_recovers_a_known_transform():
    # the sample part's datums in part coordinates, seen by the machine through TRUE
    z, x = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    plane_point = apply_points(TRUE, [37.0, 12.0, 0.0])
    line_point = apply_points(TRUE, [80.0, 0.0, 5.0])  # off the plane: projected into it
    line_dir = apply_vectors(TRUE, x + 0.3 * z)  # tilted out of the plane: projected
    tertiary = apply_points(TRUE, [0.0, 44.0, 17.0])
    T = align_321(plane_point, 2.0 * apply_vectors(TRUE, z), line_point, line_dir, tertiary)
    np.testing.assert_allclose(T, TRUE, atol=1e-10)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


def test_321_degenerate_inputs():
    with pytest.raises(AlignmentError, match="perpendicular to the plane"):
        align_321([0, 0, 0], [0, 0, 1], [1, 1, 1], [0.001, 0, 1], [0, 0, 0])
    with pytest.raises(AlignmentError, match="zero length"):
        align_321([0, 0, 0], [0, 0, 0], [1, 1, 1], [1, 0, 0], [0, 0, 0])
    with pytest.raises(AlignmentError, match="tertiary point"):
        align_321([0, 0, 0], [0, 0, 1], [1, 1, 1], [1, 0, 0], [0, np.nan, 0])


@pytest.fixture(scope="module")
def part_points():
    mesh, _ = sample_part()
    points, _ = trimesh.sample.sample_surface(mesh, 1000, seed=7)
    return mesh, np.asarray(points, dtype=np.float64)


def test_icp_recovers_small_rigid_transform(part_points):
    mesh, points = part_points
    small = make_pose(rotation_about_axis((1.0, 2.0, -0.5), np.radians(1.0)), (0.8, -1.0, 0.6))
    result = best_fit(mesh, apply_points(small, points))
    assert result.converged
    assert result.rms < 1e-6 and result.max_residual < 1e-5
    np.testing.assert_allclose(result.transform, small, atol=1e-9)


def test_icp_from_initial_pose_far_from_origin(part_points):
    mesh, points = part_points
    pose = TRUE @ make_pose(rotation_about_axis((0.0, 1.0, 1.0), np.radians(0.7)), (0.5, 0.2, -0.4))
    result = best_fit(mesh, apply_points(pose, points), initial=TRUE)
    assert result.converged and result.rms < 1e-6
    np.testing.assert_allclose(invert(result.transform) @ pose, np.eye(4), atol=1e-9)


def test_icp_reports_residuals_of_form_error(part_points):
    mesh, points = part_points
    # push 10 points 20 um outside along the normal: residuals show it, sign +
    _, _, faces = trimesh.proximity.closest_point(mesh, points[:10])
    moved = points.copy()
    moved[:10] += 0.02 * mesh.face_normals[faces]
    result = best_fit(mesh, moved)
    assert result.max_residual == pytest.approx(0.02, abs=2e-3)
    assert result.residuals[:10].min() > 0.01


def test_icp_rejects_bad_input(part_points):
    mesh, points = part_points
    with pytest.raises(AlignmentError, match="at least 6"):
        best_fit(mesh, points[:3])
    with pytest.raises(AlignmentError, match="initial pose"):
        best_fit(mesh, points, initial=np.diag([1.0, 1.0, -1.0, 1.0]))

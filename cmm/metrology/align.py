"""Part alignment: 3-2-1 from features, and point-to-plane ICP best fit to the mesh.

Both return a 4x4 part-to-machine pose (x_machine = R @ x_part + t), the
same convention as ``signed_deviation(mesh, points, pose)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from cmm.metrology.geom_basics import live_dof
from cmm.metrology.mesh import closest_points, signed_deviation, surface_index
from cmm.metrology.transform import TransformError, apply_points, as_pose, invert, make_pose, rotation_from_rotvec, unit

Array = NDArray[np.float64]


class AlignmentError(ValueError):
    """Alignment inputs are degenerate or the fit cannot be computed."""


def align_321(
    plane_point: ArrayLike,
    plane_normal: ArrayLike,
    line_point: ArrayLike,
    line_direction: ArrayLike,
    origin_point: ArrayLike,
    min_angle_deg: float = 1.0,
) -> Array:
    """Part coordinate system from a primary plane, secondary line and tertiary point.

    - primary plane (point, normal): part +Z is the plane normal as given, Z = 0 on the plane;
    - secondary line (point, direction): projected into the plane, it is the
      part +X axis (direction sign as given), Y = 0 along it;
    - tertiary point: X = 0 at its projection onto that line.
    Y = Z x X (right-handed). Inputs are in machine coordinates; returns the
    4x4 part-to-machine transform. Raises AlignmentError when the line is
    within ``min_angle_deg`` of the plane normal or a vector is zero/non-finite.
    """
    try:
        z = unit(plane_normal, "primary plane normal")
        d = unit(line_direction, "secondary line direction")
        p0, l0, q = (_point(v, name) for v, name in (
            (plane_point, "primary plane point"), (line_point, "secondary line point"), (origin_point, "tertiary point")))
    except TransformError as exc:
        raise AlignmentError(str(exc)) from exc
    in_plane = d - (d @ z) * z
    if np.linalg.norm(in_plane) < np.sin(np.radians(min_angle_deg)):
        angle = np.degrees(np.arccos(min(abs(d @ z), 1.0)))
        raise AlignmentError(
            f"the secondary line is {angle:.2f} deg from the primary plane normal (nearly perpendicular "
            "to the plane): it cannot define the X direction; probe a line along the plane"
        )
    x = in_plane / np.linalg.norm(in_plane)
    y = np.cross(z, x)
    # line projected into the plane, then the tertiary point's foot on it
    l0p = l0 - ((l0 - p0) @ z) * z
    origin = l0p + ((q - l0p) @ x) * x
    return make_pose(np.column_stack([x, y, z]), origin)


@dataclass(frozen=True)
class BestFitResult:
    """Outcome of fitting measured points to the mesh."""

    transform: Array  # 4x4 part-to-machine pose that best fits the points
    rms: float  # RMS of the signed residuals, mm
    max_residual: float  # largest |residual|, mm
    residuals: Array  # signed deviations at the fitted pose (+ = outside material)
    iterations: int
    converged: bool


def best_fit(
    mesh: trimesh.Trimesh,
    points: ArrayLike,
    initial: ArrayLike | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-10,
) -> BestFitResult:
    """Point-to-plane ICP of measured points (machine coordinates) to the part mesh.

    Each iteration maps the points into part coordinates with the current
    pose, finds their exact closest points and face normals on the mesh and
    solves the linearised (small-angle) least-squares problem for a rotation
    about the points' centroid plus a translation; the step is applied as an
    exact rotation so the pose stays orthonormal. Stops when the step moves
    no point by more than ``tolerance`` mm or after ``max_iterations``.
    ``initial`` is the starting part-to-machine pose (identity if None): ICP
    only finds the nearest minimum, so start within a few mm / degrees (for
    example from align_321).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 6:
        raise AlignmentError(f"best fit needs at least 6 points, got {len(pts)}")
    if not np.all(np.isfinite(pts)):
        raise AlignmentError("measured points contain NaN or infinite coordinates")
    try:
        pose = as_pose(initial)
    except TransformError as exc:
        raise AlignmentError(f"initial pose: {exc}") from exc

    M = invert(pose)  # machine-to-part: the points move, the mesh stays put
    index = surface_index(mesh)
    converged = False
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        q = apply_points(M, pts)
        cp = closest_points(mesh, q, index)
        normals = np.asarray(mesh.face_normals, dtype=np.float64)[cp.face_ids]
        centroid = q.mean(axis=0)
        r = q - centroid
        A = np.c_[np.cross(r, normals), normals]  # d(n.(R q + t))/d(omega, t)
        b = -np.einsum("ij,ij->i", q - cp.points, normals)
        # only the combinations the surface locates (a float32 mesh's 1e-5 mm facets otherwise let it slide)
        B = live_dof(A, np.r_[np.full(3, max(1.0, float(np.linalg.norm(r, axis=1).max()))), np.ones(3)])
        z, *_ = np.linalg.lstsq(A @ B, b, rcond=None)
        step = B @ z
        R = rotation_from_rotvec(step[:3])
        delta = make_pose(R, centroid - R @ centroid + step[3:])
        M = delta @ M
        # largest displacement of any point caused by this step
        moved = np.abs(apply_points(delta, q) - q).max()
        if moved <= tolerance:
            converged = True
            break
    pose = invert(M)
    dev = signed_deviation(mesh, pts, pose)
    return BestFitResult(
        transform=pose,
        rms=dev.rms,
        max_residual=float(np.abs(dev.deviations).max()),
        residuals=dev.deviations,
        iterations=iterations,
        converged=converged,
    )


def _point(value: ArrayLike, what: str) -> Array:
    p = np.asarray(value, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise TransformError(f"the {what} must be 3 finite numbers, got {np.asarray(value).tolist()}")
    return p

"""Rigid-transform helpers on 4x4 homogeneous matrices (float64).

A *pose* is a 4x4 part-to-machine transform: ``x_machine = R @ x_part + t``.
Plain arrays are used throughout (no classes) so poses round-trip through
JSON, session records and trimesh without conversion.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


class TransformError(ValueError):
    """A matrix that should be a rigid transform is not one."""


def as_pose(pose: ArrayLike | None, tol: float = 1e-6) -> Array:
    """Validate and return a 4x4 rigid transform as float64 (None -> identity).

    Raises TransformError when the matrix is not 4x4, not finite, has a
    non-orthonormal rotation block (beyond ``tol``), is a reflection or has a
    bottom row other than [0, 0, 0, 1].
    """
    if pose is None:
        return np.eye(4)
    T = np.array(pose, dtype=np.float64)
    if T.shape != (4, 4):
        raise TransformError(f"a pose must be a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise TransformError("the pose matrix contains NaN or infinite values")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise TransformError(f"the pose's bottom row must be 0 0 0 1, got {T[3].tolist()}")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=tol) or np.linalg.det(R) < 0:
        raise TransformError("the pose's 3x3 block is not a rotation (not orthonormal or mirrored)")
    return T


def make_pose(rotation: ArrayLike | None = None, translation: ArrayLike | None = None) -> Array:
    """Build a 4x4 pose from a 3x3 rotation and a translation vector."""
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = np.asarray(rotation, dtype=np.float64)
    if translation is not None:
        T[:3, 3] = np.asarray(translation, dtype=np.float64)
    return T


def invert(pose: ArrayLike) -> Array:
    """Inverse of a rigid transform (exact R^T form, not a general matrix inverse)."""
    T = np.asarray(pose, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    return make_pose(R.T, -R.T @ t)


def apply_points(pose: ArrayLike, points: ArrayLike) -> Array:
    """Transform an (n, 3) or (3,) array of points."""
    T = np.asarray(pose, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]


def apply_vectors(pose: ArrayLike, vectors: ArrayLike) -> Array:
    """Rotate an (n, 3) or (3,) array of direction vectors (no translation)."""
    T = np.asarray(pose, dtype=np.float64)
    return np.asarray(vectors, dtype=np.float64) @ T[:3, :3].T


def rotation_from_rotvec(rotvec: ArrayLike) -> Array:
    """3x3 rotation for a rotation vector (axis * angle in radians), Rodrigues' formula."""
    w = np.asarray(rotvec, dtype=np.float64)
    angle = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if angle < 1e-8:
        # second-order series keeps small steps accurate to ~1e-24
        return np.eye(3) + K + 0.5 * K @ K
    K /= angle
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def rotation_about_axis(axis: ArrayLike, angle: float) -> Array:
    """3x3 rotation by ``angle`` radians about ``axis`` (any length, non-zero)."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if n == 0.0:
        raise TransformError("rotation axis has zero length")
    return rotation_from_rotvec(a / n * angle)


def unit(vector: ArrayLike, what: str = "vector") -> Array:
    """Normalise a 3-vector; raise TransformError for zero or non-finite input."""
    v = np.asarray(vector, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise TransformError(f"the {what} must be 3 finite numbers, got {np.asarray(vector).tolist()}")
    n = np.linalg.norm(v)
    if n < 1e-12:
        raise TransformError(f"the {what} has zero length")
    return v / n

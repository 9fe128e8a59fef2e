"""Where a part goes on the simulated table: ``--part-pose X,Y,Z[,RZ]`` and the checks before it is put there.

The pose says where the part's CAD origin sits in machine coordinates (mm), turned ``RZ`` degrees about the
machine's Z axis. :func:`check_placement` refuses, with one sentence, a part that would stand in the reference
sphere or its stem (or closer to them than ``SPHERE_CLEARANCE``, the room the probe needs to qualify on the
sphere), sink into or float above the table, or leave the table (the machine's X/Y travel) or rise above
the Z travel.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

SPHERE_CLEARANCE = 10.0  # mm of free space around the reference sphere and its stem
STEM_DIAMETER = 8.0  # mm, the reference sphere's stem (cmm.sim.sample_part.reference_sphere)
REST_TOL = 0.01  # mm: the part's lowest point must be this close to the table top (z = 0)


class PlacementError(ValueError):
    """A part cannot be placed there; the message is one sentence for the operator."""


def parse_pose(text: str) -> np.ndarray:
    """``"X,Y,Z[,RZ]"`` (mm, degrees) -> the 4x4 part -> machine pose."""
    from .cmm_sim import pose_matrix

    try:
        values = [float(v) for v in str(text).replace(" ", "").split(",")]
    except ValueError:
        values = []
    if len(values) not in (3, 4) or not all(math.isfinite(v) for v in values):
        raise PlacementError(f"--part-pose needs X,Y,Z or X,Y,Z,RZ (mm and degrees, e.g. 150,100,0,90), not {text!r}")
    return pose_matrix(tuple(values[:3]), rz_deg=values[3] if len(values) == 4 else 0.0)


def describe_pose(pose: np.ndarray) -> str:
    rz = math.degrees(math.atan2(pose[1, 0], pose[0, 0]))
    return f"X {pose[0, 3]:.3f} Y {pose[1, 3]:.3f} Z {pose[2, 3]:.3f} mm, turned {rz:.3f}° about Z"


def check_placement(mesh: Any, pose: np.ndarray, *, sphere_centre: Any, sphere_diameter: float,
                    travel: tuple[tuple[float, float], tuple[float, float], tuple[float, float]],
                    name: str = "the part") -> None:
    """Raise PlacementError when the posed part collides with the reference sphere or leaves the table."""
    from ..metrology.mesh import signed_deviation
    from ..metrology.transform import apply_points

    pose = np.asarray(pose, dtype=np.float64)
    v = apply_points(pose, np.asarray(mesh.vertices, dtype=np.float64))
    lo, hi = v.min(axis=0), v.max(axis=0)
    (x0, x1), (y0, y1), (_, z1) = travel
    if lo[2] < -REST_TOL:
        raise PlacementError(f"{name} would sink {-lo[2]:.3f} mm into the table at {describe_pose(pose)}: set Z to "
                             f"{pose[2, 3] - lo[2]:.3f} so that its lowest point rests on the table")
    if lo[2] > REST_TOL:
        raise PlacementError(f"{name} would float {lo[2]:.3f} mm above the table at {describe_pose(pose)}: set Z to "
                             f"{pose[2, 3] - lo[2]:.3f} so that its lowest point rests on the table")
    if lo[0] < x0 or hi[0] > x1 or lo[1] < y0 or hi[1] > y1:
        raise PlacementError(f"{name} would leave the table at {describe_pose(pose)}: it spans X {lo[0]:.1f} to "
                             f"{hi[0]:.1f} and Y {lo[1]:.1f} to {hi[1]:.1f} mm, the table X {x0:g} to {x1:g} and "
                             f"Y {y0:g} to {y1:g} mm")
    if hi[2] > z1:
        raise PlacementError(f"{name} is {hi[2]:.1f} mm high, more than the machine's Z travel ({z1:g} mm): the probe "
                             "could not get over it")
    c = np.asarray(sphere_centre, dtype=np.float64)
    r = sphere_diameter / 2.0
    # the sphere's centre and points up its stem, with the room each needs
    heights = np.linspace(0.0, c[2], max(2, int(c[2] // 2.0) + 1))
    probes = np.vstack([c, np.column_stack([np.full_like(heights, c[0]), np.full_like(heights, c[1]), heights])])
    room = np.concatenate([[r + SPHERE_CLEARANCE], np.full(len(heights), STEM_DIAMETER / 2 + SPHERE_CLEARANCE)])
    near = (probes[:, 0] >= lo[0] - room) & (probes[:, 0] <= hi[0] + room) & \
           (probes[:, 1] >= lo[1] - room) & (probes[:, 1] <= hi[1] + room) & (probes[:, 2] <= hi[2] + room)
    if not near.any():
        return
    dev = signed_deviation(mesh, probes[near], pose).deviations
    gap = dev - room[near] + SPHERE_CLEARANCE  # distance from the sphere's (or stem's) surface
    if (dev < room[near]).any():
        worst = float(gap.min())
        what = "stand in" if worst < 0 else f"come within {worst:.1f} mm of"
        raise PlacementError(f"{name} would {what} the reference sphere or its stem at ({c[0]:g}, {c[1]:g}) at "
                             f"{describe_pose(pose)}: keep it {SPHERE_CLEARANCE:g} mm clear so the probe can "
                             "qualify on the sphere")


def travel_of(config: Any) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
    """The machine's X, Y and Z travel (min, max), mm: the table the part must stay on."""
    return tuple((float(config.axis(a).min), float(config.axis(a).max)) for a in "xyz")  # type: ignore[return-value]


PART_HELP = ("the part on the simulated table and the station's nominal CAD: STEP (.step/.stp), IGES (.iges/.igs) "
             "with exact surfaces, or a mesh (STL, OBJ, PLY, 3MF, GLB); default the sample part")
POSE_HELP = ("where the part's CAD origin sits in machine coordinates, mm, turned RZ degrees about the machine's Z "
             "(default: its lowest corner at the nominal set-up 190,150,0, up to the simulator's set-up error)")


def add_part_arguments(parser: Any) -> None:
    """``--part FILE`` and ``--part-pose X,Y,Z[,RZ]`` (cmm sim --cmm, serve, run, calibrate)."""
    parser.add_argument("--part", metavar="FILE", default=None, help=PART_HELP)
    parser.add_argument("--part-pose", metavar="X,Y,Z[,RZ]", default=None, help=POSE_HELP)


def part_pose_of(args: Any) -> np.ndarray | None:
    """The 4x4 pose ``--part-pose`` gives, or None (PlacementError for a malformed one)."""
    text = getattr(args, "part_pose", None)
    return None if text is None else parse_pose(text)

"""The safety rails every motion command passes, whichever front end sent it: frames and the clearance plane.

- **Frames.** Every move and programmed hit names the frame of its coordinates: ``"machine"`` (the axes'
  own) or ``"part"`` (the part's CAD coordinates, through the part's pose: the alignment once one is made,
  the nominal set-up before). Jogs and steps move along the machine axes by definition.
- **The clearance plane** (as PC-DMIS moves): a move that is not probing retracts to the clearance height
  (the part's top plus a margin), travels there and descends onto its target. A caller may ask for a
  ``"straight"`` line instead; it is accepted only when the straight line is proven free of the part:
  the tip's centre stays at least its radius plus ``STRAIGHT_MARGIN`` from the part's surface all along it
  (sphere tracing on the part mesh).
- **Hops within a feature**: a programmed hit may name a hop height below the clearance plane (the hits of a
  feature after its first). Its rapid goes straight when that line is proven free, else over the hop height
  when every leg of that route (climb, cross, descend) is proven free, else over the clearance plane.
- **The reference sphere** (when its place is known: :meth:`Workspace.keep_out`): a route that starts beside or
  under it (in the post of radius ``sphere + tip + SPHERE_MARGIN`` around it and its stand, up to its top) first
  steps out horizontally, away from its axis, before it climbs; a travel that passes over it goes above it.
- **Restart after a fault or a contact retracts first**: the next move backs off along the way the stopped
  motion came (by the retract distance) when that is known, then takes the clearance route, whatever path
  the caller asked for.

Without a part (no mesh known) the route travels at the higher of the start and the target, and a straight
line needs no proof.

The station supplies the part through a :class:`Workspace` (the control core does not know the
measurement model); ``None`` means no part.
"""

from __future__ import annotations

from typing import Any, Protocol, Sequence

import numpy as np

FRAMES = ("machine", "part")
PATHS = ("clearance", "straight")
STRAIGHT_MARGIN = 0.5  # mm between the tip and the part that a straight move must keep, beyond the tip radius
MAX_STEPS = 2000  # sphere-tracing steps before a line counts as not proven free (grazing the surface)
SAMPLE_SPACING = 0.25  # mm between the points of a line checked in one query before any sphere tracing
MAX_SAMPLES = 4000  # points of a line checked in one query (a longer line gets them wider apart)
SPHERE_MARGIN = 5.0  # mm a route keeps beyond the tip radius from a reference sphere (its set-up centre is approximate)


class Workspace(Protocol):
    """The part as the motion rails see it, in machine coordinates."""

    def part_pose(self) -> np.ndarray | None:
        """Part -> machine (4x4); None without a part."""

    def clearance_z(self) -> float | None:
        """The clearance plane (machine Z of the tip centre); None without a part."""

    def surface_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (mm) of machine points to the part's surface: + outside the material."""

    def keep_out(self) -> list[tuple[np.ndarray, float]]:
        """Spheres on stands (centre, radius; machine mm) that routes go around (optional: the reference sphere)."""


class RailError(ValueError):
    """A motion request the rails refuse, in an operator's words (nothing moved)."""


def point3(value: Any, what: str = "a target") -> np.ndarray:
    p = np.asarray(value, dtype=np.float64).reshape(-1) if value is not None else np.zeros(0)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise RailError(f"{what} needs three coordinates X, Y, Z in mm, each a finite number (a value that is "
                        f"not a number or infinite was given: {value!r})")
    return p


def check_frame(frame: Any) -> str:
    if frame not in FRAMES:
        raise RailError(f"say which frame the coordinates are in: 'machine' or 'part' (got {frame!r})")
    return frame


def check_path(path: Any) -> str:
    if path not in PATHS:
        raise RailError(f"a move's path is 'clearance' (over the clearance plane) or 'straight' (got {path!r})")
    return path


def to_machine(point: Any, frame: str, workspace: Workspace | None, *, direction: bool = False) -> np.ndarray:
    """A point (or, with ``direction``, a direction) in ``frame`` as machine coordinates."""
    p = point3(point, "a direction" if direction else "a target")
    if check_frame(frame) == "machine":
        return p
    pose = None if workspace is None else workspace.part_pose()
    if pose is None:
        raise RailError("part coordinates need a part: load one (or give machine coordinates)")
    pose = np.asarray(pose, float)
    return pose[:3, :3] @ p if direction else pose[:3, :3] @ p + pose[:3, 3]


def to_frame(point: Any, frame: str, workspace: Workspace | None) -> np.ndarray | None:
    """A machine point in ``frame`` (None when that frame is not known: part coordinates without a part)."""
    p = np.asarray(point, float)
    if check_frame(frame) == "machine":
        return p
    pose = None if workspace is None else workspace.part_pose()
    if pose is None:
        return None
    pose = np.asarray(pose, float)
    return pose[:3, :3].T @ (p - pose[:3, 3])


def straight_blocked(workspace: Workspace | None, a: Any, b: Any, radius: float,
                     margin: float = STRAIGHT_MARGIN) -> str | None:
    """Why the straight line a -> b of a tip of ``radius`` is not proven free of the part (None: it is free).

    First the line's points ``spacing`` apart, in one query: one closer than ``radius + margin`` blocks it; all
    farther than that plus half the spacing prove it free (no point between two of them can be nearer than
    that half spacing). Otherwise sphere tracing: where the tip's centre is ``d`` from the surface, the next
    ``d - radius - margin`` of the line cannot reach the part, so the line is walked in steps of that length; a
    step that would be empty means the line comes too close."""
    if workspace is None or workspace.part_pose() is None:
        return None
    a, b = np.asarray(a, float), np.asarray(b, float)
    length = float(np.linalg.norm(b - a))
    u = (b - a) / length if length > 0 else np.zeros(3)
    need = radius + margin
    count = min(MAX_SAMPLES, int(np.ceil(length / SAMPLE_SPACING)) + 1)
    ts = np.linspace(0.0, length, max(count, 2))
    ds = np.asarray(workspace.surface_distance(a + ts[:, None] * u[None, :]), float)
    near = np.flatnonzero(ds < need)
    if len(near):
        return _too_close(a + ts[near[0]] * u, float(ds[near[0]]), radius, need)
    if ds.min() >= need + (ts[1] - ts[0]) / 2:
        return None
    t = 0.0
    for _ in range(MAX_STEPS):
        p = a + u * min(t, length)
        d = float(workspace.surface_distance(p[None, :])[0])
        if d < need:
            return _too_close(p, d, radius, need)
        if t >= length:
            return None
        t += d - need + 1e-6
    return "the straight line grazes the part too long to be proven free: use the clearance path"


def _too_close(p: np.ndarray, d: float, radius: float, need: float) -> str:
    return ("the straight line passes {:.2f} mm from the part at X={:.3f} Y={:.3f} Z={:.3f} (the tip needs "
            "{:.2f} mm): use the clearance path").format(max(d - radius, -99.0), *p, need - radius)


def posts(workspace: Workspace | None, radius: float) -> list[tuple[np.ndarray, float]]:
    """(centre, R) of each sphere the workspace keeps out: the tip's centre stays R from its axis below its top
    (``centre z + R``), R = the sphere's radius + the tip's + SPHERE_MARGIN."""
    keep = getattr(workspace, "keep_out", None) if workspace is not None else None
    if keep is None:
        return []
    return [(np.asarray(c, float), float(r) + float(radius) + SPHERE_MARGIN) for c, r in keep()]


def leave_posts(here: Any, around: Sequence[tuple[np.ndarray, float]], toward: Any) -> np.ndarray | None:
    """Where the tip first goes when it stands in a post (beside, over or under a reference sphere, below its
    top): horizontally out from the post's axis to its radius (towards ``toward`` when it stands on the axis), so
    that the climb that follows cannot touch the sphere. None when it stands in none."""
    here = np.asarray(here, float)
    for c, r in around:
        d = here[:2] - c[:2]
        n = float(np.hypot(*d))
        if n >= r or here[2] >= c[2] + r:
            continue
        if n < 1e-6:  # on the axis: out on the side of where it goes next
            d = np.asarray(toward, float)[:2] - c[:2]
            n = float(np.hypot(*d))
            d, n = (d, n) if n > 1e-6 else (np.array([1.0, 0.0]), 1.0)
        out = c[:2] + d / n * (r + 1e-3)
        return np.array([out[0], out[1], here[2]])
    return None


def over_posts(a: Any, b: Any, z: float, around: Sequence[tuple[np.ndarray, float]]) -> float:
    """The height to travel from ``a`` to ``b`` at (``z`` or more): above every post whose axis the travel passes
    within its radius of."""
    a, b = np.asarray(a, float)[:2], np.asarray(b, float)[:2]
    ab = b - a
    for c, r in around:
        t = 0.0 if not ab.any() else float(np.clip((c[:2] - a) @ ab / (ab @ ab), 0.0, 1.0))
        if float(np.hypot(*(a + t * ab - c[:2]))) < r:
            z = max(z, float(c[2]) + r)
    return z


def clearance_route(here: Any, target: Any, clearance_z: float | None, z_max: float,
                    around: Sequence[tuple[np.ndarray, float]] = ()) -> list[np.ndarray]:
    """Retract to the clearance plane, travel in it, descend: the legs from ``here`` to ``target`` (machine).

    The travel height is the highest of the plane, here and the target (never down to the plane from above),
    at most ``z_max``; without a part (no plane) the higher of here and the target. Around reference spheres
    (``around``: :func:`posts`) the route first steps out of a post it starts in and travels above those it
    crosses. Legs that would not move are left out."""
    here, target = np.asarray(here, float), np.asarray(target, float)
    out_of = leave_posts(here, around, target)
    start = here if out_of is None else out_of
    z = max(float(start[2]), float(target[2]))
    z = z if clearance_z is None else max(float(clearance_z), z)
    z = min(over_posts(start, target, z, around), z_max)
    legs = [np.array([start[0], start[1], z]), np.array([target[0], target[1], z]), target]
    if out_of is not None:
        legs.insert(0, out_of)
    out: list[np.ndarray] = []
    last = here
    for leg in legs:
        if np.linalg.norm(leg - last) > 1e-9:
            out.append(leg)
            last = leg
    return out or [target]


def hop_free(workspace: Workspace | None, here: Any, pre: Any, hop_z: float, radius: float) -> bool:
    """Whether the rapid from ``here`` up to ``hop_z`` (never down), across and down to ``pre`` is proven free of the
    part, every leg of it (False without a part: nothing can be proven)."""
    if workspace is None or workspace.part_pose() is None:
        return False
    here, pre = np.asarray(here, float), np.asarray(pre, float)
    corners = [here, np.array([here[0], here[1], max(hop_z, here[2])]),
               np.array([pre[0], pre[1], max(hop_z, pre[2])]), pre]
    return all(straight_blocked(workspace, a, b, radius) is None
               for a, b in zip(corners[:-1], corners[1:]) if np.linalg.norm(b - a) > 1e-9)


def probe_clearance(here: Any, pre: Any, *, path: str, workspace: Workspace | None, radius: float,
                    clearance_z: float | None = None, restart: bool = False,
                    hop_z: float | None = None) -> float | None:
    """:func:`_probe_clearance`, raised over the reference spheres the rapid crosses (None stays None)."""
    z = _probe_clearance(here, pre, path=path, workspace=workspace, radius=radius, clearance_z=clearance_z,
                         restart=restart, hop_z=hop_z)
    return None if z is None else over_posts(here, pre, z, posts(workspace, radius))


def _probe_clearance(here: Any, pre: Any, *, path: str, workspace: Workspace | None, radius: float,
                     clearance_z: float | None = None, restart: bool = False,
                     hop_z: float | None = None) -> float | None:
    """The height a programmed hit's rapid crosses at on its way to the pre-hit point ``pre`` (machine Z of the tip
    centre), or None for a straight rapid: ``clearance_z`` when the caller gave one (below the part's clearance
    plane only when that route is proven free of the part, else the plane), else the part's clearance
    plane, else the higher of here and the pre-hit point. A straight rapid only when asked for, proven free of
    the part and no restart is pending (:class:`RailError` when it is not proven free). With ``hop_z`` (and a
    part, no restart pending): straight when that is proven free, else ``hop_z`` when that route is proven free,
    else as without it."""
    if path == "straight" and not restart:
        why = straight_blocked(workspace, here, pre, radius)
        if why is not None:
            raise RailError(why)
        return None
    if hop_z is not None and not restart and workspace is not None and workspace.part_pose() is not None:
        if straight_blocked(workspace, here, pre, radius) is None:
            return None
        if hop_free(workspace, here, pre, float(hop_z), radius):
            return float(hop_z)
    plane = None if workspace is None else workspace.clearance_z()
    if clearance_z is not None:
        cz = float(clearance_z)
        # a caller's height below the part's plane (a routine step's edited clearance, a program's) is taken only
        # when its route is proven free: one that would cross the part goes over the plane instead
        if plane is not None and cz < plane and not hop_free(workspace, here, pre, cz, radius):
            return float(plane)
        return cz
    return max(float(np.asarray(here, float)[2]), float(np.asarray(pre, float)[2])) if plane is None else float(plane)


def route(here: Any, target: Any, *, path: str, workspace: Workspace | None, radius: float, z_max: float,
          backoff: Sequence[float] | None = None, restart: bool = False) -> list[np.ndarray]:
    """The legs of a move: ``backoff`` first (after a contact), the clearance route unless a straight line was
    asked for, proven free and no restart is pending. Raises :class:`RailError` for a straight line that is not
    proven free."""
    start = np.asarray(here, float)
    legs: list[np.ndarray] = []
    if backoff is not None:
        start = start + np.asarray(backoff, float)
        legs.append(start)
    if path == "straight" and not restart:
        why = straight_blocked(workspace, start, target, radius)
        if why is not None:
            raise RailError(why)
        return legs + [np.asarray(target, float)]
    cz = None if workspace is None else workspace.clearance_z()
    return legs + clearance_route(start, target, cz, z_max, posts(workspace, radius))

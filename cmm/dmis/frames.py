"""DMIS coordinate systems: the current one maps program coordinates (mm) to machine coordinates.

``TRANS`` moves the origin, ``ROTAT`` turns about an axis of the current system, ``DATSET`` builds a system from
datums (primary direction, secondary direction, origins along each axis), ``DATSET/MCS`` is the machine's.
All as 4x4 rigid transforms (program -> machine).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

AXES = {"XAXIS": 0, "YAXIS": 1, "ZAXIS": 2}
DIRS = {"XDIR": (0, 1.0), "YDIR": (1, 1.0), "ZDIR": (2, 1.0), "XMINUS": (0, -1.0), "YMINUS": (1, -1.0),
        "ZMINUS": (2, -1.0)}
ORIGINS = {"XORIG": 0, "YORIG": 1, "ZORIG": 2}


class FrameError(ValueError):
    """A coordinate system that cannot be built from what the program gives."""


def translation(origin: Any) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = np.asarray(origin, float)
    return t


def rotation(axis: int, angle_rad: float) -> np.ndarray:
    """A rotation of the coordinate system about one of its axes (counter-clockwise seen from the axis's tip)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(4)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def apply(frame: np.ndarray, point: Any) -> np.ndarray:
    return frame[:3, :3] @ np.asarray(point, float) + frame[:3, 3]


def apply_vector(frame: np.ndarray, vector: Any) -> np.ndarray:
    return frame[:3, :3] @ np.asarray(vector, float)


def inverse(frame: np.ndarray) -> np.ndarray:
    inv = np.eye(4)
    inv[:3, :3] = frame[:3, :3].T
    inv[:3, 3] = -frame[:3, :3].T @ frame[:3, 3]
    return inv


def datum_frame(entries: list[tuple[str, str, np.ndarray | None, np.ndarray | None]],
                previous: np.ndarray | None = None) -> np.ndarray:
    """A coordinate system from datums, in machine coordinates.

    ``entries``: (datum name, word, location point, direction) in the order of the DATSET statement: the first
    direction word (XDIR ... ZMINUS) fixes its axis exactly, the second turns the next axis about it (with one
    direction word the ``previous`` system is turned the least way onto it; with none its axes stay), and each
    ORIG word puts the origin's coordinate on that axis at the datum's location (a plane: its point; a circle,
    sphere: its centre; an axis: its point). An origin no datum sets stays where the ``previous`` system had it.
    """
    dirs: list[tuple[int, np.ndarray, str]] = []
    origins: list[tuple[int, np.ndarray, str]] = []
    for name, word, point, direction in entries:
        if word in DIRS:
            if direction is None:
                raise FrameError(f"{name} has no direction for {word}: use a plane, line, axis or circle")
            axis, sign = DIRS[word]
            dirs.append((axis, sign * direction / np.linalg.norm(direction), name))
        elif word in ORIGINS:
            if point is None:
                raise FrameError(f"{name} has no location for {word}")
            origins.append((ORIGINS[word], np.asarray(point, float), name))
        else:
            raise FrameError(f"{word} is not a DATSET word: use XDIR, YDIR, ZDIR (XMINUS ...) and XORIG, YORIG, ZORIG")
    if len(dirs) > 2:
        raise FrameError(f"DATSET takes at most two direction words (a primary and a secondary axis), it has {len(dirs)}")
    R_prev = np.eye(3) if previous is None else previous[:3, :3]
    if not dirs:  # origins only: the axes stay the current system's
        R = R_prev.copy()
    else:
        if len(dirs) == 1:  # the primary axis only: the current system turned the least way onto it
            a1, d1, n1 = dirs[0]
            for cand in ((a1 + 1) % 3, (a1 + 2) % 3):
                d2 = R_prev[:, cand] - (R_prev[:, cand] @ d1) * d1
                if np.linalg.norm(d2) > 0.1:
                    dirs.append((cand, d2 / np.linalg.norm(d2), "the current system"))
                    break
        (a1, d1, n1), (a2, d2, n2) = dirs
        if a1 == a2:
            raise FrameError(f"{n1} and {n2} both set the {'XYZ'[a1]} axis")
        d2 = d2 - (d2 @ d1) * d1
        if np.linalg.norm(d2) < 1e-6:
            raise FrameError(f"{n2} is parallel to {n1}: it cannot fix the second axis")
        d2 /= np.linalg.norm(d2)
        axes: list[np.ndarray | None] = [None, None, None]
        axes[a1], axes[a2] = d1, d2
        a3 = 3 - a1 - a2
        # right-handed: x = y cross z, y = z cross x, z = x cross y
        nxt, prv = (a3 + 1) % 3, (a3 + 2) % 3
        axes[a3] = np.cross(axes[nxt], axes[prv])  # type: ignore[arg-type]
        R = np.column_stack(axes)  # type: ignore[arg-type]
    old = np.zeros(3) if previous is None else previous[:3, 3]
    coords = [float(R[:, k] @ old) for k in range(3)]
    seen = set()
    for axis, point, name in origins:
        if axis in seen:
            raise FrameError(f"two datums set the {'XYZ'[axis]} origin")
        seen.add(axis)
        coords[axis] = float(R[:, axis] @ point)
    origin = R @ np.array(coords)
    frame = np.eye(4)
    frame[:3, :3] = R
    frame[:3, 3] = origin
    return frame

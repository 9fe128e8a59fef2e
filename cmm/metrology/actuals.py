"""A feature's actuals where the operator looks for them: X, Y, Z, D, the axis and the angle in the frame of the
alignment in force (part coordinates), or in machine coordinates on demand; the frame named with them.

Used by the Features tab (tree and detail), the report and the CSV (:mod:`cmm.session.report`), so all three give
the same numbers. Pure: a feature's fitted geometry (machine coordinates, as fitted and journalled) and a pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

COLUMNS = ("X", "Y", "Z", "D", "I", "J", "K", "angle")  # the CSV's and the report's actual columns, in order


@dataclass(frozen=True)
class Frame:
    """Where actuals are given: ``pose`` part -> machine (None: machine coordinates) and its name."""

    name: str
    pose: np.ndarray | None = None

    @property
    def label(self) -> str:
        return "machine coordinates" if self.pose is None else f"part coordinates ({self.name})"


MACHINE = Frame("machine")


def alignment_frame(pose: Any, alignment_name: str = "", aligned: bool = True) -> Frame:
    """The frame of the alignment in force; machine coordinates when nothing was aligned (the part's nominal
    set-up is a guess, not an alignment)."""
    if pose is None or not aligned:
        return MACHINE
    return Frame(alignment_name.replace("_", " ").strip() or "alignment", np.asarray(pose, float).reshape(4, 4))


def model_frame(model: Any, machine: bool = False) -> Frame:
    """The live model's frame: its alignment's (``machine``: machine coordinates on demand)."""
    part = model.part
    if machine or part is None:
        return MACHINE
    return alignment_frame(part.pose, getattr(model, "alignment_name", ""), bool(getattr(model, "aligned", False)))


def session_frame(state: Any) -> Frame:
    """A journal's frame (:class:`cmm.journal.state.SessionState`): its last alignment's."""
    a = state.alignment
    if a is None or state.part_pose is None:
        return MACHINE
    names = a.info.get("names") or ()
    return alignment_frame(state.pose_array, f"{a.method} {'/'.join(str(n) for n in names)}")


def _vec(g: dict[str, Any], *keys: str) -> np.ndarray | None:
    for k in keys:
        if g.get(k) is not None:
            v = np.asarray(g[k], float).reshape(-1)
            if v.shape == (3,):
                return v
    return None


def actuals(kind: str, geometry: dict[str, Any], frame: Frame = MACHINE) -> dict[str, float]:
    """{X, Y, Z, D, I, J, K, angle}: the location (centre, point or apex), the diameter, the normal or axis
    (unit) and a cone's included angle (degrees), in ``frame``; only those the kind has."""
    g = geometry
    R, t = (np.eye(3), np.zeros(3)) if frame.pose is None else (frame.pose[:3, :3], frame.pose[:3, 3])
    out: dict[str, float] = {}
    loc = _vec(g, "apex" if kind == "cone" else "center", "center", "point")
    if loc is not None:
        x = R.T @ (loc - t)
        out.update(X=float(x[0]), Y=float(x[1]), Z=float(x[2]))
    r = g.get("radius")
    if kind in ("circle", "cylinder", "sphere", "arc") and r is not None:
        out["D"] = 2.0 * float(r)
    axis = _vec(g, "normal", "direction", "axis")
    if axis is not None and np.linalg.norm(axis) > 0:
        u = R.T @ (axis / np.linalg.norm(axis))
        out.update(I=float(u[0]), J=float(u[1]), K=float(u[2]))
    if kind == "cone" and g.get("half_angle") is not None:
        out["angle"] = math.degrees(2.0 * float(g["half_angle"]))
    return out


def actuals_text(values: dict[str, float]) -> str:
    """``X 12.3456 Y ... D 30.0012 angle 53.130°`` (mm, 4 decimals; the axis 6)."""
    parts = []
    for k in COLUMNS:
        if k in values:
            v = values[k]
            parts.append(f"{k} {v:.3f}°" if k == "angle" else f"{k} {v:.6f}" if k in "IJK" else f"{k} {v:.4f}")
    return " ".join(parts)


def cells(values: dict[str, float]) -> list[str]:
    """The CSV cells of :data:`COLUMNS` (empty where the kind has none)."""
    return ["" if k not in values else f"{values[k]:.6f}" for k in COLUMNS]

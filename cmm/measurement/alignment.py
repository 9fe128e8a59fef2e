"""Guided part alignment on a measurement model: 3-2-1 from measured features, and best fit of hits to the mesh.

3-2-1: the primary plane fixes part Z, the secondary (a plane, or a line)
the X direction, the tertiary (a point, circle, sphere centre or a third
plane) the origin. The same construction on the features' CAD nominals (part
coordinates) gives where that datum system sits in the part, so the new
part -> machine pose is ``measured @ inverse(nominal)``. Best fit moves the
part until the chosen hits lie on the mesh (ICP from the current pose).

Both give an :class:`AlignmentResult` (pose, residuals, the change from the
previous pose) that :func:`apply` journals through ``model.set_alignment``;
the features' nominals move with the part so they still compare.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..metrology.align import AlignmentError, align_321, best_fit
from ..metrology.relations import intersect_plane_plane
from ..metrology.transform import invert


@dataclass
class AlignmentResult:
    method: str  # "3-2-1" or "best_fit"
    pose: np.ndarray  # part -> machine
    residuals: dict[str, float] = field(default_factory=dict)  # mm: rms, max (best fit); per datum (3-2-1)
    info: dict[str, Any] = field(default_factory=dict)  # what to journal with it

    def shift(self, previous: np.ndarray) -> tuple[float, float]:
        """(translation mm, rotation deg) of this pose against ``previous`` at the part origin."""
        d = self.pose @ invert(previous)
        angle = float(np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1.0, 1.0))))
        return float(np.linalg.norm(self.pose[:3, 3] - previous[:3, 3])), angle

    def text(self, previous: np.ndarray | None = None) -> str:
        R, t = self.pose[:3, :3], self.pose[:3, 3]
        lines = [f"**{self.method}**: part origin at X {t[0]:.4f} Y {t[1]:.4f} Z {t[2]:.4f} mm (machine), "
                 f"part X axis ({R[0, 0]:.6f}, {R[1, 0]:.6f}, {R[2, 0]:.6f}) (machine)"]
        if previous is not None:
            dt, da = self.shift(previous)
            lines.append(f"moved {dt:.4f} mm and {da:.4f}° from the previous set-up")
        lines += [f"- {k}: {v * 1000:.2f} µm" for k, v in self.residuals.items()]
        return "\n\n".join(lines[:2]) + ("\n\n" + "\n".join(lines[2:]) if len(lines) > 2 else "")


class _Ns:
    def __init__(self, **kw: Any) -> None:
        self.__dict__.update({k: np.asarray(v, float) for k, v in kw.items()})


def _plane(kind: str, g: dict[str, Any], what: str) -> tuple[np.ndarray, np.ndarray]:
    if kind not in ("plane", "surface"):
        raise AlignmentError(f"the {what} must be a plane, not a {kind}")
    return np.asarray(g["point"], float), np.asarray(g["normal"], float)


def datum_frame(primary: tuple[str, dict], secondary: tuple[str, dict], tertiary: tuple[str, dict]
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(plane point, normal, line point, line direction, origin point) of a 3-2-1 datum system."""
    p0, n0 = _plane(*primary, "primary datum")
    ks, gs = secondary
    kt, gt = tertiary
    if ks in ("circle", "sphere", "point") and kt in ("circle", "sphere", "point"):
        # plane-circle-circle: the line from the secondary centre to the tertiary's is X, the secondary the origin
        a, b = _centre(ks, gs), _centre(kt, gt)
        if np.linalg.norm(b - a) < 1.0:
            raise AlignmentError("the two circles' centres are less than 1 mm apart: they cannot fix X")
        return p0, n0, a, b - a, a
    if ks in ("plane", "surface"):
        ps, ns = _plane(ks, gs, "secondary datum")
        axis = intersect_plane_plane(_Ns(point=p0, normal=n0), _Ns(point=ps, normal=ns))
        lp, ld = axis.point, axis.direction
    elif ks in ("line", "cylinder"):
        lp, ld = np.asarray(gs["point"], float), np.asarray(gs["direction"], float)
    else:
        raise AlignmentError(f"the secondary datum must be a plane or a line (or, with a circle as the tertiary, "
                             f"a circle), not a {ks}")
    if kt in ("point",):
        q = np.asarray(gt["point"], float)
    elif kt in ("circle", "sphere"):
        q = np.asarray(gt["center"], float)
    elif kt == "cylinder":
        q = np.asarray(gt["point"], float)
    elif kt in ("plane", "surface"):
        pt, nt = _plane(kt, gt, "tertiary datum")
        A = np.vstack([n0, np.cross(n0, ld), nt])
        try:
            q = np.linalg.solve(A, np.array([n0 @ p0, np.cross(n0, ld) @ lp, nt @ pt]))
        except np.linalg.LinAlgError:
            raise AlignmentError("the tertiary plane is parallel to the secondary datum: it cannot fix X") from None
    else:
        raise AlignmentError(f"the tertiary datum must be a point, circle, sphere or plane, not a {kt}")
    return p0, n0, lp, ld, q


def _centre(kind: str, g: dict[str, Any]) -> np.ndarray:
    return np.asarray(g["center"] if kind in ("circle", "sphere") else g["point"], float)


def _face_plane(part: Any, pose: np.ndarray, point: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(point, unit normal), part coordinates, of the CAD face nearest to a machine point at ``pose``."""
    from ..metrology.nominal_match import nominal_for_points

    plane = nominal_for_points(part.mesh, pose, [point], "plane")
    if plane is None:
        raise AlignmentError(f"{name} has no CAD nominal and lies on no flat face of the part: measure it on a "
                             "face of the part or give it a nominal")
    local = plane.transformed(invert(pose)).params
    n = np.asarray(local["normal"], float)
    return np.asarray(local["point"], float), n / np.linalg.norm(n)


def _derived_nominal(part: Any, feature: Any, pose: np.ndarray, primary_normal: np.ndarray | None
                     ) -> tuple[str, dict[str, Any]]:
    """The CAD nominal (part coordinates) of a point or line fitted from hand hits that has none: the CAD face it
    was taken on. A point's nominal is its foot on that face; a line's is the line on that face, along the face's
    intersection with the primary datum's nominal plane, through the foot of the measured line's point. Both are
    read at ``pose``; align_features repeats until the pose they give no longer moves them."""
    g = feature.result.geometry()
    inv = invert(pose)
    if feature.kind == "point":
        x = inv[:3, :3] @ np.asarray(g["point"], float) + inv[:3, 3]
        fp, fn = _face_plane(part, pose, np.asarray(g["point"], float), feature.name)
        return "point", {"point": x - ((x - fp) @ fn) * fn}
    if feature.kind == "line":
        lp = np.asarray(g["point"], float)
        fp, fn = _face_plane(part, pose, lp, feature.name)
        x = inv[:3, :3] @ lp + inv[:3, 3]
        d_meas = inv[:3, :3] @ np.asarray(g["direction"], float)
        if primary_normal is None:
            d = d_meas - (d_meas @ fn) * fn
        else:
            d = np.cross(primary_normal, fn)
            if np.linalg.norm(d) < 1e-6:
                raise AlignmentError(f"{feature.name} lies on a face parallel to the primary datum: it cannot fix X")
        d = d / np.linalg.norm(d)
        return "line", {"point": x - ((x - fp) @ fn) * fn, "direction": d if d @ d_meas >= 0 else -d}
    raise AlignmentError(f"{feature.name} has no CAD nominal: measure it on the part or give it one")


def _nominal_part(feature: Any, pose: np.ndarray, part: Any = None, primary_normal: np.ndarray | None = None,
                  at: np.ndarray | None = None) -> tuple[str, dict[str, Any]]:
    """A feature's CAD nominal in part coordinates, as (kind, geometry) of the fitted kind (a hand-hit point or
    line without one: the CAD face it was taken on at the pose ``at``, :func:`_derived_nominal`)."""
    if feature.nominal is None:
        if part is not None and feature.kind in ("point", "line"):
            return _derived_nominal(part, feature, pose if at is None else at, primary_normal)
        raise AlignmentError(f"{feature.name} has no CAD nominal: measure it on the part or give it one")
    n = feature.nominal.transformed(invert(pose))
    p = n.params
    if feature.kind == "circle" and n.kind == "cylinder":
        return "circle", {"center": p["point"], "normal": p["direction"]}
    if n.kind == "surface":
        return "plane", dict(p)
    return n.kind, dict(p)


def align_features(model: Any, primary: int, secondary: int, tertiary: int) -> AlignmentResult:
    """3-2-1 from three measured features with CAD nominals (feature ids)."""
    part = model.part
    if part is None:
        raise AlignmentError("load a part before aligning it")
    feats = []
    for fid in (primary, secondary, tertiary):
        f = model.features.get(fid)
        if f is None:
            raise AlignmentError(f"there is no feature {fid}")
        feats.append(f)
    if len({primary, secondary, tertiary}) < 3:
        raise AlignmentError("3-2-1 needs three different features")
    pose = np.asarray(part.pose, float)
    measured = datum_frame(*[(f.kind, f.result.geometry()) for f in feats])
    derived = any(f.nominal is None for f in feats)
    new = pose
    for _ in range(8 if derived else 1):  # a derived nominal is read at the pose: again until it stands still
        last = new
        nominal, new = _321_pose(feats, measured, new, part)
        if np.max(np.abs(new - last)) < 1e-10:
            break
    p0, n0, lp, ld, q = measured
    n0 = n0 if n0 @ (new[:3, :3] @ nominal[1]) >= 0 else -n0
    # how well the nominal datums land on the measured ones (non-zero when the features are not square)
    unit_n = n0 / np.linalg.norm(n0)
    res = {"primary plane offset": abs(float((new[:3, :3] @ nominal[0] + new[:3, 3] - p0) @ unit_n)),
           "origin point offset": _in_plane(new[:3, :3] @ nominal[4] + new[:3, 3] - q, unit_n)}
    info = {"features": [primary, secondary, tertiary], "names": [f.name for f in feats]}
    return AlignmentResult("3-2-1", new, res, info)


def _in_plane(d: np.ndarray, n: np.ndarray) -> float:
    """The length of ``d`` along the primary plane (its height above the plane is no error of the origin)."""
    return float(np.linalg.norm(d - (d @ n) * n))


def _321_pose(feats: list[Any], measured: tuple, pose: np.ndarray, part: Any) -> tuple[tuple, np.ndarray]:
    """(the nominal datum system, the part pose it gives) with the features' nominals read at ``pose``."""
    now = np.asarray(part.pose, float)  # stored nominals are machine coordinates at the part's pose
    primary = _nominal_part(feats[0], now, part, at=pose)
    normal = np.asarray(primary[1]["normal"], float) if primary[0] == "plane" else None
    nominal = datum_frame(primary, *[_nominal_part(f, now, part, normal, at=pose) for f in feats[1:]])
    p0, n0, lp, ld, q = measured
    # fitted normals and axes carry a canonical sign, not the CAD's: sign them like the nominal seen through
    # the current pose (the part is within a few degrees of it)
    R = pose[:3, :3]
    n0 = n0 if n0 @ (R @ nominal[1]) >= 0 else -n0
    ld = ld if ld @ (R @ nominal[3]) >= 0 else -ld
    return nominal, align_321(p0, n0, lp, ld, q) @ invert(align_321(*nominal))


def best_fit_hits(model: Any, hit_ids: list[int]) -> AlignmentResult:
    part = model.part
    if part is None:
        raise AlignmentError("load a part before aligning it")
    missing = [h for h in hit_ids if h not in model.hits]
    if missing:
        raise AlignmentError(f"no hits with ids {missing}")
    pts = np.array([model.hits[h].point for h in hit_ids], float)
    fit = best_fit(part.mesh, pts, initial=part.pose)
    return AlignmentResult("best_fit", fit.transform, {"RMS": fit.rms, "max residual": fit.max_residual},
                           {"rms": fit.rms, "max_residual": fit.max_residual, "hit_ids": list(hit_ids),
                            "converged": fit.converged})


ON_PART = 0.5  # mm: how far a program's datum hits may lie from the part's surface at the pose it aligns to


def _rigid(frame: Any, what: str) -> np.ndarray:
    T = np.asarray(frame, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise AlignmentError(f"the {what} datum system must be a 4x4 transform of finite numbers")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise AlignmentError(f"the {what} datum system is not a rigid (right-handed, unscaled) transform")
    return T


def align_program_frame(model: Any, measured: Any, nominal: Any, points: Any, name: str = "") -> AlignmentResult:
    """A program's alignment (a DMIS DATSET, or TRANS / ROTAT onto a measured feature) as the part's pose.

    ``measured``: the program's datum system as measured (program -> machine); ``nominal``: the same system built
    from its datums' nominals, i.e. where the program expected it. The part lies ``measured @ inverse(nominal)``
    away from where the program's nominals put it: the station's pose when it started, or the nominal set-up
    (the program was written for the set-up and the station has been aligned since, e.g. on the previous part).
    The candidate whose pose puts the datums' hits (``points``, machine) on the part's surface wins; when neither
    does within :data:`ON_PART` mm, the program's nominals are not this part at either place and nothing moves
    (AlignmentError, in words)."""
    part = model.part
    if part is None:
        raise AlignmentError("load a part before aligning it")
    move = _rigid(measured, "measured") @ invert(_rigid(nominal, "nominal"))
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0 or not np.all(np.isfinite(pts)):
        raise AlignmentError("the alignment needs the datums' hits to check it against the part")
    from ..metrology.mesh import signed_deviation

    candidates = [np.asarray(part.pose, float)]
    setup = getattr(part, "setup", None)
    if setup is not None and not np.allclose(setup, candidates[0], atol=1e-9):
        candidates.append(np.asarray(setup, float))
    best: tuple[float, np.ndarray] | None = None
    for start in candidates:
        pose = move @ start
        off = float(np.max(np.abs(signed_deviation(part.mesh, pts, pose).deviations)))
        if best is None or off < best[0]:
            best = (off, pose)
    off, pose = best  # type: ignore[misc]
    if off > ON_PART:
        raise AlignmentError(f"{name or 'the alignment'}: its datums' hits lie up to {off:.3f} mm from the part "
                             f"at the pose it gives (more than {ON_PART} mm): the program's nominals are not "
                             "this part at its set-up, so the station's part pose was left where it was")
    return AlignmentResult("DMIS", pose, {"datum hits off the part (max)": off},
                           {"names": [name] if name else [], "points": len(pts)})


def apply(model: Any, result: AlignmentResult) -> None:
    """Adopt the alignment (journaled); every feature's nominal moves with the part."""
    previous = np.asarray(model.part.pose, float)
    move = result.pose @ invert(previous)
    model.set_alignment(result.pose, result.method, **result.info)
    for fid, f in list(model.features.items()):
        if f.nominal is not None:
            model.set_feature_nominal(fid, f.nominal.transformed(move))

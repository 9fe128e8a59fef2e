"""Geometric tolerances for `cmm fit`: datums from point files and ``--gdt`` characteristics on the fitted feature.

    cmm fit cylinder bore.txt --datum A=plane:top.txt --datum B=plane:front.txt --datum C=plane:left.txt \\
        --gdt "position=0.05@A|B|C" --nominal 30,40,0,0,0,1 --material MMC --size-limits 29.98,30.02 --internal
    cmm fit plane top.txt --gdt flatness=0.01 --gdt "profile of a surface=0.02" --mesh part.stl
    cmm fit cylinder mid.txt --datum A=cylinder:front_bore.txt --datum B=cylinder:rear_bore.txt --gdt "coaxiality=0.02@A-B"

``--datum LABEL=KIND:FILE`` fits the datum feature (least squares) from its points; a datum plane's normal
points towards the toleranced feature (into the material). The datums of a ``--gdt`` (after ``@``, in
precedence order) build the frame (:mod:`cmm.metrology.datums`): Z along the primary's normal or axis, X along
the secondary's (squared to Z), Y = Z x X. The nominal (``--nominal x,y,z[,dx,dy,dz]``) is in that frame's
coordinates (basic dimensions from the datums); a ``--mesh`` (STL, OBJ, PLY ...) is in the points' coordinates.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from . import gdt
from .datums import DatumError, build_drf, common_datum, datum_from_feature


def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("geometric tolerances (ISO 1101)")
    g.add_argument("--gdt", action="append", default=[], metavar="CHAR=TOL[@A|B|C]",
                   help="a geometric tolerance on the fitted feature, e.g. flatness=0.01, "
                        "'perpendicularity=0.02@A', 'position=0.05@A|B|C' (repeatable)")
    g.add_argument("--datum", action="append", default=[], metavar="LABEL=KIND:FILE",
                   help="a datum feature fitted from a point file, e.g. A=plane:top.txt (repeatable)")
    g.add_argument("--nominal", help="position: nominal location x,y,z[,dx,dy,dz] in the datum frame")
    g.add_argument("--material", choices=("MMC", "LMC"), help="position at MMC or LMC (bonus)")
    g.add_argument("--size-limits", help="low,high diameters of the feature of size (MMC/LMC)")
    g.add_argument("--internal", action="store_true", help="the feature is a hole (MMC/LMC), else a pin")
    g.add_argument("--angle", type=float, help="angularity: the basic angle in degrees")
    g.add_argument("--direction", choices=("radial", "axial"), default="radial", help="runout direction")
    g.add_argument("--mesh", help="profile: the CAD mesh file, in the points' coordinates")


def _floats(text: str, n: tuple[int, ...], what: str) -> list[float]:
    try:
        v = [float(x) for x in text.replace(" ", "").split(",")]
    except ValueError:
        raise gdt.GdtError(f"{what} must be numbers separated by commas, got {text!r}") from None
    if len(v) not in n:
        raise gdt.GdtError(f"{what} needs {' or '.join(str(k) for k in n)} numbers, got {len(v)}")
    return v


def _datums(specs: list[str], towards: np.ndarray) -> dict[str, Any]:
    """The datums of ``--datum`` specs; a plane's normal is turned towards ``towards`` (the toleranced
    feature: into the material), so basic dimensions from the datums are positive as on the drawing."""
    from .fit_criteria import fit
    from .pointfile import read_points_array

    out = {}
    for spec in specs:
        label, _, rest = spec.partition("=")
        kind, _, path = rest.partition(":")
        if not (label and kind and path):
            raise gdt.GdtError(f"--datum takes LABEL=KIND:FILE (e.g. A=plane:top.txt), got {spec!r}")
        g = fit(kind, read_points_array(path), "ls").summary()
        if kind == "plane" and (towards - np.asarray(g["point"])) @ np.asarray(g["normal"]) < 0:
            g["normal"] = [-x for x in g["normal"]]
        out[label.strip().upper()] = datum_from_feature(label, kind, g)
    return out


def evaluate(args: argparse.Namespace, kind: str, summary: dict[str, Any], points: np.ndarray) -> list[dict]:
    """Each ``--gdt`` of the command line evaluated on the fitted feature (raises GdtError / DatumError)."""
    if not args.gdt:
        return []
    datums = _datums(args.datum, points.mean(axis=0))
    mesh = None
    out = []
    for spec in args.gdt:
        head, _, refs = spec.partition("@")
        name, _, tol_text = head.partition("=")
        ch = name.strip().lower()
        try:
            tol = float(tol_text)
        except ValueError:
            raise gdt.GdtError(f"--gdt takes CHARACTERISTIC=TOLERANCE[@A|B|C], got {spec!r}") from None
        labels = [x.strip().upper() for x in refs.replace(",", "|").split("|") if x.strip()]
        missing = [p for x in labels for p in x.split("-") if p not in datums]
        if missing:
            raise DatumError(f"datum {missing[0]} is not given: add --datum {missing[0]}=KIND:FILE")
        if any(len(x.split("-")) > 2 for x in labels):
            raise DatumError("a common datum is two datums, e.g. A-B")
        # "A-B": the common datum of A and B (two coaxial features, or two parallel faces)
        refs_ = [common_datum(*(datums[p] for p in x.split("-"))) if "-" in x else datums[x] for x in labels]
        drf = build_drf(refs_) if labels else None
        if ch in gdt.FORM:
            r = gdt.form(ch, points, tol)
        elif ch in gdt.ORIENTATION:
            r = gdt.orientation(ch, kind, summary, points, drf, tol, angle_deg=args.angle)  # type: ignore[arg-type]
        elif ch == "position":
            if not args.nominal:
                raise gdt.GdtError("position needs --nominal x,y,z[,dx,dy,dz] (in the datum frame)")
            v = _floats(args.nominal, (3, 6), "--nominal")
            nominal = {"point": v[:3], **({"direction": v[3:]} if len(v) == 6 else {})}
            limits = tuple(_floats(args.size_limits, (2,), "--size-limits")) if args.size_limits else None
            r = gdt.position(kind, summary, nominal, tol, drf=drf, points=points, material=args.material or "",
                             size_limits=limits, internal=args.internal)  # type: ignore[arg-type]
        elif ch in ("concentricity", "coaxiality"):
            r = gdt.coaxiality(ch, kind, summary, drf, tol, points=points)  # type: ignore[arg-type]
        elif ch in ("circular runout", "total runout"):
            r = gdt.runout(ch, points, drf, tol, args.direction)  # type: ignore[arg-type]
        elif ch in ("profile of a surface", "profile of a line"):
            if args.mesh and mesh is None:
                from .mesh import load_part

                mesh = load_part(args.mesh)
            r = gdt.profile(ch, points, mesh, np.eye(4), tol, drf=drf)
        else:
            raise gdt.GdtError(f"unknown geometric tolerance {ch!r}; use one of {', '.join(gdt.CHARACTERISTICS)}")
        out.append(r.summary())
    return out

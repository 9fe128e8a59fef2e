"""`cmm deviation MESH POINTS`: signed deviation of measured points to a part mesh."""

from __future__ import annotations

import argparse
import json
import re
import sys

from .pointfile import PointFileError, read_points, read_text

_SPLIT = re.compile(r"[,\s;]+")


class InputError(PointFileError):
    """A points or pose file cannot be read; the message names file and line."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mesh", help="part mesh (.stl .obj .ply .off .glb .gltf .3mf), units mm")
    parser.add_argument(
        "points",
        help="text file, one 'x y z' per line (comma or whitespace separated; "
        "one header line, # comments and blank lines allowed); '-' reads stdin",
    )
    parser.add_argument("--pose", help="text file with the 4x4 part-to-machine transform (16 numbers, row-major)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def read_pose(text: str, source: str = "pose") -> list[list[float]]:
    """Parse 16 numbers (4 rows of 4, any separators, # comments) into a 4x4 list."""
    values: list[float] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        try:
            values += [float(f) for f in _SPLIT.split(line) if f]
        except ValueError:
            raise InputError(f"{source} line {number}: not a number in {raw.strip()!r}") from None
    if len(values) != 16:
        raise InputError(f"{source}: expected 16 numbers (a 4x4 matrix), found {len(values)}")
    return [values[i : i + 4] for i in range(0, 16, 4)]


def run(args: argparse.Namespace) -> int:
    import warnings

    import numpy as np

    from cmm.metrology.mesh import MeshError, MeshWarning, load_part, signed_deviation

    try:
        points = np.array(read_points(args.points))
        pose = np.array(read_pose(read_text(args.pose), args.pose)) if args.pose else None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MeshWarning)
            mesh = load_part(args.mesh)
        for w in caught:
            print(f"warning: {w.message}", file=sys.stderr)
        result = signed_deviation(mesh, points, pose)
    except (InputError, MeshError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1

    if args.json:
        out = {
            "mesh": str(args.mesh),
            "watertight": result.watertight,
            "sign_convention": result.sign_convention,
            "points": [
                {"index": i, "point": p.tolist(), "deviation": float(d), "closest": c.tolist(), "normal": n.tolist()}
                for i, (p, d, c, n) in enumerate(
                    zip(points, result.deviations, result.closest_points, result.normals), start=1
                )
            ],
            "summary": result.summary(),
        }
        print(json.dumps(out, indent=2))
        return 0

    print(f"# {result.sign_convention}")
    print(f"# {'#':>5} {'x':>12} {'y':>12} {'z':>12} {'deviation':>12}")
    for i, (p, d) in enumerate(zip(points, result.deviations), start=1):
        print(f"  {i:5d} {p[0]:12.4f} {p[1]:12.4f} {p[2]:12.4f} {d:+12.6f}")
    s = result.summary()
    print(
        f"# n={s['n']}  min={s['min']:+.6f}  max={s['max']:+.6f}  "
        f"mean={s['mean']:+.6f}  rms={s['rms']:.6f}  (mm)"
    )
    return 0

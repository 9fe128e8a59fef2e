"""`cmm deviation MESH POINTS`: signed deviation of measured points to a part mesh.

Long runs show a progress bar on stderr (``--progress`` forces it, e.g. when
stderr is not a terminal); ``--summary-only`` prints only the statistics.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from typing import Callable, TextIO

from ..metrology.pointfile import PointFileError, read_points_array, read_text

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
    parser.add_argument("--progress", action="store_true",
                        help="always show the progress bar on stderr (default: only on a terminal for long runs)")
    parser.add_argument("--summary-only", action="store_true", help="print only n, min, max, mean and rms")


def progress_bar(stream: TextIO, width: int = 30) -> Callable[[int, int], None]:
    """A progress(done, total) callback drawing one updating line on `stream`."""
    start = time.monotonic()

    def update(done: int, total: int) -> None:
        frac = done / total if total else 1.0
        rate = done / max(time.monotonic() - start, 1e-9)
        bar = "#" * int(round(width * frac))
        stream.write(f"\rdeviation [{bar:<{width}}] {frac:4.0%} {done:,}/{total:,} points, {rate:,.0f} points/s")
        if done >= total:
            stream.write("\n")
        stream.flush()

    return update


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

    from cmm.metrology.mesh import CHUNK, MeshError, MeshWarning, load_part, signed_deviation

    try:
        points = read_points_array(args.points)
        pose = np.array(read_pose(read_text(args.pose), args.pose)) if args.pose else None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MeshWarning)
            mesh = load_part(args.mesh)
        for w in caught:
            print(f"warning: {w.message}", file=sys.stderr)
        show = args.progress or (len(points) > CHUNK and sys.stderr.isatty())
        result = signed_deviation(mesh, points, pose, progress=progress_bar(sys.stderr) if show else None)
    except (InputError, MeshError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1

    if args.summary_only:
        s = result.summary()
        print(json.dumps({"sign_convention": result.sign_convention, **s}) if args.json else
              f"# {result.sign_convention}\n# n={s['n']}  min={s['min']:+.6f}  max={s['max']:+.6f}  "
              f"mean={s['mean']:+.6f}  rms={s['rms']:.6f}  (mm)")
        return 0
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

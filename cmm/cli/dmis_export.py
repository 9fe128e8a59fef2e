"""`cmm dmis-export PROGRAM.toml`: a taught program written as a DMIS program (`cmm run` runs it again)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("program", help="taught program (cmm-program/1 TOML)")
    p.add_argument("-o", "--output", metavar="FILE", help="DMIS program to write (default: PROGRAM.dmi here)")
    p.add_argument("--at", metavar="X,Y,Z[,RZ]", default="190,150,0",
                   help="where the part's origin sits on the machine (mm) and its turn about Z (degrees); "
                        "default 190,150,0: the station's nominal set-up")
    p.add_argument("--tip-radius", type=float, default=None, help="stylus tip radius (default: the configuration's)")
    p.add_argument("--config", metavar="FILE", help="machine configuration TOML (probe distances, tip)")
    p.add_argument("--part", metavar="FILE", help="the part the program was taught on (STL, OBJ, PLY): a feature's "
                   "later hits then hop over it as the routine runner's (the simulator's sample part is found without "
                   "it); without it every hit goes over its clearance height")


def run(args: Any) -> int:
    from ..program.toml_program import ProgramError, load
    from ..machine.config import load as load_config
    from ..dmis.export import to_dmis

    try:
        values = [float(x) for x in args.at.split(",")]
        if len(values) not in (3, 4) or not all(math.isfinite(v) for v in values):
            raise ValueError
    except ValueError:
        print(f"cmm dmis-export: --at needs X,Y,Z or X,Y,Z,RZ in mm and degrees, got {args.at!r}", file=sys.stderr)
        return 2
    x, y, z, *rz = values
    a = math.radians(rz[0] if rz else 0.0)
    pose = [[math.cos(a), -math.sin(a), 0.0, x], [math.sin(a), math.cos(a), 0.0, y], [0.0, 0.0, 1.0, z],
            [0.0, 0.0, 0.0, 1.0]]
    try:
        program = load(args.program)
    except ProgramError as exc:
        print(f"cmm dmis-export: {exc}", file=sys.stderr)
        return 1
    mesh = None
    if args.part:
        from ..metrology.mesh import load_part
        from ..journal.session import file_sha256, mesh_sha256

        try:
            mesh = load_part(args.part)
            sums = {file_sha256(args.part), mesh_sha256(mesh)}  # as a loaded part's, or of a mesh made in memory
        except (OSError, ValueError) as exc:
            print(f"cmm dmis-export: cannot read the part {args.part}: {exc}", file=sys.stderr)
            return 1
        if program.part_sha256 not in sums:
            print(f"cmm dmis-export: {args.part} is not the part {program.part_name!r} the program was taught on",
                  file=sys.stderr)
            return 1
    elif program.part_name == "sample part":  # the simulator's part has no file: made again, as session export does
        from ..session.export import sample_part_mesh

        mesh = sample_part_mesh(program.part_sha256)
    probe = load_config(args.config).probe
    text = to_dmis(program, pose, tip_radius=args.tip_radius or probe.tip_radius, approach=probe.approach_distance,
                   search=probe.search_distance, retract=probe.retract_distance, mesh=mesh)
    out = Path(args.output) if args.output else Path(Path(args.program).stem + ".dmi")
    out.write_text(text, encoding="utf-8")
    print(f"wrote {out}: {len(program.features)} features, {len(program.hits)} hits")
    return 0

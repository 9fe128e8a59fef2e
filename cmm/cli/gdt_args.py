"""The `cmm fit` options of geometric tolerances (see :mod:`cmm.cli.gdt`), in a module that imports
nothing heavy: `cmm fit --help` loads neither scipy nor trimesh nor the GD&T code."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("geometric tolerances (ISO 1101)")
    g.add_argument("--gdt", action="append", default=[], metavar="CHAR=TOL[@A|B|C]",
                   help="a geometric tolerance on the fitted feature, e.g. flatness=0.01, "
                        "'perpendicularity=0.02@A', 'position=0.05@A|B(M)|C', 'profile of a surface=0.1UZ+0.02@A' "
                        "(an unequally disposed profile zone: its middle 0.02 outside the material) (repeatable)")
    g.add_argument("--datum", action="append", default=[], metavar="LABEL=KIND:FILE",
                   help="a datum feature fitted from a point file, e.g. A=plane:top.txt (repeatable)")
    g.add_argument("--datum-size", action="append", default=[], metavar="LABEL=LOW,HIGH,hole|pin",
                   help="a datum feature of size's diameter limits, for a datum referenced at MMB / LMB")
    g.add_argument("--datum-targets", action="append", default=[], metavar="LABEL=I,J,K",
                   help="datum plane LABEL from those points of its file (1 = first line) as target points")
    g.add_argument("--nominal", help="position: nominal location x,y,z[,dx,dy,dz] in the datum frame")
    g.add_argument("--material", choices=("MMC", "LMC"), help="position at MMC or LMC (bonus)")
    g.add_argument("--size-limits", help="low,high diameters of the feature of size (MMC/LMC)")
    g.add_argument("--internal", action="store_true", help="the feature is a hole (MMC/LMC), else a pin")
    g.add_argument("--angle", type=float, help="angularity: the basic angle in degrees")
    g.add_argument("--direction", choices=("radial", "axial"), default="radial", help="runout direction")
    g.add_argument("--mesh", help="profile: the CAD mesh file, in the points' coordinates")

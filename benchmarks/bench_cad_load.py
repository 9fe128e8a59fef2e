"""Load time and memory of CAD parts read with exact surfaces (cmm.cad, OpenCASCADE).

    python benchmarks/bench_cad_load.py [--bodies N] [--keep FILE]

Each file is loaded by ``cmm.metrology.mesh.load_part`` (what ``--part`` and the page do: read, recognise the
surfaces, triangulate, merge) in a fresh Python process, so the figures do not share caches:

- the NIST simple part, STEP and IGES, read in place from ../shared/cad;
- a STEP of about 10 MB written here with OpenCASCADE: N distinct bodies (blocks with a bore, a fused sphere and
  a rounded edge, each moved to its own place), default 400.

Printed per file: its size, the time to import OCP, the time to load it, faces and triangles, and the peak
resident memory of the process above what it held after the imports (VmHWM - VmRSS, Linux).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# NIST's part, read in place: CMM_SHARED, else the shared folder beside the checkout
SHARED = Path(os.environ.get("CMM_SHARED", ROOT.parent / "shared")) / "cad"

CHILD = r"""
import json, sys, time
def rss(key):
    for line in open('/proc/self/status'):
        if line.startswith(key):
            return int(line.split()[1]) / 1024.0
t0 = time.perf_counter()
import OCP.STEPControl, OCP.IGESControl, OCP.BRepMesh  # noqa
import cmm.metrology.mesh as m
t1 = time.perf_counter()
base = rss('VmRSS:')
t2 = time.perf_counter()
mesh = m.load_part(sys.argv[1])
t3 = time.perf_counter()
cad = mesh.metadata['cad']
print(json.dumps({'import_s': t1 - t0, 'load_s': t3 - t2, 'faces': len(cad.faces), 'triangles': len(mesh.faces),
                  'kinds': cad.counts(), 'peak_mb': rss('VmHWM:') - base, 'rss_mb': rss('VmRSS:') - base}))
"""


def write_many_bodies(path: Path, bodies: int) -> Path:
    """A STEP of ``bodies`` distinct solids on a grid: a 40 x 30 x 20 block with a D12 bore, a D10 sphere fused on
    top and a rounded vertical edge, each a copy of its own (no shared geometry), AP214."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut, BRepAlgoAPI_Fuse
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCylinder, BRepPrimAPI_MakeSphere
    from OCP.Message import Message_ProgressRange
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer
    from OCP.TopoDS import TopoDS_Compound
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt, gp_Trsf, gp_Vec

    box = BRepPrimAPI_MakeBox(gp_Pnt(0, 0, 0), 40.0, 30.0, 20.0).Shape()
    bore = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(12, 15, -1), gp_Dir(0, 0, 1)), 6.0, 22.0).Shape()
    body = BRepAlgoAPI_Cut(box, bore).Shape()
    body = BRepAlgoAPI_Fuse(body, BRepPrimAPI_MakeSphere(gp_Pnt(30, 15, 18), 5.0).Shape()).Shape()
    compound, builder = TopoDS_Compound(), BRep_Builder()
    builder.MakeCompound(compound)
    side = int(bodies ** 0.5 + 0.999)
    for k in range(bodies):
        t = gp_Trsf()
        t.SetTranslation(gp_Vec(50.0 * (k % side), 40.0 * (k // side), 0.0))
        builder.Add(compound, BRepBuilderAPI_Transform(body, t, True).Shape())  # a copy: its own geometry
    writer = STEPControl_Writer()
    writer.Transfer(compound, STEPControl_AsIs, True, Message_ProgressRange())
    writer.Write(str(path))
    return path


def measure(path: Path) -> dict:
    env = {"PYTHONPATH": str(ROOT)}
    import os

    env = {**os.environ, **env}
    out = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, default=400, help="bodies in the generated STEP (default 400: ~10 MB)")
    parser.add_argument("--keep", metavar="FILE", help="keep the generated STEP here")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        big = Path(args.keep) if args.keep else Path(tmp) / f"bodies_{args.bodies}.step"
        write_many_bodies(big, args.bodies)
        files = [SHARED / "ipp_simple.stp", SHARED / "ipp_simple.igs", big]
        print(f"{'file':<22} {'size':>9} {'import':>7} {'load':>7} {'faces':>6} {'triangles':>10} {'peak RSS':>9}")
        for f in files:
            r = measure(f)
            print(f"{f.name:<22} {f.stat().st_size / 1e6:7.2f} MB {r['import_s']:6.2f}s {r['load_s']:6.2f}s "
                  f"{r['faces']:6d} {r['triangles']:10d} {r['peak_mb']:7.0f} MB   {r['kinds']}", flush=True)


if __name__ == "__main__":
    main()

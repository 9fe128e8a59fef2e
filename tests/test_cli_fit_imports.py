"""`cmm fit --help` and a 5-point least-squares fit load no heavy module (7 to 33 s to start
on a busy machine): scipy, trimesh, igl and the GD&T / criteria / mesh code are imported only when a command
needs them. Checked by the modules loaded in a fresh interpreter, not by a time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "scipy", "trimesh", "igl", "matplotlib", "viser", "cmm.metrology.gdt", "cmm.metrology.fit_criteria",
         "cmm.metrology.mesh", "cmm.metrology.gdt_eval", "cmm.station")
PROBE = """
import json, sys
from cmm.cli import main
try:
    code = main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
HEAVY = json.loads('{heavy}')
heavy = sorted(m for m in sys.modules if any(m == h or m.startswith(h + ".") for h in HEAVY))
print("MODULES " + json.dumps(heavy), file=sys.stderr)
"""


def _loaded(argv: list[str]) -> tuple[list[str], str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    code = PROBE.replace("{heavy}", json.dumps(list(HEAVY)))
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, env=env, timeout=120)
    line = next(x for x in out.stderr.splitlines() if x.startswith("MODULES "))
    return json.loads(line[len("MODULES "):]), out.stdout


def test_fit_help_loads_no_heavy_module():
    loaded, out = _loaded(["fit", "--help"])
    assert "--gdt" in out and "--method" in out
    assert loaded == []  # not even numpy


def test_a_five_point_plane_fit_loads_no_heavy_module(tmp_path):
    f = tmp_path / "p.txt"
    f.write_text("0 0 0\n10 0 0\n0 10 0\n10 10 0.001\n5 5 0\n")
    loaded, out = _loaded(["fit", "plane", str(f), "--json"])
    assert json.loads(out)["normal"][2] == pytest.approx(1.0, abs=1e-6)
    assert [m for m in loaded if not m.startswith("numpy")] == []


def test_a_criterion_or_a_tolerance_still_loads_what_it_needs(tmp_path):
    f = tmp_path / "p.txt"
    f.write_text("0 0 0\n10 0 0\n0 10 0\n10 10 0.001\n5 5 0\n")
    loaded, out = _loaded(["fit", "plane", str(f), "--method", "minzone", "--gdt", "flatness=0.01", "--json"])
    assert "scipy" in loaded and json.loads(out)["gdt"][0]["ok"]

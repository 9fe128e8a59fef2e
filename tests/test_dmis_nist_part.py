"""Acceptance: NIST's simple DMIS program runs, as NIST wrote it, on the NIST simple part placed as its comments
say, and prints NIST's output within 2 um, all through `cmm run`.

The program's comments put the part's edges on the machine's +X and +Y axes and the hole's axis along +Z: the
part's CAD origin (the STEP file's, a corner of the block) at machine X0 Y0 Z0, unturned, which this machine's
travel (X 0-500, Y 0-400, Z 0-300) reaches; so ``--part-pose 0,0,0`` places it and no line is changed (no DMIS
TRANS is needed; on a machine whose travel could not reach it, ``--part-pose`` elsewhere with a
``D(..) = TRANS/XORIG, x, YORIG, y, ZORIG, z`` added after ``D(START) = DATSET/MCS`` is the way, as the DMIS guide of the docs folder says).
Its 4 mm probe (S(PROBE6), line 12) is qualified first with `cmm calibrate probe --probe PROBE6 --tip-diameter 4`,
on the same simulated table. The shared files are read in place."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from shared_refs import shared_path

SHARED = shared_path()  # NIST's program, its output and its part, read in place
PROGRAM = SHARED / "dmis" / "simple_in.dms"
EXPECTED = SHARED / "dmis" / "simple_out.dms"
PART = SHARED / "cad" / "ipp_simple.stp"
ARTIFACTS = Path(__file__).resolve().parents[1] / "calibration" / "artifacts"  # the shipped sphere certificate
POSE = "0,0,0"  # the part's CAD origin on the machine's origin: its edges on +X and +Y, the hole's axis along +Z


def _cmm(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cmm.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=600)


def _numbers(text: str) -> list[tuple[str, list[float]]]:
    """The statements of a DMIS output with their numbers (continuations joined)."""
    joined = re.sub(r"\$\s*\n\s*", " ", text)
    out = []
    for line in joined.splitlines():
        head = re.sub(r"-?\d+\.\d+", "#", line).replace(" ", "")
        out.append((head, [float(x) for x in re.findall(r"-?\d+\.\d+", line)]))
    return out


@pytest.mark.skipif(not (PROGRAM.is_file() and EXPECTED.is_file() and PART.is_file()),
                    reason="the NIST files are not in ../shared")
def test_the_nist_simple_program_on_the_nist_part_prints_nist_output(tmp_path):
    pytest.importorskip("OCP", reason="reading the STEP part needs OpenCASCADE (cadquery-ocp)")
    records = tmp_path / "calibration"
    shutil.copytree(ARTIFACTS, records / "artifacts")
    place = ["--part", str(PART), "--part-pose", POSE]
    # the program as NIST wrote it asks for a 4 mm probe the station has not qualified: refused before it moves
    done = _cmm("run", str(PROGRAM), "--records", str(records), *place, "-o", str(tmp_path / "no.dms"), cwd=tmp_path)
    assert done.returncode == 1
    assert ("line 13: SNSLCT/S(PROBE6): no qualified probe has a 4.0 mm tip: qualify it with `cmm calibrate probe "
            "--probe PROBE6 --tip-diameter 4.0`") in done.stderr
    assert not (tmp_path / "no.dms").exists()
    # qualify it on the reference sphere, the part on the table
    done = _cmm("calibrate", "probe", "--records", str(records), "--probe", "PROBE6", "--tip-diameter", "4", *place,
                "--quiet", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "probe PROBE6 added to the probe list: 4 mm tip" in done.stdout
    r_eff = float(re.search(r"r_eff = ([\d.]+) mm", done.stdout).group(1))
    assert r_eff == pytest.approx(2.0, abs=0.01)  # the simulator mounted the 4 mm stylus
    # and run the program, unchanged
    out = tmp_path / "simple_out.dms"
    done = _cmm("run", str(PROGRAM), "--records", str(records), *place, "-o", str(out), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    text = out.read_text()
    # each actual is followed by its expanded uncertainty as a DMIS comment ($$), which NIST's output has not
    assert re.search(r"^\$\$ FA\(A_CIRCLE\): U \(95 %\) diameter ", text, re.M), text
    text = "\n".join(line for line in text.splitlines() if not re.match(r"\$\$ FA\(\w+\): U \(95 %\)", line))
    got, want = _numbers(text), _numbers(EXPECTED.read_text())
    assert [g[0] for g in got] == [w[0] for w in want]  # the same statements, in NIST's format
    for (head, g), (_, w) in zip(got, want):
        assert g == pytest.approx(w, abs=0.002), head  # within 2 um


def test_a_mounted_4_mm_stylus_does_not_touch_the_air_over_a_bore():
    """Over the sample part's D30 bore, 1.5 mm above the top face, the nearest material is the bore's rim 15 mm
    away: with a 4 mm stylus mounted the simulator must not answer the bounding box's 1.5 mm (a contact in the air
    the NIST program met over its hole)."""
    import numpy as np

    from cmm.sim.cmm_sim import TRUE_PART_POSE, SimulatedCMM

    sim = SimulatedCMM()
    sim.mount_stylus(4.0)
    assert sim.world.probe.tip_radius == 2.0
    over_bore = (TRUE_PART_POSE @ np.array([30.0, 40.0, 41.5, 1.0]))[:3]
    distance, _ = sim.world.obstacles[1].query(over_bore)
    assert distance == pytest.approx(np.hypot(15.0, 1.5), abs=0.05)
    with pytest.raises(ValueError, match="a stylus tip of 40 mm cannot be mounted"):
        sim.mount_stylus(40.0)


def test_calibrate_refuses_a_stylus_whose_tip_is_not_the_listed_one(tmp_path):
    records = tmp_path / "calibration"
    shutil.copytree(ARTIFACTS, records / "artifacts")
    done = _cmm("calibrate", "probe", "--records", str(records), "--probe", "Probe1", "--tip-diameter", "3",
                "--quiet", cwd=tmp_path)
    assert done.returncode == 1
    assert "the probe Probe1 of the list has a 2 mm tip, not 3 mm: give another name to a stylus with another tip" \
        in done.stderr
    done = _cmm("calibrate", "probe", "--records", str(records), "--probe", "T9", "--quiet", cwd=tmp_path)
    assert done.returncode == 1 and "the probe list has no probe T9: give its tip with --tip-diameter D" in done.stderr

"""The DMIS that vendors export, run on the simulated station against its true part: a head mount (SNSMNT), a
probe with its stylus length, saved and recalled alignments (SAVE/RECALL), a DATSET with one direction, a
TRANS / ROTATE chain (ROTATE read as ROTAT with a warning), operator texts and a query, output files named on
another PC's disk written into the run's output folder only, constructions and TOL/POS 2D and 3D on a cylinder
and a point; and the strict check: non-finite and absurd numbers refused with their line, a missing ENDFIL
warned about."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import session_support as sup
from cmm.dmis.check import check, warnings
from cmm.dmis.executor import DmisError
from cmm.dmis.frames import datum_frame
from cmm.dmis.runner import run_text
from cmm.dmis.rules import device_file
from cmm.sim.cmm_sim import TRUE_PART_POSE

VENDOR = Path(__file__).parent / "data" / "dmis" / "vendor_export.dms"
NOISE = 0.004  # mm: two encoder counts and the probe's repeatability


@pytest.fixture
def station(tmp_path):
    """The station on the in-process simulator (virtual clock), homed, a session open."""
    yield from sup.sim_station(tmp_path, "vendor")


def _actuals(text: str) -> dict[str, list[float]]:
    joined = re.sub(r"\$\s*\n", " ", text)
    return {m.group(1): [float(x) for x in m.group(2).split(",")]
            for m in re.finditer(r"^FA\((\w+)\) = FEAT/[A-Z, ]+?,\s+([-\d., ]+)$", joined, re.M)}


def _tolerances(text: str) -> dict[str, tuple[float, str]]:
    return {m.group(1): (float(m.group(2)), m.group(3))
            for m in re.finditer(r"^TA\((\w+)\) = TOL/[A-Z0-9, ]+?, (-?[\d.]+), (INTOL|OUTOL)$", text, re.M)}


def test_a_vendor_export_runs_with_its_alignments_texts_and_output_files(station):
    text = VENDOR.read_text()
    stmts, problems = check(text)
    assert problems == []
    assert warnings(text, stmts) == ["line 71: ROTATE is not DMIS: read as ROTAT (write ROTAT/...)"]
    asked: list[tuple[str, bool]] = []
    told: list[str] = []
    result = run_text(text, station.controller.commands, name=VENDOR.name, on_prompt=told.append,
                      query=lambda prompt, answer: asked.append((prompt, answer)) or "SN-0042")
    assert asked == [("line 15: Serial number of the part:", True)]
    assert "Clamp the block with its corner at X190 Y150" in told  # TEXT/OPER, on the page's program status
    assert "warning: line 71: ROTATE is not DMIS: read as ROTAT (write ROTAT/...)" in result.log
    # the files the program names on the vendor's disk (and one that climbs out) are the run's, by their last name
    assert set(result.outputs) == {"vendor_part.dms", "escape.dms"}
    assert any("DID(LOG1) is written as escape.dms in the run's output folder" in line for line in result.log)
    out = result.outputs["vendor_part.dms"]
    lines = out.splitlines()
    assert lines[:2] == ["FILNAM/'VENDOR EXPORT - SAMPLE BLOCK OP20'", "UNITS/MM, ANGDEC"] and lines[-1] == "ENDFIL"
    assert "TEXT/OUTFIL, 'Serial number of the part: SN-0042'" in lines
    assert "TEXT/OUTFIL, 'OP20 inspected on the station'" in lines
    log1 = result.outputs["escape.dms"]
    assert "OUTPUT/FA(PT_TOP)" in log1 and log1.count("FA(PT_TOP) = FEAT") == 1  # closed before the last OUTPUT
    assert out.count("FA(PT_TOP) = FEAT") == 2
    fa, ta = _actuals(out), _tolerances(out)
    assert fa["CYL_BORE"][:2] == pytest.approx([0.0, 0.0], abs=NOISE) and fa["CYL_BORE"][6] == pytest.approx(30.0, abs=NOISE)
    # the boss in the part frame (ALN_ABC recalled): X40 Y-18 from the bore, whatever the local frame it was measured in
    assert fa["CYL_BOSS"][:2] == pytest.approx([40.0, -18.0], abs=NOISE)
    assert fa["CYL_BOSS"][6] == pytest.approx(20.0, abs=NOISE)
    assert ta["DIAM_B"][1] == "INTOL" and abs(ta["DIAM_B"][0]) < NOISE
    assert ta["FLAT_A"][1] == "INTOL" and ta["CYL_B"][1] == "INTOL"
    # a distance between two axes carries their tilts over the 40 mm between the bore's and the boss's points:
    # one encoder count on one hit of the 15 mm boss moves it 3 um (seen: 3.0 and 5.8 um as the sampling varied)
    assert ta["DIST_BOSS"][0] == pytest.approx(math.hypot(40.0, 18.0) - 43.863, abs=2 * NOISE)
    # 2D: across the boss axis at its axis point; 3D: the axis over its length; both well inside 0.1
    assert ta["POS2D_BOSS"][0] < 0.02 and ta["POS3D_BOSS"][0] < 0.03 and ta["POS2D_BOSS"][0] <= ta["POS3D_BOSS"][0] + 1e-6
    # the point whose nominal is 0.03 above the face: 2D (in the XY working plane) sees nothing, 3D twice 0.03
    assert ta["POS2D_PT"][0] < 2 * NOISE
    assert ta["POS3D_PT"][0] == pytest.approx(0.06, abs=2 * NOISE)
    # every TA line is followed by its U, as each FA line (the size's is the feature budget's diameter U; the
    # others propagated through DMIS's own evaluation of the word)
    for k, x in enumerate(lines):
        if x.startswith("TA("):
            label = x[3:x.index(")")]
            assert re.match(rf"\$\$ TA\({label}\): U \(95 %\) 0\.0\d+ k=2\.\d\d$", lines[k + 1]), lines[k + 1]
    bore_u = re.search(r"^\$\$ FA\(CYL_BORE\): U \(95 %\) diameter ([\d.]+)", out, re.M).group(1)
    assert f"$$ TA(DIAM_B): U (95 %) {bore_u} k=" in out
    # constructions: the bore axis pierces the top at the origin; the edge runs along X at Y -40, Z 0
    assert fa["PT_PIERCE"][:3] == pytest.approx([0.0, 0.0, 0.0], abs=NOISE)
    assert fa["LIN_EDGE"][1:3] == pytest.approx([-40.0, 0.0], abs=NOISE)
    # the last OUTPUT in the recalled partial alignment ALN_A: Z from the top face, X and Y the set-up's
    last = _actuals(out.split("RECALL/DA(ALN_A)")[1])["PT_TOP"]
    truth = (TRUE_PART_POSE @ np.array([10.0, 60.0, 40.0, 1.0]))[:3] - [190.0, 150.0, 40.0]
    assert last[:3] == pytest.approx([truth[0], truth[1], 0.0], abs=0.01)


def test_datset_with_one_direction_keeps_the_rest_of_the_current_system():
    tilted = np.array([0.0, 0.01, 1.0]) / np.linalg.norm([0.0, 0.01, 1.0])
    frame = datum_frame([("DAT(A)", "ZDIR", np.array([5.0, 6.0, 40.0]), tilted), ("DAT(A)", "ZORIG",
                         np.array([5.0, 6.0, 40.0]), tilted)])
    assert frame[:3, 2] == pytest.approx(tilted) and frame[:3, 0] == pytest.approx([1.0, 0.0, 0.0])
    assert frame[:3, 3] @ tilted == pytest.approx(np.array([5.0, 6.0, 40.0]) @ tilted)
    previous = np.eye(4)
    previous[:3, 3] = [1.0, 2.0, 3.0]
    origins = datum_frame([("FA(P)", "XORIG", np.array([7.0, 0.0, 0.0]), None)], previous)
    assert origins[:3, :3] == pytest.approx(np.eye(3)) and origins[:3, 3] == pytest.approx([7.0, 2.0, 3.0])


POINT_P = "F(P) = FEAT/POINT, CART, 1, 2, 40, 0, 0, 1\nMEAS/POINT, F(P), 1\nENDMES\n"  # lines 1-3


@pytest.mark.parametrize("program, problem", [
    ("GOTO/1e308, 0, 0\n", "line 1: 1e308 is not a usable number (more than 1e+06 in size)"),
    ("UNITS/MM\nF(P) = FEAT/POINT, CART, nan, 0, 0, 0, 0, 1\n", "line 2: nan is not a finite number"),
    ("GOTO/1e999, 0, 0\n", "line 1: 1e999 is not a finite number"),
    ("GOTO/1e300*1e300, 0, 0\n", "line 1: 1e300*1e300 is not a finite number"),
    ("GOTO/X1, 0, 0\n", "line 1: X1 is not a number (nor a variable given a value by DECL, ASSIGN or DO)"),
    ("SAVE/DA(NONE)\n", "line 1: SAVE/DA(NONE): nothing named DA(NONE) is defined before it"),
    ("DID(X) = DEVICE/STOR, 'a.dms'\nOPEN/DID(X), FDATA, VENDOR, OUTPUT\n",
     "line 2: OPEN/DID(..), FDATA, VENDOR is not supported: the station writes FDATA in the DMIS format only"),
    ("SNSMNT/XVEC, 1, 0, 0, ZVEC, 1, 0, 0, MNTOFF, 0, 0, 0\n", "line 1: SNSMNT: XVEC and ZVEC must be perpendicular"),
    ("SNSMNT/XVEC, 1, 0, 0, ZVEC, 0, 1, 0, MNTOFF, 0, 0, 0\nS(P) = SNSDEF/PROBE, FIXED, CART, 0, 0, 0, 0, 0, -1, 2\n",
     "line 2: S(P) points along (0, -1, 0): the station has one fixed probe pointing down (0, 0, -1)"),
    ("TEXT/OPER\n", "line 1: TEXT/OPER needs its text in quotes: TEXT/OPER, 'text'"),
    ("F(P) = FEAT/PLANE, CART, 1, 2, 3, 0, 0, 0\n", "line 1: FEAT/PLANE: its direction vector is zero"),
    ("F(C) = FEAT/CIRCLE, INNER, CART, 1, 2, 3, 0, 0, 1, -10\n",
     "line 1: FEAT/CIRCLE: its diameter -10 is not a positive length"),
    ("F(C) = FEAT/CYLNDR, OUTER, CART, 1, 2, 3, 0, 0, 1, 10, 0\n",
     "line 1: FEAT/CYLNDR: its length 0 is not a positive length"),
    ("F(S) = FEAT/SPHERE, OUTER, CART, 1, 2, 3, 0\n", "line 1: FEAT/SPHERE: its diameter 0 is not a positive length"),
    ("FEDRAT/POSVEL, MMPS, 0\n", "line 1: FEDRAT/POSVEL takes a unit and a positive speed, not 0"),
    ("FEDRAT/MESVEL, 5\n", "line 1: FEDRAT/MESVEL needs a unit: MPM, MMPS, IPM, IPS or PCENT"),
    ("CLOSE/DID(OUT)\n", "line 1: CLOSE/DID(OUT): no DEVICE defines DID(OUT) (DID(name) = DEVICE/STOR, 'file')"),
    ("T(P) = TOL/POS, 2D, 0.1, DAT(A)\n", "line 1: TOL/POS: DAT(A) is defined by no DATDEF in the program (DATDEF/FA(name), DAT(A))"),
    ("D(X) = DATSET/DAT(B), ZDIR, ZORIG\n", "line 1: DATSET: DAT(B) is defined by no DATDEF in the program (DATDEF/FA(name), DAT(B))"),
    ("F(Z) = FEAT/POINT, CART, 1, 2, 3, 0, 0, 1\nOUTPUT/FA(Z)\n",
     "line 2: OUTPUT/FA(Z): no MEAS or CONST in the program makes FA(Z) (output the nominal as F(Z))"),
    ("F(P) = FEAT/PLANE, CART, 0, 0, 0, 0, 0, 1\nMEAS/PLANE, F(P), 0\nENDMES\n",
     "line 2: MEAS/PLANE, F(P): the number of points must be a whole number of at least 1, not 0"),
    ("SNSLCT/S(NOPE)\n",
     "line 1: SNSLCT/S(NOPE): no SNSDEF in the program defines S(NOPE) (S(NOPE) = SNSDEF/PROBE, ..., tip diameter)"),
    (POINT_P + "T(F) = TOL/FLAT, 0.01\nOUTPUT/FA(P), TA(F)\n",
     "line 5: T(F): TOL/FLAT applies to a plane, FA(P) is a point"),
    (POINT_P + "T(D) = TOL/DIAM, -0.01, 0.01\nOUTPUT/FA(P), TA(D)\n",
     "line 5: T(D): TOL/DIAM needs a circle, cylinder or sphere with a nominal diameter; FA(P) is a point"),
    ("F(L) = FEAT/PLANE, CART, 1, 2, 40, 0, 0, 1\nMEAS/PLANE, F(L), 3\nENDMES\nT(X) = TOL/POS, 3D, 0.1\n"
     "OUTPUT/FA(L), TA(X)\n", "line 5: T(X): TOL/POS needs a point, circle, cylinder, sphere or cone with a nominal; "
                               "FA(L) is a plane"),
    (POINT_P + "DATDEF/FA(P), DAT(A)\nD(X) = DATSET/DAT(A), ZDIR, ZORIG\n",
     "line 5: DATSET: DAT(A) (FA(P), a point) has no direction for ZDIR: use a plane, line, axis or circle"),
])
def test_the_check_refuses_what_no_run_could_carry_out(program, problem):
    assert problem in check(program + "ENDFIL\n")[1]


def test_what_the_check_passes_with_names_the_run_defines_or_recalls_is_not_refused():
    program = ("DID(OUT) = DEVICE/STOR, 'a.dms'\nOPEN/DID(OUT), FDATA, DMIS, OUTPUT\nRECALL/DAT(A)\nRECALL/FA(P)\n"
               "RECALL/SA(TIP)\nSNSLCT/S(TIP)\nDECL/DOUBLE, DIA\nDIA = ASSIGN/10\nF(C) = FEAT/CIRCLE, INNER, CART, 1, 2, 3, 0, 0, 1, DIA\n"
               "T(P) = TOL/POS, 2D, 0.1, DAT(A)\nD(X) = DATSET/DAT(A), ZDIR, ZORIG\nOUTPUT/FA(P)\nCLOSE/DID(OUT)\n")
    assert check(program + "ENDFIL\n")[1] == []
    # a point's datum sets origins (its location), a plane's the direction; TOL/POS on a point is a position
    program = (POINT_P + "F(L) = FEAT/PLANE, CART, 1, 2, 40, 0, 0, 1\nMEAS/PLANE, F(L), 3\nENDMES\n"
               "DATDEF/FA(P), DAT(A)\nDATDEF/FA(L), DAT(B)\nD(X) = DATSET/DAT(B), ZDIR, DAT(A), XORIG, YORIG, ZORIG\n"
               "T(X) = TOL/POS, 3D, 0.1\nOUTPUT/FA(P), TA(X)\nT(F) = TOL/FLAT, 0.01\nOUTPUT/FA(L), TA(F)\n")
    assert check(program + "ENDFIL\n")[1] == []


def test_a_nominal_feature_outputs_the_tolerance_as_defined_and_refuses_its_actual(station):
    program = ("UNITS/MM, ANGDEC\nF(C) = FEAT/CIRCLE, INNER, CART, 30, 40, 30, 0, 0, 1, 30\n"
               "T(POS) = TOL/POS, 3D, 0.1\n")
    assert check(program + "OUTPUT/F(C), T(POS)\nENDFIL\n")[1] == []
    out = run_text(program + "OUTPUT/F(C), T(POS)\nENDFIL\n", station.controller.commands).outputs[None].splitlines()
    assert out[-3:] == ["F(C) = FEAT/CIRCLE, INNER, CART, 30.00000, 40.00000, 30.00000, 0.00000, 0.00000, 1.00000, "
                        "30.00000", "T(POS) = TOL/POS, 3D, 0.1", "ENDFIL"]
    with pytest.raises(DmisError, match=r"^line 4: TA\(POS\) is the tolerance evaluated on a measured feature, and "
                                        r"F\(C\) has not been measured: output TA\(POS\) after MEAS/\.\., F\(C\), "
                                        r"or T\(POS\) for its definition$"):
        run_text(program + "OUTPUT/F(C), TA(POS)\nENDFIL\n", station.controller.commands)


def test_cmm_run_check_refuses_absurd_numbers_and_warns_of_a_missing_endfil(tmp_path):
    bad = tmp_path / "bad.dmi"
    bad.write_text("UNITS/MM, ANGDEC\nGOTO/1e308, 0, 0\nF(P) = FEAT/POINT, CART, nan, 0, 0, 0, 0, 1\n")
    done = subprocess.run([sys.executable, "-m", "cmm.cli", "run", str(bad), "--check"], capture_output=True,
                          text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 1
    assert f"{bad}: line 2: 1e308 is not a usable number" in done.stderr
    assert f"{bad}: line 3: nan is not a finite number" in done.stderr
    ok = tmp_path / "ok.dmi"
    ok.write_text("UNITS/MM, ANGDEC\nD(R) = ROTATE/ZAXIS, 30\n")
    done = subprocess.run([sys.executable, "-m", "cmm.cli", "run", str(ok), "--check"], capture_output=True,
                          text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"{ok}: warning: line 2: ROTATE is not DMIS: read as ROTAT (write ROTAT/...)" in done.stdout
    assert f"{ok}: warning: line 2: the program does not end with ENDFIL" in done.stdout


def test_device_files_stay_in_the_output_folder():
    assert device_file(r"C:\QC\Results\part.dms") == "part.dms"
    assert device_file("../../etc/passwd") == "passwd"
    assert device_file("/tmp/out.dms") == "out.dms"
    assert device_file("C:part.dms") == "part.dms"
    assert device_file("..") is None and device_file("dir/") == "dir"


def test_a_query_without_an_operator_is_refused_in_words(station):
    with pytest.raises(DmisError, match=r"^line 2: the program asks the operator \(for an answer\) and this run has "
                                        r"no one to ask"):
        run_text("DECL/CHAR, 10, SN\nTEXT/QUERY, (SN), 10, ALPHA, L, 'Serial?'\nENDFIL\n", station.controller.commands)


UPLOADED = b"""FILNAM/'uploaded'
UNITS/MM, ANGDEC
DECL/CHAR, 20, SN
TEXT/OPER, 'Clamp the part'
TEXT/QUERY, (SN), 20, ALPHA, L, 'Serial number?'
GOTO/250, 200, 100
GOTO/260, 200, 100
TEXT/OUTFIL, 'done'
ENDFIL
"""


def _panel(station):
    from cmm.control.access import Control
    from cmm.ui.context import PanelContext
    from cmm.ui.panel_routine import RoutinePanel

    control = Control()
    assert control.take("operator", is_local=True)
    station.controller.use_policy_of(control)
    return RoutinePanel(PanelContext(station.controller.commands, control, None, client_id="operator", is_local=True))


def _wait_for(what, timeout=120.0):
    import time

    end = time.monotonic() + timeout
    while not what():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.05)


def test_the_routine_tab_runs_an_uploaded_dmis_file_and_asks_its_questions(station):
    """The page: a DMIS file uploaded from the operator's computer is checked and run with the routine's progress
    bar; TEXT/OPER shows on the program's status, TEXT/QUERY waits for the Answer; Cancel ends a waiting run."""
    from cmm.control import OpenPolicy

    panel = _panel(station)
    try:
        progress = []
        shown = panel._dmis_progress
        panel._dmis_progress = lambda f, m: (progress.append((f, m)), shown(f, m))
        assert panel.upload_dmis("notes.txt", UPLOADED) is None  # not a DMIS file: said
        assert panel.ctx.messages[-1][:2] == ("error", "Upload DMIS")
        lines = panel.upload_dmis(r"C:\QC\Programs\op20.dms", UPLOADED)
        assert lines and lines[0] == "line 1: FILNAM/'uploaded'" and panel.dmis[0].name == "op20.dms"
        assert panel.run_dmis()
        _wait_for(lambda: panel.dmis_question)
        assert panel.dmis_question == "line 5: Serial number?" and panel.dmis_status.startswith("**QUESTION**")
        assert panel.answer_dmis("SN-7")
        panel.thread.join(120)
        assert panel.dmis_status.startswith("**DONE**"), panel.dmis_status
        out = panel.dmis_results[-1].outputs[None]
        assert "TEXT/OUTFIL, 'Serial number? SN-7'" in out and "TEXT/OUTFIL, 'done'" in out
        assert any("line 4: Clamp the part" in line for line in panel.dmis_results[-1].log)
        assert progress and progress[0][0] == 0.0 and any(m.endswith("GOTO") for _, m in progress)
        # asked again, the operator cancels: the run ends there, nothing moves
        assert panel.run_dmis()
        _wait_for(lambda: panel.dmis_question)
        start = station.machine.position.copy()
        panel.control("cancel")
        panel.thread.join(120)
        assert panel.dmis_status.startswith("**STOPPED**: line 5: the question was not answered"), panel.dmis_status
        assert np.allclose(station.machine.position, start)
    finally:
        station.controller.policy = OpenPolicy()

"""DMIS statements beyond the first set, on the simulated station against its true part: manual mode (the
operator's hits, here taken where the part really is), FEAT and PTMEAS in polar coordinates, ROTAT onto a
feature, CONST/CIRCLE (section, projection, bolt circle), distances and angles between constructed features, and
TOL/POS at MMC with a datum at MMC (bonus and datum shift)."""

from __future__ import annotations

import math
import re
import time

import numpy as np
import pytest

import session_support as sup
from cmm.dmis.check import check
from cmm.dmis.executor import DmisError
from cmm.dmis.runner import needs_operator, run_text
from cmm.session.export import session_json
from cmm.session.report import features_csv, render
from cmm.journal.store import DirectoryStore, load_session
from cmm.sim.cmm_sim import pose_matrix

NOISE = 0.004  # mm: two encoder counts and the probe's repeatability
# the part as the operator put it down: 1 mm and 0.8 mm off the nominal set-up (190, 150), turned 0.8 degrees
PLACED = pose_matrix((191.0, 150.8, 0.0), rz_deg=0.8)
SETUP = np.array([190.0, 150.0, 0.0])  # where the program's D(SETUP) expects the part's corner

# the boss (part X70 Y22) and the sphere cap's top (X70 Y58 Z49) seen from the bore axis (X30 Y40) at the top
BOSS_R, BOSS_A = math.hypot(40.0, -18.0), math.degrees(math.atan2(-18.0, 40.0))
SPH_A = math.degrees(math.atan2(18.0, 40.0)) - BOSS_A  # in the frame turned onto the boss
SPH_XY = (BOSS_R * math.cos(math.radians(SPH_A)), BOSS_R * math.sin(math.radians(SPH_A)))


def _program() -> str:
    sx, sy = SPH_XY
    return f"""DMISMN/'manual 3-2-1, then automatic', 05.0
FILNAM/'manual 3-2-1, then automatic'
UNITS/MM, ANGDEC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
$$ the operator takes the 3-2-1 hits by hand where the part lies
MODE/MAN
F(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1
MEAS/PLANE, F(TOP), 3
  PTMEAS/CART, 15, 10, 40, 0, 0, 1
  PTMEAS/CART, 105, 12, 40, 0, 0, 1
  PTMEAS/CART, 50, 70, 40, 0, 0, 1
ENDMES
F(FRONT) = FEAT/PLANE, CART, 60, 0, 20, 0, -1, 0
MEAS/PLANE, F(FRONT), 3
  GOTO/60, -20, 60
  PTMEAS/CART, 15, 0, 25, 0, -1, 0
  PTMEAS/CART, 105, 0, 25, 0, -1, 0
  PTMEAS/CART, 60, 0, 10, 0, -1, 0
ENDMES
F(LEFT) = FEAT/POINT, CART, 0, 20, 15, -1, 0, 0
MEAS/POINT, F(LEFT), 1
  PTMEAS/CART, 0, 20, 15, -1, 0, 0
ENDMES
D(PART) = DATSET/FA(TOP), ZDIR, ZORIG, FA(FRONT), YMINUS, YORIG, FA(LEFT), XORIG
MODE/AUTO, PROG, MAN
SNSET/APPRCH, 4
SNSET/RETRCT, 3
GOTO/INCR, 10, 0, 0, 1
GOTO/30, 40, 30
F(BORE) = FEAT/CYLNDR, INNER, CART, 30, 40, -20, 0, 0, 1, 30, 40
MEAS/CYLNDR, F(BORE), 6
  GOTO/30, 40, -10
  PTMEAS/CART, 45, 40, -10, -1, 0, 0
  PTMEAS/CART, 22.5, 52.990381, -10, 0.5, -0.866025, 0
  PTMEAS/CART, 22.5, 27.009619, -10, 0.5, 0.866025, 0
  PTMEAS/CART, 45, 40, -30, -1, 0, 0
  PTMEAS/CART, 22.5, 52.990381, -30, 0.5, -0.866025, 0
  PTMEAS/CART, 22.5, 27.009619, -30, 0.5, 0.866025, 0
  GOTO/30, 40, -10
  GOTO/30, 40, 30
ENDMES
$$ the bore's axis is the origin; the boss is given in polar coordinates about it
D(BOREC) = TRANS/XORIG, FA(BORE), YORIG, FA(BORE)
F(BOSS) = FEAT/CIRCLE, OUTER, POL, {BOSS_R:.6f}, {BOSS_A:.6f}, 7, 0, 0, 1, 20
MEAS/CIRCLE, F(BOSS), 4
  GOTO/56, -18, 20
  PTMEAS/CART, 50, -18, 7, 1, 0, 0
  GOTO/56, -18, 20
  GOTO/40, -2, 20
  PTMEAS/CART, 40, -8, 7, 0, 1, 0
  GOTO/40, -2, 20
  GOTO/24, -18, 20
  PTMEAS/CART, 30, -18, 7, -1, 0, 0
  GOTO/24, -18, 20
  GOTO/40, -34, 20
  PTMEAS/CART, 40, -28, 7, 0, -1, 0
  GOTO/40, -34, 20
ENDMES
$$ X turned from the bore onto the boss; the sphere cap's top in polar coordinates in that frame
D(TOBOSS) = ROTAT/ZAXIS, FA(BOSS), XDIR
GOTO/{sx:.4f}, {sy:.4f}, 20
F(SPHTOP) = FEAT/POINT, POL, {BOSS_R:.6f}, {SPH_A:.6f}, 9, 0, 0, 1
MEAS/POINT, F(SPHTOP), 1
  PTMEAS/POL, {BOSS_R:.6f}, {SPH_A:.6f}, 9, 0, 0, 1
ENDMES
GOTO/{sx:.4f}, {sy:.4f}, 30
$$ constructions: the bore's section at the top face, the boss projected onto it, the bolt circle
CONST/CIRCLE, F(BT), INTOF, FA(BORE), FA(TOP)
CONST/CIRCLE, F(BP), PROJCT, FA(BOSS), FA(TOP)
CONST/CIRCLE, F(BC), BF, FA(BT), FA(BP), FA(SPHTOP)
$$ and the other constructions: the bore's axis through the top face, the top-front edge, their bisecting plane
CONST/POINT, F(BI), INTOF, FA(BORE), FA(TOP)
CONST/LINE, F(EDGE), INTOF, FA(TOP), FA(FRONT)
CONST/PLANE, F(MIDP), MIDPL, FA(TOP), FA(FRONT)
DATDEF/FA(TOP), DAT(A)
DATDEF/FA(BORE), DAT(B)
DATDEF/FA(FRONT), DAT(C)
T(DB) = TOL/DIAM, -0.01, 0.05
T(DBOSS) = TOL/DIAM, -0.05, 0.01
T(PMMC) = TOL/POS, 2D, 0.001, MMC, DAT(A), DAT(B), MMC, DAT(C)
T(PLMC) = TOL/POS, 2D, 0.001, LMC, DAT(A), DAT(B), DAT(C)
T(DIST) = TOL/DISTB, NOMINL, {BOSS_R:.6f}, -0.01, 0.01
T(ANG) = TOL/ANGLB, NOMINL, 90, -0.05, 0.05
RECALL/D(PART)
OUTPUT/FA(TOP), FA(FRONT), TA(ANG)
OUTPUT/FA(BORE), TA(DB)
OUTPUT/FA(BT), FA(BP), TA(DIST)
OUTPUT/FA(BC), FA(BI), FA(EDGE), FA(MIDP)
RECALL/D(TOBOSS)
OUTPUT/FA(BOSS), TA(DBOSS), TA(PMMC), TA(PLMC)
OUTPUT/FA(SPHTOP)
ENDFIL
"""


@pytest.fixture
def station(tmp_path):
    """The station on the in-process simulator (virtual clock), homed, the part placed off the set-up."""
    yield from sup.sim_station(tmp_path, "dmis", PLACED)


def _true(machine_point_at_setup):
    """Where a point the program names at the nominal set-up really is on the placed part."""
    return (PLACED @ np.append(np.asarray(machine_point_at_setup, float) - SETUP, 1.0))[:3]


def _operator(st, prompts):
    """The operator's hands: each guided hit taken where the part really is (the guide mapped onto the placed
    part), over the clearance height as a person jogging round the part would."""
    model = st.measurement

    def take(prompt, n, guides):
        prompts.append(prompt)
        ids = []
        for point, approach in guides[:n]:
            hit = model.probe(_true(point), PLACED[:3, :3] @ approach, clearance_z=90.0).wait(120)
            ids.append(model.hit_id(hit))
        here = np.asarray(st.machine.position, float)  # and jogs clear of the part, up to Z 70
        st.controller.move(None, [here[0], here[1], 70.0], frame="machine").wait(120)
        return ids

    return take


def _lines(out: str) -> dict[str, list[float]]:
    joined = re.sub(r"\$\s*\n", " ", out)
    return {m.group(1): [float(x) for x in m.group(3).split(",")]
            for m in re.finditer(r"^FA\((\w+)\) = FEAT/([A-Z, ]+?),\s+([-\d., ]+)$", joined, re.M)}


def _tas(out: str) -> dict[str, tuple[float, str]]:
    return {m.group(1): (float(m.group(2)), m.group(3))
            for m in re.finditer(r"^TA\((\w+)\) = TOL/[A-Z0-9, ]+?, (-?[\d.]+), (INTOL|OUTOL)$", out, re.M)}


def test_manual_alignment_polar_rotation_constructions_and_mmc_on_the_true_part(station):
    text = _program()
    stmts, problems = check(text)
    assert problems == [] and needs_operator(stmts)
    prompts: list[str] = []
    result = run_text(text, station.controller.commands, name="manual.dmi", manual_hits=_operator(station, prompts))
    out = result.outputs[None]
    # the operator was asked for each datum's hits, with where to take them
    assert prompts[0] == ("line 8: take 3 hits by hand on F(TOP) (PLANE): near 15.000, 10.000, 40.000; "
                          "near 105.000, 12.000, 40.000; near 50.000, 70.000, 40.000")
    assert [p.split(":")[1] for p in prompts] == [" take 3 hits by hand on F(TOP) (PLANE)",
                                                   " take 3 hits by hand on F(FRONT) (PLANE)",
                                                   " take 1 hit by hand on F(LEFT) (POINT)"]
    assert result.hits == 7 + 6 + 4 + 1
    # the datum frame from the hand-taken hits is where the part really lies: corner at the top, turned 0.8 deg
    frame = result.frames["PART"]
    assert np.allclose(frame[:3, 3], PLACED[:3, 3] + PLACED[:3, :3] @ [0, 0, 40.0], atol=0.01)
    assert np.allclose(frame[:3, :3], PLACED[:3, :3], atol=2e-4)
    fa = _lines(out)
    # the bore, measured automatically in that frame, is the part's bore
    assert fa["BORE"][:2] == pytest.approx([30.0, 40.0], abs=0.01) and fa["BORE"][6] == pytest.approx(30.0, abs=NOISE)
    # its section at the top face: D30 on the axis at Z0; the boss projected there: D20 at the boss
    assert fa["BT"][:3] == pytest.approx([30.0, 40.0, 0.0], abs=0.01) and fa["BT"][6] == pytest.approx(30.0, abs=NOISE)
    assert fa["BP"][:3] == pytest.approx([70.0, 22.0, 0.0], abs=0.01) and fa["BP"][6] == pytest.approx(20.0, abs=NOISE)
    # the bolt circle through the bore, the boss and the sphere's top: the circumcircle of the true locations
    a, b, c = (np.array(p) for p in ([30.0, 40.0, 0.0], [70.0, 22.0, 0.0], [70.0, 58.0, 9.0]))
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    centre = a + (np.cross(n, ab) * (ac @ ac) + np.cross(ac, n) * (ab @ ab)) / (2.0 * (n @ n))
    assert fa["BC"][:3] == pytest.approx(list(centre), abs=0.02)
    assert fa["BC"][6] == pytest.approx(2.0 * np.linalg.norm(a - centre), abs=0.02)
    assert fa["BI"][:3] == pytest.approx([30.0, 40.0, 0.0], abs=0.01)
    edge = fa["EDGE"]
    assert edge[1:3] == pytest.approx([0.0, 0.0], abs=0.01) and abs(edge[3]) == pytest.approx(1.0, abs=1e-6)
    assert fa["MIDP"][3:6] == pytest.approx([0.0, -math.sqrt(0.5), math.sqrt(0.5)], abs=2e-4)
    # in the frame turned onto the boss, the boss lies on X at its polar distance; the sphere's top at its angle
    assert "FA(BOSS) = FEAT/CIRCLE, OUTER, POL," in out
    r, ang, h = fa["BOSS"][:3]
    assert r == pytest.approx(BOSS_R, abs=0.01) and ang == pytest.approx(0.0, abs=0.02) and h == pytest.approx(7.0, abs=0.01)
    r, ang, h = fa["SPHTOP"][:3]
    assert r == pytest.approx(BOSS_R, abs=0.02) and ang == pytest.approx(SPH_A, abs=0.03)
    assert h == pytest.approx(9.0, abs=0.01)
    turned = result.frames["TOBOSS"]
    want = PLACED[:3, :3] @ [math.cos(math.radians(BOSS_A)), math.sin(math.radians(BOSS_A)), 0.0]
    assert turned[:3, 0] == pytest.approx(list(want), abs=3e-4)
    # distance and angle between constructed and measured features, against the drawing
    ta = _tas(out)
    assert abs(ta["DIST"][0]) < 0.01 and ta["DIST"][1] == "INTOL"
    assert abs(ta["ANG"][0]) < 0.02 and ta["ANG"][1] == "INTOL"
    # POS at MMC: the bonus is the boss's departure from its MMC size (20.01), with datum B's shift beside;
    # at LMC the bonus is its departure from 19.95
    boss = fa["BOSS"][6]
    notes = dict(re.findall(r"^\$\$ T\((\w+)\): (.*)$", out, re.M))
    bonus = float(re.search(r"bonus ([\d.]+)", notes["PMMC"]).group(1))
    assert bonus == pytest.approx(20.01 - boss, abs=2e-4)
    assert "datum shift" in notes["PMMC"] or ta["PMMC"][0] <= 0.001 + bonus
    allowed = float(re.search(r"allowed ([\d.]+)", notes["PMMC"]).group(1))
    assert allowed == pytest.approx(0.001 + bonus, abs=2e-5)
    assert ta["PMMC"][1] == ("INTOL" if ta["PMMC"][0] <= allowed + 1e-5 else "OUTOL")
    assert ta["PMMC"][1] == "INTOL"  # the true part is perfect: its position error is the probing noise
    lbonus = float(re.search(r"bonus ([\d.]+)", notes["PLMC"]).group(1))
    assert lbonus == pytest.approx(boss - 19.95, abs=2e-4)
    # the station's own report (its GD&T: the same datums, B at MMB for PMMC only, the boss's size limits from
    # T(DBOSS)) gives the same positions and bonuses, live and from the journal in the HTML, CSV and JSON
    model = station.measurement
    live = {d["name"]: c for d, c in model.gdt_characteristics()}
    evs = {e.tolerance.label: e for e in result.evaluations}
    for label in ("PMMC", "PLMC"):
        c, ev = live[f"T({label})"], evs[label]
        assert c.actual == pytest.approx(ev.value, abs=1e-9) and c.upper == pytest.approx(0.001 + ev.bonus, abs=1e-9)
        assert c.verdict == ("pass" if ev.intol else "FAIL")
    model.journal.close()
    session = load_session(DirectoryStore(station.measurement.session_dir), "dmis")
    mesh = model.part.mesh
    html, csv_rows = render(session, mesh=mesh), features_csv(session, mesh=mesh).splitlines()
    exported = {g["name"]: g for g in session_json(session, mesh=mesh)["gdt"]}
    for label, frame, drf in (("PMMC", "⊕ ⌀0.0010(M) | A|B(M)|C", "A|B(M)|C"),
                              ("PLMC", "⊕ ⌀0.0010(L) | A|B|C", "A|B|C")):
        c, ev = live[f"T({label})"], evs[label]
        e = exported[f"T({label})"]
        assert e["value"] == c.actual and e["allowed"] == c.upper and e["drf"] == drf == c.datums, e
        assert frame in html and f"<td>{ev.bonus:.4f}</td><td>{c.actual:.4f}</td>" in html
        assert any(r.startswith(f"BOSS,gdt,{drf},") and f",{c.upper:.6f},0.000000,{c.actual:.6f}," in r
                   for r in csv_rows), label
    # the boss's diameter in the report has T(DBOSS)'s own limits, not a +- of the wider one
    assert any(r.startswith("BOSS,circle,") and ",diameter,mm,20.000000,0.010000,-0.050000," in r for r in csv_rows)


def test_manual_hits_are_waited_for_with_the_prompt_on_the_routine_tab(station):
    """From the page's Routine tab, a manual MEAS shows its prompt and waits for the operator's next hits (taken
    with the pendant or the armed jog; here probed where the part really is), then the program goes on."""
    from cmm.control.access import Control
    from cmm.ui.context import PanelContext
    from cmm.ui.panel_routine import RoutinePanel

    control = Control()
    assert control.take("operator", is_local=True)
    panel = RoutinePanel(PanelContext(station.controller.commands, control, None, client_id="operator", is_local=True))
    (station.measurement.session_dir / "top.dmi").write_text(
        "UNITS/MM, ANGDEC\nD(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0\nMODE/MAN\n"
        "F(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1\nMEAS/PLANE, F(TOP), 3\nENDMES\nOUTPUT/FA(TOP)\nENDFIL\n")
    assert panel.open_dmis("top.dmi")
    assert panel.run_dmis()
    for _ in range(500):
        if panel.dmis_status.startswith("**WAITING**"):
            break
        time.sleep(0.02)
    assert panel.dmis_status == "**WAITING**: line 5: take 3 hits by hand on F(TOP) (PLANE) (0 of 3 taken)"
    model = station.measurement
    for x, y in ((15.0, 10.0), (105.0, 12.0), (50.0, 70.0)):  # the operator probes the top face
        model.probe(_true([190.0 + x, 150.0 + y, 40.0]), PLACED[:3, :3] @ [0, 0, -1.0], clearance_z=90.0,
                    client="operator").wait(120)
    panel.thread.join(60)
    assert panel.dmis_status.startswith("**DONE**: 1 features, 3 hits"), panel.dmis_status
    top = _lines(panel.dmis_results[-1].outputs[None])["TOP"]
    assert top[2] == pytest.approx(_true([250.0, 190.0, 40.0])[2], abs=NOISE)


def test_statement_refusals_name_their_line():
    assert check("MODE/MAN\nF(X) = FEAT/POINT, POL, 10, 30, 0, 0, 0, 1\n")[1] == []
    _, problems = check("CONST/CIRCLE, F(C), TTP, FA(A), FA(B)\nF(Y) = FEAT/CIRCLE, INNER, POL, 1, 2\n")
    assert problems == ["line 1: CONST/CIRCLE, .., TTP is not supported: CONST/CIRCLE takes BF, INTOF or PROJCT",
                        "line 2: FEAT/CIRCLE takes 7 numbers after POL, it has 2"]
    # what the run would refuse, the check finds first, each with its line
    _, problems = check("DID(IN) = DEVICE/STOR, 'in.dat'\nOPEN/DID(IN), DIRECT, INPUT\n"
                        "CONST/CIRCLE, F(M), MIDPT, FA(A), FA(B)\nCONST/CIRCLE, F(T), TTP, FA(A), FA(B), INTOF\n"
                        "CONST/POINT, F(P), MIDLI, FA(A), FA(B)\nF(X) = CONST/POINT, INTOF, FA(A), FA(B)\n"
                        "D(X) = DATSET/FA(A), ZDIR, FA(B), XAXIS\nROTAT/ZAXIS, FA(A), ZDIR\n"
                        "S(P) = SNSDEF/PROBE, INDEX, POL, 90, 0, 2\nT(F) = TOL/FLAT, 0.01, MMC\n"
                        "S(D) = SNSDEF/PROBE, INDEX, POL, 0, 0, 2\nCONST/LINE, F(L), BF, FA(A), FA(B)\n")
    assert problems == [
        "line 2: OPEN for INPUT is not supported: the station reads no data files in a program",
        "line 3: CONST/CIRCLE, .., MIDPT is not supported: CONST/CIRCLE takes BF, INTOF or PROJCT",
        "line 4: CONST/CIRCLE, .., TTP is not supported: CONST/CIRCLE takes BF, INTOF or PROJCT",
        "line 5: CONST/POINT, .., MIDLI is not supported: CONST/POINT takes INTOF, MIDPT or PROJCT",
        "line 6: CONST/POINT names the feature it constructs among its parameters: CONST/POINT, F(name), INTOF, "
        "FA(..), ...",
        "line 7: DATSET/.., XAXIS is not supported: use XDIR, YDIR, ZDIR (XMINUS ...), XORIG, YORIG, ZORIG",
        "line 8: ROTAT/ZAXIS cannot turn ZDIR onto a feature: it is the rotation axis",
        "line 9: S(P) points along (1, 0, 0): the station has one fixed probe pointing down (0, 0, -1)",
        "line 10: TOL/FLAT, MMC: a material condition applies to TOL/POS only"]
    # a position at MMC needs its feature's size limits (a TOL/DIAM output with it) before it, a datum at MMC too
    sized = ("F(B) = FEAT/CIRCLE, INNER, CART, 30, 40, 30, 0, 0, 1, 30\nF(C) = FEAT/CIRCLE, OUTER, CART, 70, 22, 40, "
             "0, 0, 1, 20\nDATDEF/FA(C), DAT(C)\nT(D) = TOL/DIAM, -0.1, 0.1\nT(P) = TOL/POS, 2D, 0.05, MMC\n"
             "T(Q) = TOL/POS, 2D, 0.05, DAT(C), MMC\n")
    problems = check(sized + "OUTPUT/FA(B), TA(P)\nOUTPUT/FA(B), TA(D), TA(P)\nOUTPUT/FA(B), TA(Q)\n"
                     "OUTPUT/FA(C), TA(D)\nOUTPUT/FA(B), TA(Q)\n")[1]
    assert [p for p in problems if "size limits" in p] == [
        "line 7: T(P) at MMC needs FA(B)'s size limits: output its TOL/DIAM first (OUTPUT/FA(B), TA(..))",
        "line 9: DAT(C) at MMC needs FA(C)'s size limits: output its TOL/DIAM first (OUTPUT/FA(C), TA(..))"]
    # the POL angles in the program's unit: a quarter turn in radians is sideways too
    assert check("UNITS/MM, ANGRAD\nS(P) = SNSDEF/PROBE, INDEX, POL, 1.5707963, 0, 2\n")[1] == [
        "line 2: S(P) points along (1, 0, 0): the station has one fixed probe pointing down (0, 0, -1)"]
    # a line: UNBND or BND, each with the normal of its plane (or, as before, without it)
    assert check("F(L) = FEAT/LINE, UNBND, CART, 0, 0, 0, 1, 0, 0, 0, 0, 1\nF(M) = FEAT/LINE, BND, CART, 0, 0, 0, "
                 "5, 0, 0, 0, -1, 0\nF(N) = FEAT/LINE, UNBND, CART, 0, 0, 0, 1, 0, 0\n")[1] == []
    _, problems = check("F(L) = FEAT/LINE, BND, CART, 0, 0, 0, 5, 0, 0, 1\n")
    assert problems == ["line 1: FEAT/LINE takes 9 numbers after CART (x1, y1, z1, x2, y2, z2, and pi, pj, pk: the "
                        "normal of the plane the line lies in), it has 7"]


def test_material_condition_outside_position_and_mmc_without_size_are_refused(station):
    base = ("UNITS/MM, ANGDEC\nD(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0\nSNSET/APPRCH, 4\n"
            "SNSET/RETRCT, 3\nGOTO/30, 40, 60\n"
            "F(B) = FEAT/CIRCLE, INNER, CART, 30, 40, 30, 0, 0, 1, 30\nMEAS/CIRCLE, F(B), 3\nGOTO/30, 40, 30\n"
            "PTMEAS/CART, 45, 40, 30, -1, 0, 0\nPTMEAS/CART, 22.5, 52.990381, 30, 0.5, -0.866025, 0\n"
            "PTMEAS/CART, 22.5, 27.009619, 30, 0.5, 0.866025, 0\nGOTO/30, 40, 60\nENDMES\n")
    with pytest.raises(DmisError, match=r"^line 14: TOL/FLAT, MMC: a material condition applies to TOL/POS only$"):
        run_text(base + "T(F) = TOL/FLAT, 0.01, MMC\n", station.controller.commands)
    with pytest.raises(DmisError, match=r"^line 15: T\(P\) at MMC needs FA\(B\)'s size limits: output its TOL/DIAM"):
        run_text(base + "T(P) = TOL/POS, 2D, 0.05, MMC\nOUTPUT/FA(B), TA(P)\n", station.controller.commands)


MANUAL_TOP = ("FILNAM/'top by hand'\nUNITS/MM, ANGDEC\nD(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0\nMODE/MAN\n"
              "F(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1\nMEAS/PLANE, F(TOP), 3\n"
              "PTMEAS/CART, 15, 10, 40, 0, 0, 1\nPTMEAS/CART, 105, 12, 40, 0, 0, 1\nPTMEAS/CART, 50, 70, 40, 0, 0, 1\n"
              "ENDMES\nOUTPUT/FA(TOP)\nENDFIL\n")


def test_cmm_run_asks_for_manual_hits_at_the_terminal(tmp_path, monkeypatch, capsys):
    """`cmm run` in manual mode: each hit confirmed at a terminal (a pseudo-terminal here), where a typed point
    replaces the program's; without a terminal it refuses in words."""
    import os
    import sys

    from cmm.cli import main

    monkeypatch.chdir(tmp_path)
    program = tmp_path / "manual.dmi"
    program.write_text(MANUAL_TOP)
    args = ["run", str(program), "--sessions", str(tmp_path / "sessions"), "-o", "out.dms"]
    assert main(args) == 1  # pytest's input is no terminal
    assert "line 6: manual mode needs an operator at the terminal" in capsys.readouterr().err
    master, slave = os.openpty()
    try:
        # Enter, a typed point (the second hit 20 mm further in X on the same face), a mistyped one, Enter
        os.write(master, b"\n230.0, 162.0, 40\nabc\n\n")
        with os.fdopen(os.dup(slave), "r") as tty:
            monkeypatch.setattr(sys, "stdin", tty)
            assert main(args) == 0
    finally:
        os.close(master)
        os.close(slave)
    printed = capsys.readouterr().out
    assert "line 6: take 3 hits by hand on F(TOP) (PLANE): near 15.000, 10.000, 40.000" in printed
    assert "three numbers please" in printed and "1 features, 3 hits" in printed
    top = _lines((tmp_path / "out.dms").read_text())["TOP"]
    assert top[2] == pytest.approx(40.0, abs=0.01) and top[5] == pytest.approx(1.0, abs=1e-4)


def _qualified(folder, name, radius):
    """A qualification record of probe ``name`` in the records folder (as `cmm calibrate probe` files it)."""
    from cmm.calibration.records import PROBE_QUALIFICATIONS, ProbeRecord, now, save_record

    save_record(ProbeRecord(now(), "sphere", radius, {}, radius, (400.0, 300.0, 100.0)),
                folder / PROBE_QUALIFICATIONS / f"{name}.toml")


def test_snslct_selects_the_qualified_probe_of_the_list_with_the_sensor_tip_or_name(station, tmp_path):
    """SNSLCT makes the station's qualified probe named like the sensor (or with the SNSDEF's tip) the one in use,
    through the select_probe verb, and the simulator mounts its stylus; a stylus that is not qualified is refused
    before anything moves, with the command that qualifies it."""
    folder = tmp_path / "calibration"
    station.calibration.load(folder)  # a probe list: Probe1, the configured 2 mm tip
    station.calibration.add_probe("T4", 4.0)
    station.calibration.add_probe("T3", 3.0)
    _qualified(folder, "T4", 1.9962)
    _qualified(folder, "Probe1", 0.9961)
    result = run_text("S(BIG) = SNSDEF/PROBE, FIXED, CART, 0, 0, 0, 0, 0, -1, 4.0\nSNSLCT/S(BIG)\n", station.controller.commands)
    assert station.measurement.probe_name == "T4" and station.prober.settings.tip_radius == pytest.approx(1.9962)
    assert station.sim.world.probe.tip_radius == 2.0  # the simulator's head carries the 4 mm stylus now
    assert any(line.startswith("line 2: S(BIG): probe T4 selected") for line in result.log)
    run_text("S(PROBE1) = SNSDEF/PROBE, FIXED, POL, 0, 0, 2.0\nSNSLCT/S(PROBE1)\n", station.controller.commands)  # by its name
    assert station.measurement.probe_name == "Probe1" and station.prober.settings.tip_radius == pytest.approx(0.9961)
    assert station.sim.world.probe.tip_radius == 1.0
    start = station.machine.position.copy()
    with pytest.raises(DmisError, match=r"^line 3: SNSLCT/S\(P2\): no qualified probe has a 3.0 mm tip: qualify "
                                         r"it with `cmm calibrate probe --probe P2 --tip-diameter 3.0` \(or in the "
                                         r"Calibration tab's probe list\); qualified probes: Probe1 \(2.0 mm\), "
                                         r"T4 \(4.0 mm\)$"):
        run_text("GOTO/100, 100, 250\nS(P2) = SNSDEF/PROBE, FIXED, CART, 0, 0, 0, 0, 0, -1, 3\nSNSLCT/S(P2)\n", station.controller.commands)
    with pytest.raises(DmisError, match=r"^line 3: SNSLCT/S\(T3\): the probe T3 \(3.0 mm\) is not qualified: "
                                         r"qualify it with `cmm calibrate probe --probe T3 --tip-diameter 3.0`"):
        run_text("GOTO/100, 100, 250\nS(T3) = SNSDEF/PROBE, FIXED, CART, 0, 0, 0, 0, 0, -1, 3\nSNSLCT/S(T3)\n", station.controller.commands)
    with pytest.raises(DmisError, match=r"^line 3: SNSLCT/S\(T4\): the probe T4 of the probe list has a 4.0 mm tip, "
                                         r"the program's S\(T4\) a 2.5 mm tip$"):
        run_text("GOTO/100, 100, 250\nS(T4) = SNSDEF/PROBE, FIXED, POL, 0, 0, 2.5\nSNSLCT/S(T4)\n", station.controller.commands)
    assert station.measurement.probe_name == "Probe1" and np.allclose(station.machine.position, start)  # unmoved

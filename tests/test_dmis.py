"""DMIS part programs on the simulated station: the NIST simple program placed on the sample part's bore, the
shipped sample-part program against the simulator's true part, refusals with line numbers before any motion,
and a taught program exported to DMIS and run again."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import session_support as sup
from cmm.cli import main
from cmm.dmis.check import check
from cmm.dmis.executor import DmisError
from cmm.dmis.features import bounded_line, nominal_from
from cmm.dmis.export import to_dmis
from cmm.dmis.lexer import statements
from cmm.dmis.parser import Expr, Word, evaluate, parse
from cmm.dmis.runner import run_text
from cmm.measurement.program import run_on
from cmm.program import toml_program as prog
from cmm.sim.cmm_sim import TRUE_PART_POSE

from shared_refs import require, shared_path

DATA = shared_path("dmis")  # NIST's simple DMIS program and its output, read in place
SAMPLE = Path(__file__).resolve().parents[1] / "cmm" / "data" / "sample_part.dmi"
NOISE = 0.004  # mm: two encoder counts and the probe's repeatability
FACETS = {"SPHERE": 0.006}  # mm: the simulated sphere is an icosphere, up to 2.9 um inside the true sphere


@pytest.fixture
def station(tmp_path):
    """The station on the in-process simulator (virtual clock), homed, its probe qualified, a session open."""
    yield from sup.sim_station(tmp_path, "dmis")


def _machine(part_point):
    return (TRUE_PART_POSE @ np.append(np.asarray(part_point, float), 1.0))[:3]


def _actuals(text: str) -> dict[str, tuple[str, list[float]]]:
    """FA(label) -> (feature words, numbers) of a DMIS output."""
    joined = re.sub(r"\$\s*\n", " ", text)
    out = {}
    for m in re.finditer(r"^FA\((\w+)\) = FEAT/([A-Z, ]+?),\s+([-\d., ]+)$", joined, re.M):
        out[m.group(1)] = (m.group(2).strip(" ,"), [float(x) for x in m.group(3).split(",")])
    return out


def _tolerances(text: str) -> dict[str, tuple[float, str]]:
    return {m.group(1): (float(m.group(2)), m.group(3))
            for m in re.finditer(r"^TA\((\w+)\) = TOL/[A-Z0-9, ]+?, (-?[\d.]+), (INTOL|OUTOL)$", text, re.M)}


# the NIST simple program's D50 hole at (50, 50, 40), 10 mm below its top, lands on our D30 bore 10 mm below the
# top face (part X30 Y40 Z30) of the part at the station's nominal set-up (part origin at machine X190 Y150 Z0)
PLACEMENT = "D(BORE) = TRANS/XORIG, 170, YORIG, 140, ZORIG, -10"


def placed_simple_program() -> str:
    text = (require("dmis") / "simple_in.dms").read_text()
    text = text.replace("D(START) = DATSET/MCS", "D(START) = DATSET/MCS\n" + PLACEMENT)
    # the program's points lie on a D50 circle: 10 mm inside our D30 bore's wall, where its 10 mm approach would
    # start touching the wall; 15 mm starts 5 mm clear of it
    # and its comment lets the probe lines change for the station's probe: its 2 mm tip (a station without a probe
    # list refuses a sensor with another tip)
    text = text.replace("0.0, 0.0, -1.0, 4.0", "0.0, 0.0, -1.0, 2.0")
    return text.replace("SNSET/APPRCH, 10.0", "SNSET/APPRCH, 15.0")


def test_the_nist_simple_program_placed_on_the_bore_outputs_its_circle(station):
    result = run_text(placed_simple_program(), station.controller.commands, name="simple_in.dms")
    out = result.outputs[None]
    # the output has the NIST output's statements, plus the placement, in its format
    expected = (DATA / "simple_out.dms").read_text().replace("D(START) = DATSET/MCS",
                                                                 "D(START) = DATSET/MCS\n" + PLACEMENT)
    # each actual is followed by a comment with its expanded uncertainty, which NIST's output has not
    got_lines = [x for x in out.strip().splitlines() if not x.startswith("$$ FA(")]
    assert re.search(r"^\$\$ FA\(A_CIRCLE\): U \(95 %\) diameter \d", out, re.M)
    want_lines = expected.strip().splitlines()
    assert len(got_lines) == len(want_lines)
    for got, want in zip(got_lines, want_lines):
        if not re.search(r"\d+\.\d{5}", want):
            assert got.replace(" ", "") == want.replace(" ", "")
    # the circle is the bore where the simulator really put the part, in the placed coordinates
    centre = _machine([30.0, 40.0, 30.0]) - [170.0, 140.0, -10.0]
    words, values = _actuals(out)["A_CIRCLE"]
    assert words == "CIRCLE, INNER, CART"
    assert values[:3] == pytest.approx(list(centre), abs=NOISE)
    assert values[3:6] == pytest.approx([0.0, 0.0, 1.0], abs=1e-4)
    assert values[6] == pytest.approx(30.0, abs=NOISE)
    assert result.hits == 4 and len(station.measurement.hits) == 4
    # the program as NIST wrote it asks for a 4 mm tip, which this station has not: refused before anything moves
    start = station.machine.position.copy()
    with pytest.raises(DmisError, match=r"^line 14: SNSLCT/S\(PROBE6\): the station's probe has a 2.0 mm tip, the "
                                        r"program's S\(PROBE6\) a 4.0 mm tip: qualify it with `cmm calibrate probe "
                                        r"--probe PROBE6 --tip-diameter 4.0`"):
        run_text(placed_simple_program().replace("-1.0, 2.0", "-1.0, 4.0"), station.controller.commands)
    assert np.allclose(station.machine.position, start)


def test_the_sample_part_program_measures_the_true_part(station):
    result = run_text(SAMPLE.read_text(), station.controller.commands, name=SAMPLE.name)
    out = result.outputs["sample_part_out.dms"]  # the program's own output device
    # the datum frame (top face, front face, bore axis) is where the simulator put the part
    frame = result.frames["PART"]
    truth = TRUE_PART_POSE.copy()
    truth[:3, 3] = _machine([30.0, 40.0, 40.0])
    assert np.allclose(frame[:3, 3], truth[:3, 3], atol=NOISE)
    assert np.allclose(frame[:3, :3], truth[:3, :3], atol=1e-4)
    # every actual, in the datum frame, is the sample part's nominal geometry within the probing noise
    fa = _actuals(out)
    want = {"TOP": ("PLANE, CART", {2: 0.0, 5: 1.0}),
            "FRONT": ("PLANE, CART", {1: -40.0, 4: -1.0}),
            "BORE": ("CYLNDR, INNER, CART", {0: 0.0, 1: 0.0, 5: 1.0, 6: 30.0}),
            "BOSS": ("CYLNDR, OUTER, CART", {0: 40.0, 1: -18.0, 5: 1.0, 6: 20.0}),
            "SPHERE": ("SPHERE, OUTER, CART", {0: 40.0, 1: 18.0, 2: -1.0, 3: 20.0}),
            "CONE": ("CONE, OUTER, CART", {5: -1.0, 6: 53.130102})}
    assert set(fa) == set(want)
    for label, (words, values) in want.items():
        assert fa[label][0] == words, label
        for k, v in values.items():
            bound = 0.05 if (label, k) == ("CONE", 6) else NOISE + FACETS.get(label, 0.0)
            assert fa[label][1][k] == pytest.approx(v, abs=bound), (label, k, fa[label][1])
    # the cone's apex is extrapolated 15 mm beyond its hits: a looser bound
    assert fa["CONE"][1][:3] == pytest.approx([70.0, 0.0, 24.0], abs=0.03)
    # tolerances: every one evaluated and in tolerance on the perfect simulated part
    ta = _tolerances(out)
    assert set(ta) == {"FLAT_A", "PERP_C", "DIAM_B", "CYL_B", "PERP_B", "DIAM_BOSS", "POS_BOSS", "DIST_BOSS",
                       "DIAM_SPH", "POS_SPH", "PROF_CONE"}
    assert all(v == "INTOL" for _, v in ta.values()), ta
    assert abs(ta["DIST_BOSS"][0]) <= 2 * NOISE  # sqrt(40^2 + 18^2) between the bore and boss axes
    # the station's own session has the features with the DMIS tolerances the report shows
    feats = {f.name: f for f in station.measurement.features.values()}
    assert set(feats) == set(want)
    assert feats["BORE"].tolerance["size"] == pytest.approx(0.02)
    # a position to datums is the station's GD&T, on the same datums: the same value as the DMIS output
    gdt = {d["name"]: c for d, c in station.measurement.gdt_characteristics()}
    assert set(station.measurement.datums) == {"A", "B", "C"}
    for label in ("POS_BOSS", "POS_SPH"):
        c = gdt[f"T({label})"]
        assert c.actual == pytest.approx(ta[label][0], abs=6e-6) and c.upper == 0.04 and c.datums == "A|B|C"


BAD = """DMISMN/'bad'
UNITS/MM, ANGDEC
GOTO/100, 100, 250
F(C1) = FEAT/CIRCLE, INNER, CART, 50, 50, 40, 0, 0, 1, 50
SCNMOD/ON
MEAS/TORUS, F(C1), 4
ENDMES
ENDFIL
"""


def test_unsupported_statements_and_syntax_errors_are_refused_with_their_lines_before_any_motion(station, tmp_path,
                                                                                                  capsys):
    start = station.machine.position.copy()
    with pytest.raises(DmisError, match=r"^line 5: SCNMOD is not supported$"):
        run_text(BAD, station.controller.commands)
    _, problems = check(BAD)
    assert problems == ["line 5: SCNMOD is not supported", "line 6: MEAS/TORUS is not supported"]
    # a syntax error names its line; continuation lines count
    syntax = "UNITS/MM, ANGDEC\nGOTO/1, $\n 2, 3\nF(X) = FEAT/POINT, CART, 1, 2, (3, 0, 0, 1\n"
    with pytest.raises(DmisError, match=r"^line 4: a '\(' is not closed with '\)'$"):
        run_text(syntax, station.controller.commands)
    assert [s.line for s in statements(syntax)] == [1, 2, 4]
    # the check reads on past a statement it cannot read: one pass lists every problem, in line order
    assert check(BAD.replace("ENDMES\n", "ENDMES\nGOTO/1, $\n  2, (3\n"))[1] == [
        "line 5: SCNMOD is not supported", "line 6: MEAS/TORUS is not supported",
        "line 8: a '(' is not closed with ')'"]
    assert check("GOTO/1, 2\nPTMEAS/CART, 1, 2, 3\nMEAS/PLANE, F(P), 3\n")[1] == [
        "line 1: GOTO takes X, Y, Z, it has 2 numbers", "line 2: PTMEAS outside MEAS ... ENDMES",
        "line 3: F(P) is measured before it is defined (F(P) = FEAT/...)", "line 3: MEAS is not closed with ENDMES"]
    probe = "GOTO/100, 100, 250\nS(SIDE) = SNSDEF/PROBE, INDEX, CART, 0, 0, 0, 1, 0, 0, 2\n"
    with pytest.raises(DmisError, match=r"^line 2: S\(SIDE\) points along \(1, 0, 0\): the station has one fixed probe"):
        run_text(probe, station.controller.commands)
    assert np.allclose(station.machine.position, start)  # nothing moved
    assert station.measurement.hits == {}
    # a statement that fails while running stops the program there; its output so far is kept, saying why
    into = ("FILNAM/'into the part'\nD(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0\nGOTO/60, 40, 70\n"
            "GOTO/60, 40, 20\nENDFIL\n")
    with pytest.raises(DmisError, match=r"^line 4: GOTO: the straight line") as stopped:
        run_text(into, station.controller.commands)
    out = stopped.value.result.outputs[None]
    assert out.startswith("FILNAM/'into the part'") and "$$ the program stopped: line 4: GOTO:" in out
    assert out.endswith("ENDFIL\n") and station.machine.position[2] > 60.0  # it stopped above the part
    # `cmm run --check` lists every problem and runs nothing
    path = tmp_path / "bad.dmi"
    path.write_text(BAD)
    assert main(["run", str(path), "--check"]) == 1
    err = capsys.readouterr().err
    assert "bad.dmi: line 5: SCNMOD is not supported" in err and "line 6: MEAS/TORUS is not supported" in err


def _program() -> prog.Program:
    """The taught features of the sample part (the teach-and-repeat tests' hits), as teaching writes them."""
    sim, machine, _ = sup.setup()
    machine.close()
    hits, feats = [], []
    for name, kind, pts in sup.feature_hits()[1:]:  # the boss and the dome (the top plane: a faster test)
        ids = []
        for p, u in pts:
            hits.append(prog.ProgramHit(len(hits) + 1, tuple(float(x) for x in p), tuple(float(x) for x in u),
                                        sup.CLEARANCE_Z))
            ids.append(len(hits))
        feats.append(prog.ProgramFeature(name, kind, "ls", ids, {"size": 0.02, "form": 0.02, "location": 0.02},
                                         sim.nominal_features[name].to_dict(), name))
    from cmm.journal.session import mesh_sha256

    return prog.Program("sample check", "sample part", mesh_sha256(sim.part_mesh), feats, hits, 10.0)


def test_a_taught_program_exported_to_dmis_runs_again_with_the_same_features(station):
    program = _program()
    model = station.measurement
    taught = run_on(station.controller, model, program)
    text = to_dmis(program, model.part.pose, tip_radius=station.prober.settings.tip_radius,
                   approach=station.config.probe.approach_distance, search=station.config.probe.search_distance,
                   retract=station.config.probe.retract_distance)
    assert check(text)[1] == []
    again = run_text(text, station.controller.commands, name="exported")
    assert set(again.actuals) == {"BOSS", "DOME"}
    a, b = taught.features, again.actuals
    g1, g2 = a["boss"].result.geometry(), b["BOSS"].geometry
    assert g2["radius"] == pytest.approx(g1["radius"], abs=NOISE)
    d = np.array(g1["direction"])
    r = np.array(g2["point"]) - g1["point"]
    assert np.linalg.norm(r - (r @ d) * d) <= NOISE
    g1, g2 = a["dome"].result.geometry(), b["DOME"].geometry
    assert g2["radius"] == pytest.approx(g1["radius"], abs=NOISE)
    assert np.linalg.norm(np.array(g2["center"]) - g1["center"]) <= NOISE
    # the exported program outputs its tolerances: sizes and form in tolerance; the positions are out, as the
    # part was not aligned (it sits 0.4 mm and 0.5 degrees off the nominal set-up the program was placed at)
    verdicts = {e.tolerance.label: e for e in again.evaluations}
    assert set(verdicts) == {"BOSS_D", "BOSS_F", "BOSS_P", "DOME_D", "DOME_P"}
    assert all(verdicts[k].intol for k in ("BOSS_D", "BOSS_F", "DOME_D"))
    offset = 2 * np.linalg.norm(_machine([70.0, 22.0, 40.0])[:2] - (model.part.pose @ [70.0, 22.0, 40.0, 1.0])[:2])
    assert verdicts["BOSS_P"].value == pytest.approx(offset, abs=2 * NOISE) and not verdicts["BOSS_P"].intol


FLOW = """UNITS/MM, ANGDEC
DECL/LOCAL, INTGR, I
DECL/LOCAL, REAL, X, TOPZ
TOPZ = ASSIGN/40
M(CLEAR) = MACRO/'H'
  GOTO/10, 10, H
ENDMAC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
CALL/M(CLEAR), TOPZ + 30
GOTO/INCR, 5, 0, 0, 1
F(TOP) = FEAT/PLANE, CART, 60, 40, TOPZ, 0, 0, 1
MEAS/PLANE, F(TOP), 3
  DO/I, 1, 3
    X = ASSIGN/10 + (I - 1) * 50
    IF/(I .EQ. 2)
      PTMEAS/CART, X, 5, TOPZ, 0, 0, 1
    ELSE
      IF/(I .EQ. 1)
        PTMEAS/POL, 14.1421356, 45, TOPZ, 0, 0, 1
      ELSE
        PTMEAS/CART, X, $
          10, TOPZ, 0, 0, 1
      ENDIF
    ENDIF
  ENDDO
ENDMES
D(TOP) = TRANS/ZORIG, FA(TOP)
OUTPUT/FA(TOP)
RECALL/D(SETUP)
OUTPUT/FA(TOP)
UNITS/INCH, ANGDEC
OUTPUT/FA(TOP)
ENDFIL
"""


def test_variables_loops_conditions_macros_and_coordinate_systems(station):
    result = run_text(FLOW, station.controller.commands, name="flow")
    hits = [station.measurement.hits[h].point for h in sorted(station.measurement.hits)]
    # the loop's three points (the first in polar coordinates, the second the IF's): where the part really is
    want = [[10, 10], [60, 5], [110, 10]]
    assert len(hits) == 3
    for p, (x, y) in zip(hits, want):
        assert np.linalg.norm(np.array(p[:2]) - (np.array([190.0 + x, 150.0 + y]))) < 0.01
        assert p[2] == pytest.approx(40.0, abs=NOISE)
    assert len(out_lines := result.outputs[None].splitlines()) > 0 and out_lines[-1] == "ENDFIL"
    out = result.outputs[None]
    lines = [ln for ln in out.splitlines() if ln.startswith("  ")]
    zs = [float(ln.split(",")[2]) for ln in lines]
    assert zs[0] == pytest.approx(0.0, abs=1e-5)  # in D(TOP): the origin on the measured plane
    assert zs[1] == pytest.approx(hits[0][2] - 0.0, abs=NOISE)  # D(SETUP): the table is Z 0
    assert zs[2] == pytest.approx(zs[1] / 25.4, abs=1e-5)  # in inches
    assert "D(TOP) = TRANS/ZORIG, FA(TOP)" in out and "RECALL/D(SETUP)" in out and "UNITS/INCH, ANGDEC" in out


def _ring(centre, radius, zs, n=12):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.array([[centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), z] for z in zs for a in t])


def test_surface_profile_with_unequal_limits_is_an_offset_zone():
    """TOL/PROFS, -0.025, 0.015: a zone 0.04 wide whose middle is 0.005 inside the material (ISO 1101 UZ-0.005);
    hits at +0.01 and -0.02 from the nominal plane give 0.03 (twice the largest distance from the middle)."""
    from cmm.dmis.features import Actual, Nominal
    from cmm.dmis.tolerances import Tolerance, evaluate

    z = np.array([0.0, 0.0, 1.0])
    pts = np.array([[x, y, 50 + (0.01 if (x + y) % 2 else -0.02)] for x in range(4) for y in range(4)], float)
    face = Actual("F", "plane", {"point": [1.5, 1.5, 50], "normal": [0, 0, 1], "form": 0.03},
                  Nominal("PLANE", None, np.array([0, 0, 50.0]), z), hit_points=pts)
    unequal = evaluate(Tolerance("U", "PROFS", lower=-0.025, upper=0.015), [face], {}, np.eye(4))
    assert unequal.value == pytest.approx(0.03, abs=1e-12) and unequal.intol
    equal = evaluate(Tolerance("E", "PROFS", lower=-0.02, upper=0.02), [face], {}, np.eye(4))
    assert equal.value == pytest.approx(0.04, abs=1e-12) and equal.intol
    outside = evaluate(Tolerance("O", "PROFS", lower=-0.01, upper=0.03), [face], {}, np.eye(4))
    assert outside.value == pytest.approx(0.06, abs=1e-12) and not outside.intol


def test_tolerances_on_known_geometry():
    """Runout, concentricity, orientation, angles, distances and constructions on exact geometry (no probing)."""
    from cmm.dmis.construct import construct_actual
    from cmm.dmis.features import Actual, Nominal
    from cmm.dmis.tolerances import Tolerance, ToleranceError, evaluate

    z = np.array([0.0, 0.0, 1.0])
    datum = Actual("D", "cylinder", {"point": [0, 0, 0], "direction": [0, 0, 1], "radius": 10.0},
                   Nominal("CYLNDR", False, np.zeros(3), z, diameter=20.0), hit_points=_ring((0, 0), 10, [0, 10]))
    e = 0.01  # a second cylinder 0.01 mm off the datum axis
    other = Actual("O", "cylinder", {"point": [e, 0, 20], "direction": [0, 0, 1], "radius": 5.0},
                   Nominal("CYLNDR", False, np.array([0, 0, 20.0]), z, diameter=10.0),
                   hit_points=_ring((e, 0), 5, [20, 30]))
    datums = {"A": datum}
    frame = np.eye(4)
    run = evaluate(Tolerance("R", "RUNOUT", upper=0.05, datums=["A"], options=["CIRCLR"]), [other], datums, frame)
    assert run.value == pytest.approx(2 * e, abs=1e-6) and run.intol
    con = evaluate(Tolerance("C", "CONCEN", upper=0.015, datums=["A"]), [other], datums, frame)
    assert con.value == pytest.approx(2 * e, abs=1e-6) and not con.intol  # 0.02 > 0.015: OUTOL
    # a face tilted by 0.01 mm over 20 mm: parallel to the datum plane within 0.01, at 90 deg to the axis
    face_pts = np.array([[x, y, 50 + 0.0005 * x] for x in (-10, 10) for y in (-10, 10)])
    n = np.array([-0.0005, 0.0, 1.0]) / np.linalg.norm([-0.0005, 0.0, 1.0])
    face = Actual("F", "plane", {"point": [0, 0, 50], "normal": n.tolist(), "form": 0.0},
                  Nominal("PLANE", None, np.array([0, 0, 50.0]), z), hit_points=face_pts)
    base = Actual("B", "plane", {"point": [0, 0, 0], "normal": [0, 0, 1], "form": 0.0},
                  Nominal("PLANE", None, np.zeros(3), z), hit_points=np.array([[x, y, 0.0] for x in (-9, 9)
                                                                                for y in (-9, 9)]))
    datums["P"] = base
    par = evaluate(Tolerance("P1", "PARLEL", upper=0.02, datums=["P"]), [face], datums, frame)
    assert par.value == pytest.approx(0.01, abs=1e-6) and par.intol
    perp = evaluate(Tolerance("P2", "PERPEND", upper=0.02, datums=["A"]), [face], datums, frame)
    assert perp.value == pytest.approx(0.01, abs=1e-6)
    ang = evaluate(Tolerance("P3", "ANGLR", upper=0.02, nominal=0.0, datums=["P"]), [face], datums, frame)
    assert ang.value == pytest.approx(par.value, abs=1e-9)
    anglb = evaluate(Tolerance("AB", "ANGLB", lower=-0.01, upper=0.01, nominal=0.0), [face, base], datums, frame)
    assert anglb.value == pytest.approx(np.degrees(np.arctan(0.0005)), abs=1e-6) and not anglb.intol
    dist = evaluate(Tolerance("DZ", "DISTB", lower=-0.1, upper=0.1, nominal=50.0, options=["ZAXIS"]),
                    [base, face], datums, frame)
    assert dist.value == pytest.approx(0.0, abs=1e-9) and dist.intol
    # constructions: the axis through the plane is the point on it; the mid-plane of the two faces
    kind, g = construct_actual("point", "INTOF", [other, face])
    assert kind == "point" and g["point"] == pytest.approx([e, 0, 50 + 0.0005 * e], abs=1e-9)
    kind, g = construct_actual("plane", "MIDPL", [base, face])
    assert kind == "plane" and g["point"][2] == pytest.approx(25.0)
    kind, g = construct_actual("point", "PROJCT", [other, base])
    assert g["point"] == pytest.approx([e, 0, 0], abs=1e-12)
    with pytest.raises(ToleranceError, match=r"T\(X\) \(TOL/POS\) applies to 1 feature"):
        evaluate(Tolerance("X", "POS", upper=0.1), [other, face], datums, frame)
    with pytest.raises(ToleranceError, match="no DATDEF"):
        evaluate(Tolerance("Y", "PERPEND", upper=0.1, datums=["Q"]), [face], datums, frame)


def test_cmm_run_writes_the_dmis_output_and_the_station_report(tmp_path, monkeypatch, capsys):
    """The command line: the simulated station, a session, the DMIS output and the HTML report beside it."""
    monkeypatch.chdir(tmp_path)
    program = tmp_path / "top.dmi"
    program.write_text("FILNAM/'top face'\nUNITS/MM, ANGDEC\nD(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0\n"
                       "GOTO/10, 10, 50\nF(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1\nMEAS/PLANE, F(TOP), 3\n"
                       "PTMEAS/CART, 10, 10, 40, 0, 0, 1\nPTMEAS/CART, 60, 5, 40, 0, 0, 1\n"
                       "PTMEAS/CART, 110, 10, 40, 0, 0, 1\nENDMES\nT(F) = TOL/FLAT, 0.01\nOUTPUT/FA(TOP), TA(F)\n"
                       "ENDFIL\n")
    assert main(["run", str(program), "--sessions", str(tmp_path / "sessions"), "-o", "top_out.dms"]) == 0
    printed = capsys.readouterr().out
    assert "1 features, 3 hits, 1 tolerances, 0 out of tolerance" in printed
    out = (tmp_path / "top_out.dms").read_text()
    assert out.startswith("FILNAM/'top face'\n") and out.endswith("ENDFIL\n")
    assert _actuals(out)["TOP"][1][2] == pytest.approx(40.0, abs=0.01)
    assert _tolerances(out)["F"][1] == "INTOL"
    report = (tmp_path / "top_report.html").read_text()
    assert "TOP" in report and "flatness" in report
    assert len(list((tmp_path / "sessions").glob("*.jsonl"))) == 1


def test_the_routine_tab_opens_checks_and_runs_a_dmis_program(station):
    """The page's Routine tab: a DMIS file is checked and listed, a refused one names its line, Run writes the
    output beside the sessions; it runs with the run_dmis verb, which only the control holder may send."""
    from cmm.control import OpenPolicy
    from cmm.control.access import Client, Control
    from cmm.dmis.runner import register_verbs

    register_verbs(station.controller.commands)  # as the station's page does
    control = Control()
    assert control.take("operator", is_local=True)
    station.controller.use_policy_of(control)
    try:
        refused = station.controller.commands.call(Client("observer", local=True), "run_dmis",
                                                   {"text": placed_simple_program(), "name": "simple.dms"})
        assert refused.error["code"] == "refused" and "only observes" in refused.error["message"], refused
        _routine_tab_runs_dmis(station, control)
    finally:
        station.controller.policy = OpenPolicy()


def _routine_tab_runs_dmis(station, control):
    from cmm.ui.context import PanelContext
    from cmm.ui.panel_routine import RoutinePanel

    panel = RoutinePanel(PanelContext(station.controller.commands, control, None, client_id="operator", is_local=True))
    folder = station.measurement.session_dir
    (folder / "bad.dmi").write_text(BAD)
    assert panel.open_dmis("bad.dmi") is None and panel.dmis is None
    assert "line 5: SCNMOD is not supported" in panel.dmis_text
    assert panel.ctx.messages[-1][:2] == ("error", "DMIS program refused")
    (folder / "simple.dms").write_text(placed_simple_program())
    lines = panel.open_dmis("simple.dms")
    assert lines and lines[0].startswith("line 1: DMISMN") and any("MEAS/CIRCLE" in x for x in lines)
    assert panel.run_dmis(wait=True), panel.ctx.messages[-2:]
    assert panel.dmis_status.startswith("**DONE**: 1 features, 4 hits"), panel.dmis_status
    outputs = list(folder.glob("*_out.dms")) + [p for p in folder.iterdir() if p.suffix == ".dms" and "out" in p.name]
    assert any("A_CIRCLE" in p.read_text() for p in outputs), [p.name for p in folder.iterdir()]


EDGES = """FILNAM/'edges'
UNITS/MM, ANGRAD
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
S(P) = SNSDEF/PROBE, FIXED, POL, 0, 0, 2.0
SNSLCT/S(P)
SNSET/DEPTH, 3
SNSET/APPRCH, 5
SNSET/RETRCT, 5
GOTO/60, -15, 60
F(EDGE) = FEAT/LINE, UNBND, CART, 20, 0, 20, 1, 0, 0, 0, -1, 0
MEAS/LINE, F(EDGE), 3
  PTMEAS/CART, 20, 0, 20, 0, -1, 0
  PTMEAS/CART, 60, 0, 20, 0, -1, 0
  PTMEAS/CART, 100, 0, 20, 0, -1, 0
ENDMES
GOTO/100, -15, 20
GOTO/100, -15, 70
GOTO/90, 22, 70
GOTO/90, 22, 50
F(BOSSC) = FEAT/CIRCLE, OUTER, CART, 70, 22, 50, 0, 0, 1, 20
MEAS/CIRCLE, F(BOSSC), 4
  PTMEAS/CART, 80, 22, 50, 1, 0, 0
  GOTO/86, 38, 50
  PTMEAS/CART, 70, 32, 50, 0, 1, 0
  GOTO/54, 38, 50
  PTMEAS/CART, 60, 22, 50, -1, 0, 0
  GOTO/54, 6, 50
  PTMEAS/CART, 70, 12, 50, 0, -1, 0
ENDMES
GOTO/70, 5, 70
GOTO/70, 22, 70
F(PT) = FEAT/POINT, CART, 70, 22, 55, 0, 0, 1
MEAS/POINT, F(PT), 1
  PTMEAS/CART, 70, 22, 55, 0, 0, 1
ENDMES
GOTO/70, 22, 70
GOTO/135, 70, 70
GOTO/135, 70, 20
F(SIDE) = FEAT/LINE, BND, CART, 120, 70, 20, 120, 10, 20, 1, 0, 0
MEAS/LINE, F(SIDE), 3
  PTMEAS/CART, 120, 70, 20
  PTMEAS/CART, 120, 40, 20
  PTMEAS/CART, 120, 10, 20
ENDMES
T(STR) = TOL/STRGHT, 0.01
T(RAD) = TOL/RAD, -0.01, 0.01
T(CIR) = TOL/CIRLTY, 0.01
T(PL) = TOL/PROFL, 0.02
OUTPUT/FA(EDGE), TA(STR)
OUTPUT/FA(BOSSC), TA(RAD), TA(CIR), TA(PL)
OUTPUT/FA(PT)
OUTPUT/FA(SIDE)
F(PB) = FEAT/LINE, BND, POL, 10, 1.5707963, 5, 20, 0.5, 5, 0, 0, 1
OUTPUT/F(PB)
D(TURNED) = ROTAT/ZAXIS, 1.5707963
OUTPUT/FA(EDGE)
OUTPUT/F(PB)
ENDFIL
"""


def test_lines_points_outer_circles_radius_straightness_roundness_line_profile_and_radians(station):
    """The statements the sample program does not use: a polar SNSDEF, SNSET/DEPTH, FEAT/LINE, FEAT/POINT, an
    outer circle, TOL/RAD, STRGHT, CIRLTY, PROFL, and a ROTAT in radians (UNITS/.., ANGRAD)."""
    result = run_text(EDGES, station.controller.commands, name="edges")
    out = result.outputs[None]
    first, turned = out.split("D(TURNED) = ROTAT/ZAXIS")
    fa, ta = _actuals(first), _tolerances(first)
    setup = np.array([190.0, 150.0, 0.0])
    part_x = TRUE_PART_POSE[:3, 0]
    # the front face's edge at Z 20: along the true part's X axis, through its true points
    words, line = fa["EDGE"]
    assert words == "LINE, UNBND, CART" and len(line) == 9
    d = np.array(line[3:6]) / np.linalg.norm(line[3:6])  # the output's 5 decimals
    assert d @ part_x == pytest.approx(1.0, abs=1e-6)  # the FEAT's direction (+X), not the fit's sign
    r = _machine([60.0, 0.0, 20.0]) - setup - line[:3]
    assert np.linalg.norm(r - (r @ d) * d) <= NOISE
    # its plane normal: the front face's outward normal (the part's -Y), square to the line
    assert np.array(line[6:9]) == pytest.approx(-TRUE_PART_POSE[:3, 1], abs=NOISE / 30)
    # the bounded line on the right face, probed without vectors (along its plane normal): BND with the first and
    # last hit projected onto the line as end points, in the order the FEAT gave them, and the face's normal
    words, side = fa["SIDE"]
    assert words == "LINE, BND, CART" and len(side) == 9
    a, b = np.array(side[:3]), np.array(side[3:6])
    assert a[1] == pytest.approx(70.0, abs=1.0) and b[1] == pytest.approx(10.0, abs=1.0)
    hits = np.array([station.measurement.hits[h].point for h in sorted(station.measurement.hits)])
    assert len(hits) == 11
    u = (b - a) / np.linalg.norm(b - a)
    assert u @ -TRUE_PART_POSE[:3, 1] == pytest.approx(1.0, abs=1e-6)  # from Y70 to Y10: along the part's -Y
    for end, hit in ((a, hits[8]), (b, hits[10])):
        r = hit - setup - end
        assert np.linalg.norm(r - (r @ u) * u) <= NOISE and abs(r @ u) <= 1e-4  # the hit's foot on the line
    assert np.array(side[6:9]) == pytest.approx(TRUE_PART_POSE[:3, 0], abs=NOISE / 30)
    part = (np.linalg.inv(TRUE_PART_POSE) @ np.c_[hits[8:], np.ones(3)].T).T[:, :3]
    assert part[:, 0] == pytest.approx([120.0] * 3, abs=NOISE)
    # the output reads back with the station's own parser: the same statement, the same numbers
    for label, (words, nums) in (("EDGE", fa["EDGE"]), ("SIDE", fa["SIDE"])):
        text = re.search(rf"^FA\({label}\) = FEAT/LINE.*?\$\s*\n.*$", first, re.M).group(0)
        (st,) = parse(text)
        assert st.major == "FEAT" and st.label.name == label
        assert [p.text for p in st.params if isinstance(p, Word)] == [w.strip() for w in words.split(",")]
        assert [evaluate(p, {}, 1) for p in st.params if isinstance(p, Expr)] == nums
        assert check(text.replace("FA(", "F("))[1] == []
    # a bounded line given in POL: both end points polar (radians here), written back as given
    assert "F(PB) = FEAT/LINE, BND, POL, 10.00000, 1.57080, 5.00000, 20.00000, 0.50000, 5.00000, 0.00000, " \
        "0.00000, 1.00000" in first.splitlines()
    pb = [float(x) for x in turned.split("F(PB) = FEAT/LINE, BND, POL, ")[1].splitlines()[0].split(",")]
    assert pb[0::3][:2] == [10.0, 20.0] and pb[2] == pb[5] == 5.0 and pb[6:] == [0.0, 0.0, 1.0]
    assert abs(pb[1] - 1.5708) == pytest.approx(1.5708, abs=1e-4)  # a quarter turn, whichever way
    assert pb[4] - pb[1] == pytest.approx(0.5 - 1.5708, abs=1e-4)
    # read back as nominals, both lines keep their plane normal and the bounded one its end points
    assert nominal_from("LINE", None, fa["EDGE"][1], np.eye(4), 1.0, 1.0).plane == pytest.approx(line[6:9], abs=1e-5)
    back = bounded_line(side, np.eye(4), 1.0)
    assert back.bounded and back.plane == pytest.approx(side[6:9], abs=1e-5)
    assert back.point + back.length * back.vector == pytest.approx(b, abs=1e-9)
    assert 0.0 <= ta["STR"][0] <= NOISE and ta["STR"][1] == "INTOL"
    # the boss's section at Z 50: where the part really is, D20
    words, circle = fa["BOSSC"]
    assert words == "CIRCLE, OUTER, CART"
    assert circle[:2] == pytest.approx(list((_machine([70.0, 22.0, 50.0]) - setup)[:2]), abs=NOISE)
    assert circle[6] == pytest.approx(20.0, abs=NOISE)
    assert ta["RAD"] == (pytest.approx(circle[6] / 2 - 10.0, abs=1e-5), "INTOL")
    assert 0.0 <= ta["CIR"][0] <= NOISE and ta["CIR"][1] == "INTOL"
    # the line profile: twice the hits' largest distance from the nominal circle (the part sits off the set-up)
    hits = hits[:8]
    off = np.abs(np.linalg.norm(hits[3:7, :2] - setup[:2] - [70.0, 22.0], axis=1) - 10.0)
    assert ta["PL"] == (pytest.approx(2 * off.max(), abs=1e-4), "OUTOL") and off.max() > 0.1
    # each TA line with its U as each FA line (a $$ comment after it), or why it has none: the radius's U is half
    # the circle's diameter U; roundness and the line profile propagated through DMIS's own evaluation
    u_ta = dict(re.findall(r"^\$\$ TA\((\w+)\): (.*)$", first, re.M))
    assert u_ta["STR"].startswith("no U: the toleranced feature has no uncertainty budget"), u_ta
    diameter_u = float(re.search(r"^\$\$ FA\(BOSSC\): U \(95 %\) diameter ([\d.]+)", first, re.M).group(1))
    assert u_ta["RAD"].startswith(f"U (95 %) {diameter_u / 2:.5f} k=")
    for label in ("CIR", "PL"):
        assert 0 < float(re.match(r"U \(95 %\) ([\d.]+) k=", u_ta[label]).group(1)) < 0.01, u_ta
    # the point on the boss's top, and every hit on the true part's surface where it was asked for
    assert fa["PT"][1][2] == pytest.approx(55.0, abs=NOISE) and fa["PT"][1][3:] == [0.0, 0.0, 1.0]
    part = (np.linalg.inv(TRUE_PART_POSE) @ np.c_[hits, np.ones(len(hits))].T).T[:, :3]
    assert part[:3, 1] == pytest.approx([0.0] * 3, abs=NOISE) and part[7, 2] == pytest.approx(55.0, abs=NOISE)
    # ANGRAD: the system turned a quarter turn, not 1.57 degrees, turns the edge's direction with it
    t = _actuals(turned)["EDGE"][1][3:6]
    assert abs(t[0]) == pytest.approx(abs(d[1]), abs=2e-5) and abs(t[1]) == pytest.approx(abs(d[0]), abs=2e-5)
    assert any("SNSET/DEPTH has no effect" in line for line in result.log)
    # a polar SNSDEF in radians: A = a quarter turn points the probe sideways, which the station has not
    with pytest.raises(DmisError, match=r"^line 2: S\(SIDE\) points along \(1, 0, "):
        run_text("UNITS/MM, ANGRAD\nS(SIDE) = SNSDEF/PROBE, INDEX, POL, 1.5707963, 0, 2\n", station.controller.commands)


def test_cmm_run_ends_without_noise_on_stderr(tmp_path):
    """A run from the shell prints its results and nothing else: libigl's bindings report every surface index
    still alive when the interpreter ends as a leak (49 lines on stderr), so the cached indexes go at exit."""
    program = tmp_path / "top.dmi"
    program.write_text("UNITS/MM, ANGDEC\nD(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0\nGOTO/10, 10, 50\n"
                       "F(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1\nMEAS/PLANE, F(TOP), 3\n"
                       "PTMEAS/CART, 10, 10, 40, 0, 0, 1\nPTMEAS/CART, 60, 5, 40, 0, 0, 1\n"
                       "PTMEAS/CART, 110, 10, 40, 0, 0, 1\nENDMES\nENDFIL\n")
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-m", "cmm.cli", "run", str(program)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(root)})
    assert done.returncode == 0, done.stderr
    assert "1 features, 3 hits" in done.stdout and (tmp_path / "top_out.dms").exists()
    # run where no calibration records are: the results come with the reason they may read off
    assert "no calibration records in calibration: the probe is not qualified" in done.stdout
    assert done.stderr == ""

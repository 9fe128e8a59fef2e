"""A DMIS program's nominals and the station's are the same after the program re-aligns, and every run of a
program is a part of its own: its own session, one row per tolerance, one point in the trends."""

from __future__ import annotations

import re

import numpy as np
import pytest

import session_support as sup
from cmm.session.gdt_session import session_gdt
from cmm.journal.store import DirectoryStore, load_session
from cmm.sim.cmm_sim import TRUE_PART_POSE

# the sample part at the nominal set-up (machine X190 Y150); every FEAT is given before the TRANS onto the bore
# finds the part elsewhere: BOSS is measured before it, BORE2 (the bore 10 mm deeper) after it
PROGRAM = """FILNAM/'position after a re-alignment'
UNITS/MM, ANGDEC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
SNSET/APPRCH, 2
SNSET/SEARCH, 3
SNSET/RETRCT, 2
FEDRAT/POSVEL, MMPS, 50
FEDRAT/MESVEL, MMPS, 2
F(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1
F(BORE) = FEAT/CIRCLE, INNER, CART, 30, 40, 30, 0, 0, 1, 30
F(BOSS) = FEAT/CIRCLE, OUTER, CART, 70, 22, 45, 0, 0, 1, 20
F(BORE2) = FEAT/CIRCLE, INNER, CART, 30, 40, 20, 0, 0, 1, 30
GOTO/15, 60, 50
MEAS/PLANE, F(TOP), 3
  PTMEAS/CART, 15, 60, 40, 0, 0, 1
  PTMEAS/CART, 15, 20, 40, 0, 0, 1
  PTMEAS/CART, 50, 65, 40, 0, 0, 1
ENDMES
GOTO/30, 40, 50
GOTO/30, 40, 30
MEAS/CIRCLE, F(BORE), 4
  PTMEAS/CART, 45, 40, 30, -1, 0, 0
  PTMEAS/CART, 30, 55, 30, 0, -1, 0
  PTMEAS/CART, 15, 40, 30, 1, 0, 0
  PTMEAS/CART, 30, 25, 30, 0, 1, 0
ENDMES
GOTO/30, 40, 60
MEAS/CIRCLE, F(BOSS), 4
  GOTO/83, 22, 60
  PTMEAS/CART, 80, 22, 45, 1, 0, 0
  GOTO/83, 22, 60
  GOTO/70, 35, 60
  PTMEAS/CART, 70, 32, 45, 0, 1, 0
  GOTO/70, 35, 60
  GOTO/57, 22, 60
  PTMEAS/CART, 60, 22, 45, -1, 0, 0
  GOTO/57, 22, 60
  GOTO/70, 9, 60
  PTMEAS/CART, 70, 12, 45, 0, -1, 0
  GOTO/70, 9, 60
ENDMES
D(BORE) = TRANS/XORIG, FA(BORE), YORIG, FA(BORE)
GOTO/0, 0, 50
GOTO/0, 0, 20
MEAS/CIRCLE, F(BORE2), 4
  PTMEAS/CART, 15, 0, 20, -1, 0, 0
  PTMEAS/CART, 0, 15, 20, 0, -1, 0
  PTMEAS/CART, -15, 0, 20, 1, 0, 0
  PTMEAS/CART, 0, -15, 20, 0, 1, 0
ENDMES
GOTO/0, 0, 50
DATDEF/FA(TOP), DAT(A)
DATDEF/FA(BORE), DAT(B)
T(PBOSS) = TOL/POS, 2D, 1.0
T(PBORE2) = TOL/POS, 2D, 0.05
T(PDAT) = TOL/POS, 2D, 1.0, DAT(A), DAT(B)
OUTPUT/FA(BOSS), TA(PBOSS), TA(PDAT)
OUTPUT/FA(BORE2), TA(PBORE2)
ENDFIL
"""
# the FEAT locations (machine XY at the nominal set-up)
NOMINAL_XY = {"BORE": np.array([220.0, 190.0]), "BOSS": np.array([260.0, 172.0]), "BORE2": np.array([220.0, 190.0])}


@pytest.fixture
def station(tmp_path):
    """The station on the in-process simulator (virtual clock), homed; the part a few tenths off and turned
    0.5 degrees from the nominal set-up (the simulator's true part)."""
    yield from sup.sim_station(tmp_path, "nominals")


def _ta(text: str) -> dict[str, float]:
    return {m.group(1): float(m.group(2)) for m in re.finditer(r"^TA\((\w+)\) = TOL/[A-Z0-9, ]+?, (-?[\d.]+), ", text, re.M)}


def _report_positions(session) -> dict[str, float]:
    """Feature name -> its "position ⌀" as the station's report gives it (the journal, not the live model)."""
    out = {}
    for f in session.state.features.values():
        for c in f.characteristics():  # at its own tolerance, over the defaults
            if c.name.startswith("position"):
                out[f.name] = c.actual
    return out


def _expected(session) -> dict[str, float]:
    """By hand, from the session's fits: the TRANS found the bore at its fitted centre, so the part (and every
    FEAT nominal with it) moved by the bore's offset from its nominal; each position is 2 x the centre's distance
    from its moved nominal across the nominal axis (Z)."""
    centre = {f.name: np.asarray(f.fit["center"], float) for f in session.state.features.values()
              if f.kind == "circle"}
    move = centre["BORE"][:2] - NOMINAL_XY["BORE"]
    return {name: 2.0 * float(np.linalg.norm(centre[name][:2] - (NOMINAL_XY[name] + move)))
            for name in ("BOSS", "BORE2")}


def test_each_run_is_a_part_and_judges_positions_after_a_re_alignment_as_the_report_does(station, tmp_path):
    """The Routine tab runs the program twice, the second time from another page (a reload: its run count starts
    again). Each run: its own session with its own features and one row per tolerance, one part in the trends,
    and the positions after the program re-aligned the same in the DMIS output, the station's report and by
    hand: BOSS measured before the TRANS onto the bore, BORE2 defined before it and measured after it."""
    from cmm.control.access import Control
    from cmm.session.trends import SEP, open_trends
    from cmm.ui.context import PanelContext
    from cmm.ui.panel_routine import RoutinePanel

    model = station.measurement
    folder = model.session_dir
    (folder / "realign.dmi").write_text(PROGRAM)
    model.trends = open_trends(tmp_path / "trends", station="cmm-1", background=False)
    store = DirectoryStore(folder)
    try:
        control = Control()
        assert control.take("operator", is_local=True)
        positions = []
        for part in (1, 2):
            panel = RoutinePanel(PanelContext(station.controller.commands, control, None, client_id="operator", is_local=True))
            assert panel.open_dmis("realign.dmi")
            assert panel.run_dmis(wait=True), panel.ctx.messages[-2:]
            assert panel.dmis_status.startswith("**DONE**: 4 features, 15 hits, 3 tolerances"), panel.dmis_status
            result = panel.dmis_results[-1]
            assert any("D(BORE) moved the station's part" in line for line in result.log), result.log
            # the live model (the tree, the GD&T tab) holds this part only
            assert sorted(f.name for f in model.features.values()) == ["BORE", "BORE2", "BOSS", "TOP"]
            assert [d["name"] for d, _ in model.gdt_characteristics()] == ["T(PDAT)"]
            # the part's session: its own features, one row per tolerance
            session = load_session(store, f"realign {part}")
            assert sorted(f.name for f in session.state.features.values()) == ["BORE", "BORE2", "BOSS", "TOP"]
            assert [d["name"] for d, _ in session_gdt(session)] == ["T(PDAT)"]
            # the positions: the DMIS evaluation, the station's report and the hand computation agree
            expected = _expected(session)
            report = _report_positions(session)
            evaluations = {e.tolerance.label: e.value for e in result.evaluations}
            ta = _ta(result.outputs[None])
            for name, label in (("BOSS", "PBOSS"), ("BORE2", "PBORE2")):
                assert evaluations[label] == pytest.approx(expected[name], abs=1e-9), name
                assert report[name] == pytest.approx(expected[name], abs=1e-9), name
                assert ta[label] == pytest.approx(expected[name], abs=6e-6), name  # the output's five decimals
            # what the numbers mean on the true part: the boss relative to the bore turned 0.5 degrees about the
            # part's corner (43.9 mm from the bore: 0.383 mm off, a 0.766 mm zone); the bore deeper down on itself
            rel = np.array([40.0, -18.0])
            assert expected["BOSS"] == pytest.approx(2.0 * float(np.linalg.norm(TRUE_PART_POSE[:2, :2] @ rel - rel)),
                                                     abs=0.02)
            assert expected["BORE2"] < 0.02  # the same bore: the probing noise of two centres
            positions.append(report["BOSS"])
        assert not store.exists("realign 3")
        # the trends: the program's series has the two parts, each with its run's value
        series = "realign.dmi"
        history = model.trends.history(series, f"BOSS{SEP}POS T(PBOSS)")
        assert len(history) == 2 and list(history.station) == ["cmm-1", "cmm-1"]
        assert list(history.value) == pytest.approx(positions, abs=1e-9)
        assert len(model.trends.history(series, f"BOSS{SEP}POS T(PDAT)")) == 2
    finally:
        model.trends.close()
        model.trends = None

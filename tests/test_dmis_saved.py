"""SAVE and RECALL across programs, as the standard means them: a fixture's alignment and a datum saved by one
program are recalled by the next program run on the station (kept in its records, dmis-saved.json in the sessions
folder); a RECALL of what no program saved is a warning of the check and a refusal before any motion."""

from __future__ import annotations

import re

import numpy as np
import pytest

import session_support as sup
from cmm.dmis.check import check, warnings
from cmm.dmis.executor import DmisError
from cmm.dmis.runner import run_text

HEAD = """UNITS/MM, ANGDEC
SNSET/APPRCH, 5
SNSET/RETRCT, 5
"""
POINT = """GOTO/260, 172, 70
F(PT) = FEAT/POINT, CART, 260, 172, 55, 0, 0, 1
MEAS/POINT, F(PT), 1
  PTMEAS/CART, 260, 172, 55, 0, 0, 1
ENDMES
GOTO/260, 172, 70
"""
FIRST = ("FILNAM/'fixture'\n" + HEAD + POINT + "DATDEF/FA(PT), DAT(A)\nD(FIX) = DATSET/DAT(A), ZORIG\n"
         "SAVE/DA(FIX)\nSAVE/DAT(A)\nENDFIL\n")
SECOND = ("FILNAM/'next'\n" + HEAD + "RECALL/DA(FIX)\nRECALL/DAT(A)\n"
          + POINT.replace("260, 172, 70", "260, 172, 15").replace("260, 172, 55", "260, 172, 0")
          + "OUTPUT/FA(PT)\nENDFIL\n")
NOISE = 0.004


@pytest.fixture
def station(tmp_path):
    yield from sup.sim_station(tmp_path, "saved")


def _point(out):
    joined = re.sub(r"\$\s*\n", " ", out)  # the output's continued lines joined
    line = next(x for x in joined.splitlines() if x.startswith("FA(PT) = FEAT/POINT"))
    return np.array([float(v) for v in line.split(",")[2:5]])


def test_an_alignment_and_a_datum_saved_by_one_program_are_recalled_by_the_next(station):
    stmts, problems = check(SECOND)
    assert problems == []
    assert ("line 5: RECALL/DA(FIX): nothing named DA(FIX) is defined or saved before it in this program: the run "
            "takes it from the station's saved items (an earlier program's SAVE) and stops before any motion when "
            "it has none") in warnings(SECOND, stmts)
    # before any program saved it: refused before anything moves
    start = station.machine.position.copy()
    with pytest.raises(DmisError, match=r"^line 5: RECALL/DA\(FIX\): nothing named DA\(FIX\) is defined or saved "
                                        r"before it, nor saved by an earlier program on this station$"):
        run_text(SECOND, station.controller.commands, name="next.dms")
    assert np.allclose(station.machine.position, start)
    first = run_text(FIRST, station.controller.commands, name="fixture.dms")
    assert "SAVE/DA(FIX)" in first.outputs[None]
    assert (station.measurement.session_dir / "dmis-saved.json").is_file()
    top = first.actuals["PT"].location()[2]  # the boss top, machine Z
    # the next program: its nominals in the saved fixture system (Z from the boss top), its point read there; the
    # datum comes back too (a DATSET on it would build the same system)
    second = run_text(SECOND, station.controller.commands, name="next.dms")
    assert any("DA(FIX) as saved by program 'fixture.dms' at" in line for line in second.log), second.log
    assert "RECALL/DA(FIX)" in second.outputs[None]
    got = _point(second.outputs[None])
    assert got == pytest.approx([260.0, 172.0, 0.0], abs=NOISE)
    assert second.actuals["PT"].location()[2] == pytest.approx(top, abs=NOISE)
    assert any("DAT(A) as saved by program 'fixture.dms' at" in line for line in second.log), second.log

"""A DMIS run's Pause, Resume, Skip step and Cancel, sent through the command API as the page's buttons send them.

The station runs on the simulator's virtual clock. Each control is sent at a known point of the program: the
program asks the operator (TEXT/MAN) just before it, and the answer (the run's query callback, in the run's
thread) sends the verb, so the run reaches the next statement with the request already made.
"""

from __future__ import annotations

import threading

import pytest

import session_support as sup
from cmm.dmis.executor import DmisError
from cmm.dmis.runner import register_verbs

PROGRAM = """FILNAM/'controls'
UNITS/MM, ANGDEC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
S(P) = SNSDEF/PROBE, FIXED, POL, 0, 0, 2.0
SNSLCT/S(P)
SNSET/APPRCH, 5
SNSET/RETRCT, 5
GOTO/60, -15, 20
F(EDGE) = FEAT/LINE, UNBND, CART, 20, 0, 20, 1, 0, 0, 0, -1, 0
TEXT/MAN, 'skip the edge'
MEAS/LINE, F(EDGE), 3
  PTMEAS/CART, 20, 0, 20, 0, -1, 0
  PTMEAS/CART, 60, 0, 20, 0, -1, 0
  PTMEAS/CART, 100, 0, 20, 0, -1, 0
ENDMES
GOTO/100, -15, 70
GOTO/70, 22, 70
F(PT) = FEAT/POINT, CART, 70, 22, 55, 0, 0, 1
TEXT/MAN, 'pause before the point'
MEAS/POINT, F(PT), 1
  PTMEAS/CART, 70, 22, 55, 0, 0, 1
ENDMES
GOTO/70, 22, 70
T(STR) = TOL/STRGHT, 0.01
OUTPUT/FA(EDGE), TA(STR)
OUTPUT/FA(PT)
TEXT/MAN, 'cancel here'
GOTO/135, 70, 70
ENDFIL
"""
LINE = {text.split("'")[1]: n + 1 for n, text in enumerate(PROGRAM.splitlines()) if text.startswith("TEXT/MAN")}


@pytest.fixture
def station(tmp_path):
    yield from sup.sim_station(tmp_path, "dmis controls")


def test_pause_resume_skip_and_cancel_reach_a_dmis_run_between_its_statements(station):
    register_verbs(station.controller.commands)
    commands = station.controller.commands
    model = station.measurement
    progress: list[str] = []
    paused = threading.Event()
    answers = {"skip the edge": "pause", "pause before the point": "pause", "cancel here": "cancel"}
    at_pause: list[int] = []

    def on_progress(_fraction: float, message: str) -> None:
        progress.append(message)
        if message.startswith("paused"):
            at_pause.append(len(model.hits))
            paused.set()

    def query(prompt: str, _answer: bool) -> str:
        verb = answers[prompt.split(": ", 1)[1]]
        commands.invoke(None, verb)  # the page's Pause / Cancel while the program asks
        return ""

    outcome: list[object] = []

    def run() -> None:
        try:
            outcome.append(commands.invoke(None, "run_dmis", text=PROGRAM, name="controls.dms", query=query,
                                           progress=on_progress))
        except DmisError as exc:
            outcome.append(exc)

    thread = threading.Thread(target=run, name="dmis run")
    thread.start()
    # paused before the edge's MEAS: Skip step leaves the edge out (and lets the run go on)
    assert paused.wait(600), progress
    paused.clear()
    assert progress[-1] == f"paused before line {LINE['skip the edge'] + 1}: MEAS/LINE; Resume to go on", progress
    assert commands.invoke(None, "skip_step")["skipped"] == ["DMIS program 'controls.dms'"]
    # paused before the point's MEAS: nothing is probed while it holds; Resume measures the point
    assert paused.wait(600), progress
    assert progress[-1].startswith(f"paused before line {LINE['pause before the point'] + 1}: MEAS/POINT"), progress
    assert at_pause[-1] == len(model.hits) == at_pause[0]  # the skipped edge took no hit
    assert commands.invoke(None, "resume")["resumed"] == ["DMIS program 'controls.dms'"]
    thread.join(600)
    assert not thread.is_alive()
    # the answer to the last question cancelled it: the run stopped before the next statement, its output kept
    (exc,) = outcome
    assert isinstance(exc, DmisError), exc
    assert str(exc) == (f"line {LINE['cancel here'] + 1}: the program was cancelled by the operator before this "
                        "statement")
    result = exc.result
    assert set(result.actuals) == {"PT"} and result.hits == 1
    out = result.outputs[None]
    assert "$$ F(EDGE) skipped by the operator before its first hit (line 11): not measured" in out
    assert "$$ FA(EDGE): skipped by the operator (line 11, before its first hit), not measured" in out
    assert "$$ TA(STR): not evaluated: FA(EDGE) was skipped by the operator" in out
    assert "FA(PT) = FEAT/POINT" in out and out.rstrip().endswith("ENDFIL")
    assert any(line.endswith("paused by the operator") for line in result.log), result.log


def test_skip_step_in_the_middle_of_a_measurement_leaves_the_rest_of_its_hits_and_a_later_use_stops_in_words(station):
    """Skip asked while a MEAS block is under way: its remaining hits are not taken, the feature is not fitted,
    and a statement that needs it (here a DATDEF) stops the run naming the skip."""
    register_verbs(station.controller.commands)
    commands = station.controller.commands
    text = PROGRAM.replace("TEXT/MAN, 'skip the edge'\n", "").replace(
        "  PTMEAS/CART, 60, 0, 20, 0, -1, 0\n", "  PTMEAS/CART, 60, 0, 20, 0, -1, 0\n  TEXT/MAN, 'skip now'\n").replace(
        "T(STR) = TOL/STRGHT, 0.01\n", "DATDEF/FA(EDGE), DAT(A)\n")

    def query(prompt: str, _answer: bool) -> str:
        if prompt.endswith("skip now"):
            commands.invoke(None, "skip_step")
        return ""

    with pytest.raises(DmisError) as caught:
        commands.invoke(None, "run_dmis", text=text, name="skip.dms", query=query)
    assert str(caught.value).endswith("FA(EDGE) was skipped by the operator (line 10, after 2 hits): this statement "
                                      "needs it"), caught.value
    result = caught.value.result
    assert result.hits == 3 and set(result.actuals) == {"PT"}  # two of the edge's hits, then the point's
    assert "$$ F(EDGE) skipped by the operator after 2 hits (line 10): not measured" in result.outputs[None]

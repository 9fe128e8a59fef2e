"""The part programs' one runner (cmm/program/runner.py) through the command API on the simulator (virtual clock),
for both formats: a routine and a DMIS program are paused, resumed, skipped and cancelled with the ``pause``,
``resume``, ``skip_step`` and ``cancel`` verbs, and their progress (hits taken of hits planned, what the run does
now) is read with the ``job`` query while they run.

Each control is sent at a known point of the run: the routine's progress callback (in the run's thread) sends it
after a given hit; the DMIS program asks the operator (TEXT/MAN) just before it and the answer sends it."""

from __future__ import annotations

import threading

import pytest

import session_support as sup
from cmm.dmis.executor import DmisError
from cmm.dmis.runner import register_verbs
from cmm.measurement.routine import Routine
from cmm.measurement.routine_run import RoutineCancelled
from cmm.program.runner import StepRunner
from cmm.sim.cmm_sim import TRUE_PART_POSE

# three datum planes of the block (part mm): hits on the top, the front and the left face, approach into them
@pytest.fixture
def station(tmp_path):
    yield from sup.sim_station(tmp_path, "runner controls")


def _routine(model) -> Routine:
    return sup.planes_routine(model.part, "planes")


def _the(jobs: list[dict], description: str) -> dict:
    (job,) = [j for j in jobs if j["description"] == description]
    return job


def test_a_routine_run_is_paused_resumed_skipped_and_cancelled_through_the_api(station):
    api, model = station.controller.commands, station.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's set-up")
    sent: dict[str, object] = {}
    paused = threading.Event()
    go_on = threading.Event()

    def send(verb: str) -> None:  # the run's progress is told again while the verb acts: send each verb once
        sent[verb] = None
        sent[verb] = api.invoke(None, verb)

    def on_progress(p):
        if p.state == "paused":
            paused.set()
        elif p.hits == 1 and "pause" not in sent:  # after the first hit
            send("pause")
        elif p.step == 1 and p.hits == 4 and "skip_step" not in sent:  # FRONT's first hit taken: skip the rest
            sent["job at skip"] = api.invoke(None, "job")
            send("skip_step")
        elif p.step == 2 and p.hits == 5 and "cancel" not in sent:  # LEFT's first hit: cancel the run
            send("cancel")

    run = api.invoke(None, "new_routine_run", routine=_routine(model), part_name="P1", on_progress=on_progress)
    assert run.progress.state == "ready" and (run.progress.steps, run.progress.total_hits) == (3, 9)
    outcome: list[object] = []

    def work():
        try:
            outcome.append(api.invoke(None, "run_routine", run=run))
        except Exception as exc:  # noqa: BLE001 - the test reads it
            outcome.append(exc)
        go_on.set()

    thread = threading.Thread(target=work, name="routine run")
    thread.start()
    assert paused.wait(600)
    # held between hits: the job query says so, with the hits taken of the hits planned (beside the routine, the
    # job that measures its feature)
    job = _the(api.invoke(None, "job"), "routine 'planes'")
    assert job == {"description": "routine 'planes'", "done": 1, "total": 9,
                   "step": "paused after the hit in progress: Resume to go on"}
    assert run.progress.hits == 1 and len(model.hits) == 1
    assert api.invoke(None, "resume")["resumed"] == ["routine 'planes'"]
    thread.join(600)
    assert not thread.is_alive()
    (exc,) = outcome
    assert isinstance(exc, RoutineCancelled), exc
    assert sent["pause"]["paused"] == ["routine 'planes'"] and sent["skip_step"]["skipped"] == ["routine 'planes'"]
    assert _the(sent["job at skip"], "routine 'planes'") == {"description": "routine 'planes'", "done": 4, "total": 9,
                                                            "step": run.routine.describe(1)}
    assert sent["cancel"]["cancelled"] == ["routine 'planes'", "routine 'planes': measure LEFT"]
    p = run.progress
    assert (p.state, p.step, p.hits, p.total_hits) == ("cancelled", 2, 5, 9)
    assert set(p.results) == {"TOP"}  # FRONT skipped after one hit, LEFT cancelled after one
    assert api.invoke(None, "job") == [] and not run.can_resume


PROGRAM = """FILNAM/'runner'
UNITS/MM, ANGDEC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
S(P) = SNSDEF/PROBE, FIXED, POL, 0, 0, 2.0
SNSLCT/S(P)
SNSET/APPRCH, 5
SNSET/RETRCT, 5
GOTO/70, 22, 70
F(PT) = FEAT/POINT, CART, 70, 22, 55, 0, 0, 1
MEAS/POINT, F(PT), 1
  PTMEAS/CART, 70, 22, 55, 0, 0, 1
ENDMES
TEXT/MAN, 'pause'
GOTO/70, 22, 70
GOTO/100, -15, 70
GOTO/60, -15, 20
F(EDGE) = FEAT/LINE, UNBND, CART, 20, 0, 20, 1, 0, 0, 0, -1, 0
TEXT/MAN, 'skip'
MEAS/LINE, F(EDGE), 3
  PTMEAS/CART, 20, 0, 20, 0, -1, 0
  PTMEAS/CART, 60, 0, 20, 0, -1, 0
  PTMEAS/CART, 100, 0, 20, 0, -1, 0
ENDMES
GOTO/60, -15, 70
GOTO/70, 22, 70
F(PT2) = FEAT/POINT, CART, 70, 22, 55, 0, 0, 1
MEAS/POINT, F(PT2), 1
  PTMEAS/CART, 70, 22, 55, 0, 0, 1
ENDMES
TEXT/MAN, 'cancel'
GOTO/70, 22, 70
ENDFIL
"""
LINE = {text.split("'")[1]: n + 1 for n, text in enumerate(PROGRAM.splitlines()) if text.startswith("TEXT/MAN")}


def test_a_dmis_run_is_paused_resumed_skipped_and_cancelled_through_the_api(station):
    api = station.controller.commands
    register_verbs(api)
    description = "DMIS program 'runner.dms'"
    paused = threading.Event()
    jobs: dict[str, object] = {}
    fractions: list[float] = []

    def on_progress(fraction: float, message: str) -> None:
        fractions.append(fraction)
        if message.startswith("paused"):
            paused.set()

    def query(prompt: str, _answer: bool) -> str:
        what = prompt.split(": ", 1)[1]
        jobs[what] = api.invoke(None, "job")
        api.invoke(None, {"pause": "pause", "skip": "skip_step", "cancel": "cancel"}[what])
        return ""

    outcome: list[object] = []

    def work():
        try:
            outcome.append(api.invoke(None, "run_dmis", text=PROGRAM, name="runner.dms", query=query,
                                      progress=on_progress))
        except DmisError as exc:
            outcome.append(exc)

    thread = threading.Thread(target=work, name="dmis run")
    thread.start()
    assert paused.wait(600)
    # held before the next statement: the job query gives the hits taken and where it holds (a DMIS run cannot
    # say how many hits it takes before it runs: total 0)
    (job,) = api.invoke(None, "job")
    assert job == {"description": description, "done": 1, "total": 0,
                   "step": f"paused before line {LINE['pause'] + 1}: GOTO; Resume to go on"}
    assert api.invoke(None, "resume")["resumed"] == [description]
    thread.join(600)
    assert not thread.is_alive()
    (exc,) = outcome
    assert isinstance(exc, DmisError), exc
    assert str(exc) == f"line {LINE['cancel'] + 1}: the program was cancelled by the operator before this statement"
    assert exc.result.hits == 2 and set(exc.result.actuals) == {"PT", "PT2"}  # the edge skipped before its hits
    assert [j[0]["done"] for j in (jobs["pause"], jobs["skip"], jobs["cancel"])] == [1, 1, 2]
    assert fractions == sorted(fractions) and 0.0 < fractions[-1] < 1.0
    assert api.invoke(None, "job") == []


def test_the_runners_controls_and_progress_without_a_machine():
    """The runner alone: pause holds at the next checkpoint, resume and skip let it go on, cancel ends every wait;
    a fault leaves the step for resume; the fraction is by hits when they are planned, else by steps."""
    told = []
    r = StepRunner(steps=4, total_hits=8, on_progress=lambda p: told.append((p.state, p.message)))
    assert r.progress.fraction == 0.0 and r.hold() is True
    r.pause()
    assert r.paused and told[-1] == ("paused", "paused after the hit in progress: Resume to go on")
    assert r.resume() is True and not r.paused and told[-1] == ("running", "resumed")
    assert r.resume() is False  # not paused
    r.skip()
    assert r.take_skip() is True and r.take_skip() is False
    done = []
    r.run_steps(0, lambda i: (done.append(i), r.hit_taken(2)), skipped=lambda i: i == 2, describe=lambda i: f"s{i}")
    assert done == [0, 1, 3] and r.progress.hits == 6 and r.progress.fraction == 6 / 8
    with pytest.raises(RuntimeError):
        r.run_steps(1, lambda i: (_ for _ in ()).throw(RuntimeError("contact")))
    assert r.fail("step 2 stopped: contact") == 1 and r.can_resume
    assert r.cancel() is True and told[-1][0] == "cancelled" and not r.can_resume and r.hold() is False
    quiet = StepRunner(steps=10, pause_text=None, resume_text=None)
    quiet.update(step=5)
    assert quiet.progress.fraction == 0.5
    quiet.pause()
    assert quiet.progress.state == "ready" and quiet.resume() is True

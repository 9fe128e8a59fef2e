"""STOP and E-STOP end the whole run, not only its current move: homing, a probe qualification, a DMIS program.

A run is many moves; a STOP that only cut the current move short let the run go on with its next one (a DMIS program's
next PTMEAS, a routine's next hit, a run's climb to the clearance plane), motion the operator did not ask for. Here the
real station runs its threaded machine loop on the simulator's virtual clock; the press is made as the page and the
pendant make it (the command API's stop / estop verb) from another thread while the run moves. Asserted on the
simulator's machine clock and its own probe triggers: once the axes stand after the press, nothing moves again for
2 s of machine time, no further hit is taken, the run ends with an error that names the stop, and the station says
STOPPED (E-STOPPED) with every axis standing.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import session_support as sup

from cmm.control import Mode
from cmm.dmis.runner import run_text
from dmis_programs import APPROACH, FRONT_FACE, program

pytestmark = pytest.mark.timeout(600)

# three hits on each of two faces: long enough to be stopped between its hits
PROGRAM = program("faces", APPROACH, "GOTO/60, -30, 60\nGOTO/20, -15, 20\n", FRONT_FACE, "GOTO/60, -30, 60\n",
                  FRONT_FACE.replace("FRONT", "FRONT2").replace("20, 0, 20", "30, 0, 20")
                  .replace("60, 0, 30", "60, 0, 25").replace("100, 0, 20", "90, 0, 20"))
QUIET_S = 2.0  # machine seconds after the standstill in which nothing may move


@pytest.fixture(scope="module")
def station(module_stations):
    st = module_stations.station(qualified=True)
    st.measurement.new_session("stops")
    return st


class Watch:
    """Every sample the machine loop takes (machine time, position, largest axis speed), from the press on."""

    def __init__(self, station) -> None:
        self.samples: list[tuple[float, np.ndarray, float]] = []
        self.on = False
        self.unsubscribe = station.machine.subscribe(self)

    def __call__(self, state) -> None:
        if self.on:
            self.samples.append((float(state.time), np.array(state.position, float),
                                 max(abs(a.velocity) for a in state.axes)))

    def moved_after_standstill(self) -> float:
        """The largest distance (mm) the tip moved after the first sample in which every axis stood still."""
        still = next((i for i, (_, _, v) in enumerate(self.samples) if v < 1e-9), None)
        assert still is not None, "the axes never stood still after the press"
        here = self.samples[still][1]
        return max(float(np.linalg.norm(p - here)) for _, p, _ in self.samples[still:])


def _ready(station) -> None:
    ctl = station.controller
    if ctl.state.mode is not Mode.IDLE:
        ctl.commands.invoke(None, "reset")
    end = time.monotonic() + 60
    while ctl.state.mode is not Mode.IDLE and time.monotonic() < end:
        time.sleep(0.01)
    assert ctl.state.mode is Mode.IDLE, ctl.state
    _off_the_sphere(station)


def _off_the_sphere(station) -> None:
    """A qualification's stop leaves the probe beside the reference sphere, often over its upper half, where a
    climb to the clearance plane (the next run's first move) would hit the sphere from below: the operator moves
    it clear first, out from the sphere's centre, then sideways, then up."""
    ctl = station.controller
    centre = np.array(station.sim.settings.sphere_centre, float)
    here = np.array(ctl.state.machine.position, float)
    away = here - centre
    if not ctl.state.homed or np.linalg.norm(away) > 60.0:
        return
    out = centre + away / max(np.linalg.norm(away), 1e-9) * 40.0  # radially out: never nearer the sphere
    side = out.copy()
    flat = np.linalg.norm(away[:2])
    side[:2] = centre[:2] + (away[:2] / flat if flat > 1e-6 else np.array([1.0, 0.0])) * 40.0
    for target in (out, side, [side[0], side[1], centre[2] + 60.0]):
        ctl.commands.invoke(None, "move", target=[float(v) for v in target], frame="machine").wait(120)


def _stop_during(station, run, when, verb: str):
    """``run()`` on a thread; ``verb`` pressed (the command API, as the page's and the pendant's press) once
    ``when()`` holds while the machine moves. Returns (the run's error, the stop's report, the watch, hits taken
    after the press). Waits on the machine clock for QUIET_S after the answer."""
    ctl = station.controller
    outcome: dict[str, object] = {}

    def go() -> None:
        try:
            outcome["result"] = run()
        except Exception as exc:  # noqa: BLE001 - the run's end, asserted by the caller
            outcome["error"] = exc
    thread = threading.Thread(target=go, daemon=True)
    watch = Watch(station)
    try:
        thread.start()
        end = time.monotonic() + 300
        while not (when() and ctl.state.machine is not None and
                   max(abs(a.velocity) for a in ctl.state.machine.axes) > 1.0):
            assert thread.is_alive(), f"the run ended before the press: {outcome}"
            assert time.monotonic() < end, "the run never reached the moment of the press"
            time.sleep(0.002)
        watch.on = True
        triggers = station.sim.triggers
        report = ctl.commands.invoke(None, verb)
        thread.join(120)
        assert not thread.is_alive(), "the run did not end after the stop"
        answered = ctl.clock.now()
        while ctl.clock.now() < answered + QUIET_S:  # machine time: does anything move on its own?
            time.sleep(0.005)
            assert thread.is_alive() is False
        return outcome.get("error"), report, watch, station.sim.triggers - triggers
    finally:
        watch.unsubscribe()


def _assert_ended(station, error, report, watch, hits_after, verb: str) -> None:
    word = "STOP" if verb == "stop" else "E-STOP"
    assert report["ok"] and "stands still" in report["message"], report
    assert error is not None, "the run went on to its end after the stop"
    text = str(error)
    assert ("stopped by the operator" in text or word in text or "emergency stop" in text), text
    assert watch.moved_after_standstill() < 0.01, "the machine moved again after it stood still"
    assert hits_after <= 1, f"{hits_after} hits were taken after the press"  # at most the touch being made
    st = station.controller.state
    assert st.mode is (Mode.STOPPED if verb == "stop" else Mode.ESTOPPED), st
    assert max(abs(a.velocity) for a in st.machine.axes) < 1e-9


@pytest.mark.parametrize("verb", ["stop", "estop"])
def test_a_stop_ends_a_dmis_run(station, verb):
    _ready(station)
    # where the program starts (its first GOTO, part coordinates), over the clearance plane from wherever a stop left it
    station.controller.commands.invoke(None, "move", target=[60.0, -30.0, 60.0], frame="part").wait(120)
    first = station.sim.triggers
    error, report, watch, after = _stop_during(
        station, lambda: run_text(PROGRAM, station.controller.commands, name=f"{verb}.dmi"), lambda: station.sim.triggers >= first + 1, verb)
    _assert_ended(station, error, report, watch, after, verb)
    assert station.sim.triggers - first <= 2  # the program had six hits: it did not go on to the others
    assert "DMIS program" in str(error), error  # the run says that it ended, not only the move


@pytest.mark.parametrize("verb", ["stop", "estop"])
def test_a_stop_ends_the_homing_cycle(station, verb):
    _ready(station)
    ctl = station.controller
    error, report, watch, _ = _stop_during(station, lambda: ctl.home(None),
                                           lambda: ctl.state.mode is Mode.HOMING, verb)
    _assert_ended(station, error, report, watch, 0, verb)
    assert not ctl.state.homed
    ctl.commands.invoke(None, "reset")
    ctl.home(None)  # the next test needs a homed machine
    assert ctl.state.homed


@pytest.mark.parametrize("verb", ["stop", "estop"])
def test_a_stop_ends_a_probe_qualification(station, verb):
    _ready(station)
    first = station.sim.triggers

    def qualify():
        return station.controller.commands.invoke(None, "qualify", routine="probe",
                                                  options={"per_ring": 4, "repeats": 1})
    # pressed while it measures the pattern's points (after the five hits that locate the sphere): a point whose
    # hit failed used to be skipped, and the qualification went on with the next point after a STOP
    error, report, watch, after = _stop_during(station, qualify, lambda: station.sim.triggers >= first + 7, verb)
    _assert_ended(station, error, report, watch, after, verb)
    assert not station.calibration.holding


def test_a_run_that_meets_the_e_stop_before_the_modules_do_says_the_operator_ended_it(station, monkeypatch):
    """The E-STOP latch and the run's end are one step: a run whose next move is refused under the latch while the
    press is still on its way to the modules (a slow link, a busy computer) ends in the stop's words, never as a
    plain refusal ("cannot move: the emergency stop is latched") that reads as the program's own failure."""
    _ready(station)
    ctl = station.controller
    met = threading.Event()
    halt = ctl._halt_now

    def slow_halt(verb):  # the press reaches the modules only once the run has met the latch
        met.wait(60)
        return halt(verb)
    monkeypatch.setattr(ctl, "_halt_now", slow_halt)
    started = threading.Event()

    def work(job):
        here = np.array(ctl.state.machine.position, float)
        for i in range(10_000):
            started.set()
            try:
                ctl.commands.invoke(None, "move", target=[float(here[0] + (i % 2)), float(here[1]), float(here[2])],
                                    frame="machine").wait(60)
            except Exception:
                met.set()
                raise
        raise AssertionError("the run never met the E-STOP")
    outcome = {}

    def go():
        try:
            ctl.commands.invoke(None, "run_job", description="the latch test", work=work)
        except Exception as exc:  # noqa: BLE001 - asserted below
            outcome["error"] = exc
    thread = threading.Thread(target=go, daemon=True)
    thread.start()
    assert started.wait(60)
    report = ctl.commands.invoke(None, "estop")
    thread.join(60)
    assert not thread.is_alive() and met.is_set()
    assert report["ok"], report
    assert "the latch test ended by the operator's E-STOP" in str(outcome.get("error")), outcome
    assert ctl.state.mode is Mode.ESTOPPED


def test_after_a_stop_ends_an_auto_measure_the_next_move_goes(station):
    """An auto-measure is a run the stop ends like the others, but it takes no mark of the stop itself: once it
    has ended, the stop's "the run ends" inhibit must go with it (it stayed, and the next Go to failed with
    "motion inhibited ... the run ends" until Reset while the status bar said STOPPED)."""
    from cmm.measurement.plan import plan_at_pick

    _ready(station)
    ctl, model = station.controller, station.measurement
    name, origin, direction = sup.BLOCK_FACES[0]
    pose = model.part.pose
    picked = model.pick((pose @ np.array([*origin, 1.0]))[:3], pose[:3, :3] @ np.array(direction, float))
    plan = plan_at_pick(model, picked[0].face_id)
    first = station.sim.triggers
    error, report, watch, after = _stop_during(
        station, lambda: ctl.commands.invoke(None, "auto_measure", plan=plan, name="stopped " + name),
        lambda: station.sim.triggers >= first + 2, "stop")
    # the press asks the auto-measure to cancel too; whichever way it ends, it says the operator's STOP ended it
    assert report["ok"] and error is not None, (report, error)
    assert f"auto-measure of stopped {name} ended by the operator's STOP" in str(error), error
    assert after <= 1
    assert station.machine.inhibit is None
    here = ctl.state.machine.position
    status = ctl.commands.invoke(None, "move", target=[float(here[0]), float(here[1]), float(here[2]) + 5.0],
                                 frame="machine")
    assert np.asarray(status.wait(120))[2] == pytest.approx(here[2] + 5.0, abs=0.01)

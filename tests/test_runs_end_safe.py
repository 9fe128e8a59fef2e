"""Runs end safe: every DMIS run and auto-measure ends at the clearance plane, so the next run can start;
a refused or stopped run is a toast and a STOPPED status-bar state, not only a line in its folder.

On the in-process simulator (virtual clock), through the command API and the page's Routine and Auto-measure panels
(a PanelContext stands in for the tab).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import session_support as sup

from cmm.control import OpenPolicy
from cmm.control.access import Client, Control
from cmm.dmis.runner import register_verbs, run_text
from cmm.sim.cmm_sim import TRUE_PART_POSE
from dmis_programs import APPROACH, FRONT_FACE, program

# three hits on the front face: the last one leaves the tip 5 mm in front of it, below the part's top
FRONT = program("front", APPROACH, "GOTO/60, -30, 60\nGOTO/20, -15, 20\n", FRONT_FACE)
# straight to a point over the middle of the part: through its front edge from where FRONT's last hit left the tip
GOTO_OVER = program("over", "GOTO/60, 40, 70\n")


@pytest.fixture
def station(tmp_path):
    yield from sup.sim_station(tmp_path, "ends")


def _plane(station) -> float:
    return float(station.controller.workspace.clearance_z())


def test_a_dmis_run_ends_at_the_clearance_plane_and_the_next_program_can_start(station):
    """a run left the tip beside the part and the next program's first straight GOTO was refused ("the
    straight line passes 0.29 mm from the part"). The front-face program's last hit leaves the tip 5 mm in front
    of the face, below the part's top: the run now climbs to the clearance plane, and a program that goes
    straight over the part runs."""
    run_text(FRONT, station.controller.commands, name="front.dmi")
    z = station.controller.frame_position("machine")[2]
    assert z == pytest.approx(_plane(station), abs=0.01), (z, _plane(station))
    result = run_text(GOTO_OVER, station.controller.commands, name="over.dmi")  # refused on the old code: through the front edge
    assert "ENDFIL" in result.outputs[None]
    here = station.controller.frame_position("machine")
    assert here[2] >= _plane(station) - 0.01, here


def test_an_auto_measure_ends_at_the_clearance_plane(station):
    """The bore's last hit leaves the tip down in the bore: the auto-measure ends with it at the clearance plane."""
    from cmm.measurement.plan import plan_at_pick

    model = station.measurement
    pose = model.part.pose
    picked = model.pick((pose @ np.array([30.0, 40.0, 20.0, 1.0]))[:3], pose[:3, :3] @ np.array([1.0, 0.0, 0.0]))
    plan = plan_at_pick(model, picked[0].face_id)
    answer = station.controller.commands.call(None, "auto_measure", {"plan": plan, "name": "bore"}, wait=True)
    assert answer.ok, answer.error
    assert station.controller.frame_position("machine")[2] == pytest.approx(_plane(station), abs=0.01)


def test_a_refused_dmis_run_is_a_toast_and_a_stopped_status_bar(station):
    """Run DMIS refused as one line of text in its folder, no toast, and the status bar back to IDLE.
    The refusal is a toast (an error notification) and every tab's status bar says STOPPED with the program and
    the reason until the next run starts."""
    from cmm.ui.context import PanelContext
    from cmm.ui.panel_routine import RoutinePanel
    from cmm.ui.panel_status import status_html

    register_verbs(station.controller.commands)
    control = Control()
    assert control.take("operator", is_local=True)
    station.controller.use_policy_of(control)
    try:
        shared = SimpleNamespace(calibration_job=None, cycle=None, cycle_paused=False, run_stopped="")
        panel = RoutinePanel(PanelContext(station.controller.commands, control, None, client_id="operator", is_local=True, shared=shared))
        folder = station.measurement.session_dir
        # the tip stands 1 mm in front of the front face, below its top: a straight line to the back is refused
        start = (TRUE_PART_POSE @ np.array([60.0, -3.0, 20.0, 1.0]))[:3]
        assert station.controller.commands.call(Client("operator", local=True), "move",
                                                {"target": list(start), "frame": "machine"}, wait=True).ok
        (folder / "through.dmi").write_text(GOTO_OVER.replace("GOTO/60, 40, 70", "GOTO/60, 90, 20"))
        assert panel.open_dmis("through.dmi")
        assert panel.run_dmis(wait=True)
        assert panel.dmis_status.startswith("**STOPPED**"), panel.dmis_status
        level, title, body = panel.ctx.messages[-1]
        assert (level, title) == ("error", "DMIS program stopped") and "straight line" in body, panel.ctx.messages
        assert shared.cycle is None and "DMIS program through.dmi stopped: " in shared.run_stopped
        bar = status_html(station.controller.commands, "", run_stopped=shared.run_stopped)
        assert ">STOPPED</span>" in bar and "through.dmi stopped" in bar and ">IDLE</span>" not in bar, bar
        panel.ctx.begin_cycle("DMIS program next.dmi")  # the next run starts: the stop is no longer the news
        assert shared.run_stopped == ""
    finally:
        station.controller.policy = OpenPolicy()


def test_a_run_ended_by_stop_does_not_climb_while_the_axes_still_brake(station):
    """The climb at a run's end is left out when a STOP ended the run, also while the axes still brake (the mode is
    "moving", its activity the control core's STOPPING): nothing moves on its own after the press. A loaded run's
    page showed STOPPED and then an axis moving again."""
    import threading

    from cmm.control.modes import STOPPING
    from cmm.measurement.run_end import end_at_clearance

    api, ctl = station.controller.commands, station.controller
    start = ctl.frame_position("machine")
    low = [float(start[0]), float(start[1]), _plane(station) - 20.0]  # below the clearance plane: a climb is due
    api.invoke(None, "move", target=low, frame="machine", path="clearance").wait(120)
    # a slow move (0.5 mm/s, braking at 1 mm/s^2: 0.5 s of braking), stopped on its way
    api.invoke(None, "move", target=[low[0] + 20.0, low[1], low[2]], frame="machine", path="straight", speed=0.5,
               accel=1.0)
    t0 = ctl.clock.now()
    while ctl.clock.now() < t0 + 2.0:
        ctl.clock.sleep(0.05)
    stopper = threading.Thread(target=api.invoke, args=(None, "stop"))
    stopper.start()
    while ctl.state.activity != STOPPING:  # braking (bounded by the test's timeout)
        assert stopper.is_alive(), f"the stop answered before its braking was seen: {ctl.state}"
        ctl.clock.sleep(0.002)
    assert end_at_clearance(api, None) is None  # on the old code: a climb, refused "busy (stopping)" or made after
    stopper.join(60)
    z = ctl.frame_position("machine")[2]
    assert z == pytest.approx(low[2], abs=0.01), z  # it stands where it braked, below the plane

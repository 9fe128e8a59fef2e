"""Every coordinate field says its frame: the Go to target, the DRO, the pick, the probe's last trigger, the
auto-measure hits and the feature detail name machine or part coordinates (and the alignment part coordinates
go through). And the Plan button's path preview, which Run clears."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("viser")

from cmm.sim.cmm_sim import TRUE_PART_POSE  # noqa: E402
from cmm.ui.panel_status import status_html  # noqa: E402


@pytest.fixture(scope="module")
def app(module_stations):
    return module_stations.app(module_stations.station("frames"), pendant=False, ask_name=False)


def test_coordinate_fields_name_their_frame_and_the_alignment(app):
    st = app.station
    capp = app.add_client(client_id="frames", is_local=True)
    assert capp.take_control()
    assert capp.target_label() == "Target, machine (mm)"
    capp.status.set_frame("Part")  # the DRO's frame is the Go to fields' default
    assert capp.goto_frame == "Part" and capp.target_label().startswith("Target, part")
    capp.status.set_frame("Machine")
    assert capp.goto_frame == "Machine" and capp.target_label() == "Target, machine (mm)"
    capp.set_goto_frame("Part")
    assert capp.target_label() == "Target, part (nominal set-up, no alignment made) (mm)"
    assert "nominal set-up, no alignment made" in status_html(st.controller.commands, "", frame="Part")
    assert "nominal set-up" not in status_html(st.controller.commands, "", frame="Machine")
    st.measurement.set_alignment(TRUE_PART_POSE, "3-2-1", names=["TOP", "FRONT", "LEFT"])
    assert capp.target_label() == "Target, part (alignment 3-2-1 TOP/FRONT/LEFT) (mm)"
    assert "alignment 3-2-1 TOP/FRONT/LEFT" in status_html(st.controller.commands, "", frame="Part")
    assert "alignment 3-2-1 TOP/FRONT/LEFT" in capp.goto_frame_text()
    capp.set_goto_frame("Machine")
    # a pick and the auto-measure plan: machine coordinates, said so
    pose = st.measurement.part.pose
    top = (pose @ np.array([20.0, 10.0, 100.0, 1.0]))[:3]
    assert capp.pick(top, pose[:3, :3] @ np.array([0.0, 0.0, -1.0])) is not None
    assert "Z={:.3f} (machine)".format(capp.ctx.picked[0].point[2]) in capp.messages[-1][2]
    plan = capp.measure.make_plan(3)
    assert plan is not None, capp.messages[-2:]
    text = capp.measure.text()
    assert "(machine)" in text and "Hits (machine coordinates, mm):" in text
    # Plan previews the path the control core will run, from where the tip is; Run clears it
    cycles = capp.measure.preview.cycles
    assert len(cycles) == len(plan) and np.allclose(cycles[0].start, st.machine.state.position)
    assert "Path preview: 3 hits" in text
    assert capp.measure.run("TOP", wait=True), capp.messages[-2:]
    assert capp.measure.preview.cycles == [] and "Path preview" not in capp.measure.text()
    capp.select_feature(capp.measure.feature.id)
    # the actuals are in the alignment's frame, named; machine coordinates on demand
    text = capp.features.feature_markdown()
    assert "actual in part coordinates (3-2-1 TOP/FRONT/LEFT)" in text and "geometry (machine" not in text
    capp.features.machine = True
    text = capp.features.feature_markdown()
    assert "actual in machine coordinates" in text and "geometry (machine coordinates, mm):" in text
    capp.features.machine = False


def test_a_preview_the_rails_refuse_says_why(app):
    capp = app.add_client(client_id="frames-2", is_local=True)
    z_max = app.station.config.axis("z").max
    assert capp.measure.preview.show([((100.0, 100.0, z_max + 50.0), (0.0, 0.0, -1.0), None)]) is None
    level, title, body = capp.messages[-1]
    assert level == "error" and "outside the travel" in body and capp.measure.preview.cycles == []


def test_the_routine_tabs_preview_is_the_routines_hits_and_run_clears_it(app):
    capp = app.add_client(client_id="frames-3", is_local=True)
    assert capp.take_control()
    if not app.station.measurement.features:  # the first test measured the top face; alone, measure it here
        pose = app.station.measurement.part.pose
        capp.pick((pose @ np.array([20.0, 10.0, 100.0, 1.0]))[:3], pose[:3, :3] @ np.array([0.0, 0.0, -1.0]))
        assert capp.measure.make_plan(3) is not None and capp.measure.run("TOP", wait=True)
    routine = capp.routine.teach("preview")
    assert routine is not None, capp.messages[-2:]
    cycles = capp.routine.preview_path()
    targets = routine.targets(app.station.measurement.part.pose)
    assert cycles is not None and len(cycles) == len(targets) > 0
    assert all(np.allclose(c.contact, p - app.station.prober.settings.tip_radius * u / np.linalg.norm(u))
               for c, (_n, p, u, _cz) in zip(cycles, targets))
    assert capp.routine.start("p2")
    assert capp.routine.preview.cycles == []  # Run clears the preview
    # the whole run is RUNNING in every tab's status bar, also between its steps (set before its first move)
    assert app.shared.cycle == "routine preview on p2" and ">RUNNING</span>" in capp.status.html()
    capp.routine.thread.join(300)
    assert capp.routine.run_.progress.state == "done", capp.routine.progress_text()
    assert app.shared.cycle is None and ">RUNNING</span>" not in capp.status.html()
    # a step that stopped: Reset is asked for only when the machine needs it (not after a skipped datum)
    run, ctl = capp.routine.run_, app.station.controller
    assert capp.routine._recovery(run).startswith("Then Resume from step")
    ctl.fault("a test fault")
    try:
        for _ in range(200):  # the loop publishes the fault with its next sample
            if ctl.state.mode.value == "fault":
                break
            time.sleep(0.05)
        assert capp.routine._recovery(run).startswith("Clear the cause, press Reset, then Resume from step")
    finally:
        ctl.reset(None)

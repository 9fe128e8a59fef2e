"""The path preview is the path the machine runs: an auto-measure plan and a routine, previewed through the
control core (``Controller.probe_paths``, the rails and the prober's cycle), then run on the simulator (virtual
clock) while every servo tick's axis positions are recorded. Every corner of the preview is passed, and the tip
never leaves the previewed polyline."""

from __future__ import annotations

import numpy as np
import pytest
from netutil import SIM

from cmm.control import Refused
from cmm.measurement.plan import plan_at_pick, plan_targets, run_plan
from cmm.measurement.routine import RoutineRun, teach_routine
from cmm.session.store import open_session
from cmm.sim.cmm_sim import TRUE_PART_POSE
from cmm.station import Station

CORNER = 0.05  # mm: a previewed corner (rapid corner, pre-hit point, retract point) is passed this close
CONTACT = 0.1  # mm: the trigger is where the nominal surface is, within the pre-travel and the stop
OFF_PATH = 0.1  # mm: the recorded tip never strays further from the previewed polyline


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    st = Station(port=SIM, session_dir=tmp_path_factory.mktemp("preview")).start("preview", home=True)
    st.measurement.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    yield st
    st.close()


def _pick(model, origin, direction):
    pose = model.part.pose
    return model.pick((pose @ np.array([*origin, 1.0]))[:3], pose[:3, :3] @ np.array(direction, float))[0]


class Recorder:
    """The simulated axes' positions at every servo tick while installed."""

    def __init__(self, station):
        self.station, self.points = station, []

    def __enter__(self):
        self.station.sim.network.add_tick_hook(lambda net, tick: self.points.append(self.station.sim.axis_readings()))
        return self

    def __exit__(self, *exc):
        self.station.sim.network.tick_hooks.pop()


def _segment_distance(points, a, b):
    ab = b - a
    t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)


def assert_runs_as_previewed(cycles, recorded):
    pts = np.asarray(recorded, float)
    assert len(pts) > 100
    line = np.concatenate([cycles[0].polyline()[:1]] + [c.polyline()[1:] for c in cycles])
    # every corner is passed, in order (the contact within the pre-travel and the stop)
    at = 0
    for c in cycles:
        for point, tol in [(q, CORNER) for q in c.rapid] + [(c.contact, CONTACT), (c.retract, CORNER + CONTACT)]:
            d = np.linalg.norm(pts[at:] - point, axis=1)
            near = np.flatnonzero(d < tol)  # the first passage (a later cycle may cross the same point)
            assert len(near), f"the tip never came within {tol} mm of {point} (closest {d.min():.4f} mm)"
            k = int(near[0])
            at += k
    # and never leaves the previewed polyline
    off = np.min(np.stack([_segment_distance(pts, a, b) for a, b in zip(line[:-1], line[1:])]), axis=0)
    assert off.max() < OFF_PATH, f"the tip left the previewed path by {off.max():.4f} mm at {pts[int(off.argmax())]}"


def test_an_auto_measure_plan_runs_the_previewed_path(station):
    model, ctl = station.measurement, station.controller
    plan = plan_at_pick(model, _pick(model, (30.0, 40.0, 20.0), (1, 0, 0)).face_id, n=4)  # the bore
    cycles = ctl.probe_paths(plan_targets(plan))
    assert len(cycles) == len(plan) >= 4
    assert all(max(q[2] for q in c.rapid) >= plan.clearance_z - 1e-9 for c in cycles)  # over the clearance plane
    with Recorder(station) as rec:
        run_plan(model, plan, name="bore")
    assert_runs_as_previewed(cycles, rec.points)


def test_a_routine_runs_the_previewed_path(station):
    model, ctl = station.measurement, station.controller
    model.new_session("taught")  # the routine is taught from this session: the top face and the boss
    for name, origin, direction in (("TOP", (20.0, 10.0, 100.0), (0, 0, -1)), ("boss", (70.0, -20.0, 47.0), (0, 1, 0))):
        run_plan(model, plan_at_pick(model, _pick(model, origin, direction).face_id, n=3), name=name)
    routine = teach_routine(open_session(model.journal.path), name="preview", part_mesh=model.part.mesh,
                            part_nominals=model.part.nominal_features)
    assert "align" not in [s["kind"] for s in routine.steps]  # no 3-2-1 made: nothing moves the part mid-run
    targets = routine.targets(model.part.pose)
    assert [t[0] for t in targets] == [n for n in routine.measured_features()
                                       for _ in routine.program.feature(n).hits]
    cycles = ctl.probe_paths([t[1:] for t in targets])
    with Recorder(station) as rec:
        progress = RoutineRun(routine, model, ctl, part_name="p2").run()
    assert progress.state == "done" and progress.hits == len(cycles)
    assert_runs_as_previewed(cycles, rec.points)


def test_a_preview_refuses_a_hit_outside_the_travel_in_words(station):
    z_max = station.config.axis("z").max
    with pytest.raises(Refused, match=r"hit 1: .*outside the travel"):
        station.controller.probe_paths([((100.0, 100.0, z_max + 50.0), (0.0, 0.0, -1.0), None)])

"""The path preview is the path the machine runs: an auto-measure plan and a routine, previewed through the
control core (``Controller.probe_paths``, the rails and the prober's cycle), then run on the simulator (virtual
clock) while every servo tick's axis positions are recorded. Every corner of the preview is passed, and the tip
never leaves the previewed polyline. A routine's preview includes its alignment (the datums measured after the
operator's hand hits, from over the first automatic hit) and, for the resume of a run an unexpected contact
stopped, the back-off and the retract to the clearance height before the stopped step."""

from __future__ import annotations

import numpy as np
import pytest

from cmm.control import Refused
from cmm.measurement.plan import plan_at_pick, plan_targets, run_plan
from cmm.measurement.alignment import align_features, apply
from cmm.measurement.routine import teach_routine
from cmm.measurement.routine_path import routine_path
from cmm.measurement.routine_host import StationRoutineHost
from cmm.measurement.routine_run import RoutineRun
from cmm.program.toml_program import machine_targets
from cmm.journal.store import open_session
from cmm.sim.cmm_sim import TRUE_PART_POSE

CORNER = 0.05  # mm: a previewed corner (rapid corner, pre-hit point, retract point) is passed this close
CONTACT = 0.1  # mm: the trigger is where the nominal surface is, within the pre-travel and the stop
OFF_PATH = 0.1  # mm: the recorded tip never strays further from the previewed polyline


@pytest.fixture(scope="module")
def station(module_stations):
    st = module_stations.station("preview")
    st.measurement.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    return st


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


def assert_runs_as_previewed(cycles, recorded, tail=()):
    """``tail``: the preview's end after the last cycle (a routine's climb to the clearance plane)."""
    pts = np.asarray(recorded, float)
    assert len(pts) > 100
    line = np.concatenate([cycles[0].polyline()[:1]] + [c.polyline()[1:] for c in cycles]
                          + ([np.asarray(tail[1:], float)] if len(tail) else []))
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
    assert max(q[2] for q in cycles[0].rapid) >= plan.clearance_z - 1e-9  # the first hit over the clearance plane
    # the others straight inside the bore, below its rim: the rails prove those lines free of the part
    assert plan.hop_z < plan.clearance_z and all(len(c.rapid) == 1 for c in cycles[1:])
    assert all(np.linalg.norm(c.rapid[0][:2] - plan.nominal.params["point"][:2]) < plan.nominal.params["radius"]
               for c in cycles[1:])
    with Recorder(station) as rec:
        run_plan(model, plan, name="bore")
    assert_runs_as_previewed(cycles, rec.points)


def test_a_preview_refuses_a_hit_outside_the_travel_in_words(station):
    z_max = station.config.axis("z").max
    with pytest.raises(Refused, match=r"hit 1: .*outside the travel"):
        station.controller.probe_paths([((100.0, 100.0, z_max + 50.0), (0.0, 0.0, -1.0), None)])


# the operator's manual 3-2-1 (part coordinates: point, approach): 3 on TOP, 2 on FRONT, 1 on LEFT
MANUAL = [((15.0, 10.0, 40.0), (0, 0, -1)), ((105.0, 12.0, 40.0), (0, 0, -1)), ((50.0, 70.0, 40.0), (0, 0, -1)),
          ((15.0, 0.0, 15.0), (0, 1, 0)), ((105.0, 0.0, 15.0), (0, 1, 0)), ((0.0, 20.0, 15.0), (1, 0, 0))]


def _from_corner(recorded, corner):
    """The recorded tip from its first passage by ``corner`` on (the path before it is the operator's hands)."""
    pts = np.asarray(recorded, float)
    near = np.flatnonzero(np.linalg.norm(pts - corner, axis=1) < CORNER)
    assert len(near), f"the tip never came within {CORNER} mm of {corner}"
    return pts[int(near[0]):]


@pytest.fixture
def fresh_station(stations):
    """A station of its own: applying an alignment carries every feature of the model into the session, and a
    routine is taught from the session's features only."""
    st = stations.station("taught-321")
    st.measurement.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    return st


def test_a_routine_runs_the_previewed_path_with_its_alignment_after_the_hand_hits(fresh_station):
    station = fresh_station
    model, ctl = station.measurement, station.controller
    # three planes, the boss and a 3-2-1 on the planes: the routine starts with the alignment
    ids = {name: run_plan(model, plan_at_pick(model, _pick(model, origin, direction).face_id, n=3), name=name).id
           for name, origin, direction in (("TOP", (20.0, 10.0, 100.0), (0, 0, -1)),
                                           ("FRONT", (20.0, -50.0, 20.0), (0, 1, 0)),
                                           ("LEFT", (-50.0, 10.0, 20.0), (1, 0, 0)),
                                           ("boss", (70.0, -20.0, 47.0), (0, 1, 0)))}
    apply(model, align_features(model, ids["TOP"], ids["FRONT"], ids["LEFT"]))
    routine = teach_routine(open_session(model.journal.path), name="aligned", part_mesh=model.part.mesh,
                            part_nominals=model.part.nominal_features)
    assert routine.steps[0]["kind"] == "align" and routine.steps[0]["manual"]
    path = routine_path(routine, ctl, model.part.pose, mesh=model.part.mesh)
    assert routine.measured_features() == ["TOP", "FRONT", "LEFT", "boss"]  # the datums first, where they stand
    assert path.features == [n for n in routine.measured_features() for _ in routine.program.feature(n).hits]
    r = station.prober.settings.tip_radius
    assert np.allclose([c.contact for c in path.cycles],  # each hit where its taught target is
                       [p - r * u / np.linalg.norm(u) for _n, p, u, _cz in routine.targets(model.part.pose)])
    assert path.hand == {0: ["3 hits by hand on TOP", "2 hits by hand on FRONT", "1 hit by hand on LEFT"]}
    assert "by hand on TOP" in path.text()
    first = path.cycles[0]
    assert np.allclose(first.start, first.rapid[-2]) and first.start[2] >= first.pre[2]  # over the first datum hit

    pose = model.part.pose
    queue = [((pose @ np.array([*p, 1.0]))[:3], pose[:3, :3] @ np.array(u, float)) for p, u in MANUAL]
    rec, recording = Recorder(station), []

    def hands(prompt, n):  # the operator's hits where the part stands; the machine's path is recorded after them
        got = [model.hit_id(model.probe(*queue.pop(0), clearance_z=90.0).wait(120)) for _ in range(n)]
        if not queue:
            recording.append(rec.__enter__())
        return got

    try:
        progress = RoutineRun(routine, StationRoutineHost(model, ctl), part_name="p2").run(manual_hits=hands)
    finally:
        if recording:
            rec.__exit__()
    assert progress.state == "done" and progress.hits == len(path.cycles)  # the automatic hits: hand hits apart
    assert path.tail and path.tail[-1][2] > path.tail[0][2] and "up to the clearance plane" in path.text()
    assert_runs_as_previewed(path.cycles, _from_corner(rec.points, first.start), path.tail)


def test_a_resume_preview_backs_off_the_contact_and_retracts_first(station):
    model, ctl = station.measurement, station.controller
    model.new_session("taught-boss")
    run_plan(model, plan_at_pick(model, _pick(model, (70.0, -20.0, 47.0), (0, 1, 0)).face_id, n=3), name="boss")
    routine = teach_routine(open_session(model.journal.path), name="boss", part_mesh=model.part.mesh,
                            part_nominals=model.part.nominal_features)
    cfg = station.config.probe
    hits = routine.program.feature("boss").hits
    p, u = next((p, u) for h, p, u, _cz in machine_targets(routine.program, model.part.pose) if h.id == hits[1])
    station.sim.place_artifacts([(p - (cfg.tip_radius + cfg.approach_distance) * u + [0.0, 0.0, 6.0], 3.0)])
    run = RoutineRun(routine, StationRoutineHost(model, ctl), part_name="p4")
    try:
        with pytest.raises(Exception, match="unexpected probe contact"):
            run.run()
    finally:
        station.sim.place_artifacts([])  # the operator takes the chip away
    ctl.reset(None)
    here = np.asarray(ctl.frame_position("machine"), float)
    path = routine_path(routine, ctl, model.part.pose, run, mesh=model.part.mesh)
    assert path.features == ["boss"] * len(hits) and "first the retract" in path.text()
    back = path.lead[0] - here  # the back-off: up, the way the tip came down onto the chip
    assert np.linalg.norm(back) == pytest.approx(cfg.retract_distance) and back[2] > 0.9 * cfg.retract_distance
    assert path.lead[-1][2] >= model.clearance_z() - 1e-9 and np.allclose(path.cycles[0].start, here)
    # a preview from where the tip stands (Auto-measure's) backs off the same way first
    assert np.allclose(ctl.probe_paths([t[1:] for t in routine.targets(model.part.pose)])[0].rapid[0], path.lead[0])
    with Recorder(station) as rec:
        progress = run.resume_after_fault()
    assert progress.state == "done" and len(run.discarded) == 1
    assert_runs_as_previewed(path.cycles, rec.points, path.tail)

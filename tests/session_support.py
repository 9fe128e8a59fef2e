"""Helpers for the session tests: record real sessions on the simulated CMM (in-process, virtual clock)."""

from __future__ import annotations

import functools
import shutil
import tempfile
from pathlib import Path

import numpy as np

from cmm.machine.config import load
from cmm.machine.motion import Machine
from cmm.machine.probing import Prober
from cmm.metrology.align import best_fit
from cmm.metrology.compensation import PretravelModel
from cmm.measurement.model import Part
from cmm.measurement.recording import record
from cmm.journal.store import DirectoryStore
from cmm.sim.cmm_sim import NOMINAL_PART_POSE, CmmSimSettings, SimulatedCMM, pose_matrix


def matched_pretravel(sim) -> PretravelModel:
    p = sim.settings.probe
    return PretravelModel({"const": p.pretravel_xy, "s_cos3": p.pretravel_lobe, "z2": p.pretravel_z - p.pretravel_xy})


def sim_station(session_dir, session: str, placed=None):
    """A fixture's body: ``yield from sup.sim_station(tmp_path, "dmis")``: the station on the in-process simulator
    (virtual clock), homed, its pre-travel the simulator's, the part placed at ``placed`` (part -> machine) if
    given, a session ``session`` open; closed after the test (tests/stations.py: the kind ``probing``)."""
    from stations import Stations

    with Stations(lambda: session_dir) as built:
        yield built.probing(session, placed=placed)


def setup(part_pose=None):
    config = load()
    sim = SimulatedCMM(config, CmmSimSettings() if part_pose is None else CmmSimSettings(part_pose=part_pose))
    machine = Machine(config, sim.transport())
    machine.connect()
    prober = Prober(machine)
    prober.settings.pretravel = matched_pretravel(sim)
    return sim, machine, prober


def to_machine(pose, p):
    return (pose @ np.append(np.asarray(p, float), 1.0))[:3]


def dir_to_machine(pose, u):
    return pose[:3, :3] @ np.asarray(u, float)


# alignment hits (part coordinates, approach into the surface): top, front, left faces
ALIGN_HITS = [((15, 10, 40), (0, 0, -1)), ((110, 15, 40), (0, 0, -1)), ((110, 70, 40), (0, 0, -1)),
              ((15, 70, 40), (0, 0, -1)),
              ((15, 0, 20), (0, 1, 0)), ((100, 0, 20), (0, 1, 0)), ((60, 0, 10), (0, 1, 0)),
              ((0, 15, 20), (1, 0, 0)), ((0, 65, 20), (1, 0, 0))]


def feature_hits():
    """(name, kind, [(part point, approach)]) for the taught features."""
    top = [((10, 30, 40), (0, 0, -1)), ((50, 5, 40), (0, 0, -1)), ((112, 72, 40), (0, 0, -1)), ((95, 10, 40), (0, 0, -1))]
    boss = []
    for z in (44.0, 52.0):
        for a in np.radians([10, 100, 190, 280]):
            n = np.array([np.cos(a), np.sin(a), 0.0])
            boss.append((np.array([70, 22, z]) + 10 * n, -n))
    dome = [((70, 58, 49), (0, 0, -1))]
    for a in np.radians([20, 110, 200, 290]):
        t = np.radians(50)
        n = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.cos(t)])
        dome.append((np.array([70, 58, 39]) + 10 * n, -n))
    return [("top_plane", "plane", top), ("boss", "cylinder", boss), ("dome", "sphere", dome)]


CLEARANCE_Z = 65.0  # part z


def align(rec, machine_guess_pose):
    """Probe the alignment hits where the part is believed to be, best-fit them to the mesh."""
    ids = []
    for p, u in ALIGN_HITS:
        hit = rec.probe(to_machine(machine_guess_pose, p), dir_to_machine(machine_guess_pose, u),
                        clearance_z=to_machine(machine_guess_pose, [p[0], p[1], CLEARANCE_Z])[2]).wait()
        ids.append(rec.hit_id(hit))
    pts = np.array([rec.hits[i].point for i in ids])
    fit = best_fit(rec.part.mesh, pts, initial=machine_guess_pose)
    rec.set_alignment(fit.transform, "best_fit", rms=fit.rms, max_residual=fit.max_residual, hit_ids=ids)
    return fit.transform


def measure(rec, pose, nominals):
    for name, kind, hits in feature_hits():
        ids = []
        for p, u in hits:
            hit = rec.probe(to_machine(pose, p), dir_to_machine(pose, u),
                            clearance_z=to_machine(pose, [p[0], p[1], CLEARANCE_Z])[2]).wait()
            ids.append(rec.hit_id(hit))
        rec.fit_feature(kind, ids, "ls", name, nominals[name].transformed(pose))


def record_session(store, name, part_pose=None, guess_pose=None):
    """A complete session: start, alignment (9 hits + best fit), 3 features (17 hits), a note."""
    sim, machine, prober = setup(part_pose)
    part = Part("sample part", sim.part_mesh, (NOMINAL_PART_POSE if guess_pose is None else guess_pose).copy(),
                    dict(sim.nominal_features))
    rec = record(store.create(name), machine, prober, part, port="in-process")
    try:
        pose = align(rec, part.pose)
        measure(rec, pose, sim.nominal_features)
        rec.note("taught on the first set-up")
    finally:
        rec.close()
        machine.close()
    return sim


@functools.lru_cache(maxsize=1)
def _recorded() -> Path:
    root = Path(tempfile.mkdtemp(prefix="cmm-session-tests-"))
    record_session(DirectoryStore(root), "taught")
    return root / "taught.jsonl"


def recorded_copy(directory: Path, name: str = "taught") -> Path:
    """A copy of the (once per test process) recorded session journal in ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    dest = directory / f"{name}.jsonl"
    shutil.copyfile(_recorded(), dest)
    return dest


SECOND_POSE = pose_matrix((240.0, 190.0, 0.0), rz_deg=20.0)
SECOND_GUESS = pose_matrix((240.5, 189.6, 0.0), rz_deg=19.6)


# (name, ray origin in part coordinates, ray direction): what the operator clicks to auto-measure on the block
BLOCK_FACES = [("TOP", (20.0, 10.0, 100.0), (0, 0, -1)), ("FRONT", (20.0, -50.0, 20.0), (0, 1, 0)),
               ("LEFT", (-50.0, 10.0, 20.0), (1, 0, 0)), ("bore", (30.0, 40.0, 20.0), (1, 0, 0)),
               ("boss", (70.0, -20.0, 47.0), (0, 1, 0)), ("dome", (73.0, 58.0, 100.0), (0, 0, -1))]


def teach_block(model, faces=BLOCK_FACES):
    """On the simulator's true set-up: auto-measure ``faces`` where the operator clicks, align 3-2-1 on
    TOP/FRONT/LEFT, construct the bore-boss distance (when both are among the faces); returns (feature ids by
    name, the distance or None) as taught."""
    from cmm.measurement.alignment import align_features, apply
    from cmm.measurement.plan import plan_at_pick, run_plan
    from cmm.sim.cmm_sim import TRUE_PART_POSE

    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    ids = {}
    for name, origin, direction in faces:
        pose = model.part.pose
        picked = model.pick((pose @ np.array([*origin, 1.0]))[:3], pose[:3, :3] @ np.array(direction, float))
        ids[name] = run_plan(model, plan_at_pick(model, picked[0].face_id), name=name).id
    apply(model, align_features(model, ids["TOP"], ids["FRONT"], ids["LEFT"]))
    if "bore" not in ids or "boss" not in ids:  # the three datum planes alone: no construction
        return ids, None
    return ids, model.construct_feature("distance", ids["bore"], ids["boss"], "bore-boss")


def standing(station, what: str, still: float = 0.2, timeout: float = 60.0) -> None:
    """Wait until no axis of ``station`` has moved for ``still`` s of the machine's clock (a zero velocity in one
    sample is not enough: on a starved host a late hold can restart a jog that had run out its horizon, and an
    abrupt stop's servo settles for a few samples)."""
    import time

    since = [station.machine.state.time, station.machine.state.position.copy()]

    def stood() -> bool:
        s = station.machine.state
        if any(abs(a.velocity) > 1e-9 for a in s.axes) or not np.array_equal(s.position, since[1]):
            since[:] = [s.time, s.position.copy()]
            return False
        return s.time - since[0] >= still

    end = time.monotonic() + timeout
    while not stood():
        if time.monotonic() > end:
            raise AssertionError(f"{what}: the axes did not stand still within {timeout:g} s")
        time.sleep(0.02)


# The sample block's three datum faces, three hits each (part coordinates: point, approach direction)
PLANE_FACES = {
    "TOP": [((15.0, 10.0, 40.0), (0, 0, -1)), ((105.0, 12.0, 40.0), (0, 0, -1)), ((50.0, 70.0, 40.0), (0, 0, -1))],
    "FRONT": [((15.0, 0.0, 15.0), (0, 1, 0)), ((105.0, 0.0, 15.0), (0, 1, 0)), ((60.0, 0.0, 30.0), (0, 1, 0))],
    "LEFT": [((0.0, 20.0, 15.0), (1, 0, 0)), ((0.0, 50.0, 15.0), (1, 0, 0)), ((0.0, 35.0, 30.0), (1, 0, 0))]}


def planes_routine(part, name: str, faces=("TOP", "FRONT", "LEFT")):
    """A routine that measures the named faces of PLANE_FACES as least-squares planes on ``part``."""
    from cmm.measurement.routine import Routine
    from cmm.program.toml_program import Program, ProgramFeature, ProgramHit, part_hash

    hits, features = [], []
    for face in faces:
        ids = []
        for point, approach in PLANE_FACES[face]:
            hits.append(ProgramHit(len(hits) + 1, point, approach, 65.0))
            ids.append(hits[-1].id)
        features.append(ProgramFeature(face, "plane", "ls", ids))
    return Routine(Program(name, "block", part_hash(part), features, hits))

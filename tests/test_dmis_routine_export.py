"""A routine taught in the page (3-2-1 alignment, planes, bore, boss, a distance between them) exported to DMIS
and run by the DMIS interpreter on the simulator with the part placed elsewhere on the table: the program aligns
on the datums, measures the same features and gives the construction's value, all within the probing noise."""

from __future__ import annotations

import numpy as np
import pytest

import session_support as sup
from cmm.dmis.check import check
from cmm.dmis.export import to_dmis
from cmm.dmis.runner import run_text
from cmm.measurement.plan import plan_at_pick, run_plan
from cmm.measurement.routine import teach_routine
from cmm.measurement.routine_path import routine_path
from cmm.metrology.transform import invert
from cmm.journal.store import open_session
from cmm.sim.cmm_sim import TRUE_PART_POSE, pose_matrix

FACES = sup.BLOCK_FACES[:5]  # the five features the routine measures (no dome)
TOL = 0.01  # mm: a feature measured twice with different hits' noise


@pytest.fixture
def station(tmp_path):
    yield from sup.sim_station(tmp_path, "teach")


def _part(pose, point):
    return (invert(pose) @ np.append(np.asarray(point, float), 1.0))[:3]


def test_a_taught_routine_exported_to_dmis_runs_again_on_a_part_placed_elsewhere(station):
    st, model = station, station.measurement
    ids, dist = sup.teach_block(model, FACES)
    taught_pose = np.asarray(model.part.pose, float)
    routine = teach_routine(open_session(model.journal.path), name="block", part_mesh=model.part.mesh,
                            part_nominals=model.part.nominal_features)
    routine.steps.insert(len(routine.steps) - 1, {"kind": "construct", "name": "skipped", "operation": "midpoint",
                                                  "of": ["bore", "boss"], "skip": True})
    text = to_dmis(routine.program, taught_pose, tip_radius=st.prober.settings.tip_radius,
                   approach=st.config.probe.approach_distance, search=st.config.probe.search_distance,
                   retract=st.config.probe.retract_distance)
    assert check(text)[1] == []
    lines = text.splitlines()
    # the steps in their order: the datums, the 3-2-1 alignment from them, the features, the construction
    order = [next(i for i, ln in enumerate(lines) if ln.startswith(s)) for s in (
        "MEAS/PLANE, F(TOP)", "MEAS/PLANE, F(FRONT)", "MEAS/PLANE, F(LEFT)",
        "D(ALIGN) = DATSET/FA(TOP), ZDIR, ZORIG, FA(FRONT), YMINUS, YORIG, FA(LEFT), XORIG",
        "MEAS/CYLNDR, F(BORE)", "MEAS/CYLNDR, F(BOSS)", "T(BORE_BOSS) = TOL/DISTB", "OUTPUT/FA(BORE), FA(BOSS)")]
    assert order == sorted(order)
    assert "$$ step skipped is skipped in the routine" in lines and "F(SKIPPED)" not in text

    # the next part: 0.25 mm and 0.2 mm off the taught set-up and turned 0.1 degrees (the datums' hits are taken
    # at D(PART), within the rails' 0.5 mm of where the program puts the part); the program's DATSET finds it
    moved = pose_matrix((190.25, 150.2, 0.0), rz_deg=0.1) @ invert(pose_matrix((190.0, 150.0, 0.0))) @ TRUE_PART_POSE
    st.sim.place_part(moved)
    # the operator starts the program with the probe above the part (the program's first move is straight across)
    above = taught_pose @ np.array([60.0, 40.0, routine.program.hits[0].clearance_z, 1.0])
    answer = st.controller.commands.call(None, "move", {"target": above[:3].tolist(), "frame": "machine",
                                                        "path": "clearance"}, wait=True, timeout=120)
    assert answer.ok, answer.error
    again = run_text(text, st.controller.commands, name="exported")
    assert {"TOP", "FRONT", "LEFT", "BORE", "BOSS"} <= set(again.actuals)
    pose = np.asarray(model.part.pose, float)  # where the DATSET moved the station's part
    delta = pose @ invert(moved)
    assert np.linalg.norm(delta[:3, 3]) < TOL
    for name in ("bore", "boss"):
        g1 = model.features[ids[name]].result.geometry()
        g2 = again.actuals[name.upper()].geometry
        assert g2["radius"] == pytest.approx(g1["radius"], abs=TOL)
        # the axis where the part has it, on either part
        c1, c2 = _part(taught_pose, g1["point"]), _part(moved, g2["point"])
        assert np.hypot(*(c2 - c1)[:2]) < TOL
    verdicts = {e.tolerance.label: e for e in again.evaluations}
    d = verdicts["BORE_BOSS"]
    assert d.tolerance.nominal + d.value == pytest.approx(dist.result.value, abs=TOL) and d.intol


class _Tab:
    """What the Routine tab's viser client is asked for: a notification and a file download (recorded)."""

    def __init__(self) -> None:
        self.downloads: list[tuple[str, bytes]] = []

    def send_file_download(self, name: str, content: bytes) -> None:
        self.downloads.append((name, content))

    def add_notification(self, *args, **kwargs) -> None:
        pass


def test_the_routine_tab_exports_dmis_beside_the_routine_file_and_offers_it(station, tmp_path):
    from cmm.control.access import Control
    from cmm.ui.context import PanelContext
    from cmm.ui.panel_routine import RoutinePanel

    model = station.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    for name, origin, direction in (FACES[0], FACES[3]):  # the top face and the bore: a cheap routine
        picked = model.pick((TRUE_PART_POSE @ np.array([*origin, 1.0]))[:3], np.array(direction, float))
        run_plan(model, plan_at_pick(model, picked[0].face_id), name=name)
    control = Control()
    assert control.take("operator", is_local=True)
    tab = _Tab()
    panel = RoutinePanel(PanelContext(station.controller.commands, control, None, tab, client_id="operator", is_local=True))
    assert panel.export_dmis("") is None and panel.ctx.messages[-1][:2] == ("error", "Export DMIS")
    assert panel.teach("block 7") is not None
    folder = tmp_path / "routines"
    folder.mkdir()
    saved = panel.save(str(folder / "block.toml"))
    out = panel.export_dmis(str(folder / "block.toml"))
    assert out == saved.parent / "block_7.dmi" and out.is_file()
    level, title, body = panel.ctx.messages[-1]
    assert (level, title) == ("info", "DMIS program exported") and str(out) in body
    assert tab.downloads == [("block_7.dmi", out.read_bytes())]
    text = out.read_text()
    assert check(text)[1] == [] and "MEAS/PLANE, F(TOP), " in text and "MEAS/CYLNDR, F(BORE), " in text
    assert panel.open_dmis(str(out))  # the page opens and checks what it exported
    # a folder that is not there: said, nothing written
    assert panel.export_dmis(str(tmp_path / "nowhere" / "block.toml")) is None
    assert panel.ctx.messages[-1][0] == "error" and "cannot write" in panel.ctx.messages[-1][2]


def test_a_line_in_a_routine_is_exported_as_a_bounded_line_in_its_face_and_measures_again(station):
    """A line taught on the block's front face (three hits along X) is written FEAT/LINE, BND from the first to the
    last hit with the face's normal as its plane, and the exported program measures the same edge line again."""
    from cmm.program.toml_program import Program, ProgramFeature, ProgramHit

    station.measurement.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    top = float(station.measurement.part.mesh.bounds[1][2]) + 10.0  # part Z above everything on the part
    hits = [ProgramHit(i, (x, 0.0, 25.0 + 0.5 * i), (0.0, 1.0, 0.0), top) for i, x in enumerate((15.0, 60.0, 105.0), 1)]
    program = Program("edge", "block", "0" * 64, [ProgramFeature("edge", "line", "ls", [1, 2, 3])], hits)
    text = to_dmis(program, TRUE_PART_POSE, tip_radius=station.prober.settings.tip_radius)
    assert check(text)[1] == []
    words = next(ln for ln in text.splitlines() if ln.startswith("F(EDGE) = FEAT/")).split("FEAT/")[1].split(", ")
    assert words[:3] == ["LINE", "BND", "CART"]
    # from (15, 0, 25.5) to (105, 0, 26.5) as the least-squares line puts them, in the plane of the face (0, -1, 0)
    nums = [float(x) for x in words[3:]]
    assert nums[0:3] == pytest.approx([15.0, 0.0, 25.5], abs=1e-3) and nums[3:6] == pytest.approx([105, 0, 26.5], abs=1e-3)
    assert nums[6:9] == pytest.approx([0.0, -1.0, 0.0], abs=1e-6)
    st = station
    above = TRUE_PART_POSE @ np.array([60.0, -30.0, top, 1.0])
    answer = st.controller.commands.call(None, "move", {"target": above[:3].tolist(), "frame": "machine",
                                                        "path": "clearance"}, wait=True, timeout=120)
    assert answer.ok, answer.error
    run = run_text(text, st.controller.commands, name="edge")
    g = run.actuals["EDGE"].geometry
    d = TRUE_PART_POSE[:3, :3].T @ np.asarray(g["direction"], float)  # the measured line, in part axes
    assert abs(d[0]) == pytest.approx(np.cos(np.arctan2(1.0, 90.0)), abs=1e-3)


def _taught_top(station, hits):
    """The top face auto-measured with ``hits`` hits on the part at its true set-up, and the routine taught from it."""
    model = station.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    name, origin, direction = FACES[0]  # the top face
    picked = model.pick((TRUE_PART_POSE @ np.array([*origin, 1.0]))[:3], np.array(direction, float))
    run_plan(model, plan_at_pick(model, picked[0].face_id, n=hits), name=name)
    return model, teach_routine(open_session(model.journal.path), name="top", part_mesh=model.part.mesh,
                                part_nominals=model.part.nominal_features)


def test_an_exported_features_later_hits_hop_as_the_routine_runner_and_measure_the_same(station):
    """With the part mesh the exporter writes a feature's later hits as the routine runner takes them (the rails'
    hop: straight or over the feature's local top, GOTO points between the PTMEAS statements, none up at the
    clearance height); the program checks, runs on the simulator in less machine time per hit and measures the
    same plane as the export without the mesh (every hit over the clearance height)."""
    model, routine = _taught_top(station, 5)
    program, top = routine.program, routine.program.hits[0].clearance_z
    probe = station.config.probe
    kw = dict(tip_radius=station.prober.settings.tip_radius, approach=probe.approach_distance,
              search=probe.search_distance, retract=probe.retract_distance)
    texts = {False: to_dmis(program, TRUE_PART_POSE, **kw),
             True: to_dmis(program, TRUE_PART_POSE, mesh=model.part.mesh, **kw)}
    gotos = {k: [[float(x) for x in ln.split("GOTO/")[1].split(", ")] for ln in t.splitlines() if "GOTO/" in ln]
             for k, t in texts.items()}
    assert all(g[2] == pytest.approx(top) for g in gotos[False])  # every hit up and over the clearance height
    high = [g for g in gotos[True] if g[2] >= top - 1e-6]
    assert len(high) == 2  # up for the first hit, back up after the last: the others hop
    assert check(texts[True])[1] == []
    # the routine runner's path: each later hit straight, or over the same height as the exported GOTOs
    heights, goto = [], []
    for ln in texts[True].split("MEAS/PLANE")[1].splitlines()[1:]:
        if "GOTO/" in ln:
            goto.append(float(ln.split(", ")[-1]))
        elif "PTMEAS/" in ln:
            heights.append(max(goto) if goto else None)
            goto = []
    cycles = routine_path(routine, station.controller, TRUE_PART_POSE, mesh=model.part.mesh).cycles
    assert [None if len(c.rapid) == 1 else pytest.approx(max(q[2] for q in c.rapid) - TRUE_PART_POSE[2, 3])
            for c in cycles[1:]] == heights[1:]
    assert None in heights[1:]  # the rails prove some of the lines over the top face straight
    results = {}
    for hops, text in texts.items():
        above = TRUE_PART_POSE @ np.array([60.0, 40.0, top, 1.0])
        answer = station.controller.commands.call(None, "move", {"target": above[:3].tolist(), "frame": "machine",
                                                                  "path": "clearance"}, wait=True, timeout=120)
        assert answer.ok, answer.error
        t0 = station.machine.clock.now()
        run = run_text(text, station.controller.commands, name=f"top {hops}")
        results[hops] = ((station.machine.clock.now() - t0) / len(program.hits), run.actuals["TOP"].geometry)
    (s_over, over), (s_hop, hop) = results[False], results[True]
    print(f"exported top plane: {s_over:.2f} machine s/hit over the clearance height, {s_hop:.2f} hopping")
    assert s_hop < 0.9 * s_over
    n1, n2 = np.asarray(over["normal"], float), np.asarray(hop["normal"], float)
    assert abs(n1 @ n2) > 1 - 1e-6
    assert abs((np.asarray(hop["point"], float) - np.asarray(over["point"], float)) @ n1) < TOL


def test_cmm_dmis_export_with_the_part_writes_the_hops_and_refuses_another_part(station, tmp_path, capsys):
    """`cmm dmis-export PROGRAM --part FILE`: a program taught on a part loaded from an STL file, that file given
    (its checksum matches the program's): the exported top plane's later hits hop (GOTO points below the
    clearance height); without --part every hit goes over the clearance height; a program taught on the
    simulator's sample part (no file) hops without --part; another part is refused with a message naming the
    program's part, and nothing is written."""
    from cmm.cli import main
    from cmm.journal.session import file_sha256
    from cmm.program.toml_program import save

    model, routine = _taught_top(station, 4)
    taught_on_sample = save(routine.program, tmp_path / "sample.toml")  # taught on the simulator's sample part
    part_file = tmp_path / "block.stl"
    model.part.mesh.export(part_file)
    # as a program taught with the part loaded from that file (its file's checksum; the sample part has no file)
    routine.program.part_sha256 = file_sha256(part_file)
    program_file = save(routine.program, tmp_path / "top.toml")
    top = routine.program.hits[0].clearance_z
    at = ",".join(f"{v:g}" for v in TRUE_PART_POSE[:3, 3])

    def gotos(path):
        return [float(ln.split("GOTO/")[1].split(", ")[2]) for ln in path.read_text().splitlines() if "GOTO/" in ln]

    assert main(["dmis-export", str(program_file), "--at", at, "-o", str(tmp_path / "over.dmi")]) == 0
    assert main(["dmis-export", str(program_file), "--at", at, "--part", str(part_file),
                 "-o", str(tmp_path / "hop.dmi")]) == 0
    over, hop = gotos(tmp_path / "over.dmi"), gotos(tmp_path / "hop.dmi")
    assert over and all(z == pytest.approx(top) for z in over)  # every hit over the clearance height
    assert any(z < top - 1.0 for z in hop)  # later hits hop below it
    assert check((tmp_path / "hop.dmi").read_text())[1] == []
    # the sample part has no file: it is made again, and its program's later hits hop without --part
    assert main(["dmis-export", str(taught_on_sample), "--at", at, "-o", str(tmp_path / "sample.dmi")]) == 0
    assert gotos(tmp_path / "sample.dmi") == hop

    other = tmp_path / "other.stl"
    import trimesh

    trimesh.creation.box((10.0, 10.0, 10.0)).export(other)
    capsys.readouterr()
    assert main(["dmis-export", str(program_file), "--part", str(other), "-o", str(tmp_path / "x.dmi")]) == 1
    assert f"is not the part {routine.program.part_name!r}" in capsys.readouterr().err
    assert not (tmp_path / "x.dmi").exists()

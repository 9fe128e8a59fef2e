"""A DMIS program's alignment moves the station's part: after a DATSET from the datums, the motion rails prove
the program's straight moves against the part where the program found it, not against the nominal set-up."""

from __future__ import annotations

import numpy as np
import pytest

import session_support as sup
from cmm.control.rails import straight_blocked
from cmm.dmis.executor import DmisError
from cmm.dmis.runner import run_text
from cmm.metrology.align import AlignmentError
from cmm.metrology.mesh import signed_deviation
from cmm.metrology.transform import invert
from cmm.session.report import render
from cmm.journal.store import DirectoryStore, load_session
from cmm.sim.cmm_sim import NOMINAL_PART_POSE, pose_matrix

# the part put down 5 mm and 2 mm off the nominal set-up (190, 150) and turned 1 degree
PLACED = pose_matrix((195.0, 152.0, 0.0), rz_deg=1.0)
SETUP = np.array([190.0, 150.0, 0.0])

PROGRAM = """FILNAM/'aligned, then close to the part'
UNITS/MM, ANGDEC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
MODE/MAN
F(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1
MEAS/PLANE, F(TOP), 3
  PTMEAS/CART, 15, 10, 40, 0, 0, 1
  PTMEAS/CART, 105, 12, 40, 0, 0, 1
  PTMEAS/CART, 50, 70, 40, 0, 0, 1
ENDMES
F(FRONT) = FEAT/PLANE, CART, 60, 0, 20, 0, -1, 0
MEAS/PLANE, F(FRONT), 3
  PTMEAS/CART, 15, 0, 25, 0, -1, 0
  PTMEAS/CART, 105, 0, 25, 0, -1, 0
  PTMEAS/CART, 60, 0, 10, 0, -1, 0
ENDMES
F(LEFT) = FEAT/POINT, CART, 0, 20, 15, -1, 0, 0
MEAS/POINT, F(LEFT), 1
  PTMEAS/CART, 0, 20, 15, -1, 0, 0
ENDMES
D(PART) = DATSET/FA(TOP), ZDIR, ZORIG, FA(FRONT), YMINUS, YORIG, FA(LEFT), XORIG
MODE/AUTO
RECALL/D(SETUP)
GOTO/2, 40, 60
GOTO/2, 40, 20
GOTO/2, 40, 60
GOTO/122, 40, 60
GOTO/122, 40, 20
ENDFIL
"""
# line 25: down beside the real part's left face (inside the nominal part: the nominal set-up would refuse it);
# line 28: down into the real part's right end (2 mm clear of the nominal part: the nominal set-up takes it)
BESIDE = (SETUP + [2.0, 40.0, 60.0], SETUP + [2.0, 40.0, 20.0])
INTO = (SETUP + [122.0, 40.0, 60.0], SETUP + [122.0, 40.0, 20.0])


@pytest.fixture
def station(tmp_path):
    """The station on the in-process simulator (virtual clock), homed, the part placed off the set-up."""
    yield from sup.sim_station(tmp_path, "pose", PLACED)


class _Posed:
    """The rails' view of the part at a given pose (the nominal set-up, or where it really lies)."""

    def __init__(self, mesh, pose):
        self.mesh, self.pose = mesh, pose

    def part_pose(self):
        return self.pose

    def clearance_z(self):
        return 90.0

    def surface_distance(self, points):
        return signed_deviation(self.mesh, points, self.pose).deviations


def _operator(st):
    """The operator's hands: each guided hit taken where the part really is, then clear of it (Z 70)."""
    model = st.measurement

    def take(prompt, n, guides):
        ids = []
        for point, approach in guides[:n]:
            true = (PLACED @ np.append(np.asarray(point, float) - SETUP, 1.0))[:3]
            hit = model.probe(true, PLACED[:3, :3] @ approach, clearance_z=90.0).wait(120)
            ids.append(model.hit_id(hit))
        here = np.asarray(st.controller.frame_position("machine"), float)
        st.controller.move(None, [here[0], here[1], 70.0], frame="machine").wait(120)
        return ids

    return take


def test_datset_moves_the_station_part_and_the_rails_follow_it(station):
    mesh, r = station.measurement.part.mesh, float(station.controller.tip_radius)
    nominal, placed = _Posed(mesh, NOMINAL_PART_POSE), _Posed(mesh, PLACED)
    # the premise: on the nominal set-up the first descent is refused and the second taken; on the part as it lies,
    # the other way round
    assert straight_blocked(nominal, *BESIDE, r) is not None and straight_blocked(nominal, *INTO, r) is None
    assert straight_blocked(placed, *BESIDE, r) is None and straight_blocked(placed, *INTO, r) is not None

    with pytest.raises(DmisError, match=r"^line 28: GOTO: the straight line passes .* use the clearance path$") as err:
        run_text(PROGRAM, station.controller.commands, name="pose.dmi", manual_hits=_operator(station))
    # the DATSET put the station's part where it lies, journalled as an alignment (the 3-D view and the report
    # read the same pose), and the run says so
    model = station.measurement
    pose = np.asarray(model.part.pose, float)
    assert pose[:3, 3] == pytest.approx(list(PLACED[:3, 3]), abs=0.02)
    assert np.allclose(pose[:3, :3], PLACED[:3, :3], atol=3e-4)
    assert model.aligned and model.alignment_name == "DMIS D(PART)"
    assert any("line 21: D(PART) moved the station's part" in line for line in err.value.result.log)
    # the descent beside the real part ran; the one into it was refused before it moved, over the part's end
    here = np.asarray(station.controller.frame_position("machine"), float)
    assert here == pytest.approx(list(INTO[0]), abs=0.01)
    # nothing restores the nominal set-up behind the operator's back: the part stays where the program found it
    assert np.array_equal(np.asarray(model.part.pose, float), pose)
    # the journal has the alignment: the report's header names it, a replay ends at the aligned pose
    model.journal.close()
    session = load_session(DirectoryStore(model.session_dir), "pose")
    assert np.allclose(np.array(session.state.part_pose, float), pose, atol=1e-12)
    assert "DMIS D(PART)" in render(session, mesh=mesh)


def test_a_program_alignment_that_does_not_fit_the_part_moves_nothing(station):
    model = station.measurement
    before = np.asarray(model.part.pose, float).copy()
    # points on the top, front and left faces of the part as it really lies
    part_points = [(15, 10, 40), (105, 12, 40), (50, 70, 40), (15, 0, 25), (105, 0, 25), (0, 20, 15)]
    true = np.array([(PLACED @ np.append(p, 1.0))[:3] for p in part_points])
    move = PLACED @ invert(NOMINAL_PART_POSE)  # where the program found its datums against where it expected them
    cmds = station.controller.commands
    with pytest.raises(AlignmentError, match=r"^D\(X\): its datums' hits lie up to [1-9]\.\d+ mm from the part at the pose it gives"):
        cmds.invoke(None, "align", measured=np.eye(4), nominal=np.eye(4), points=true, name="D(X)")
    with pytest.raises(AlignmentError, match="not a rigid"):
        cmds.invoke(None, "align", measured=np.diag([2.0, 1.0, 1.0, 1.0]), nominal=np.eye(4), points=true)
    assert np.array_equal(np.asarray(model.part.pose, float), before) and not model.aligned
    # the station aligned elsewhere since (the previous part): the program's nominals are for the set-up, and
    # the pose that puts the datums' hits on the part wins
    model.set_alignment(pose_matrix((188.0, 149.0, 0.0), rz_deg=-0.7))
    result = cmds.invoke(None, "align", measured=move, nominal=np.eye(4), points=true, name="D(Y)")
    assert np.allclose(result.pose, PLACED, atol=1e-9) and np.allclose(model.part.pose, PLACED, atol=1e-9)

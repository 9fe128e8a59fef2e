"""The page's Setup > Part tab: a part file uploaded, placed, picked with its exact surfaces, and the simulator's next part
moved and turned (or refused off the table), through the command API as the page sends it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import ui_support
from shared_refs import shared_path

pytest.importorskip("viser")

from cmm.sim.cmm_sim import pose_matrix  # noqa: E402
from cmm.ui.scene import SCALE  # noqa: E402

STP = shared_path("cad", "ipp_simple.stp")  # read in place; the upload stores its bytes as a page would send them
pytestmark = pytest.mark.skipif(not STP.is_file(), reason=f"the reference part {STP} is not here (set CMM_SHARED)")


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    yield from ui_support.station_app(tmp_path_factory, pendant_port=0)


@pytest.fixture()
def operator(app):
    capp = app.add_client(client_id="operator", is_local=True)
    assert capp.take_control()
    yield capp
    capp.release_control()


def test_an_uploaded_step_part_is_placed_drawn_and_picked_on_its_exact_surfaces(app, operator):
    st = app.station
    part = operator.part.upload("ipp_simple.stp", STP.read_bytes(), pose=[150.0, 120.0, 0.0, 30.0])
    assert part is not None, operator.messages[-3:]
    pose = pose_matrix((150.0, 120.0, 0.0), rz_deg=30.0)
    assert st.measurement.part.name == "ipp_simple.stp"
    np.testing.assert_allclose(st.measurement.part.pose, pose, atol=1e-12)
    np.testing.assert_allclose(st.sim.settings.part_pose, pose, atol=1e-12)  # the same part on the simulated table
    assert st.sim.part_mesh.metadata.get("cad") is not None
    stored = Path(st.measurement.part.mesh.metadata["path"])
    assert stored.parent.name == "parts" and stored.read_bytes() == STP.read_bytes()
    assert "8 faces (1 cylinder, 7 plane)" in operator.part.text()
    # a click down the hole's wall picks the bore with its exact diameter
    axis = pose[:3, :3] @ [50.0, 50.0, 40.0] + pose[:3, 3]
    picked = operator.on_scene_click(axis * SCALE, tuple(pose[:3, :3] @ [1.0, 0.2, 0.0]))
    assert picked is not None
    hit, nominal = picked
    assert nominal.kind == "cylinder" and nominal.params["bore"] and abs(nominal.params["radius"] - 25.0) <= 1e-9
    assert math.hypot(*(hit.point[:2] - axis[:2])) == pytest.approx(25.0, abs=1e-9)


def test_next_part_moves_and_turns_the_simulated_part_and_is_refused_off_the_table(app, operator):
    st = app.station
    if st.measurement.part is None or st.measurement.part.name != "ipp_simple.stp":
        operator.part.upload("ipp_simple.stp", STP.read_bytes(), pose=[150.0, 120.0, 0.0, 30.0])
    before = np.array(st.sim.settings.part_pose)
    believed = np.array(st.measurement.part.pose)
    assert operator.part.next_part(5.0, -3.0, 2.0) is not None, operator.messages[-3:]
    after = np.array(st.sim.settings.part_pose)
    np.testing.assert_allclose(after[:3, 3], before[:3, 3] + [5.0, -3.0, 0.0], atol=1e-9)
    turn = math.degrees(math.atan2(after[1, 0], after[0, 0]) - math.atan2(before[1, 0], before[0, 0]))
    assert turn == pytest.approx(2.0, abs=1e-9)
    np.testing.assert_allclose(st.measurement.part.pose, believed)  # the station finds it by aligning
    assert operator.part.next_part(400.0, 0.0, 0.0) is None
    level, title, body = operator.messages[-1]
    assert level == "error" and "would leave the table" in body and "\n" not in body
    np.testing.assert_allclose(st.sim.settings.part_pose, after)


def test_an_observer_cannot_load_a_part_and_a_broken_file_is_one_sentence(app, operator):
    observer = app.add_client(client_id="observer")
    name = app.station.measurement.part.name
    assert observer.part.upload("ipp_simple.stp", STP.read_bytes()) is None
    assert observer.messages[-1][0] == "error" and app.station.measurement.part.name == name
    assert operator.part.upload("broken.step", b"ISO-10303-21;\nDATA;\n#1=NONSENSE(;\n", pose=[150, 120, 0]) is None
    level, _, body = operator.messages[-1]
    assert level == "error" and "broken.step" in body and "not a valid STEP file" in body and "\n" not in body
    assert operator.part.upload("notes.txt", b"hello", pose=[150, 120, 0]) is None
    assert "not a part file" in operator.messages[-1][2]

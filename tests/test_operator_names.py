"""Operator names: the name a tab gives (start dialog or the browser's saved name) in the control messages,
the status bar and the report header, on the simulator (virtual clock)."""

from __future__ import annotations

import pytest

pytest.importorskip("viser")

from cmm.control import Refused  # noqa: E402
from cmm.session.report import render  # noqa: E402
from cmm.journal.store import DirectoryStore, load_session  # noqa: E402


@pytest.fixture(scope="module")
def app(module_stations, tmp_path_factory):
    sessions = tmp_path_factory.mktemp("sessions")
    return module_stations.app(module_stations.station("named", session_dir=sessions), pendant=False), sessions


def test_names_in_control_messages_status_bar_and_report(app):
    ui, sessions = app
    st = ui.station
    maria = ui.add_client(client_id="viser-1", is_local=True)
    jon = ui.add_client(client_id="viser-2", is_local=True)
    assert not maria.set_operator("   ")  # an empty name is refused with a sentence
    assert "enter your name" in maria.messages[-1][2]
    assert maria.set_operator("Maria  Lopez") and maria.operator == "Maria Lopez"
    assert maria.take_control()
    assert "Maria Lopez (you)" in maria.ctx.control_text()
    assert "control is held by **Maria Lopez**" in jon.ctx.control_text()
    assert "viser-1" not in jon.ctx.control_text()
    assert "control is held by Maria Lopez" in jon.status.html()  # the status bar
    assert "Maria Lopez (you) controls" in maria.status.html()
    # the control core's refusal names the holder too
    with pytest.raises(Refused, match="held by Maria Lopez"):
        st.controller.move("viser-2", st.machine.position, frame="machine")
    # the holder is the session's operator: the report header shows the name
    assert st.measurement.info["operator"] == "Maria Lopez"
    # another operator takes over: the first tab is told who, by name
    assert jon.set_operator("Jon")
    maria.watch_control()
    assert jon.take_control()
    maria.watch_control()
    assert "Jon now controls the machine" in maria.messages[-1][2]
    assert st.measurement.info["operator"] == "Jon"
    assert maria.set_operator("Maria")  # not the holder: the report's operator stays Jon
    assert st.measurement.info["operator"] == "Jon"
    page = render(load_session(DirectoryStore(sessions), st.measurement.journal.path.stem))
    header = page.split("operator", 1)[1][:120]
    assert "Jon" in header and "—" not in header, header

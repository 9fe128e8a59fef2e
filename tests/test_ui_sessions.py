"""The Sessions tab (cmm.ui.panel_sessions) on the in-process station app (simulator, loopback).

Handlers are driven through ``ClientApp.sessions`` (what each button calls);
one test connects a raw WebSocket client so the tab's widgets and the replay
drawing (into that client's scene) really exist.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import ui_support
from netutil import SIM

pytest.importorskip("viser")

from cmm.ui.panel_sessions import describe_event  # noqa: E402



@pytest.fixture(scope="module")
def app(tmp_path_factory):
    yield from ui_support.station_app(tmp_path_factory, port=SIM, session="first", pendant=False)


@pytest.fixture(scope="module")
def operator(app):
    capp = app.add_client(client_id="operator", is_local=True)
    assert capp.take_control()
    return capp


@pytest.fixture(scope="module")
def recorded(app, operator):
    """Three hits and a plane in session 'first', then a new live session 'second'."""
    st = app.station
    b = st.measurement.part.mesh.bounds
    for dx, dy in ((60.0, 40.0), (70.0, 40.0), (65.0, 50.0)):
        local = np.array([dx, dy, b[1][2] + 30.0])
        hit, _ = st.measurement.pick(st.measurement.part.pose[:3, :3] @ local + st.measurement.part.pose[:3, 3], [0.0, 0.0, -1.0])
        st.measurement.probe_here(hit.point, hit.normal).wait(40)
    assert len(st.measurement.hits) == 3
    assert operator.features.fit("plane", "ls", last_n=3) is not None, operator.messages[-2:]
    assert operator.sessions.new_session("second") is not None, operator.messages[-2:]
    assert operator.sessions.live_name() == "second"
    # the next part starts with an empty tree: what the page shows is what 'second' records
    assert not st.measurement.hits and not st.measurement.features
    return "first"


def _wait(job, timeout=30.0):
    assert job is not None
    assert job.wait(timeout), f"{job.title} did not finish"
    assert job.error is None, job.error
    return job.result


def test_list_shows_the_live_session(app, operator):
    rows = {r["name"]: r for r in operator.sessions.sessions()}
    live = operator.sessions.live_name()
    assert live in rows and rows[live]["recording"]
    assert live in operator.sessions.list_markdown() and "recording" in operator.sessions.list_markdown()


def test_replay_scrubber_counts_hits(app, operator, recorded):
    panel = operator.sessions
    rows = {r["name"]: r for r in panel.sessions()}
    assert rows["first"]["hits"] == 3 and rows["first"]["features"] == 1 and not rows["first"]["recording"]
    _wait(panel.open("first"))
    assert panel.session.name == "first" and panel.state is not None
    n = len(panel.replay)
    assert panel.index == n - 1 and len(panel.state.hits) == 3 and len(panel.state.features) == 1
    kinds = [panel.replay.event(i)["kind"] for i in range(n)]
    for i in range(n):
        state = panel.scrub(i)
        assert len(state.hits) == sum(k == "hit" for k in kinds[: i + 1]), i
    first_hit = kinds.index("hit")
    panel.scrub(first_hit)
    assert "hit 1" in panel.event_text() and "1 hits" in panel.event_text()
    assert "event" in panel.event_text()
    panel.back_to_live()
    assert panel.replay is None and "live" in panel.event_text()
    assert panel.scrub(0) is None and operator.messages[-1][0] == "error"  # nothing open


def test_rename_delete_refused_for_live_allowed_for_other(app, operator, recorded):
    panel = operator.sessions
    live = panel.live_name()
    assert not panel.rename(live, "other-name")
    assert "being recorded" in operator.messages[-1][2]
    assert not panel.delete(live)
    assert "being recorded" in operator.messages[-1][2]
    assert panel.store().exists(live)
    assert not panel.new_session("first")  # an existing name
    assert panel.rename("first", "first-renamed"), operator.messages[-1]
    assert panel.store().exists("first-renamed") and not panel.store().exists("first")
    assert panel.rename("first-renamed", "first"), operator.messages[-1]
    panel.new_session("scratch")
    panel.new_session("third")
    assert panel.delete("scratch"), operator.messages[-1]
    assert not panel.store().exists("scratch")


def test_export_report_and_reevaluate(app, operator, recorded):
    panel = operator.sessions
    files = _wait(panel.export("first"))
    csv_file, json_file = files
    assert csv_file.read_text().count("\n") == 4  # header + 3 hits
    assert json.loads(json_file.read_text())["session"]["hits"] == 3
    html, table = _wait(panel.report("first"))
    assert html.name == "first-report.html" and "<html" in html.read_text()
    assert table.name == "first-features.csv" and table.read_text().startswith("feature,kind,method,hits,")
    assert panel.last_files == [html, table]
    _wait(panel.reevaluate("first", "first-r12", tip_radius=1.2, method="ls"))
    rows = {r["name"]: r for r in panel.sessions()}
    assert rows["first-r12"]["hits"] == 3 and rows["first-r12"]["features"] == 1
    from cmm.journal.store import load_session

    derived = load_session(panel.store(), "first-r12")
    assert derived.start["tip_radius"] == pytest.approx(1.2) and derived.derived_from["session"] == "first"
    assert panel.reevaluate("first", "first-r12") is None  # the name is taken
    assert "already exists" in operator.messages[-1][2]


def test_observer_is_refused(app, operator, recorded):
    observer = app.add_client(client_id="observer-s", is_local=False)
    panel = observer.sessions
    before = {r["name"] for r in panel.sessions()}
    assert not panel.rename("first", "stolen")
    assert not panel.delete("first")
    assert panel.new_session("observer-session") is None
    assert panel.reevaluate("first", "observer-r") is None
    assert all(level == "error" and "observes" in body for level, _, body in observer.messages)
    assert {r["name"] for r in panel.sessions()} == before
    assert panel.live_name() == operator.sessions.live_name()
    _wait(panel.open("first"))  # looking is open to everyone
    assert len(panel.state.hits) == 3


def test_describe_event_words():
    assert describe_event({"kind": "hit", "id": 4, "mode": "manual", "point": [1, 2, 3]}).startswith("hit 4 (manual)")
    assert "deleted" in describe_event({"kind": "hit_deleted", "id": 2, "undo": True})
    assert "form 1.50 um" in describe_event({"kind": "feature", "name": "plane 1", "feature_kind": "plane",
                                             "method": "ls", "hit_ids": [1, 2, 3], "form": 0.0015})
    assert "error (machine:limit)" in describe_event({"kind": "error", "source": "machine:limit", "message": "x"})


def test_browser_tab_builds_tabs_and_draws_replay(app, operator, recorded):
    with ui_support.viser_tab(app) as (ws, capp):
        assert {"list", "session", "scrub", "event"} <= set(capp.sessions.gui)
        assert "first" in capp.sessions.gui["session"].options
        _wait(capp.sessions.open("first"))
        assert capp.sessions._view is not None and capp.sessions._view._nodes  # hits and the plane drawn
        assert capp.sessions.gui["scrub"].max == len(capp.sessions.replay) - 1
        capp.sessions._step("|◀")
        assert capp.sessions.index == 0 and not capp.sessions._view._nodes
        capp.sessions.back_to_live()
        assert capp.sessions._view._part is None
        for _ in range(5):
            try:
                ws.recv(timeout=0.05)
            except TimeoutError:
                pass


def test_qif_button_writes_valid_qif_results(app, operator, recorded):
    """The Report tab's "QIF 3 results": the session's QIF document in the sessions folder, valid against the
    QIF 3.0.0 schemas (skipped with the reason when ../shared/qif is absent), with the plane's flatness."""
    import qif_support
    from qif_support import NS

    qif_support.schema_or_skip()
    (path,) = _wait(operator.sessions.qif("first"))
    assert path.name == "first.qif" and operator.sessions.last_files == [path]
    root = qif_support.validate(path)
    assert root.find(".//q:PlaneFeatureItem/q:FeatureName", NS) is not None
    assert root.find(".//q:FlatnessCharacteristicMeasurement/q:Value", NS) is not None

"""The recorded sessions, the trends, the calibration and the part through the command API alone: what the page's
Sessions, Trends, Calibration, Part and Diagnostics tabs read with queries (open to observers) and change with
verbs (the control holder's), on the in-process simulator."""

from __future__ import annotations

import pytest

from cmm.control.access import Client, Control
from cmm.journal.store import open_store
from cmm.session.trends import TrendError, Trends

OPERATOR = Client("operator", local=True)
OBSERVER = Client("observer")  # a LAN tab that did not take control


@pytest.fixture(scope="module")
def station(module_stations, tmp_path_factory):
    root = tmp_path_factory.mktemp("api-sessions")
    trends = Trends(root / "trends", station="cmm-api")
    st = module_stations.station("first", home=False, session_dir=root / "sessions",
                                calibration_dir=root / "calibration", trends=trends)
    st.controller.use_policy_of(Control(lan=True, access_code="c0de"))
    api = st.controller.commands
    api.invoke(OPERATOR, "take_control")
    api.invoke(OPERATOR, "note", text="something recorded in the first session")
    api.invoke(OPERATOR, "new_session", name="second")
    yield st
    st.close()
    trends.close()


def test_the_session_store_and_its_sessions_are_queries_open_to_observers(station):
    api = station.controller.commands
    where = api.invoke(OBSERVER, "session_store")
    assert where == {"store": str(station.measurement.session_dir), "url": False, "live": "second",
                     "export_dir": str(station.measurement.session_dir)}
    rows = {r["name"]: r for r in api.invoke(OBSERVER, "sessions", wait=True)}
    assert set(rows) == {"first", "second"}
    assert rows["second"]["recording"] and not rows["first"]["recording"]
    assert rows["first"]["hits"] == 0 and rows["first"]["events"] >= 2  # its start and the note
    assert api.call(OBSERVER, "sessions").ok  # and as a request, JSON: plain data


def test_rename_and_delete_are_the_holders_and_never_touch_the_live_session(station):
    api = station.controller.commands
    store = open_store(station.measurement.session_dir)
    refused = api.call(OBSERVER, "rename_session", {"old": "first", "new": "stolen"})
    assert refused.error["code"] == "refused" and "observes" in refused.error["message"]
    assert store.exists("first") and not store.exists("stolen")
    live = api.call(OPERATOR, "rename_session", {"old": "second", "new": "other"})
    assert not live.ok and "being recorded" in live.error["message"] and store.exists("second")
    assert not api.call(OPERATOR, "rename_session", {"old": "first", "new": "no/slash"}).ok
    assert api.invoke(OPERATOR, "rename_session", old="first", new=" renamed ") == "renamed"
    assert store.exists("renamed") and not store.exists("first")
    assert {r["name"] for r in api.invoke(OBSERVER, "sessions", wait=True)} == {"renamed", "second"}

    assert api.call(OBSERVER, "delete_session", {"name": "renamed"}).error["code"] == "refused"
    assert "being recorded" in api.call(OPERATOR, "delete_session", {"name": "second"}).error["message"]
    assert api.invoke(OPERATOR, "delete_session", name="renamed") == "renamed"
    assert not store.exists("renamed") and store.exists("second")


def test_a_reevaluation_is_the_holders_and_refused_into_a_taken_name(station):
    api = station.controller.commands
    api.invoke(OPERATOR, "new_session", name="third")
    refused = api.call(OBSERVER, "reevaluate_session", {"name": "second", "new": "second-r"})
    assert refused.error["code"] == "refused"
    taken = api.call(OPERATOR, "reevaluate_session", {"name": "second", "new": "third"})
    assert "already exists" in taken.error["message"]
    bad = api.call(OPERATOR, "reevaluate_session", {"name": "second", "new": "second-r", "method": "guess"})
    assert "unknown fit method" in bad.error["message"]
    result = api.invoke(OPERATOR, "reevaluate_session", name="second", new="second-r", method="ls")
    assert result["hits"] == 0 and result["features"] == 0
    assert open_store(station.measurement.session_dir).exists("second-r")


def test_the_trends_are_queries(station):
    api = station.controller.commands
    trends = api.invoke(OBSERVER, "trends")
    assert trends == {"version": station.measurement.trends.version, "shared": False,
                      "directory": str(station.measurement.trends.directory)}
    series = api.invoke(OBSERVER, "trend_series")
    assert series["series"] == [] and "cmm-api" in series["status"]
    assert api.invoke(OBSERVER, "trend_options", series="none") == {"characteristics": [], "stations": []}
    kept, station.measurement.trends = station.measurement.trends, None
    try:  # a station that records no trends says so
        assert api.invoke(OBSERVER, "trends") is None
        with pytest.raises(TrendError, match="records no trends"):
            api.invoke(OBSERVER, "trend_series")
    finally:
        station.measurement.trends = kept


def test_the_calibration_is_read_with_queries_and_changed_by_the_holder(station):
    api = station.controller.commands
    run = api.invoke(OBSERVER, "calibration_run")
    assert run == {"running": False, "paused": False, "holding": False, "instruction": "", "resumable": False}
    records = api.invoke(OBSERVER, "calibration_records")
    assert records["directory"] == str(station.calibration.records_dir) and records["records"] == []
    assert records["qualified_probing_speed"] == station.config.speeds.probing  # nothing qualified yet
    cert = api.invoke(OBSERVER, "calibration_certificate", routine="probe")
    assert "certificate problem" in cert["text"] and cert["problem"]
    assert api.invoke(OBSERVER, "calibration_certificate", routine="servo")["problem"] is None
    names = [r["name"] for r in api.invoke(OBSERVER, "probes")["probes"]]

    assert api.call(OBSERVER, "add_probe", {"name": "Star1", "tip_diameter": 3.0}).error["code"] == "refused"
    added = api.invoke(OPERATOR, "add_probe", name="Star1", tip_diameter=3.0, stylus=[1.0, 0.0, 0.0])
    assert added == {"name": "Star1", "tip_diameter": 3.0, "stylus": [1.0, 0.0, 0.0]}
    rows = {r["name"]: r for r in api.invoke(OBSERVER, "probes")["probes"]}
    assert list(rows) == [*names, "Star1"] and rows["Star1"]["tip_radius"] is None and not rows["Star1"]["selected"]
    assert "already a probe" in api.call(OPERATOR, "add_probe", {"name": "Star1", "tip_diameter": 2.0}).error["message"]

    certificate = {"diameter": 25.0, "serial": "RS-9", "uncertainty_um": 0.1}
    assert api.call(OBSERVER, "set_sphere_certificate", certificate).error["code"] == "refused"
    assert "serial" in api.call(OPERATOR, "set_sphere_certificate", {**certificate, "serial": ""}).error["message"]
    entered = api.invoke(OPERATOR, "set_sphere_certificate", **certificate, form_um=0.05, certified="2026-03-12")
    assert entered["serial"] == "RS-9" and entered["uncertainty_um"] == pytest.approx(0.1)
    assert entered["certified"] == "2026-03-12" and "RS-9" in entered["text"]
    assert api.invoke(OBSERVER, "calibration_certificate", routine="probe")["problem"] is None
    assert api.invoke(OPERATOR, "bar_placed") is False  # no geometry set-up waits for the bar


def test_the_part_and_the_byte_trace_are_queries(station):
    api = station.controller.commands
    part = api.invoke(OBSERVER, "part")
    model = station.measurement.part
    assert part["name"] == model.name and part["pose"] == model.pose.tolist()
    assert part["description"] and api.call(OBSERVER, "part").ok  # plain data
    trace = api.invoke(OBSERVER, "trace", last=5).splitlines()  # the last packets on the link, one a line
    assert 0 < len(trace) <= 5 and all(" TX " in line or " RX " in line for line in trace)

"""The Calibration tab (cmm.ui.panel_calibration) on the in-process station app (simulator, loopback).

The served simulator runs in real time, so a full probe qualification
(~45 s even with a 13-point pattern) is not run here: the probe result view
and Save record are tested on a qualification analysed from synthetic tip
centres; the servo tuning (one axis, ~10 s) runs for real through the panel.
"""

from __future__ import annotations

import dataclasses

import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")

from cmm.calibration.probe import analyse_qualification, qualification_pattern  # noqa: E402
from cmm.calibration.records import load_probe_record, load_servo_record, load_sphere_certificate  # noqa: E402
from cmm.control import Refused  # noqa: E402
from cmm.ui.panel_calibration import residual_series, residual_svg  # noqa: E402

REPO = Path(__file__).resolve().parents[1]



@pytest.fixture(scope="module")
def records(tmp_path_factory):
    d = tmp_path_factory.mktemp("calibration")
    shutil.copytree(REPO / "calibration" / "artifacts", d / "artifacts")
    shutil.copy(REPO / "calibration" / "probe.toml", d / "probe.toml")
    return d


@pytest.fixture(scope="module")
def app(module_stations, records):
    station = module_stations.station(calibration_dir=records)
    assert station.calibration.directory == records
    return module_stations.app(station, pendant=False)


@pytest.fixture(scope="module")
def operator(app):
    capp = app.add_client(client_id="operator", is_local=True)
    assert capp.take_control()
    return capp


def _errors(capp, n=1):
    return [m for m in capp.messages if m[0] == "error"][-n:]


def test_panel_lists_records_and_certificate(app, operator, records):
    panel = operator.calibration
    rows = panel.records()
    probe = next(r for r in rows if r["kind"] == "probe")
    assert probe["date"] and "r_eff" in probe["result"]
    text = panel.records_markdown()
    assert "probe" in text and str(records) in text and "in force" in text
    assert "reference sphere" in panel.certificate_markdown("probe")
    assert "ball bar 300" in panel.certificate_markdown("geometry")
    assert "no artifact" in panel.certificate_markdown("servo")


def test_run_refused_for_observer_busy_machine_and_missing_certificate(app, operator, records, tmp_path):
    st = app.station
    observer = app.add_client(client_id="observer-c", is_local=False)
    assert observer.calibration.run("servo", axes=("x",)) is None
    assert "observes" in _errors(observer)[0][2]
    # the command API checks access too: an observer calling the station's calibration service directly
    with pytest.raises(Refused):
        st.calibration.run("observer-c", "servo", axes=("x",))
    assert not st.calibration.running
    # busy: a move is under way
    start = st.machine.state.position
    status = operator.go_to(start[0] + 20.0, start[1], start[2])
    assert status is not None
    assert operator.calibration.run("Servo tuning", axes=("x",)) is None
    assert "moving" in _errors(operator)[0][2]
    status.wait(20)
    # a missing certificate: refused before anything moves; the records and the settings stay
    before_text = (records / "probe.toml").read_text()
    before_settings = st.prober.settings
    st.calibration.directory = tmp_path  # no artifacts/ here
    try:
        assert "certificate problem" in operator.calibration.certificate_markdown("probe")
        assert operator.calibration.run("probe") is None
        level, title, body = _errors(operator)[0]
        assert "missing" in body and "previous calibration stays in force" in body
    finally:
        st.calibration.directory = records
    assert (records / "probe.toml").read_text() == before_text
    assert st.prober.settings is before_settings
    assert not operator.calibration.running and not st.machine.busy


def test_servo_tuning_proposes_and_applies_only_on_accept(app, operator, records):
    st = app.station
    panel = operator.calibration
    original = st.machine.modules[0].gains
    assert panel.accept_gains() is False  # nothing proposed yet
    job = panel.run("servo", axes=("x",))
    assert job is not None, operator.messages[-2:]
    assert panel.running
    assert operator.calibration.run("servo", axes=("y",)) is None  # one routine at a time
    assert job.wait(60) and job.error is None, job.error
    assert job.fraction == 1.0 and "nothing applied" in job.message
    routine, result = panel.result
    assert routine == "servo" and set(result.proposed) == {"x"}
    proposed = result.proposed["x"]
    text = panel.results_markdown()
    assert f"**{proposed.kp}**" in text and "Nothing is applied" in text
    assert st.machine.modules[0].gains == original  # NOT applied
    assert not (records / "servo.toml").exists()
    try:
        assert panel.accept_gains(), operator.messages[-2:]
        assert st.machine.modules[0].gains == proposed
        rec = load_servo_record(records / "servo.toml")
        assert rec.accepted and rec.gains["x"]["kp"] == proposed.kp
        assert "Accepted" in panel.results_markdown()
        assert any(r["kind"] == "servo" for r in panel.records())
    finally:
        from cmm.calibration.servo import apply_gains

        apply_gains(st.machine, {"x": original})


def _synthetic_qualification(cert, centre=(400.0, 300.0, 100.0), r_tip=1.0):
    normals = qualification_pattern((35.0, 80.0, 120.0), 12)
    polar = np.arccos(normals[:, 2])
    az = np.arctan2(normals[:, 1], normals[:, 0])
    pretravel = 0.002 + 0.0015 * np.sin(polar) ** 2 * np.cos(3 * az)  # 3-lobed kinematic probe
    t = np.asarray(centre) + normals * (cert.diameter / 2 + r_tip - pretravel)[:, None]
    return analyse_qualification(t, -normals, cert, nominal_tip_radius=r_tip)


def test_probe_results_view_and_save_applies(app, operator, records):
    st = app.station
    panel = operator.calibration
    cert = load_sphere_certificate(records / "artifacts" / "reference-sphere.toml")
    q = _synthetic_qualification(cert)
    panel.result = ("probe", q)  # what a finished run leaves
    text = panel.results_markdown()
    assert f"{q.record.tip_radius:.5f}" in text and "polar" in text
    series = residual_series(q)
    assert [round(p) for p, *_ in series] == [0, 35, 80, 120]
    svg = residual_svg(q)
    assert svg.startswith("<svg") and svg.count("<polyline") == 2 * (len(series) - 1)  # the pole has no azimuth
    path = panel.save_record()
    assert path == records / "probe.toml", operator.messages[-2:]
    saved = load_probe_record(path)
    assert saved.tip_radius == pytest.approx(q.record.tip_radius)
    assert st.prober.settings.tip_radius == pytest.approx(q.record.tip_radius)  # applied to the live station
    assert st.calibration.status["probe"]["tip_radius"] == pytest.approx(q.record.tip_radius)  # the status bar's
    assert st.prober.settings.pretravel.coefficients == pytest.approx(q.settings.pretravel.coefficients)
    assert any("probe" in line for line in st.calibration.log)
    observer = app.add_client(client_id="observer-save", is_local=False)
    observer.calibration.result = ("probe", q)
    assert observer.calibration.save_record() is None


def test_routine_failure_is_a_notification_and_changes_nothing(app, operator, records):
    """ISO test with the sphere looked for where there is none: SurfaceNotFound -> notification."""
    st = app.station
    panel = operator.calibration
    settings = st.prober.settings
    text = (records / "probe.toml").read_text()
    pos = st.machine.state.position
    job = panel.run("iso", approx_centre=(pos[0], pos[1], max(pos[2] - 40.0, 20.0)))
    assert job is not None, operator.messages[-2:]
    assert job.wait(40)
    assert job.error is not None
    level, title, body = _errors(operator)[0]
    assert "stopped" in title and "previous calibration stays in force" in body
    from cmm.calibration.service import calibration_errors

    assert isinstance(job.error, calibration_errors()), repr(job.error)  # an operator's error, not a crash
    assert panel.result is None
    assert st.prober.settings is settings and (records / "probe.toml").read_text() == text
    st.controller.reset(None)


def test_geometry_bar_placement(app, operator):
    """The station's calibration service places the bar on the simulator; on real hardware the tab shows the
    service's set-up instruction and its "Bar placed, continue" lets the routine go on."""
    from cmm.calibration.geometry import default_setups

    service = app.station.calibration
    panel = operator.calibration
    certs = service.certificates("geometry")
    setup = default_setups(lengths={k: c.length for k, c in certs.items()})[0]
    service.placer(certs)(setup)  # the simulator: the service places the bar itself, under the simulator's lock
    balls = app.station.sim._artifacts
    assert len(balls) == 2 and np.linalg.norm(balls[0].centre - np.array(setup.ball1)) < 1.0
    # on real hardware the routine waits for the operator's "Bar placed, continue"
    assert panel.bar_placed() is False and "no set-up is waiting" in _errors(operator)[0][2]
    # real hardware: the service is handed no simulator's bench (the operator places the bar)
    host, service.host = service.host, dataclasses.replace(service.host, bench=None)
    try:
        place = service.placer(certs)
        t = threading.Thread(target=place, args=(setup,))
        t.start()
        end = time.monotonic() + 30  # bounds, not pauses: a loaded machine schedules the thread late
        while not service.instruction and time.monotonic() < end:
            time.sleep(0.01)
        assert "set-up **X**" in service.instruction and t.is_alive()
        time.sleep(0.3)
        assert t.is_alive()  # still waiting
        observer = app.add_client(client_id="observer-bar", is_local=False)
        assert observer.calibration.bar_placed() is False and t.is_alive()  # only the operator in control
        assert panel.bar_placed()
        t.join(30)
        assert not t.is_alive() and service.instruction == ""
    finally:
        service.host = host


def test_geometry_waits_for_the_operator_in_the_machine_loop_and_cancel_changes_nothing(app, operator):
    """A real geometry run through the tab and the service (on "hardware": no simulator to place the bar): the
    routine waits in the machine loop for the bar, every tab shows the set-up, Cancel ends it with a message and
    the correction in force is the one before."""
    st = app.station
    panel = operator.calibration
    correction = st.machine.correction
    host, st.calibration.host = st.calibration.host, dataclasses.replace(st.calibration.host, bench=None)
    try:
        job = panel.run("geometry", repeats=1)
        assert job is not None, operator.messages[-2:]
        end = time.monotonic() + 30
        while not st.calibration.instruction and time.monotonic() < end:
            time.sleep(0.01)
        assert "set-up **X**" in st.calibration.instruction and not job.done
        assert st.controller.state.activity and "Machine geometry" in st.controller.state.activity  # a job of the loop
        other = app.add_client(client_id="other-tab", is_local=True)
        assert other.calibration.run("probe") is None  # one routine at a time, whichever tab
        panel.cancel()
        assert job.wait(10) and job.error is not None
        assert "cancelled" in str(job.error) and "previous calibration stays in force" in _errors(operator)[0][2]
        assert st.calibration.instruction == "" and not st.calibration.running
        assert st.machine.correction is correction
    finally:
        st.calibration.host = host
        st.controller.reset(None)

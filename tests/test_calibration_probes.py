"""Probes and styli from the Calibration tab, on the simulator's virtual clock: a fresh calibration folder (no
certificate, no records), the reference sphere's certificate entered in the page, a second stylus added and
qualified after a fault left the probe under the sphere, the probe list with the qualified radius, a
qualification paused and resumed and one resumed after an E-STOP, the probe name with each hit, and the I++
server's tool list."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytest.importorskip("viser")

from cmm.calibration.records import load_probe_record, load_sphere_certificate  # noqa: E402
from cmm.ippdme.backend import StationBackend  # noqa: E402
from cmm.ippdme.tools import Limits, ToolChanger  # noqa: E402
from cmm.journal.writer import read_events  # noqa: E402


@pytest.fixture(scope="module")
def fresh(module_stations, tmp_path_factory):
    folder = tmp_path_factory.mktemp("fresh-calibration")
    ui = module_stations.app(module_stations.station(calibration_dir=folder), pendant=False)
    operator = ui.add_client(client_id="operator", is_local=True)
    assert operator.take_control()
    return ui, operator, folder


def _errors(capp):
    return [m for m in capp.messages if m[0] == "error"]


def test_certificate_entered_in_the_page_lets_qualification_run(fresh):
    ui, operator, folder = fresh
    panel = operator.calibration
    assert "certificate problem" in panel.certificate_markdown("probe")
    assert "enter the sphere's diameter, serial and uncertainty" in panel.certificate_markdown("probe")  # here
    assert panel.run("probe") is None and "missing" in _errors(operator)[-1][2]
    # a wrong entry is refused with a sentence and writes nothing
    assert not panel.enter_certificate(25.0, "", 0.1)
    assert "serial" in _errors(operator)[-1][2]
    assert not panel.enter_certificate(25.0, "RS-7", 50.0)  # 50 um: not a sphere certificate's uncertainty
    assert "uncertainty" in _errors(operator)[-1][2]
    assert not (folder / "artifacts" / "reference-sphere.toml").exists()
    assert not panel.enter_certificate(25.0, "RS-7", 0.1, 0.0, "12/03/2026")
    assert "YYYY-MM-DD" in _errors(operator)[-1][2]
    assert not panel.enter_certificate(25.0, "RS-7", 0.1, 0.0, "2999-01-01")
    assert "in the future" in _errors(operator)[-1][2]
    assert not (folder / "artifacts" / "reference-sphere.toml").exists()
    assert panel.enter_certificate(25.0, "RS-7", 0.1, 0.05, "2026-03-12")
    cert = load_sphere_certificate(folder / "artifacts" / "reference-sphere.toml")
    assert (cert.diameter, cert.serial, cert.uncertainty) == (25.0, "RS-7", pytest.approx(0.0001))
    assert cert.certified == "2026-03-12" and cert.form == pytest.approx(0.00005)
    # on the simulator the set-up centre is where its sphere stands
    assert np.allclose(cert.approx_centre, ui.station.sim.settings.sphere_centre)
    text = panel.certificate_markdown("probe")
    assert "certificate problem" not in text and "RS-7" in text


def test_probe_list_add_select_and_qualify_after_a_fault(fresh):
    ui, operator, folder = fresh
    st = ui.station
    panel = operator.calibration
    rows = panel.probes()
    assert [r["name"] for r in rows] == ["Probe1"] and rows[0]["selected"] and rows[0]["tip_radius"] is None
    assert "not qualified" in panel.probes_markdown()
    assert not panel.add_probe("T 2", 2.0, "0, 0, -1")  # a space: refused with a sentence
    assert "letters, digits" in _errors(operator)[-1][2]
    assert not panel.add_probe("T2", 2.0, "0, 0, 0")
    assert "stylus vector" in _errors(operator)[-1][2]
    tip_d = 2 * st.config.probe.tip_radius
    assert panel.add_probe("T2", tip_d, "0, 0, -1")
    assert not panel.add_probe("T2", tip_d)  # the name is taken
    assert panel.add_probe("T5", tip_d, "1 0 0"), _errors(operator)[-1:]  # spaces between the numbers, too
    assert next(r for r in panel.probes() if r["name"] == "T5")["stylus"] in ((1.0, 0.0, 0.0), [1.0, 0.0, 0.0])
    assert panel.select_probe("T2"), _errors(operator)[-1:]
    assert st.measurement.probe_name == "T2"
    assert st.prober.settings.tip_radius == pytest.approx(tip_d / 2)  # not qualified: nominal radius
    # a stopped run left the probe under the sphere's equator, closer to its axis than the sphere's radius:
    # straight up from there runs into the sphere
    c = np.asarray(st.sim.settings.sphere_centre, float)
    under = c + np.array([9.0, 0.0, -16.0])
    st.controller.run_job("operator", "set-up", lambda: st.machine.move_path(
        [[c[0] + 40.0, c[1], st.machine.position[2]], [c[0] + 40.0, c[1], under[2]], under]).wait())
    assert np.allclose(st.machine.position, under, atol=0.05)
    st.controller.fault("test: the link dropped mid-routine")
    st.controller.reset("operator")
    job = panel.run("probe", per_ring=4, repeats=1)
    assert job is not None, _errors(operator)[-1:]
    assert job.wait(600) and job.error is None, job.error
    assert panel.result[1].probe == "T2" and panel.result[1].skipped == []
    path = panel.save_record()
    assert path == folder / "probe.toml"
    rec = load_probe_record(folder / "probes" / "T2.toml")
    assert rec.tip_radius == pytest.approx(st.prober.settings.tip_radius)  # in use for compensation
    assert abs(rec.tip_radius - tip_d / 2) < 0.01
    rows = {r["name"]: r for r in panel.probes()}
    assert rows["T2"]["tip_radius"] == pytest.approx(rec.tip_radius) and rows["T2"]["selected"]
    assert "RS-7" in rows["T2"]["sphere"] and rows["T2"]["expires"] > rows["T2"]["qualified_on"]
    assert rows["Probe1"]["tip_radius"] is None
    assert f"{rec.tip_radius:.5f} mm" in panel.probes_markdown()
    # back to Probe1 (nominal) and T2 again (its qualification, from its own record)
    assert panel.select_probe("Probe1")
    assert st.prober.settings.tip_radius == pytest.approx(tip_d / 2) and not (folder / "probe.toml").exists()
    assert panel.select_probe("T2")
    assert st.prober.settings.tip_radius == pytest.approx(rec.tip_radius)


def _wait(predicate, timeout, what):
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, f"{what} did not happen within {timeout} s"
        time.sleep(0.01)


def test_qualification_pauses_lifts_before_going_on_and_resumes_after_a_fault(fresh):
    """The qualification of T2 paused after a point holds the machine; Resume lifts to the safe height first. An
    E-STOP mid-pattern stops it with the points kept; Resume is refused until Reset, then measures only the rest."""
    ui, operator, folder = fresh
    st = ui.station
    panel = operator.calibration
    assert panel.select_probe("T2")
    safe_z = st.config.axis("z").max - 5.0
    # (tip Z, the run's progress message then), recorded on the machine loop: every sample reaches its
    # subscribers before the move it ends is judged done, so the top of a lift is seen while the run still says
    # it is lifting (the dispatcher's coalesced states can skip a lift the simulator's clock ran in a few ms).
    zs: list[tuple[float, str]] = []

    def lifted(during: str) -> bool:
        return any(z >= safe_z - 0.1 for z, m in zs if m.startswith(during))

    # On the simulator's clock the pattern runs faster than a test thread is sure to be scheduled on a busy
    # computer, so the machine loop (and the machine's clock) waits at point 3 until the pause has reached the
    # station, and at point 7 until the E-STOP has latched: the operator's presses land where the test says.
    at3, at7 = threading.Event(), threading.Event()

    def gate(state) -> None:
        message = panel.job.message if panel.job is not None else ""
        zs.append((float(state.position[2]), message))
        for point, event, done in ((3, at3, lambda: st.calibration.paused),
                                   (7, at7, lambda: st.machine.inhibit is not None)):
            if f"point {point} of 13" in message and not event.is_set():
                event.set()
                end = time.monotonic() + 120.0
                while not done() and time.monotonic() < end:
                    time.sleep(0.005)

    ungate = st.machine.subscribe(gate)
    try:
        job = panel.run("probe", per_ring=4, repeats=1)
        assert job is not None, _errors(operator)[-1:]
        _wait(at3.is_set, 300, "point 3")
        assert panel.pause()
        _wait(lambda: st.calibration.holding, 120, "the hold")
        held = (job.message, st.machine.position.copy(), st.machine.state.time)
        _wait(lambda: st.machine.state.time > held[2] + 1.0, 120, "a machine second of the hold")
        assert not job.done and job.message == held[0] and np.allclose(st.machine.position, held[1])
        assert held[1][2] < safe_z - 20  # it holds beside the sphere
        zs.clear()
        assert panel.resume()
        _wait(lambda: "point 5 of 13" in job.message, 300, "point 5")
        assert lifted("lifting to the clearance height after the pause")  # lifted clear before it went on
        _wait(at7.is_set, 300, "point 7")
        st.controller.emergency_stop("operator")
        assert job.wait(120) and job.error is not None
        assert "press Reset, then Resume qualification" in str(job.error)
        kept = len(st.calibration.checkpoint.points)
        assert 6 <= kept < 13
        assert not panel.resume()  # latched: refused with a sentence, nothing moves
        assert "emergency" in _errors(operator)[-1][2].lower() or "estop" in _errors(operator)[-1][2].lower()
        st.controller.reset("operator")
        zs.clear()
        assert panel.resume(), _errors(operator)[-1:]
        job = panel.job
        assert job.wait(600) and job.error is None, job.error
        assert lifted("lifting to the clearance height")  # the resumed run lifted first
        result = panel.result[1]
        assert result.probe == "T2" and result.skipped == [] and result.record.n_points == 13
        assert abs(result.record.tip_radius - st.config.probe.tip_radius) < 0.01
        assert st.calibration.checkpoint is None
        assert panel.save_record() is not None
    finally:
        ungate()


def test_hits_remember_their_probe_and_ippdme_lists_the_probes(fresh):
    ui, operator, folder = fresh
    st = ui.station
    c = np.asarray(st.sim.settings.sphere_centre, float)
    status = st.controller.probe("operator", c + [0, 0, 12.5], [0, 0, -1], frame="machine")
    hit = status.wait(60)
    assert hit is not None
    events = read_events(st.measurement.journal.path).events
    hits = [e for e in events if e.get("kind") == "hit"]
    assert hits and hits[-1]["probe"] == st.measurement.probe_name == "T2"
    backend = StationBackend(st.controller.commands)
    probes = dict(backend.probes())
    assert set(probes) == {"Probe1", "T2", "T5"}  # T5: added with its stylus along +X
    assert probes["T2"] == pytest.approx(st.prober.settings.tip_radius)
    tools = ToolChanger.build(Limits.from_config(st.config), backend.probes())
    assert {"Probe1", "T2"} <= set(tools.names())
    assert tools.select("T2", "ChangeTool").radius == pytest.approx(st.prober.settings.tip_radius)


def test_ippdme_enumtools_and_changetool_use_the_station_probes(fresh):
    """Over the I++ protocol: EnumTools lists the station's probes, one added after the server started is listed
    from the next session on, and ChangeTool makes a station probe the one in use."""
    from cmm.ippdme.client import IppClient
    from cmm.ippdme.server import IppServer

    ui, operator, folder = fresh
    st = ui.station
    operator.release_control()  # the I++ client takes the station's control
    server = IppServer(StationBackend(st.controller.commands), "127.0.0.1", 0).start()
    client = IppClient("127.0.0.1", server.port, timeout=60)
    try:
        assert client.call("StartSession()").ok
        assert {'"Probe1"', '"T2"'} <= set(client.call("EnumTools()").data)
        assert client.call('ChangeTool("Probe1")').ok
        assert st.measurement.probe_name == "Probe1"
        assert st.prober.settings.tip_radius == pytest.approx(st.config.probe.tip_radius)  # Probe1: nominal
        assert client.call('ChangeTool("T2")').ok
        assert st.measurement.probe_name == "T2"
        assert st.prober.settings.tip_radius == pytest.approx(load_probe_record(folder / "probes" / "T2.toml").tip_radius)
        assert client.call("EndSession()").ok
        st.calibration.add_probe("T3", 3.0, (1.0, 0.0, 0.0))
        assert client.call("StartSession()").ok
        assert '"T3"' in client.call("EnumTools()").data
        assert client.call("EndSession()").ok
    finally:
        client.close()
        server.close()


def test_a_restarted_station_uses_the_selected_probe(fresh, stations, tmp_path):
    ui, operator, folder = fresh
    t2 = load_probe_record(folder / "probes" / "T2.toml")
    for name, radius in (("T2", t2.tip_radius), ("T3", 1.5)):  # qualified; never qualified: nominal D 3 mm
        assert ui.station.calibration.select_probe(None, name)
        again = stations.station(start=False, session_dir=tmp_path / name, calibration_dir=folder)
        try:
            assert again.measurement.probe_name == name
            assert again.prober.settings.tip_radius == pytest.approx(radius)
        finally:
            again.close()


def test_the_probe_list_defines_and_qualifies_a_4_mm_stylus_that_the_simulator_mounts(fresh):
    ui, operator, folder = fresh
    st = ui.station
    panel = operator.calibration
    assert operator.take_control()  # the I++ test above handed the station's control to its client
    assert panel.add_probe("PROBE6", 4.0, "0, 0, -1"), _errors(operator)[-1:]
    assert panel.select_probe("PROBE6"), _errors(operator)[-1:]
    assert st.sim.world.probe.tip_radius == 2.0  # the simulator's head carries the 4 mm stylus now
    job = panel.run("probe", per_ring=4, repeats=1)
    assert job is not None, _errors(operator)[-1:]
    assert job.wait(600) and job.error is None, job.error
    assert panel.result[1].probe == "PROBE6"
    panel.save_record()
    rec = load_probe_record(folder / "probes" / "PROBE6.toml")
    assert rec.tip_radius == pytest.approx(2.0, abs=0.01)  # qualified on the sphere with the 4 mm ball
    row = next(r for r in panel.probes() if r["name"] == "PROBE6")
    assert row["tip_diameter"] == 4.0 and row["tip_radius"] == pytest.approx(rec.tip_radius) and row["selected"]

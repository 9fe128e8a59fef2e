"""The command API every front end goes through: one access rule, the motion rails (frames, the clearance plane,
straight lines only when proven free, a restart that backs off first), the jog-hold pipeline, and the same probe
through the I++ server, the pendant and the viser page with the same hit."""

from __future__ import annotations

import json

import numpy as np
import pytest
import session_support as sup
import trimesh

from cmm.control import OpenPolicy, Refused
from cmm.control.access import Client, Control, HolderPolicy, OriginPolicy, is_local_connection, is_loopback_host
from cmm.control.rails import clearance_route, probe_clearance, route, straight_blocked, to_frame, to_machine
from cmm.ippdme.backend import StationBackend
from control_support import wait_idle

SIM = "sim://?cmm=1&pace=25"  # the in-process simulated CMM on its virtual clock, paced for threaded waits


# --- access: one rule for every front end ------------------------------------------------------------

def test_one_local_rule_for_web_pages_and_the_ippdme_server(stations):
    assert is_local_connection(("127.0.0.1", 5000), "127.0.0.1:8080")
    assert is_local_connection(("::ffff:127.0.0.1", 5, 0, 0), "localhost:8080")
    assert not is_local_connection(("127.0.0.1", 5000), "station.example:8080")  # a page naming another host
    assert not is_local_connection(("10.0.0.7", 5000), "127.0.0.1:8080")
    assert is_local_connection("127.0.0.5") and is_local_connection("::1") and not is_local_connection("10.0.0.7")
    # a listening address: loopback-only (no access code, local pages only) or beyond this PC, by the same rule
    assert all(is_loopback_host(h) for h in ("127.0.0.1", "localhost", "::1"))
    assert not any(is_loopback_host(h) for h in ("0.0.0.0", "", "::", "192.168.1.9"))

    station = stations.station(start=False)
    try:
        backend = StationBackend(station.controller.commands)  # the I++ backend gets the command API only
        assert backend.for_client("127.0.0.1:4000").client.local
        assert backend.for_client("[::1]:4000").client.local
        assert not backend.for_client("192.168.1.9:4000").client.local
    finally:
        station.close()


def test_the_stations_own_pages_may_connect_across_its_ports_and_no_other_page():
    origins = OriginPolicy()
    origins.ports.add(8080)  # the viser page's port: its hold refresher talks to the pendant port
    assert origins.check({"Host": "127.0.0.1:8081", "Origin": "http://127.0.0.1:8080"}) is None
    assert origins.check({"Host": "127.0.0.1:8081", "Origin": "http://127.0.0.1:8081"}) is None
    assert "another web page" in origins.check({"Host": "127.0.0.1:8081", "Origin": "http://127.0.0.1:9999"})
    assert "another web page" in origins.check({"Host": "127.0.0.1:8081", "Origin": "http://evil.example:8080"})


def test_the_holder_policy_refuses_observers_and_lets_everyone_local_stop():
    control = Control(lan=True, access_code="c0de")
    policy = HolderPolicy(control)
    assert control.take("tab", is_local=True)
    assert policy.refusal(Client("tab", local=True), "move") is None
    assert "observes" in policy.refusal(Client("pendant", local=True), "move")
    assert policy.refusal(Client("pendant", local=True), "stop") is None  # at the station PC: may always stop
    assert "access code" in policy.refusal(Client("lan-tab"), "stop")  # an anonymous LAN observer may not
    assert policy.refusal(Client("lan-tab", authenticated=True), "estop") is None


# --- the motion rails, on a box part ----------------------------------------------------------------------

class Box:
    """A 100 x 80 x 40 mm block whose part origin sits at machine (100, 50, 0)."""

    mesh = trimesh.creation.box(extents=(100.0, 80.0, 40.0), transform=trimesh.transformations.translation_matrix(
        (50.0, 40.0, 20.0)))
    pose = trimesh.transformations.translation_matrix((100.0, 50.0, 0.0))

    def part_pose(self):
        return self.pose

    def clearance_z(self):
        return 51.0  # top 40 + 10 + tip radius 1

    def surface_distance(self, points):
        from cmm.metrology.mesh import signed_deviation

        return signed_deviation(self.mesh, points, self.pose).deviations


def test_part_coordinates_go_through_the_part_pose_and_back():
    box = Box()
    assert np.allclose(to_machine([10.0, 20.0, 45.0], "part", box), [110.0, 70.0, 45.0])
    assert np.allclose(to_frame([110.0, 70.0, 45.0], "part", box), [10.0, 20.0, 45.0])
    with pytest.raises(ValueError, match="'machine' or 'part'"):
        to_machine([1, 2, 3], "Machine ", box)
    with pytest.raises(ValueError, match="need a part"):
        to_machine([1, 2, 3], "part", None)


def test_a_move_climbs_to_the_clearance_plane_travels_and_descends():
    here, target = np.array([120.0, 60.0, 20.0]), np.array([180.0, 110.0, 42.0])
    legs = clearance_route(here, target, 51.0, 300.0)
    assert [list(p) for p in legs] == [[120.0, 60.0, 51.0], [180.0, 110.0, 51.0], [180.0, 110.0, 42.0]]
    assert len(clearance_route([0.0, 0.0, 80.0], [10.0, 0.0, 80.0], 51.0, 300.0)) == 1  # above it: one leg


def test_a_straight_line_is_accepted_only_when_proven_free_of_the_part():
    box = Box()
    inside_to_across = ([110.0, 60.0, 20.0], [250.0, 60.0, 20.0])  # starts beside a wall... through the block
    assert "passes" in straight_blocked(box, [90.0, 60.0, 20.0], [210.0, 60.0, 20.0], 1.0)
    assert straight_blocked(box, [90.0, 60.0, 45.0], [210.0, 60.0, 45.0], 1.0) is None  # 5 mm above the top
    assert "passes" in straight_blocked(box, [90.0, 60.0, 41.2], [210.0, 60.0, 41.2], 1.0)  # 0.2 mm: too close
    with pytest.raises(ValueError, match="clearance path"):
        route(inside_to_across[0], inside_to_across[1], path="straight", workspace=box, radius=1.0, z_max=300.0)
    # after a contact the route backs off first, then goes over the plane even when a straight line was asked for
    legs = route([90.0, 60.0, 45.0], [210.0, 60.0, 45.0], path="straight", workspace=box, radius=1.0, z_max=300.0,
                 backoff=[-1.0, 0.0, 0.0], restart=True)
    assert np.allclose(legs[0], [89.0, 60.0, 45.0]) and np.allclose(legs[1], [89.0, 60.0, 51.0])


def test_a_hop_goes_straight_or_over_its_height_only_where_proven_free_else_over_the_plane():
    box = Box()  # top at Z 40, front face at Y 50, back face at Y 130; tip radius 1

    def height(here, pre, hop, **kw):
        return probe_clearance(here, pre, path="clearance", workspace=kw.pop("workspace", box), radius=1.0,
                               clearance_z=kw.pop("clearance_z", 60.0), hop_z=hop, **kw)

    on_top = ([120.0, 70.0, 42.0], [180.0, 110.0, 43.0])  # a retract and the next pre-hit point over the top face
    assert height(*on_top, 42.0) is None  # straight: 2 mm over the top all along
    assert height(*on_top, None) == 60.0  # no hop asked for: over the clearance plane
    front_to_back = ([150.0, 48.0, 20.0], [150.0, 133.0, 20.0])  # the straight line goes through the block
    assert height(*front_to_back, 42.0) == 42.0  # up the front face, 2 mm over the top, down the back face
    assert height(*front_to_back, 41.2) == 60.0  # 0.2 mm over the top: not proven, over the plane
    assert height(*front_to_back, 30.0) == 60.0  # through the block: over the plane
    assert height(*front_to_back, 30.0, clearance_z=None) == 51.0  # the part's plane
    assert height(*front_to_back, 42.0, restart=True) == 60.0  # after a contact: never a hop
    assert height(*on_top, 42.0, workspace=None) == 60.0  # without a part nothing is proven: no hop
    # a caller's clearance below the part's plane (a routine step's edited clearance): taken where proven free,
    # over the part's plane where it would cross the part
    assert height(*front_to_back, None, clearance_z=45.0) == 45.0  # 5 mm over the top: free
    assert height(*front_to_back, None, clearance_z=20.0) == 51.0  # through the block: the plane
    assert height(*front_to_back, None, clearance_z=20.0, workspace=None) == 20.0  # no part: the caller's


# --- the station: Go to after a bore cycle, a restart after a contact ----------------------------------

@pytest.fixture(scope="module")
def station(module_stations):
    return module_stations.station()


def _contacts(station):
    seen = []
    station.controller.subscribe(lambda kind, info: seen.append(info) if kind == "contact" else None)
    return seen


def test_go_to_in_part_coordinates_after_a_bore_cycle_retracts_and_arrives_without_contact(station):
    """The walk through the UI: a bore cycle leaves the tip inside the bore; Go to a point over the far side of the
    part, in part coordinates, used to cut straight through the block."""
    api, m = station.controller.commands, station.measurement
    contacts = _contacts(station)
    pose = m.part.pose
    for angle in (0.0, 90.0, 180.0, 270.0):  # four hits on the bore wall (part: axis (30, 40), radius 15) at z 20
        u = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle)), 0.0])
        point = pose[:3, :3] @ (np.array([30.0, 40.0, 20.0]) + 15.0 * u) + pose[:3, 3]
        m.probe(point, pose[:3, :3] @ u).wait(120)
    here = station.controller.frame_position("part")
    assert np.hypot(here[0] - 30.0, here[1] - 40.0) < 15.0 and here[2] < 25.0  # inside the bore
    target = [110.0, 10.0, 45.0]  # 5 mm over the top face, across the block
    refused = api.call("op", "move", {"target": target, "frame": "part", "path": "straight"})
    assert refused.error["code"] == "refused" and "clearance path" in refused.error["message"]
    done = api.call("op", "move", {"target": target, "frame": "part"}, wait=True, timeout=120)
    assert done.ok, done.error
    assert np.allclose(station.controller.frame_position("part"), target, atol=0.003)
    station.controller.dispatcher.flush()
    assert contacts == []


def test_a_move_after_a_contact_backs_off_first(station):
    api = station.controller.commands
    contacts = _contacts(station)
    pose = station.measurement.part.pose
    above = (pose @ np.array([60.0, 40.0, 45.0, 1.0]))[:3]
    assert api.call(None, "move", {"target": above, "frame": "machine"}, wait=True, timeout=120).ok
    into = (pose @ np.array([60.0, 40.0, 30.0, 1.0]))[:3]  # straight down into the top face: a plain move
    station.controller.workspace, workspace = None, station.controller.workspace  # a station that knows no part
    try:
        hit = api.call(None, "move", {"target": into, "frame": "machine", "path": "straight"}, wait=True, timeout=60)
    finally:
        station.controller.workspace = workspace
    station.controller.dispatcher.flush()  # events reach listeners on the dispatcher thread
    assert hit.error["code"] == "contact" and len(contacts) == 1
    station.controller.reset(None)
    back = api.call(None, "move", {"target": above, "frame": "machine", "path": "straight"}, wait=True, timeout=120)
    assert back.ok, back.error  # the retract first (the probe was deflected), then up and over: no new contact
    station.controller.dispatcher.flush()
    assert len(contacts) == 1 and np.allclose(station.controller.frame_position("machine"), above, atol=0.003)


def test_a_restart_after_a_fault_goes_over_the_clearance_plane_even_when_a_straight_line_was_asked_for(station):
    """A straight line 5 mm over the top face, clear of the boss, dome and cone: proven free, so it runs straight;
    after a fault (reset) the next move retracts to the clearance plane first, whatever was asked."""
    api, ctl = station.controller.commands, station.controller
    a, b = [10.0, 5.0, 45.0], [110.0, 5.0, 45.0]  # part coordinates
    assert api.call(None, "move", {"target": a, "frame": "part"}, wait=True, timeout=120).ok
    heights: list[float] = []
    station.sim.network.add_tick_hook(lambda net, tick: heights.append(station.sim.axis_readings()[2]))
    try:
        straight = api.call(None, "move", {"target": b, "frame": "part", "path": "straight"}, wait=True, timeout=120)
        assert straight.ok, straight.error
        top = station.measurement.part.pose[2, 3] + 45.0
        assert max(heights) < top + 0.01  # straight across, no climb
        ctl.fault("a test fault")
        ctl.reset(None)
        heights.clear()
        back = api.call(None, "move", {"target": a, "frame": "part", "path": "straight"}, wait=True, timeout=120)
        assert back.ok, back.error
        assert max(heights) > station.measurement.clearance_z() - 0.01  # retracted to the plane first
        assert np.allclose(ctl.frame_position("part"), a, atol=0.003)
    finally:
        station.sim.network.tick_hooks.pop()


def test_a_programmed_hit_whose_clearance_is_below_the_part_goes_over_the_plane_not_through_the_part(station):
    """A routine step's clearance edited to below the part's top (part Z 25, the top is at 40): the rapid from in
    front of the block to over the top face would cut through the front face at that height."""
    api, m = station.controller.commands, station.measurement
    pose = m.part.pose
    in_front = [60.0, -15.0, 20.0]  # part coordinates: 15 mm in front of the front face, half way up
    assert api.call(None, "move", {"target": in_front, "frame": "part"}, wait=True, timeout=120).ok
    contacts = _contacts(station)
    low = float((pose @ np.array([0.0, 0.0, 25.0, 1.0]))[2])
    point = (pose @ np.array([60.0, 40.0, 40.0, 1.0]))[:3]
    hit = m.probe(point, pose[:3, :3] @ [0.0, 0.0, -1.0], clearance_z=low).wait(120)
    station.controller.dispatcher.flush()
    assert contacts == [], contacts
    assert abs(float((np.linalg.inv(pose) @ np.array([*hit.point, 1.0]))[2]) - 40.0) < 0.05  # on the top face


def test_routes_from_under_the_reference_sphere_step_out_before_they_climb(station):
    """A stopped qualification can leave the tip under the reference sphere's bulge: the next move's climb and the
    next hit's rapid went straight up into it ("unexpected probe contact"). Both step out from the sphere's axis
    first (horizontally, to the sphere + tip + margin), then climb and travel above it; previews show the same."""
    from cmm.control.rails import SPHERE_MARGIN

    api, m = station.controller.commands, station.measurement
    contacts = _contacts(station)
    c = np.array(station.bench.sphere_centre)
    r = station.bench.settings.sphere_diameter / 2
    keep = r + station.prober.settings.tip_radius + SPHERE_MARGIN
    under = c + [0.8 * r, 0.0, -0.85 * (r + station.prober.settings.tip_radius)]  # under the bulge, clear of it

    def go_under():  # as a qualification leaves it: beside the sphere first, then straight in under the bulge
        beside = c + [2 * keep, 0.0, under[2] - c[2]]
        for target, path in ((beside, "clearance"), (under, "straight")):
            assert api.call(None, "move", {"target": list(target), "frame": "machine", "path": path},
                            wait=True, timeout=120).ok
    go_under()
    away = (m.part.pose @ np.array([60.0, 40.0, 60.0, 1.0]))[:3]  # over the part's top face
    legs = station.controller.move_legs(list(away), frame="machine")
    assert legs[0][2] == pytest.approx(under[2], abs=0.005) and np.hypot(*(legs[0][:2] - c[:2])) == pytest.approx(keep, abs=0.01)
    assert all(p[2] >= c[2] + keep - 1e-6 for p in legs[1:3]), legs  # climbs, then travels above the sphere
    assert api.call(None, "move", {"target": list(away), "frame": "machine"}, wait=True, timeout=120).ok
    station.controller.dispatcher.flush()
    assert contacts == [], contacts
    go_under()
    point, down = away - [0.0, 0.0, 20.0], np.array([0.0, 0.0, -1.0])  # a hit on the top face from under the sphere
    (preview,) = station.controller.probe_paths([(point, down, None)])
    assert np.hypot(*(preview.rapid[0][:2] - c[:2])) == pytest.approx(keep, abs=0.01), preview.rapid
    hit = m.probe(point, down, clearance_z=None).wait(120)
    station.controller.dispatcher.flush()
    assert contacts == [], contacts
    assert abs(float((np.linalg.inv(m.part.pose) @ np.array([*hit.point, 1.0]))[2]) - 40.0) < 0.05


# --- the jog-hold pipeline ------------------------------------------------------------------------------

def test_the_jog_pipeline_clamps_and_says_so_and_refuses_what_is_not_a_velocity(station):
    jogs = station.controller.jogs
    fast = station.config.speeds.jog_fast
    v, note = jogs.clamp([1e308, 0.0, -5.0])
    assert list(v) == [fast, 0.0, -5.0] and "1e+308 mm/s limited" in note
    v, note = jogs.clamp([0.0, 0.0, -30.0], probe=True)
    assert np.linalg.norm(v) == pytest.approx(station.calibration.qualified_probing_speed) and "qualified" in note
    for bad in ([float("nan"), 0, 0], [1, 2], "fast"):
        with pytest.raises(Refused, match="three finite velocities"):
            jogs.hold(None, bad)


def test_a_hold_is_refused_for_an_observer_and_a_release_drops_older_holds(station):
    here = station.machine.position
    station.controller.move(None, [here[0], here[1], station.config.axis("z").max], frame="machine").wait(120)
    control = Control()
    station.controller.use_policy_of(control)
    try:
        with pytest.raises(Refused, match="observes"):
            station.controller.jogs.hold(Client("watcher", local=True), [1.0, 0.0, 0.0])
        # toward the end an axis stands at (Z at its top), an observer hears of control first
        with pytest.raises(Refused, match="Take control"):
            station.controller.jogs.hold(Client("watcher", local=True), [0.0, 0.0, 10.0])
        assert control.take("op", is_local=True)
        who = Client("op", local=True)
        ticket = station.controller.jogs.ticket(who)  # a front end took it when a hold arrived...
        station.controller.jogs.release(who)  # ... and the release came before that hold ran
        station.controller.jogs.hold(who, [5.0, 0.0, 0.0], after=ticket)
        wait_idle(station, 5)
        assert not station.machine.busy  # the late hold did not restart the released jog
    finally:
        station.controller.policy = OpenPolicy()


# --- the same probe through the three front ends ----------------------------------------------------------

def test_the_same_probe_through_the_ippdme_server_the_pendant_and_the_viser_page_gets_the_same_hit(station):
    from websockets.sync.client import connect

    from cmm.ippdme.client import IppClient
    from cmm.ippdme.server import IppServer
    from stations import station_page
    from netutil import free_port

    pose = station.measurement.part.pose
    top = (pose @ np.array([20.0, 15.0, 40.0, 1.0]))[:3]  # the sample part's top face, part (20, 15, 40)
    speed = station.config.speeds.probing
    app = station_page(station, host="127.0.0.1", port=free_port(), pendant_port=0)
    ipp = IppServer(StationBackend(station.controller.commands), "127.0.0.1", 0).start()
    hits = {}
    try:
        # the viser page: pick the point on the part, Probe here (along the picked normal)
        page = app.add_client(client_id="page", is_local=True)
        assert page.take_control()
        assert page.pick(top + [0.0, 0.0, 30.0], [0.0, 0.0, -1.0]) is not None
        status = page.probe_here()
        assert status is not None, page.messages[-3:]
        hits["viser page"] = np.asarray(status.wait(120).machine)
        page.release_control()
        # the pendant: the command API's probe verb, as a "call" message
        with connect(app.pendant.ws_url) as ws:
            ws.send(json.dumps({"type": "take"}))
            ws.send(json.dumps({"type": "call", "id": 7, "method": "probe", "wait": True, "params": {
                "target": top.tolist(), "approach": [0, 0, -1], "frame": "machine"}}))
            while True:
                msg = json.loads(ws.recv(timeout=120))
                if msg["type"] == "result":
                    break
            assert msg["id"] == 7 and "result" in msg, msg
            hits["pendant"] = np.asarray(msg["result"]["machine"])
        # the I++ DME server: PtMeas with the same probing speed (its straight rapid is proven free of the part).
        # A connecting client takes control only from a holder whose machine stands still (the pendant's retract
        # may still be settling in the last sample on a busy computer)
        sup.standing(station, "the axes after the pendant's probe")
        with IppClient("127.0.0.1", ipp.port, timeout=120) as c:
            for cmd in ("StartSession()", 'ChangeTool("Probe1")', f"SetProp(Tool.PtMeasPar.Speed({speed}))"):
                assert c.call(cmd).ok, cmd
            t = c.call(f"PtMeas(X({top[0]}), Y({top[1]}), Z({top[2]}), IJK(0, 0, 1))")
            assert t.ok, t.responses
            v = t.values()
            hits["I++ DME"] = np.array([v["X"][0], v["Y"][0], v["Z"][0]])
            c.call("EndSession()")
    finally:
        ipp.close()
        app.close()
    for name, hit in hits.items():  # the tip centre where the probe triggered: 1 mm (the tip) above the face
        assert hit == pytest.approx(hits["viser page"], abs=0.002), name
    assert hits["pendant"][2] == pytest.approx(top[2] + station.prober.settings.tip_radius, abs=0.05)


# --- cancel: whatever job runs ends cleanly, from any front end ------------------------------------------

def test_cancel_ends_a_running_auto_measure_after_the_hit_in_progress_from_another_front_end(station):
    """The page runs an auto-measure; the pendant at the station PC (an observer) sends ``cancel``: the run ends
    before its next hit with its hits recorded and the machine standing idle; an anonymous LAN observer may not
    cancel, and a cancel with nothing running says so."""
    import threading

    control = Control(lan=True, access_code="c0de")
    station.controller.use_policy_of(control)
    api, m = station.controller.commands, station.measurement
    try:
        assert control.take("page", is_local=True)
        page = Client("page", local=True)
        pose = m.part.pose
        top = (pose @ np.array([20.0, 15.0, 40.0, 1.0]))[:3]
        picked, _ = m.pick(top + [0.0, 0.0, 30.0], [0.0, 0.0, -1.0])
        first_hit, cancel_sent, result = threading.Event(), threading.Event(), {}

        def progress(k, n):
            if k == 1:
                first_hit.set()
                cancel_sent.wait(60)  # the cancel arrives while the first hit is the one in progress

        before = len(m.hits)
        run = threading.Thread(target=lambda: result.update(r=api.call(page, "auto_measure", {
            "face": int(picked.face_id), "n": 5, "name": "TOP", "progress": progress})))
        run.start()
        assert first_hit.wait(120)
        refused = api.call(Client("lan-tab"), "cancel")
        assert refused.error["code"] == "refused" and "access code" in refused.error["message"]
        done = api.call(Client("pendant", local=True), "cancel")
        cancel_sent.set()
        assert done.ok and done.result["cancelled"] == ["auto-measure of TOP"], done
        run.join(120)
        r = result["r"]
        assert r.error["code"] == "cancelled" and "after 1 of 5 hits" in r.error["message"], r
        assert len(m.hits) - before == 1 and "TOP" not in [f.name for f in m.features.values()]
        assert station.controller.jobs.descriptions() == []
        wait_idle(station, 30)
        assert station.controller.state.mode.value == "idle"  # ended between hits: nothing stopped, no fault
        again = api.call(None, "cancel")
        assert again.ok and again.result["cancelled"] == [] and "nothing was running" in again.result["message"]
    finally:
        station.controller.policy = OpenPolicy()


def test_cancel_ends_a_program_and_a_job_without_a_cancel_of_its_own(station, tmp_path):
    """A measurement program ends before its next hit; a job that has no cancel of its own (a DMIS run) is
    ended by a controlled stop of its move: either way the machine is left standing, nothing in fault."""
    import threading

    from cmm.program.toml_program import teach, to_toml
    from cmm.journal.store import open_session

    api, m = station.controller.commands, station.measurement
    pose = m.part.pose
    ids = []
    for x, y in ((20.0, 5.0), (100.0, 5.0), (20.0, 15.0)):  # three hits on the top face, a plane: the program
        p = (pose @ np.array([x, y, 40.0, 1.0]))[:3]
        ids.append(m.hit_id(m.probe(p, pose[:3, :3] @ np.array([0.0, 0.0, -1.0])).wait(120)))
    m.fit_feature("plane", ids, name="TOPPLANE")
    program = teach(open_session(m.journal.path), name="top")
    path = tmp_path / "top.toml"
    path.write_text(to_toml(program))
    started, result = threading.Event(), {}
    station.controller.subscribe(lambda kind, info: started.set() if kind == "hit" else None)
    run = threading.Thread(target=lambda: result.update(r=api.call(None, "run_program", {"path": str(path)})))
    run.start()
    assert started.wait(120)
    assert api.call(None, "cancel").result["cancelled"] == ["program 'top'"]
    run.join(120)
    assert result["r"].error["code"] == "cancelled" and "stay recorded" in result["r"].error["message"]

    far = np.array([station.config.axis(a).max - 5.0 for a in "xyz"])
    moving = threading.Event()

    def work(job):
        status = job.machine.move_to(far)
        moving.set()
        status.wait(120)
    run = threading.Thread(target=lambda: result.update(j=api.call(None, "run_job", {"description": "a long move",
                                                                                      "work": work})))
    run.start()
    assert moving.wait(60)
    assert api.call(None, "cancel").result["cancelled"] == ["a long move"]
    run.join(120)
    assert not result["j"].ok and result["j"].error["code"] in ("cancelled", "motion"), result["j"]
    wait_idle(station, 30)
    assert station.controller.state.mode.value in ("idle", "stopped")
    assert not np.allclose(station.controller.frame_position("machine"), far, atol=1.0)
    station.controller.reset(None)


def test_every_verb_the_control_core_registers_takes_the_parameters_it_lists(station):
    """A verb's listed parameters are what its function takes: a step sent as a request moves one step."""
    import inspect

    for verb in station.controller.commands.verbs():
        sig = inspect.signature(verb.fn)
        takes_any = any(p.kind is p.VAR_KEYWORD for p in sig.parameters.values())
        assert takes_any or set(verb.params) <= set(list(sig.parameters)[1:]), verb.name
    here = np.array(station.controller.frame_position("machine"))
    done = station.controller.commands.call(None, "step", {"axis": "x", "mm": 0.5}, wait=True, timeout=60)
    assert done.ok, done.error
    assert np.allclose(station.controller.frame_position("machine"), here + [0.5, 0.0, 0.0], atol=0.003)


def test_nominal_tolerance_datum_gdt_refit_and_report_header_are_verbs_checked_and_journalled(station):
    """The Features tab's edits as requests (the JSON shape an adapter sends): only the control holder may make
    them, each is journalled (the session replays to the same nominal, tolerance, datum and header), and a
    nominal the model cannot use is refused in a sentence with nothing changed."""
    from cmm.journal.store import open_session

    control = Control()
    station.controller.use_policy_of(control)
    api, m = station.controller.commands, station.measurement
    try:
        assert control.take("page", is_local=True)
        page, observer = Client("page", local=True), Client("other-tab", local=True)
        pose = m.part.pose
        ids = []
        for x, y in ((15.0, 10.0), (110.0, 15.0), (110.0, 70.0), (15.0, 70.0)):  # the top face
            hit = api.call(page, "probe", {"target": [x, y, 40.0], "approach": [0.0, 0.0, -1.0], "frame": "part"},
                           wait=True, timeout=120)
            assert hit.ok, hit.error
            ids.append(m.hit_id(hit.result))
        fitted = api.request(page, {"id": 1, "method": "measure_feature",
                                    "params": {"kind": "plane", "hits": ids, "name": "TOP"}})
        fid = fitted["result"]["id"]
        top = (pose @ np.array([0.0, 0.0, 40.0, 1.0]))[:3]
        normal = pose[:3, :3] @ np.array([0.0, 0.0, 1.0])
        nominal = {"kind": "plane", "point": top.tolist(), "normal": normal.tolist()}
        refused = api.request(observer, {"id": 2, "method": "set_nominal", "params": {"feature": fid,
                                                                                      "nominal": nominal}})
        assert refused["error"]["code"] == "refused" and "observes" in refused["error"]["message"]
        bad = api.call(page, "set_nominal", {"feature": fid, "nominal": {"kind": "blob"}})
        assert not bad.ok and "the nominal cannot be used" in bad.error["message"], bad
        assert api.call(page, "set_nominal", {"feature": fid, "nominal": nominal,
                                              "tolerance": {"form": 0.02}}).ok
        assert np.allclose(m.features[fid].nominal.params["point"], top)
        assert m.features[fid].tolerance == {"form": 0.02}
        refit = api.call(page, "refit_feature", {"feature": fid, "hits": ids[:3]})
        assert refit.ok and m.features[fid].hit_ids == ids[:3] and m.features[fid].tolerance == {"form": 0.02}
        assert api.call(page, "define_datum", {"label": "A", "feature": fid}).ok
        gdt = api.call(page, "define_gdt", {"characteristic": "flatness", "feature": fid, "tolerance": 0.05})
        assert gdt.ok, gdt.error
        definition, flatness = gdt.result
        assert flatness.actual < 0.05 and definition["id"] in m.gdt
        assert api.call(observer, "delete_gdt", {"gdt": definition["id"]}).error["code"] == "refused"
        assert api.call(page, "delete_gdt", {"gdt": definition["id"]}).ok and definition["id"] not in m.gdt
        assert api.call(page, "set_info", {"operator": "Maria", "temperature": "20.5"}).ok
        assert api.call(page, "set_info", {"colour": "red"}).error["code"] == "bad_params"
        state = open_session(m.journal.path).state
        assert state.features[fid].hit_ids == tuple(ids[:3]) and state.features[fid].tolerance == {"form": 0.02}
        assert np.allclose(state.features[fid].nominal["point"], top)
        assert state.datums["A"]["feature"] == fid and definition["id"] not in state.gdt
        assert state.info["operator"] == "Maria" and state.info["temperature"] == 20.5
    finally:
        station.controller.policy = OpenPolicy()


# --- the journal and the let-go: verbs with their access rules ---------------------------------------------

def test_an_observers_let_go_is_ignored_and_never_ends_the_holders_jog(station):
    """A key let go on a pendant that only observes (and was not jogging) is a let-go the core drops: no release
    reaches the machine, so it cannot end the holder's jog; the holder's let-go and a plain release are sent."""
    control = Control()
    station.controller.use_policy_of(control)
    api, ctl = station.controller.commands, station.controller
    try:
        assert control.take("op", is_local=True)
        op, watcher = Client("op", local=True), Client("watcher", local=True)
        before = ctl.release_seq(watcher), ctl.release_seq(op)
        assert api.invoke(watcher, "jog_release", let_go=True) is False
        assert api.invoke(watcher, "jog_hold", velocity=[0.0, 0.0, 0.0]) is None  # all zeros: a let-go too
        assert (ctl.release_seq(watcher), ctl.release_seq(op)) == before
        with pytest.raises(Refused, match=r"only observes \(not in control\).*press Take control to jog"):
            api.invoke(watcher, "jog_hold", velocity=[1.0, 0.0, 0.0])
        with pytest.raises(Refused, match="control is held by op; press Take control to jog"):
            api.invoke(watcher, "step", axis="x", mm=0.5)
        assert api.invoke(op, "jog_release", let_go=True) is True
        assert api.invoke(watcher, "jog_release") is True  # a release by STOP's rule: a local client may
        assert (ctl.release_seq(watcher), ctl.release_seq(op)) == (before[0] + 1, before[1] + 1)
    finally:
        station.controller.policy = OpenPolicy()


def test_the_journal_is_written_through_verbs_by_the_holder_or_at_the_station(station):
    """New session, note and a front end's own event are verbs: a note by the holder or a client at the station's
    own computer (or the station itself), never by an anonymous LAN observer; a new session by the holder only;
    a front end records only its own kinds of event (a routine saved), never a hit."""
    from cmm.journal.writer import read_events

    control = Control(lan=True, access_code="c0de")
    station.controller.use_policy_of(control)
    api = station.controller.commands
    try:
        assert control.take("op", "c0de", peer="10.0.0.5")  # a remote holder, with the access code
        op, desk, lan = Client("op", authenticated=True), Client("desk", local=True), Client("lan")
        path = api.invoke(op, "new_session", name="journal verbs")
        with pytest.raises(Refused, match="observes"):
            api.invoke(desk, "new_session", name="another")
        api.invoke(op, "note", text="by the holder")
        api.invoke(desk, "note", text="at the station")
        refused = api.call(lan, "note", {"text": "from the LAN"})
        assert refused.error["code"] == "refused" and "session journal" in refused.error["message"], refused
        api.invoke(op, "record_event", kind="routine_saved", data={"name": "block", "path": "block.toml", "text": "x"})
        bad = api.call(op, "record_event", {"kind": "hit", "data": {"id": 1}})
        assert not bad.ok and "routine_saved" in bad.error["message"], bad
        assert not api.call(desk, "record_event", {"kind": "routine_saved", "data": [1]}).ok
        api.invoke(None, "note", text="the station's own")
        # a remote I++ client that lost control to a browser: what its server saw still reaches the journal
        from cmm.ippdme.backend import StationBackend
        StationBackend(station.controller.commands, "ippdme 10.0.0.9:5000", local=False).end_session()
    finally:
        station.controller.policy = OpenPolicy()
    events = read_events(path).events
    assert events[0]["kind"] == "start" and path.name == "journal verbs.jsonl"
    assert [e["text"] for e in events if e["kind"] == "note"] == ["by the holder", "at the station", "the station's own",
                                                                   "I++ DME session ended"]
    assert [(e["name"], e["path"]) for e in events if e["kind"] == "routine_saved"] == [("block", "block.toml")]
    assert not any(e["kind"] == "hit" for e in events)


def test_pause_resume_and_skip_step_reach_the_running_job_for_the_holder_only(station):
    """A job that can hold (a routine, a probe qualification) registers its pause / resume / skip: the ``pause``
    verb is allowed like STOP, ``resume`` and ``skip_step`` only to the control holder; an anonymous observer is
    refused all three, and with nothing running the answer says so."""
    control = Control(lan=True, access_code="c0de")
    station.controller.use_policy_of(control)
    api, done = station.controller.commands, []
    holder, at_station, lan = Client("page", local=True), Client("pendant", local=True), Client("lan-tab")
    try:
        assert control.take("page", is_local=True)
        with station.controller.jobs.running("a routine", lambda: done.append("cancel"),
                                             pause=lambda: done.append("pause"), resume=lambda: done.append("resume"),
                                             skip=lambda: done.append("skip")):
            for verb in ("pause", "resume", "skip_step"):
                assert api.call(lan, verb).error["code"] == "refused"
            for verb in ("resume", "skip_step"):
                r = api.call(at_station, verb)
                assert r.error["code"] == "refused" and "Take control" in r.error["message"], r
            assert done == []
            assert api.call(at_station, "pause").result["paused"] == ["a routine"]
            assert api.call(holder, "resume").result["resumed"] == ["a routine"]
            assert api.call(holder, "skip_step").result["skipped"] == ["a routine"]
            assert done == ["pause", "resume", "skip"]
        with station.controller.jobs.running("a program", lambda: None):  # nothing to pause in it
            r = api.call(holder, "pause")
        assert r.ok and r.result["paused"] == [] and "nothing was running" in r.result["message"]
    finally:
        station.controller.policy = OpenPolicy()


def test_control_is_taken_and_released_through_verbs_and_the_ippdme_listener_grants_it(station):
    """``take_control`` / ``release_control`` for every front end: a LAN client needs the access code, a local one
    does not; an I++ connection takes control without a code only when its listener was opened to grant it (the
    operator's address at start-up), which the server is told where it is built, not in the adapter."""
    control = Control(lan=True, access_code="c0de")
    station.controller.use_policy_of(control)
    api = station.controller.commands
    try:
        r = api.call(Client("lan-tab"), "take_control", {"peer": "10.0.0.7"})
        assert r.error["code"] == "refused" and "access code" in r.error["message"], r
        assert api.call(Client("lan-tab"), "take_control", {"code": "c0de", "peer": "10.0.0.8"}).ok
        assert control.holder == "lan-tab"
        assert api.call(Client("pendant", local=True), "take_control").ok and control.holder == "pendant"
        assert api.call(Client("lan-tab"), "release_control").result["released"] is False
        assert api.call(Client("pendant", local=True), "release_control").result["released"] is True
        assert control.holder is None
        plain = StationBackend(station.controller.commands).for_client("192.168.1.9:4000")
        assert "access code" in plain.acquire() and control.holder is None
        opened = StationBackend(station.controller.commands, grants_control=True).for_client("192.168.1.9:4000")
        assert not opened.client.local and opened.acquire() is None
        assert control.holder == "ippdme 192.168.1.9:4000"
        opened.release()
        assert control.holder is None
    finally:
        station.controller.policy = OpenPolicy()


def test_the_pages_reads_are_queries_open_to_observers_and_documented(station):
    """What the page shows it reads through queries of the API (never the station's objects): the set-up, the link,
    whether this client may act (in the core's words), the probe data and the calibration's state; each is open to
    an observer. The access holder is handed over with the use_policy verb, which takes nothing else. Every query
    the station registers is in the architecture's table of queries."""
    import re
    from pathlib import Path

    api = station.controller.commands
    control = Control()
    with pytest.raises(ValueError):
        api.invoke(None, "use_policy", control="not an access holder")
    api.invoke(None, "use_policy", control=control)
    assert api.invoke(None, "control_policy") is control
    holder, observer = Client("holder", local=True), Client("observer", local=True)
    assert control.take("holder", is_local=True)
    try:
        assert api.invoke(holder, "access", command="move") is None
        why = api.invoke(observer, "access", command="move")
        assert why is not None and why == HolderPolicy(control).refusal(observer, "move")
        with pytest.raises(Refused, match=re.escape(why)):
            station.controller.check_access(observer, "move")
        assert api.invoke(observer, "machine_config").speeds == station.config.speeds
        assert api.invoke(observer, "link_info")["port"] == str(station.port)
        assert api.invoke(observer, "probe_settings").tip_radius == station.controller.tip_radius
        data = api.invoke(observer, "probe_data")
        assert data["tip_radius"] == station.measurement.probe_data()["tip_radius"]
        assert data["name"] == station.measurement.probe_name
        calibration = api.invoke(observer, "calibration_state")
        assert calibration["probing_speed"] == station.calibration.qualified_probing_speed
        assert calibration["holding"] is False
        assert api.invoke(observer, "samples") <= api.invoke(observer, "samples")
    finally:
        control.release("holder")
    doc = (Path(__file__).resolve().parents[1] / "docs" / "architecture.md").read_text()
    named = set(re.findall(r"`([a-z_]+)`", doc))
    assert sorted(v.name for v in api.queries() if v.name not in named) == []

"""Probing cycles on the simulated CMM: hits against the true geometry the simulator holds."""

import ast
import inspect
from dataclasses import replace

import numpy as np
import pytest

from cmm.machine import probing
from cmm.machine.config import load
from cmm.machine.motion import ContactError, Machine
from cmm.machine.probing import Prober, SurfaceNotFound
from cmm.machine.status import Cancelled, MotionError
from cmm.metrology.compensation import PretravelModel
from cmm.nmc import codec
from cmm.sim.cmm_sim import SimulatedCMM

COUNT = 0.002  # mm


def matched_pretravel(sim) -> PretravelModel:
    """The station's model of the simulated probe, exact for horizontal and vertical approaches."""
    p = sim.settings.probe
    return PretravelModel({"const": p.pretravel_xy, "s_cos3": p.pretravel_lobe, "z2": p.pretravel_z - p.pretravel_xy})


def part_to_machine(sim, xyz):
    return (sim.settings.part_pose @ np.append(xyz, 1.0))[:3]


def test_hits_on_the_top_face_lie_on_the_true_surface(sim_machine):
    sim, m, prober = sim_machine
    prober.settings.pretravel = matched_pretravel(sim)
    for xy in [(20, 15), (60, 75), (110, 10)]:  # around the bore, boss, dome and cone
        nominal = part_to_machine(sim, [*xy, 40.0])
        hit = prober.probe(nominal, [0, 0, -1], clearance_z=70.0).wait()
        assert abs(hit.point[2] - 40.0) <= 2 * COUNT
        assert hit.mode == "programmed" and hit.speed == m.config.speeds.probing
        assert hit.counts[2] == m.config.axes[2].to_counts(hit.machine[2])
    assert not m.state.probe_triggered  # retracted and re-seated


def test_hits_on_the_reference_sphere_lie_on_it(sim_machine):
    sim, m, prober = sim_machine
    prober.settings.pretravel = matched_pretravel(sim)
    c = np.array(sim.settings.sphere_centre)
    R = sim.settings.sphere_diameter / 2
    dirs = [np.array([np.cos(a), np.sin(a), 0.0]) for a in np.radians([0, 50, 130, 200, 290])] + [np.array([0, 0, 1.0])]
    for n in dirs:
        hit = prober.probe(c + R * n, -n, clearance_z=c[2] + R + 5).wait()
        assert abs(np.linalg.norm(np.array(hit.point) - c) - R) <= 2 * COUNT


def test_ten_hits_at_one_spot_repeat_within_one_count(sim_machine):
    sim, m, prober = sim_machine
    nominal = part_to_machine(sim, [40.0, 70.0, 40.0])
    zs = [prober.probe(nominal, [0, 0, -1]).wait().counts[2] for _ in range(10)]
    assert max(zs) - min(zs) <= 2  # +-1 count about the middle


def test_surface_not_found_in_the_air(sim_machine):
    _, m, prober = sim_machine
    hits = []
    prober.listeners.append(hits.append)
    with pytest.raises(SurfaceNotFound, match="surface not found"):
        prober.probe([450.0, 50.0, 150.0], [0, 0, -1]).wait()
    assert hits == []
    assert not m.busy


def test_manual_hit_while_jogging_takes_the_motion_direction(sim_machine):
    sim, m, prober = sim_machine
    above = part_to_machine(sim, [60.0, 40.0, 43.0])
    m.move_to(above).wait()
    hits = []
    prober.listeners.append(hits.append)
    for _ in range(200):
        prober.jog_probe([0.0, 0.0, -1.0])
        m.run_for(0.05)
        if hits:
            break
    m.run_for(1.5)  # back-off
    assert len(hits) == 1
    hit = hits[0]
    assert hit.mode == "manual" and hit.approach == pytest.approx((0, 0, -1))
    assert abs(hit.point[2] - 40.0) <= 3 * COUNT  # nominal pre-travel model: constant 0
    assert m.position[2] > hit.machine[2] + 0.5
    assert not m.state.probe_triggered


def test_bad_probe_requests_are_refused(sim_machine):
    _, _, prober = sim_machine
    with pytest.raises(Exception, match="approach direction"):
        prober.probe([100, 100, 40], [0, 0, 0])
    with pytest.raises(Exception, match="outside the travel"):
        prober.probe([100, 100, 299.5], [0, 0, 1])


def test_the_guarded_move_returns_latched_counts_or_none(sim_machine):
    sim, m, _ = sim_machine
    top = part_to_machine(sim, [60.0, 40.0, 40.0])
    m.move_to(top + [0, 0, 2.0]).wait()
    latched = m.probing_move(top - [0, 0, 1.0], 2.0, 400.0).wait()
    assert len(latched) == 3 and all(isinstance(c, int) for c in latched)
    assert m.config.axes[2].to_mm(latched[2]) == pytest.approx(40.0 + m.config.probe.tip_radius, abs=0.05)
    assert m.state.probe_triggered and not m.busy  # stopped on the trigger tick, resting on the part
    with pytest.raises(ContactError, match="deflected"):
        m.probing_move(top + [0, 0, 3.0], 2.0, 400.0)
    m.move_to(top + [0, 0, 2.0], protect=False).wait()
    assert m.probing_move(top + [0, 0, 4.0], 2.0, 400.0).wait() is None  # away from the part: no trigger


def _spy_guarded_moves(m) -> list:
    started = []
    plain = m.probing_move

    def spy(*args, **kwargs):
        started.append(plain(*args, **kwargs))
        return started[-1]

    m.probing_move = spy
    return started


def _run_until(m, condition, seconds: float) -> None:
    end = m.clock.now() + seconds
    while not condition() and m.clock.now() < end:
        m.poll()
        m.clock.sleep(m.poll_pause)
    assert condition()


def test_cancelling_a_probe_cycle_stops_its_guarded_move(sim_machine):
    _, m, prober = sim_machine
    started = _spy_guarded_moves(m)
    cycle = prober.probe([450.0, 50.0, 150.0], [0, 0, -1])
    _run_until(m, lambda: bool(started), 10.0)
    m.run_for(0.3)
    cycle.cancel()
    assert started[0].done and isinstance(started[0].error, Cancelled)
    with pytest.raises(Cancelled, match="probe at X=450.000"):
        cycle.wait()
    m.run_for(0.3)
    assert not m.busy and all(a.velocity == 0 for a in m.sample().axes)


def test_an_emergency_stop_during_the_guarded_move_ends_the_cycle(sim_machine):
    _, m, prober = sim_machine
    started = _spy_guarded_moves(m)
    cycle = prober.probe([450.0, 50.0, 150.0], [0, 0, -1])
    _run_until(m, lambda: bool(started), 10.0)
    m.run_for(0.2)
    m.emergency_stop()
    assert cycle.done  # it used to wait for a trigger that could no longer come
    with pytest.raises(MotionError, match="emergency stop"):
        cycle.wait()


def test_the_prober_uses_only_public_machine_members():
    tree = ast.parse(inspect.getsource(probing))
    private = sorted({node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)
                      and isinstance(node.value, ast.Name) and node.value.id == "m" and node.attr.startswith("_")})
    via_self = sorted({node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)
                       and isinstance(node.value, ast.Attribute) and node.value.attr == "machine"
                       and node.attr.startswith("_")})
    assert private == [] and via_self == []
    assert "_Motion" not in {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}


def _on_firmware(firmware: str):
    config = load()
    config = replace(config, link=replace(config.link, firmware=firmware,
                                          read_following_error=firmware == "pic-servo-sc"))
    sim = SimulatedCMM(config)
    m = Machine(config, sim.transport())
    m.connect()
    return sim, m


@pytest.mark.parametrize("firmware", ["pic-servo", "pic-servo-sc"])
def test_the_probe_on_limit1_stops_nothing_by_itself_on_either_firmware(firmware):
    sim, m = _on_firmware(firmware)
    try:
        if firmware == "pic-servo-sc":
            assert [mod.sc_io for mod in sim.network.modules] == [0x00] * 3  # no limit stop, no drive option
        else:
            assert [mod.io for mod in sim.network.modules] == [0x0C] * 3  # both LIMIT pins inputs
        errors = []
        m.on_event(lambda kind, info: errors.append(info) if kind == "error" else None)
        hit = Prober(m).probe(part_to_machine(sim, [60.0, 40.0, 40.0]), [0, 0, -1]).wait()
        assert abs(hit.machine[2] - 41.0) < 0.05
        st = m.sample()
        # the retract climbed with the stylus deflected (LIMIT1 active): the servos stayed on
        assert all(a.aux & codec.AUX_SERVO_ON and not a.status & codec.POS_ERROR for a in st.axes)
        assert not st.probe_triggered and st.position[2] > hit.machine[2] + 0.5 and errors == []
    finally:
        m.close()


def test_the_original_firmwares_inputs_byte_would_stop_an_sc_axis_on_the_probe():
    """Why the byte depends on the firmware: 0x0C on an SC turns the motor off while the probe is deflected."""
    sim, m = _on_firmware("pic-servo-sc")
    try:
        for mod in m.modules:
            mod.io_control(limit1_input=True, limit2_input=True)  # 0x0C, the original firmware's "both inputs"
        hit = Prober(m).probe(part_to_machine(sim, [60.0, 40.0, 40.0]), [0, 0, -1]).wait()
        st = m.sample()
        assert not st.axes[2].aux & codec.AUX_SERVO_ON  # Z went limp on the retract, still on the part
        assert st.probe_triggered and st.position[2] < hit.machine[2] + 0.1
    finally:
        m.close()


def _touch_while_braking(sim, m):
    """Jog +X at full speed toward the left face and let go inside the braking distance: the probe touches while
    the axes brake (no jog velocity left). Returns the face point (machine mm)."""
    r = m.config.probe.tip_radius
    face = part_to_machine(sim, [0.0, 20.0, 15.0])  # the left face (the part's x = 0), approached along +X
    fast = m.config.speeds.jog_fast
    braking = fast ** 2 / (2 * m.config.accelerations.stop)
    m.move_to(face - [r + 5.0, 0.0, 0.0]).wait()
    hits = []
    while m.position[0] < face[0] - r - braking * 0.5:  # held at full speed, then let go
        m.jog([fast, 0.0, 0.0], manual_probe=lambda latched, v: hits.append(latched))
        m.run_for(0.002)
    m.jog_release()
    m.run_for(0.5)
    assert m.state.probe_triggered and not hits  # a touch while braking: a contact stop, not a hit at a known speed
    return face


def _jog_on(m, v, seconds=1.0):
    """The operator holds a jog (refreshed every 10 ms); returns the refusal, if any."""
    for _ in range(round(seconds / 0.01)):
        try:
            m.jog(v)
        except ContactError as exc:
            return str(exc)
        m.run_for(0.01)
    m.run_for(0.3)
    return None


def test_a_touch_while_a_released_jog_brakes_is_not_jogged_through(sim_machine):
    """The operator lets go (or the dead-man stops the jog) just before the surface and the probe touches while
    the axes brake: the touch keeps the way the jog went, so a jog on into the part is refused while the probe is
    deflected (seen in the browser walk: an X+ jog then ran 95 mm through the part's left face), and one off the
    part frees the probe and is armed again, so the next touch stops it."""
    sim, m, prober = sim_machine
    face = _touch_while_braking(sim, m)
    stopped = m.position[0]
    fast = m.config.speeds.jog_fast
    assert "jog away from the part" in (_jog_on(m, [fast, 0.0, 0.0]) or "")
    assert m.position[0] == pytest.approx(stopped, abs=0.01)
    assert _jog_on(m, [-10.0, 0.0, 0.0], seconds=0.2) is None  # off the part: allowed, and armed once free
    assert not m.state.probe_triggered and m.position[0] < stopped - 1.0
    _jog_on(m, [10.0, 0.0, 0.0], seconds=1.0)  # back toward the face: the touch stops it
    assert m.state.probe_triggered
    assert m.position[0] == pytest.approx(face[0] - m.config.probe.tip_radius, abs=0.2)


def test_a_jog_with_the_probe_deflected_the_way_unknown_stops_if_it_stays_deflected(sim_machine):
    """Deflected with no touch direction known (the probe pushed by hand, a station restarted on the part): a jog
    runs unarmed, so it is watched: it stops within DEFLECTED_JOG_MM if the probe stays deflected, saying why."""
    from cmm.machine.jogging import DEFLECTED_JOG_MM

    sim, m, prober = sim_machine
    _touch_while_braking(sim, m)
    m._contact_dir = None  # the way it touched is not known
    stopped = m.position[0]
    _jog_on(m, [m.config.speeds.jog_fast, 0.0, 0.0], seconds=0.2)  # on into the part
    assert m.position[0] - stopped <= DEFLECTED_JOG_MM + 0.5  # its braking distance at full speed: 0.8 mm
    assert m.state.probe_triggered
    assert "jog away from the part" in (_jog_on(m, [10.0, 0.0, 0.0]) or "")  # the way it went in is known now

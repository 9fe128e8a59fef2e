"""The control core on the simulated CMM (virtual clock): state model, refusals, homing, safe state on failures."""

from __future__ import annotations

import errno
import time

import numpy as np
import pytest
from control_support import make_controller

from cmm.control import ControlError, Mode, Refused
from cmm.machine.status import MotionError
from cmm.nmc.bus import NmcError


@pytest.fixture
def rig():
    sim, ctl, port = make_controller(start_at=(3.0, 2.0, 297.0))
    yield sim, ctl, port
    port.broken = False
    ctl.close()


@pytest.fixture
def homed(rig):
    sim, ctl, port = rig
    ctl.home(None)
    return rig


def test_starts_not_homed_and_refuses_to_measure(rig):
    sim, ctl, _ = rig
    assert ctl.state.mode is Mode.NOT_HOMED and not ctl.state.homed
    with pytest.raises(Refused, match="not homed"):
        ctl.move(None, [100, 100, 200], frame="machine")
    with pytest.raises(Refused, match="not homed"):
        ctl.probe(None, [250, 190, 40], [0, 0, -1], frame="machine")
    assert "move" not in ctl.state.allowed and "home" in ctl.state.allowed


def test_homing_cycle_finds_the_switches():
    sim, ctl, _ = make_controller(start_at=(60.0, 40.0, 220.0))
    assert sim.axis_readings() == pytest.approx((60.0, 40.0, 220.0), abs=0.01)
    modes = []
    ctl.subscribe(lambda kind, info: modes.append(info["mode"]) if kind == "mode" else None)
    ctl.home(None)
    assert ctl.state.mode is Mode.IDLE and ctl.state.homed
    assert "homing" in modes
    # the counters now read the home coordinates where the switches are (X min, Y min, Z max)
    assert ctl.machine.position == pytest.approx([0.0, 0.0, 300.0], abs=0.003)
    assert sim.axis_readings() == pytest.approx((0.0, 0.0, 300.0), abs=0.003)
    ctl.move(None, [100.0, 50.0, 250.0], frame="machine").wait()
    assert sim.axis_readings() == pytest.approx((100.0, 50.0, 250.0), abs=0.003)
    ctl.close()


def _jog_into_the_top_face(ctl):
    """Jog down onto the part's top face (Z 40) until the probe touches; returns the refusal of the next jog."""
    ctl.move(None, [250.0, 190.0, 44.0], frame="machine").wait()  # 3 mm above it (tip radius 1)
    for _ in range(60):
        try:
            ctl.jog(None, [0.0, 0.0, -10.0])
        except MotionError as exc:
            return exc
        ctl.run_for(0.03)
    raise AssertionError("the jog never touched")


def test_zero_needs_confirmation_and_a_free_probe(homed):
    sim, ctl, _ = homed
    with pytest.raises(Refused, match="confirm"):
        ctl.zero(None)
    _jog_into_the_top_face(ctl)
    assert ctl.machine.sample().probe_triggered
    before = ctl.machine.position.copy()
    with pytest.raises(Refused, match="probe is deflected"):
        ctl.zero(None, confirm=True)
    assert ctl.machine.position == pytest.approx(before)
    ctl.move(None, [250.0, 190.0, 60.0], frame="machine").wait()  # away from the part
    ctl.zero(None, confirm=True)  # free probe, confirmed: here becomes the home coordinates
    assert ctl.machine.sample().position == pytest.approx([0.0, 0.0, 300.0])


def test_estop_is_latched_until_reset_and_says_it_worked(homed):
    sim, ctl, _ = homed
    status = ctl.move(None, [300.0, 200.0, 250.0], frame="machine")
    ctl.run_for(0.2)
    report = ctl.emergency_stop(None)
    assert report.ok and "amplifiers off" in report.message
    assert ctl.state.mode is Mode.ESTOPPED
    with pytest.raises(MotionError, match="emergency stop"):
        status.wait()
    with pytest.raises(Refused, match="emergency stop is latched"):
        ctl.move(None, [10.0, 10.0, 250.0], frame="machine")
    with pytest.raises(Refused, match="emergency stop is latched"):
        ctl.jog(None, [5.0, 0, 0])
    ctl.reset(None)
    assert ctl.state.mode is Mode.IDLE
    ctl.move(None, [10.0, 10.0, 250.0], frame="machine").wait()


def test_stop_reports_and_leaves_stopped(homed):
    sim, ctl, _ = homed
    status = ctl.move(None, [300.0, 200.0, 250.0], frame="machine")
    ctl.run_for(0.2)
    report = ctl.stop(None)
    assert report.ok
    with pytest.raises(MotionError, match="stopped by the operator"):
        status.wait()
    assert ctl.state.mode is Mode.STOPPED
    ctl.run_for(0.3)
    ctl.move(None, [10.0, 10.0, 250.0], frame="machine").wait()  # a new command is accepted after a stop
    assert ctl.state.mode is Mode.IDLE


def test_disconnect_during_a_jog_faults_and_the_horizon_stops_the_axis(homed):
    sim, ctl, port = homed
    ctl.move(None, [100.0, 100.0, 250.0], frame="machine").wait()
    for _ in range(10):
        ctl.jog(None, [40.0, 0.0, 0.0])
        ctl.run_for(0.03)
    x_at_drop = sim.axis_readings()[0]
    port.broken = True
    ctl.run_for(0.05)
    assert ctl.state.mode is Mode.FAULT and not ctl.state.link_ok
    assert "link failure" in ctl.state.reason
    with pytest.raises(Refused, match="fault"):
        ctl.jog(None, [40.0, 0.0, 0.0])
    ctl.run_for(1.0)  # nobody can reach the modules: they stop on their own at the horizon goal
    x_end = sim.axis_readings()[0]
    assert x_end - x_at_drop <= 40.0 * (ctl.config.jog.horizon + 0.03) + 0.05
    ctl.run_for(0.5)
    assert sim.axis_readings()[0] == pytest.approx(x_end, abs=0.002)
    with pytest.raises(Refused, match="Reconnect"):
        ctl.reset(None)
    port.broken = False
    ctl.run_for(0.5)  # the loop sees the link answer again
    assert ctl.state.link_ok and ctl.state.mode is Mode.FAULT
    ctl.reset(None)
    assert ctl.state.mode is Mode.IDLE and ctl.state.homed  # the modules kept power: positions are good


def test_stop_on_a_dead_link_says_it_did_not_work(homed):
    sim, ctl, port = homed
    port.broken = True
    report = ctl.stop(None)
    assert not report.ok and "NOT CONFIRMED" in report.message
    assert ctl.state.mode is Mode.FAULT
    report = ctl.emergency_stop(None)
    assert not report.ok and "NOT CONFIRMED" in report.message


def test_link_failure_in_a_command_is_a_clear_error_and_a_fault(homed):
    sim, ctl, port = homed
    port.broken = True
    with pytest.raises(ControlError, match="link to the modules failed"):
        ctl.move(None, [100.0, 100.0, 250.0], frame="machine")
    assert ctl.state.mode is Mode.FAULT


def test_failing_listeners_never_stop_the_loop(homed):
    sim, ctl, _ = homed
    ctl.subscribe(lambda kind, info: 1 / 0)
    ctl.subscribe_state(lambda state: 1 / 0)
    ctl.machine.subscribe(lambda state: 1 / 0)
    ctl.move(None, [100.0, 100.0, 250.0], frame="machine").wait()
    ctl.jog(None, [0.0, 10.0, 0.0])
    ctl.run_for(0.5)  # no refresh: the dead-man in the loop stops it
    assert ctl.state.mode is Mode.IDLE
    assert sim.axis_readings()[1] < 100.0 + 10.0 * 0.3


def test_full_disk_while_recording_a_hit_faults_and_stops(homed):
    sim, ctl, _ = homed

    def full(hit):
        raise OSError(errno.ENOSPC, "No space left on device")

    ctl.on_hit(full)
    status = ctl.probe(None, [250.0, 190.0, 40.0], [0, 0, -1], frame="machine", clearance_z=60.0)
    with pytest.raises(MotionError):
        status.wait(30)
    assert ctl.state.mode is Mode.FAULT
    assert "could not be recorded" in ctl.state.reason and "No space" in ctl.state.reason
    assert all(abs(a.velocity) < 1e-9 for a in ctl.machine.sample().axes)


def _faulty_homed_controller():
    """(sim, controller, fault-injecting port): homed, on the virtual clock, statuses drive the loop."""
    from cmm.control import Controller
    from cmm.machine.config import load
    from cmm.machine.motion import Machine
    from cmm.nmc.faults import FaultyTransport
    from cmm.sim.cmm_sim import SimulatedCMM
    from cmm.sim.home_switches import HomeSwitches

    config = load()
    sim = SimulatedCMM(config)
    HomeSwitches(sim)
    port = FaultyTransport(sim.transport(), seed=5)
    ctl = Controller(Machine(config, port))
    ctl.connect()
    ctl.home(None)
    return sim, ctl, port


@pytest.mark.parametrize("when", ["next leg of the rapid", "touch"])
def test_a_probe_cycle_ends_with_the_link_error_when_the_link_drops_between_its_moves(when):
    """The cable goes as the cycle sends its next move (a leg of the rapid, the retract after the touch).

    The cycle must end at once with the link failure and the machine in fault, not wait for a move
    that was never sent while the axes stand.
    """
    from cmm.nmc.faults import Fault

    sim, ctl, port = _faulty_homed_controller()
    try:
        machine = ctl.machine
        if when == "touch":
            ctl.prober.listeners.append(lambda hit: port.inject(Fault("disconnect", error="oserror")))
        else:
            sends, plain_move_to = [], machine.move_to

            def move_to(*args, **kwargs):
                sends.append(args[0])
                if len(sends) == 2:  # the first leg has ended; the second leg goes out on a dead link
                    port.inject(Fault("disconnect", error="serial"))
                return plain_move_to(*args, **kwargs)

            machine.move_to = move_to
        status = ctl.probe(None, [250.0, 190.0, 40.0], [0, 0, -1], frame="machine", clearance_z=290.0)
        try:
            result = status.wait(30)  # machine seconds: the whole cycle takes about 20
        except (MotionError, NmcError) as exc:  # the link failure itself, or the fault it caused
            assert when != "touch" and ("link" in str(exc) or "fault" in str(exc)), exc
        else:
            assert when == "touch" and result.point[2] == pytest.approx(40.0, abs=0.01)  # the latched hit stands
        ctl.run_for(0.1)
        assert status.done and ctl.state.mode is Mode.FAULT and "link failure" in ctl.state.reason
    finally:
        port.restore()
        ctl.close()


def test_unexpected_contact_while_jogging_stops_on_that_tick(homed):
    sim, ctl, _ = homed
    events = []
    ctl.subscribe(lambda kind, info: events.append(kind))
    refusal = _jog_into_the_top_face(ctl)
    assert "jog away from the part" in str(refusal)  # further down is refused while the probe is deflected
    assert "contact" in events
    z = ctl.machine.sample().position[2]
    assert 40.9 < z < 41.0  # the tip centre stopped at the surface (pre-travel), not pushed through it
    for _ in range(10):  # away from the part is allowed
        ctl.jog(None, [0.0, 0.0, 10.0])
        ctl.run_for(0.03)
    assert ctl.machine.sample().position[2] > 41.5 and not ctl.machine.state.probe_triggered


def test_probe_rapids_over_the_clearance_height(homed):
    """From beyond the part's right side to a hit on its left face (X 190): over the top, not through it."""
    sim, ctl, _ = homed
    ctl.move(None, [330.0, 190.0, 20.0], frame="machine").wait()  # beside the part
    path = []
    sim.network.add_tick_hook(lambda net, tick: path.append(sim.axis_readings()))
    hit = ctl.probe(None, [190.35, 190.0, 20.0], [1, 0, 0], frame="machine", clearance_z=60.0).wait(60)
    assert hit.point[0] == pytest.approx(190.0, abs=0.5)  # the left face (the part is turned half a degree)
    xyz = np.array(path)
    over = (xyz[:, 0] > 192.0) & (xyz[:, 0] < 312.0)
    assert over.any() and xyz[over, 2].min() > 59.9  # every point above the part's footprint is at clearance


def test_a_jog_goal_is_never_beyond_the_travel_even_if_nobody_polls_again(homed):
    """The modules themselves hold the limit. One jog command near the end of X, then silence."""
    sim, ctl, _ = homed
    ctl.move(None, [498.5, 100.0, 250.0], frame="machine").wait()
    ctl.jog(None, [40.0, 0.0, 0.0])  # the loaded goal: 0.12 s ahead would be 503.3; clamped to 500
    ctl.clock.sleep(1.0)  # the station is dead: no poll, no dead-man, no re-target
    assert sim.axis_readings()[0] == pytest.approx(500.0, abs=0.004)
    ctl.clock.sleep(0.5)
    assert sim.axis_readings()[0] == pytest.approx(500.0, abs=0.004)


def test_a_jog_stops_by_itself_one_horizon_ahead_when_the_loop_stalls(homed):
    sim, ctl, _ = homed
    ctl.move(None, [100.0, 100.0, 250.0], frame="machine").wait()
    for _ in range(10):
        ctl.jog(None, [0.0, 40.0, 0.0])
        ctl.run_for(0.03)
    y = sim.axis_readings()[1]
    ctl.clock.sleep(1.0)  # the loop stalls (GIL, a hung listener, kill -9): the module stops at its goal
    assert 0 < sim.axis_readings()[1] - y <= 40.0 * ctl.config.jog.horizon + 0.05


def test_reconnect_after_a_link_fault_keeps_positions_when_the_modules_kept_them(homed):
    sim, ctl, port = homed
    ctl.move(None, [100.0, 100.0, 250.0], frame="machine").wait()
    port.broken = True
    ctl.run_for(0.1)
    assert ctl.state.mode is Mode.FAULT and not ctl.state.link_ok
    port.broken = False
    ctl.reconnect(None)
    assert ctl.state.mode is Mode.IDLE and ctl.state.homed
    assert ctl.machine.sample().position == pytest.approx([100.0, 100.0, 250.0], abs=0.003)
    ctl.move(None, [110.0, 100.0, 250.0], frame="machine").wait()


def test_state_listeners_get_coalesced_states_and_every_move_end_at_once(homed):
    """During a move listeners get a state at most every STATE_INTERVAL of machine time, not one per sample;
    a move's end and every mode change reach them in the sample that shows it."""
    from cmm.control.core import STATE_INTERVAL

    from cmm.machine.motion import VIRTUAL_POLL_PAUSE

    sim, ctl, _ = homed
    ctl.machine.poll_pause = VIRTUAL_POLL_PAUSE  # samples several times per STATE_INTERVAL, as a jog's
    states = []
    ctl.subscribe_state(states.append)
    s0, t0 = ctl.machine.samples, ctl.machine.state.time
    ctl.move(None, [200.0, 150.0, 250.0], frame="machine").wait()
    samples, elapsed = ctl.machine.samples - s0, ctl.machine.state.time - t0
    assert len(states) < samples / 1.5  # coalesced
    assert len(states) <= elapsed / STATE_INTERVAL + 4
    gaps = np.diff([s.machine.time for s in states if s.machine.moving])
    assert gaps.max() < STATE_INTERVAL + 0.02  # positions still reach listeners at that rate
    last = states[-1]  # the sample that ended the move: idle, at the target
    assert last.mode is Mode.IDLE and last is ctl.state
    assert last.machine.position == pytest.approx([200.0, 150.0, 250.0], abs=0.003)
    assert [s.mode for s in states].count(Mode.MOVING) >= 1


def test_a_front_end_waits_for_a_slow_loop_and_gives_up_on_a_stuck_one(rig):
    """A busy computer makes the loop slow, not stuck: a command waits as long as the loop keeps stepping (here a
    command that keeps the loop sampling for many times the patience), and gives up only when no step comes."""
    import threading

    sim, ctl, _ = rig
    ctl.command_timeout = 0.5
    ctl.start()
    steps = 0

    def busy(setup):  # the loop is working: it samples, as a routine waiting on a move does, for 2 s or more
        nonlocal steps
        start = time.monotonic()
        while time.monotonic() - start < 2.0 or steps < 100:
            ctl.poll()
            steps += 1
            time.sleep(0.005)
        return setup.machine.position

    assert ctl.configure(None, busy) is not None
    assert steps >= 100
    release = threading.Event()
    try:
        with pytest.raises(ControlError, match="took no step for 0.5 s"):
            ctl.configure(None, lambda setup: release.wait(30))
    finally:
        release.set()
    assert ctl.configure(None, lambda setup: "again") == "again"  # the loop went on once free

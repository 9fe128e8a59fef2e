"""Machine layer on the simulated CMM, through the NMC byte stream."""

import logging

import numpy as np
import pytest

from cmm.machine.config import load
from cmm.machine.motion import ContactError, LimitError, Machine
from cmm.machine.status import MotionError
from cmm.nmc import codec
from cmm.nmc.bus import NmcError
from cmm.nmc.faults import Fault, FaultyTransport
from cmm.sim.cmm_sim import SimulatedCMM


def test_connect_sets_up_three_axes_at_home(sim_machine):
    sim, m, _ = sim_machine
    assert m.position == pytest.approx([0.0, 0.0, 300.0])
    assert [mod.gains.kp for mod in m.modules] == [m.config.axes[0].gains.kp] * 3
    st = m.sample()
    assert all(a.status & codec.POWER_ON and not a.status & codec.POS_ERROR for a in st.axes)
    assert all(a.aux & codec.AUX_SERVO_ON for a in st.axes)


def test_coordinated_move_is_a_straight_line_and_axes_arrive_together(sim_machine):
    sim, m, _ = sim_machine
    start = m.position
    target = np.array([120.0, 60.0, 250.0])
    status = m.move_to(target)
    off_line, done_at = [], [None, None, None]
    while not status.done:
        st = m.poll()
        p = st.position
        d = target - start
        s = np.dot(p - start, d) / np.dot(d, d)
        off_line.append(np.linalg.norm(p - (start + s * d)))
        for i, a in enumerate(st.axes):
            if a.status & codec.MOVE_DONE and done_at[i] is None:
                done_at[i] = st.time
    status.wait()
    assert max(off_line) < 0.05  # following error only: the axes share one time base
    assert max(done_at) - min(done_at) < 0.005
    assert m.position == pytest.approx(target, abs=0.0021)  # within 1 count
    assert np.abs(sim.tip_position() - target).max() < 0.003


def test_out_of_travel_and_nan_targets_refused_before_any_motion(sim_machine):
    _, m, _ = sim_machine
    before = len(m.bus.trace.entries())
    with pytest.raises(LimitError, match=r"target X=612.000 mm is outside the travel 0..500 mm"):
        m.move_to([612.0, 10.0, 100.0])
    with pytest.raises(LimitError, match="not a number"):
        m.move_to([float("nan"), 10.0, 100.0])
    sent = [e for e in m.bus.trace.entries()[before:] if e.direction == "tx"]
    assert not any("LOAD_TRAJ" in e.note for e in sent)


def test_move_status_cancel_stops_the_axes(sim_machine):
    _, m, _ = sim_machine
    status = m.move_to([400.0, 300.0, 300.0])
    m.run_for(0.5)
    status.cancel()
    m.run_for(0.5)
    p1 = m.position
    m.run_for(0.3)
    assert np.allclose(m.position, p1, atol=0.0021)
    assert p1[0] < 390
    with pytest.raises(MotionError, match="cancelled"):
        status.wait()


def test_motion_view_and_abort_are_the_control_cores_public_surface(sim_machine):
    """``machine.motion`` says what runs (kind, status) without handing out the machine's own record;
    ``abort(error)`` fails the running motion with that error (the caller stops the axes, here with ``halt``)."""
    _, m, _ = sim_machine
    assert m.motion is None and m.abort(MotionError("nothing")) is False
    status = m.move_to([200.0, 100.0, 250.0])
    m.run_for(0.2)
    view = m.motion
    assert view is not None and view.kind == "move" and view.status is status and not status.done
    with pytest.raises(AttributeError):
        view.kind = "jog"  # read-only
    m.halt("abrupt")
    assert m.abort(MotionError("fault: test")) is True
    assert m.motion is None and not m.busy and status.done
    with pytest.raises(MotionError, match="fault: test"):
        status.wait()
    m.run_for(0.1)
    p1 = m.sample().position
    m.run_for(0.3)
    assert np.allclose(m.position, p1, atol=0.0021) and p1[0] < 199  # stopped on the way, nothing running
    m.jog([5.0, 0.0, 0.0])
    assert m.motion.kind == "jog"
    m.stop()
    assert m.motion is None


def test_jog_dead_man_stops_within_200_ms(sim_machine):
    _, m, _ = sim_machine
    m.move_to([100.0, 100.0, 200.0]).wait()
    m.jog([20.0, 0.0, 0.0])
    for _ in range(10):  # refreshed every 50 ms: keeps moving
        m.run_for(0.05)
        m.jog([20.0, 0.0, 0.0])
    last_refresh = m.clock.now()
    x0 = m.position[0]
    m.run_for(0.05)  # still inside the dead-man time: full speed (the module reports whole counts per tick)
    assert (m.position[0] - x0) / (m.clock.now() - last_refresh) == pytest.approx(20.0, rel=0.1)
    events = []
    m.on_event(lambda kind, info: events.append(kind))
    stopped_at = None
    while m.clock.now() - last_refresh < 0.5:
        st = m.poll()
        if stopped_at is None and abs(st.axes[0].velocity) < 1e-9:
            stopped_at = st.time
    assert "deadman" in events
    assert stopped_at is not None and stopped_at - last_refresh <= 0.2
    assert not m.busy


def test_a_release_on_its_way_to_the_loop_is_not_overtaken_by_the_dead_man(sim_machine):
    """The control core posts a release (``release_now``) and the loop serves it before its next sample. A sample
    read meanwhile, past the dead-man's time since the last hold, leaves the stop to the release: the operator let
    go, and is not told "Jog stopped" for it."""
    _, m, _ = sim_machine
    deadman = m.config.deadman_timeout
    m.move_to([100.0, 100.0, 200.0]).wait()
    events = []
    m.on_event(lambda kind, info: events.append(kind))
    m.jog([20.0, 0.0, 0.0])  # the last hold
    m.run_for(0.8 * deadman)
    m.release_now()  # the let-go reached the control core: its release waits for the loop's next step
    m.clock.sleep(0.5 * deadman)  # the sample in hand ends past the dead-man's time since the last hold
    m.poll()
    assert "deadman" not in events
    m.jog_release()  # the loop's next step
    m.run_for(0.3)
    assert "deadman" not in events and not m.busy and m.sample().axes[0].velocity == 0
    # a release posted that never came keeps the dead-man back for one dead-man time at most
    m.jog([20.0, 0.0, 0.0])
    m.release_now()
    m.run_for(3 * deadman)
    assert events.count("deadman") == 1 and m.sample().axes[0].velocity == 0


def test_jog_release_and_step_jog_one_count(sim_machine):
    _, m, _ = sim_machine
    m.move_to([100.0, 100.0, 200.0]).wait()
    m.jog([0.0, -10.0, 0.0])
    m.run_for(0.2)
    m.jog_release()
    m.run_for(0.2)
    assert not m.busy and m.position[1] < 100.0
    y0 = m.sample().axes[1].counts
    m.step("y", 0.002).wait()
    assert m.sample().axes[1].counts == y0 + 1
    m.step("y", -10.0).wait()
    assert m.sample().axes[1].counts == y0 + 1 - 5000
    with pytest.raises(MotionError, match="between one count"):
        m.step("y", 11.0)


def test_unexpected_contact_during_rapid_stops_and_records_nothing(sim_machine):
    sim, m, prober = sim_machine
    hits = []
    prober.listeners.append(hits.append)
    m.move_to([250.0, 190.0, 60.0]).wait()  # above the part's top face (z 40)
    status = m.move_to([250.0, 190.0, 20.0])  # straight down into it
    with pytest.raises(ContactError, match="unexpected probe contact"):
        status.wait()
    m.run_for(0.1)
    assert hits == []
    assert m.position[2] == pytest.approx(41.0, abs=0.2)  # stopped right at the surface
    assert all(abs(a.velocity) < 1e-9 for a in m.state.axes)


def test_emergency_stop_turns_the_servos_off(sim_machine):
    _, m, _ = sim_machine
    status = m.move_to([300.0, 0.0, 300.0])
    m.run_for(0.3)
    m.emergency_stop()
    with pytest.raises(MotionError, match="emergency stop"):
        status.wait()
    m.run_for(0.2)
    assert all(not a.aux & codec.AUX_SERVO_ON for a in m.state.axes)
    m.reset()
    assert all(a.aux & codec.AUX_SERVO_ON for a in m.sample().axes)
    m.move_to([10.0, 0.0, 300.0]).wait()


def test_zero_and_home(sim_machine):
    sim, m, _ = sim_machine
    m.move_to([100.0, 50.0, 250.0]).wait()
    m.zero()  # the thesis's "Cero": here becomes the configured home coordinates
    assert m.position == pytest.approx([0.0, 0.0, 300.0])
    m.move_to([30.0, 20.0, 280.0]).wait()
    m.home().wait()
    assert m.position == pytest.approx([0.0, 0.0, 300.0], abs=0.0021)
    assert sim.axis_readings()[0] == pytest.approx(100.0, abs=0.003)  # physically back where Zero was taken


def test_jog_stops_inside_the_travel(sim_machine):
    _, m, _ = sim_machine
    m.move_to([5.0, 3.0, 200.0]).wait()
    events = []
    m.on_event(lambda kind, info: events.append(kind))
    for _ in range(40):  # full jog speed towards Y = 0, refreshed
        m.jog([0.0, -m.config.speeds.jog_fast, 0.0])
        m.run_for(0.05)
    m.jog_release()
    m.run_for(0.3)
    assert "limit" in events
    assert 0.0 <= m.position[1] < 1.5
    m.step("y", 0.1).wait()  # and it can still step


def test_velocity_mode_jog_for_firmware_without_goal_changes(stations):
    """[jog] mode = "velocity": the dead-man in the loop stops it, the travel limit watch too."""
    from dataclasses import replace

    from cmm.machine.config import load

    config = load()
    config = replace(config, jog=replace(config.jog, mode="velocity"))
    sim, m, _ = stations.machine(config)
    try:
        m.move_to([100.0, 100.0, 200.0]).wait()
        for _ in range(6):
            m.jog([20.0, 0.0, 0.0])
            m.run_for(0.05)
        last = m.clock.now()
        assert m.position[0] > 103
        while m.busy and m.clock.now() - last < 1.0:
            m.poll()
        assert not m.busy and m.clock.now() - last <= 0.25
        x = m.position[0]
        m.run_for(0.3)
        assert m.position[0] == pytest.approx(x, abs=0.003)
    finally:
        m.close()


def test_close_leaves_the_modules_at_power_up_for_the_next_start_up():
    config = load()
    sim = SimulatedCMM(config)
    first = Machine(config, sim.transport())
    first.connect()
    moving = first.move_to([60.0, 40.0, 250.0])
    first.run_for(0.3)
    first.close()
    assert moving.done and "closed" in str(moving.error)
    assert all(m.address == 0 and m.group == 0xFF and m.baud == 19200 and not m.servo_on
               for m in sim.network.modules)
    second = Machine(config, sim.transport())  # a second station on the same modules
    second.connect()
    try:
        here = second.position
        second.move_to(here + [5.0, 0.0, -5.0]).wait(10)
        assert second.position == pytest.approx(here + [5.0, 0.0, -5.0], abs=0.0021)
    finally:
        second.close()


def test_close_on_a_dead_link_does_not_raise_and_says_what_it_could_not_do(caplog):
    config = load()
    sim = SimulatedCMM(config)
    port = FaultyTransport(sim.transport(), seed=1)
    m = Machine(config, port)
    m.connect()
    port.inject(Fault("disconnect"))
    with caplog.at_level(logging.WARNING, logger="cmm.machine.motion"):
        m.close()
    text = caplog.text
    assert "motor off was not confirmed" in text and "STOP NOT CONFIRMED" in text
    assert "modules were not reset to their power-up state" in text and "next start-up resets them" in text
    port.restore()
    again = Machine(config, sim.transport())  # the modules, still addressed and servoing, are found again
    again.connect()
    again.close()


def test_the_shipped_configuration_reads_the_following_error(sim_machine):
    _, m, _ = sim_machine
    assert m.config.link.firmware == "pic-servo-sc" and m.items & codec.SEND_PERROR
    status = m.move_to([40.0, 30.0, 280.0])
    seen = []
    while not status.done:
        seen.append([a.following_error for a in m.poll().axes])
    status.wait()
    assert all(isinstance(e, int) for row in seen for e in row)
    assert max(abs(e) for row in seen for e in row) > 0  # the servo lags while it accelerates


def test_an_sc_configuration_on_original_modules_says_which_setting_to_change():
    config = load()  # the shipped configuration is for SC modules and reads the following error
    sim = SimulatedCMM(config, firmware="pic-servo")  # the thesis's modules: no status item 0x40
    m = Machine(config, sim.transport())
    with pytest.raises(NmcError, match='module 1 .X. does not answer .* needs SC firmware. For original PIC-SERVO '
                                       'modules set .link. firmware = "pic-servo" and read_following_error = false'):
        m.connect()
    m.close()  # the replies are understood again: the modules are stopped and released
    assert all(mod.address == 0 and not mod.servo_on for mod in sim.network.modules)


def test_a_jog_for_the_link_process_carries_plain_numbers_only(sim_machine):
    """The link process (cmm/nmc/link_process.py) runs without numpy: a numpy scalar in a jog's GuardSpec made
    it import numpy to unpickle the first jog of a session, 0.4-0.9 s on a busy computer, and a short press
    was released before its jog ever started (a jog that "never starts", with nothing to say why)."""
    import pickle

    _, machine, _ = sim_machine
    spec = machine._guard_spec(np.array([10.0, -7.5, 0.0]))  # numpy in, as the control core passes it
    assert b"numpy" not in pickle.dumps(spec)
    assert spec.axes[0].velocity == 10.0 * machine.config.axes[0].counts_per_mm


def test_a_wait_on_the_virtual_clock_counts_machine_time_not_wall_time(sim_machine):
    """With the poll loop running on the simulator's virtual clock, a wait's limit is machine time: a move of well
    under a second of machine time, paced to a tenth of real time (several wall seconds, as on a busy computer
    where the simulation gets a tenth of a core), finishes inside a 1 s limit; a loop that hung (the clock stands
    still) is given up on after the limit instead of waited for forever."""
    sim, m, _ = sim_machine
    sim.network.set_pace(0.1)
    m.start_polling()
    try:
        t0 = m.clock.now()
        status = m.move_to(m.position + np.array([5.0, 0.0, 0.0]))
        status.wait(1.0)  # wall-clock limit before the fix: TimeoutError after 1 s of a move 10 times longer
        took = m.clock.now() - t0
        assert status.success and 0.1 < took < 1.0, took  # paced: at least 1 s of wall time
        assert m.position[0] == pytest.approx(5.0, abs=0.01)
    finally:
        m.stop_polling()
        sim.network.set_pace(None)
    m.polling = True  # as a loop thread that hung: the flag up, nobody sampling
    try:
        status = m.move_to(m.position + np.array([5.0, 0.0, 0.0]))
        with pytest.raises(TimeoutError, match="clock stood still"):
            status.wait(0.5)
    finally:
        m.polling = False

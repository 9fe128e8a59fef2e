"""A jog's dead-man runs from the moment its front end heard the hold, wherever the hold is taken later.

A busy station (web load, a thread pool, the machine loop's queue) may pass a hold on late; it must never keep a
jog going longer than ``heard + deadman_timeout``, and a hold heard longer ago than the dead-man must neither
start nor refresh a jog. All on the simulator's virtual clock: the loop's lateness is machine time that passes
without a poll, and the stops are read from the simulated machine's samples.
"""

from __future__ import annotations

import numpy as np
import pytest

from cmm.control import Mode
from cmm.nmc.link_process import GuardHeld, JogGuard
from control_support import make_controller

V = [40.0, 0.0, 0.0]


@pytest.fixture
def ctl():
    _, c, _ = make_controller(start_at=[200.0, 200.0, 250.0])
    yield c
    c.close()


def _at_speed(c) -> None:
    """Hold the jog as a front end does (a hold every 40 ms, taken at once) until X runs at jog_fast."""
    for _ in range(40):
        c.jogs.hold(None, V)
        c.run_for(0.04)
        if abs(c.state.machine.axes[0].velocity) >= 39.0:
            return
    raise AssertionError("the jog never reached speed")


def _standing_from(c, limit: float = 1.0) -> float:
    """Run the loop until every axis stands; the machine time of the first standing sample."""
    end = c.clock.now() + limit
    while c.clock.now() < end:
        c.run_for(0.005)
        st = c.state.machine
        if all(abs(a.velocity) < 1e-9 for a in st.axes):
            return st.time
    raise AssertionError("the jog did not stop")


def test_a_hold_the_loop_takes_late_does_not_keep_the_jog_going(ctl):
    _at_speed(ctl)
    deadman = ctl.config.deadman_timeout
    heard = ctl.clock.now()  # the operator's last hold reaches the front end ...
    ctl.clock.sleep(0.12)  # ... and waits 0.12 s in a busy station before the loop takes it
    ctl.jogs.hold(None, V, heard=heard)
    stood = _standing_from(ctl)
    brake = 40.0 / ctl.config.accelerations.stop
    # from the hold's moment: the dead-man, the braking and a few samples; counted from when the loop took it,
    # it would stand 0.12 s later (and 4.8 mm further)
    assert stood - heard <= deadman + brake + 0.03, stood - heard
    assert ctl.state.mode is not Mode.FAULT


def test_a_hold_heard_longer_ago_than_the_dead_man_starts_nothing(ctl):
    ctl.run_for(0.05)
    before = ctl.state.machine.position.copy()
    ctl.jogs.hold(None, V, heard=ctl.clock.now() - 1.5 * ctl.config.deadman_timeout)
    ctl.run_for(0.3)
    assert np.allclose(ctl.state.machine.position, before, atol=1e-3)
    assert ctl.state.mode is not Mode.JOGGING


def test_a_late_hold_after_the_dead_man_fired_does_not_restart_the_jog(ctl):
    _at_speed(ctl)
    heard = ctl.clock.now()
    ctl.run_for(0.25)  # nobody holds: the dead-man stops the jog
    assert all(abs(a.velocity) < 1e-9 for a in ctl.state.machine.axes)
    x = ctl.state.machine.position[0]
    ctl.jogs.hold(None, V, heard=heard)  # a hold from before the stop, passed on only now
    ctl.run_for(0.3)
    assert abs(ctl.state.machine.position[0] - x) < 1e-3


def test_the_link_process_guard_runs_its_dead_man_from_the_moment_heard(sim_machine):
    _, m, _ = sim_machine
    m.move_to([100.0, 100.0, 200.0]).wait()
    v = np.array([40.0, 0.0, 0.0])
    guard = JogGuard(m.bus)
    clock = m.bus.clock
    spec = m._guard_spec(v)
    t0 = clock.now()
    guard.arm(spec, heard=t0)
    assert guard.deadline == pytest.approx(t0 + spec.deadman)
    clock.sleep(0.1)
    guard.refresh(None, heard=t0 - 0.05)  # passed on late: an older hold keeps nothing going
    guard.arm(spec, heard=t0)  # the station's loop re-arming with the same hold, late
    assert guard.deadline == pytest.approx(t0 + spec.deadman)
    t1 = clock.now()
    guard.refresh(None, heard=t1)
    assert guard.deadline == pytest.approx(t1 + spec.deadman)
    guard.stop("deadman")
    clock.sleep(0.3)
    with pytest.raises(GuardHeld, match="longer ago than the dead-man"):
        guard.arm(spec, heard=t1)  # a new jog from a hold heard before the dead-man fired
    guard.arm(spec)  # a hold heard now starts it again
    assert guard.state.fired is None
    guard.stop("release")


def test_a_loop_slower_than_the_holds_still_samples_and_the_jog_runs():
    """A slowly scheduled station: each hold takes the machine loop longer to carry out (here 60 ms of wall time)
    than the front end takes to send the next (20 ms). The loop carries out the holds waiting when its step began
    and then samples: the state follows the axes and the jog runs. (It used to serve holds for as long as new ones
    kept coming: it never sampled again, the state froze at the start, and every hold re-targeted the jog from
    that stale sample, so the axis never got past its first goal. The viser tests saw it on a machine clock
    slowed to 0.1 of the wall clock.) Machine time is paced at the wall clock, so the holds stay fresh."""
    import threading
    import time

    sim, c, _ = make_controller(start_at=[200.0, 200.0, 250.0])
    sim.network.set_pace(1.0)
    carry_out = c.machine.jog

    def slow_jog(*args, **kwargs):
        time.sleep(0.06)  # the loop descheduled while it carries out this hold
        return carry_out(*args, **kwargs)
    c.machine.jog = slow_jog
    c.start()
    done = threading.Event()

    def front_end() -> None:
        while not done.is_set():
            c.jogs.hold(None, [10.0, 0.0, 0.0])
            time.sleep(0.02)
    holder = threading.Thread(target=front_end)
    try:
        t0, x0 = c.state.machine.time, c.state.machine.position[0]
        holder.start()
        end = time.monotonic() + 30
        while c.state.machine.position[0] < x0 + 2.0:  # past the first goal (one horizon: 1.2 mm at 10 mm/s)
            assert time.monotonic() < end, (c.state.machine.time - t0, c.state.machine.position[0] - x0)
            time.sleep(0.01)
        assert c.state.mode is Mode.JOGGING
    finally:
        done.set()
        holder.join(5)
        c.close()

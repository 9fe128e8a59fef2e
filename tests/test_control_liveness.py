"""A busy machine loop is not a dead one: a front end waiting for the loop judges it by its progress.

Beside two CPU hogs an I++ client's move ended with "Controller communications failure": an E-STOP waited a flat
0.5 s of wall time for the machine loop, and the busy loop was taken for a stuck one (fault "the machine loop stopped
answering"). The loop's progress (steps and link transactions) decides now, and a waiter that was itself not
scheduled is credited one slice for that wake-up (:mod:`cmm.control.liveness`). The liveness rule is tested on the
simulator's virtual clock; the loop that works on the link without taking a step on the real simulated modules.
"""

from __future__ import annotations

import threading

import pytest
from control_support import make_controller

from cmm.control import ControlError
from cmm.control.liveness import Liveness


@pytest.fixture
def sim_clock():
    sim, ctl, port = make_controller(start_at=(3.0, 2.0, 297.0))
    try:
        yield sim.network
    finally:
        ctl.close()


def test_a_loop_without_progress_is_stuck_after_its_patience(sim_clock):
    progress = [0]
    live = Liveness(lambda: progress[0], 0.5, clock=lambda: sim_clock.seconds)
    looks = 0
    while not live.stuck():
        sim_clock.advance(live.slice)  # the waiter's slice passes, the loop does nothing
        looks += 1
        assert looks < 1000
    assert 0.5 <= looks * live.slice <= 0.5 + 2 * live.slice


def test_a_loop_that_progresses_is_never_stuck(sim_clock):
    progress = [0]
    live = Liveness(lambda: progress[0], 0.5, clock=lambda: sim_clock.seconds)
    for _ in range(500):  # 5 s of waiting, a step now and then (every 0.3 s)
        sim_clock.advance(live.slice)
        if _ % 30 == 0:
            progress[0] += 1
        assert not live.stuck()


def test_a_waiter_that_was_not_scheduled_does_not_call_the_starved_loop_stuck(sim_clock):
    """The computer was busy: the waiter woke 2 s late (so was the loop, it took no step meanwhile). That is one
    slice of patience spent, not 2 s; a loop that then steps again is alive."""
    progress = [0]
    live = Liveness(lambda: progress[0], 0.5, clock=lambda: sim_clock.seconds)
    for _ in range(3):
        sim_clock.advance(2.0)
        assert not live.stuck()
    progress[0] += 1
    sim_clock.advance(live.slice)
    assert not live.stuck() and live.idle == 0.0


def test_a_command_waits_for_a_loop_that_works_on_the_link_without_taking_a_step():
    """The loop busy on the link (a module's patient retries, a long read of every axis) takes no step for many
    times the patience, but its transactions go on: a command queued meanwhile waits and is carried out; only a
    loop that does nothing at all is stuck."""
    sim, ctl, port = make_controller(start_at=(3.0, 2.0, 297.0))
    try:
        ctl.command_timeout = 0.2
        ctl.start()
        release = threading.Event()
        busy = threading.Event()
        waited: list[object] = []

        def on_the_link(setup):  # in the loop: real transactions with the simulated modules, no loop step
            busy.set()
            while not release.is_set():
                setup.machine.sample()
            return "done"

        holder = threading.Thread(target=lambda: waited.append(ctl.configure(None, on_the_link)))
        holder.start()
        assert busy.wait(30)
        other: list[object] = []

        def queued() -> None:
            try:
                other.append(ctl.configure(None, lambda setup: "carried out"))
            except ControlError as exc:  # the old wall-clock rule: "took no step for 0.2 s (it is stuck)"
                other.append(exc)
        waiter = threading.Thread(target=queued)
        waiter.start()
        waiter.join(2.0)  # ten times the patience (a bound on this thread's wait, nothing is timed)
        release.set()
        waiter.join(30)
        holder.join(30)
        assert other == ["carried out"], other
        assert waited == ["done"]
        stuck = threading.Event()
        with pytest.raises(ControlError, match="took no step for 0.2 s"):
            ctl.configure(None, lambda setup: stuck.wait(30))
        stuck.set()
    finally:
        ctl.close()

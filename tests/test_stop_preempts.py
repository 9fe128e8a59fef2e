"""STOP pre-empts the bus's patient retry of a missed reply (every axis standing) and never ends in a false FAULT.

While the machine stands still a missed reply is retried with doubling waits for up to 6 s (cmm/nmc/bus.py). A
STOP pressed meanwhile must not wait behind that retry (it used to wait for the bus lock for seconds, then went
to the bus itself and put the machine in FAULT, "the machine loop stopped answering"): the retry is cut short,
the loop serves the STOP, whose own stops are retried patiently until the module answers again.

On the simulator's virtual clock, with a threaded machine loop: the module's replies are dropped for 2 s of
machine time (a silent module that comes back); the STOP is pressed from another thread while the loop is in
its retry. The test waits for events with generous wall-clock time-outs but asserts only outcomes.
"""

from __future__ import annotations

import threading

import numpy as np

import pytest

from cmm.control import Controller, Mode
from cmm.machine.config import load
from cmm.machine.motion import Machine
from cmm.nmc.bus import Bus, Preempted
from cmm.nmc.faults import Fault, FaultyTransport
from cmm.sim.cmm_sim import SimulatedCMM
from test_bus import faulty_bus

pytestmark = pytest.mark.timeout(60)


def test_stop_during_an_idle_retry_cuts_it_short_and_stops_without_a_fault():
    config = load()
    sim = SimulatedCMM(config)
    port = FaultyTransport(sim.transport())
    ctl = Controller(Machine(config, port))
    ctl.connect()
    bus = ctl.machine.bus
    reports: list = []
    stoppers: list[threading.Thread] = []
    pressed = threading.Event()
    preempted = threading.Event()
    warn = bus._warn
    preempt = bus.preempt

    def press_stop() -> None:
        reports.append(ctl.stop(None))

    def on_preempt() -> None:
        preempt()
        preempted.set()

    def on_warn(text: str) -> None:  # the loop is in its patient retry: the operator presses STOP now
        warn(text)
        if not pressed.is_set() and threading.current_thread() is ctl._thread:
            stoppers.append(threading.Thread(target=press_stop, daemon=True))
            stoppers[0].start()
            pressed.set()
            preempted.wait(3.0)  # the loop holds on here (in the retry) until the STOP asked for the link

    bus._warn = on_warn
    bus.preempt = on_preempt
    ctl.start()
    try:
        port.inject(Fault("blackout", "rx", duration=2.0))  # the module's replies are lost for 2 s of machine time
        assert pressed.wait(20), "the loop never retried"
        stoppers[0].join(20)
        assert reports, "STOP did not answer"
        report = reports[0]
        assert report.ok, report.message
        assert "sent directly" not in report.message
        assert ctl.state.mode is Mode.STOPPED, ctl.state
        assert ctl.state.mode is not Mode.FAULT
    finally:
        ctl.close()


def test_a_stop_pre_empts_only_a_patient_retry_begun_before_it():
    """The bus side on its own: a retry begun before the stop's request gives up (Preempted); a transaction
    begun after it (the stop's own) retries patiently as before and gets its answer."""
    config = load()
    sim = SimulatedCMM(config)
    port, bus, mods = faulty_bus(sim.transport())
    late = bus._late  # a retry while all stands: counted (not a warning); the stop asks for the link there

    def on_late(text: str) -> None:
        late(text)
        bus.preempt()  # the stop asks for the link during the first retry
    bus._late = on_late
    port.inject(Fault("blackout", "rx", duration=2.0))
    t0 = bus.clock.now()
    with pytest.raises(Preempted, match="cut short by a stop"):
        mods[1].nop()
    assert bus.clock.now() - t0 < 2.0  # given up well before the module came back
    bus._late = late
    st = mods[1].nop()  # the stop's own transaction: patient, answered once the module is back
    assert st.position is not None


def test_a_jog_stop_in_the_link_process_cuts_short_a_retry_during_motion(stations):
    """The link process's jog stop (a release, the dead-man) asks for the link while a transaction of the
    station's is retrying a lost reply during the jog: that transaction gives up (Preempted, not a link failure)
    instead of resynchronising first, and the stop goes out next."""
    from cmm.nmc.link_process import JogGuard

    sim, m, _ = stations.machine(link=FaultyTransport)
    port = m.bus.port
    try:
        m.move_to([100.0, 100.0, 200.0]).wait()
        v = np.array([40.0, 0.0, 0.0])
        for _ in range(8):  # at speed
            m.jog(v)
            m.run_for(0.05)
        bus = m.bus
        assert not bus.still()
        guard = JogGuard(bus)
        guard.arm(m._guard_spec(v))
        attempt = bus._attempt

        def lost_then_stop(*args, **kwargs):
            st = attempt(*args, **kwargs)
            if st is None:  # the reply was lost: the release arrives in the link process now
                bus.preempt(urgent=True)
            return st
        bus._attempt = lost_then_stop
        port.inject(Fault("drop", "rx", count=3))
        resyncs = bus.stats["resyncs"]
        with pytest.raises(Preempted):
            m.modules[0].nop()
        assert bus.stats["resyncs"] == resyncs  # it gave the link up before resynchronising
        bus._attempt = attempt
        guard.stop("release")
        assert guard.state.fired == "release" and guard.state.stops == 1 and not guard.state.errors
        bus.clock.sleep(0.3)
        assert all(abs(a.velocity) < 1e-9 for a in m.sample().axes)
    finally:
        m.close()

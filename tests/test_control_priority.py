"""The machine loop's own CPU priority (cmm.control.priority): per thread, and said when it cannot be had."""

from __future__ import annotations

import os
import sys
import threading
import time

import pytest

from cmm.control.priority import raise_thread_priority, thread_nice

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="thread niceness is a Linux feature")


def _in_thread(fn):
    out = {}
    t = threading.Thread(target=lambda: out.update(result=fn()))
    t.start()
    t.join(10)
    return out["result"]


def test_a_thread_raises_its_own_priority_only_and_says_when_it_may_not():
    before = thread_nice()

    def attempt():
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)  # this thread only, to the lowest
        return raise_thread_priority(before), thread_nice()
    raised, nice = _in_thread(attempt)
    permitted = os.geteuid() == 0 or _nice_limit() <= before
    assert (raised, nice) == ((True, before) if permitted else (False, 19))
    assert thread_nice() == before  # the caller's (and the process's other threads') priority is untouched
    assert raise_thread_priority(19) is True and thread_nice() == before  # never lowers a priority


def _nice_limit() -> int:
    import resource

    soft = resource.getrlimit(resource.RLIMIT_NICE)[0]
    return 20 - soft if soft not in (resource.RLIM_INFINITY, 0) else 20


@pytest.mark.parametrize("realtime", [True, False])
def test_the_machine_loop_raises_its_priority_on_a_wall_clock_only(realtime):
    from cmm.control import Controller
    from cmm.machine.config import load
    from cmm.machine.motion import Machine
    from cmm.sim.cmm_sim import SimulatedCMM

    config = load()
    ctl = Controller(Machine(config, SimulatedCMM(config, realtime=realtime).transport()))
    ctl.connect()
    assert ctl.loop_priority_raised is None  # no loop thread yet
    try:
        ctl.start()
        end = time.monotonic() + 30
        while ctl.loop_priority_raised is None and time.monotonic() < end:
            time.sleep(0.01)
        nice = os.getpriority(os.PRIO_PROCESS, ctl._thread.native_id)
        if realtime:  # raised where permitted (and said so); never on the virtual clock, where the loop never sleeps
            assert ctl.loop_priority_raised == (nice == -10)
            assert ctl.loop_priority_raised == (os.geteuid() == 0 or _nice_limit() <= -10)
        else:
            assert ctl.loop_priority_raised is False and nice == thread_nice()
    finally:
        ctl.close()

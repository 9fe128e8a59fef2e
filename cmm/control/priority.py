"""CPU priority for the station and the threads on the jog path (the machine loop, the pendant server).

The station shares its CPU with whatever else runs on the PC (a desktop browser,
other programs). The machine loop must get the CPU when a bus reply or a jog
release arrives, so it asks the kernel for a higher priority for its own
thread (Linux: ``setpriority`` on the thread id; niceness is per thread there).
That alone is not enough in one Python process: the loop also needs the
interpreter lock, and a station thread at normal priority that holds it and is
pre-empted by another program keeps the loop waiting (priority inversion). So
``cmm serve`` raises the whole station (:func:`raise_station_priority`, before
it starts any thread: threads inherit it); heavy session work runs in a worker
process at a lower priority (:mod:`cmm.session.worker`).
That needs the right to raise priority (root, ``CAP_SYS_NICE``, or an
``RLIMIT_NICE`` such as ``@cmm - nice -10`` in /etc/security/limits.conf);
without it the thread keeps its priority and the station says so once in its
log. A nice value, not a real-time class: a bug that spins in the loop cannot
lock the PC up.
"""

from __future__ import annotations

import logging
import os
import threading

LOOP_NICE = -10  # the machine loop and the pendant server: ahead of web, report and other desktop work

log = logging.getLogger(__name__)
_warned = False


def raise_thread_priority(nice: int = LOOP_NICE) -> bool:
    """Give the calling thread niceness ``nice`` (lower = more CPU); False (logged once) if not permitted."""
    global _warned
    if not hasattr(os, "setpriority"):
        return False
    tid = threading.get_native_id()
    try:
        if os.getpriority(os.PRIO_PROCESS, tid) <= nice:
            return True
        os.setpriority(os.PRIO_PROCESS, tid, nice)
        return True
    except OSError as exc:
        if not _warned:
            _warned = True
            log.warning("cannot raise the priority of %s to nice %d (%s): it runs at the station's priority; "
                        "allow it with CAP_SYS_NICE or an RLIMIT_NICE entry", threading.current_thread().name, nice,
                        exc)
        return False


def raise_priority_on(clock: object, nice: int = LOOP_NICE) -> bool:
    """Raise the calling thread's priority unless ``clock`` is the simulator's virtual clock (tests: a loop on
    it never sleeps, and a raised spinning thread would starve everything else)."""
    return not getattr(clock, "virtual", False) and raise_thread_priority(nice)


def raise_station_priority(nice: int = LOOP_NICE) -> bool:
    """At start-up, before any thread exists: the station's threads (which inherit it) run at ``nice``."""
    return raise_thread_priority(nice)


def thread_nice() -> int | None:
    """The calling thread's niceness (None where unknown)."""
    try:
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    except (AttributeError, OSError):
        return None

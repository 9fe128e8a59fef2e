"""How a waiting front end tells a slow machine loop from a stuck one: by the loop's progress, never by a wall-clock wait.

A STOP whose direct stop-all was not confirmed by every module waits for the machine loop to carry it out; when the
loop is stuck, the caller talks to the bus itself and puts the machine in fault. On a busy computer (two CPU hogs
beside the station) the loop is slow, not stuck: a fixed 0.5 s wait for it took a busy machine for a dead loop, and
an I++ client's move ended with "Controller communications failure". Here the loop is judged by what it does: every
step it begins and every transaction it makes on the link count as progress. Only the waiter's own scheduled time
without any progress counts towards ``patience``, and a waiter that was itself not scheduled for a long while (the
computer was busy, it overslept its slice many times over) is credited one slice for that wake-up, not the whole
time it lay idle: the loop was starved with it, not stuck.
"""

from __future__ import annotations

import time
from typing import Any, Callable

SLICE = 0.01  # s the waiter sleeps between two looks at the loop's progress
OVERSLEPT = 4.0  # a wake-up later than this many slices: the waiter was not scheduled (a busy computer)


class Liveness:
    """``stuck()`` once the loop made no progress during ``patience`` s of the waiter's credited time.

    ``progress()`` returns any value that changes whenever the loop does something (a step begun, a transaction);
    ``clock``: seconds (``time.monotonic`` by default; a test gives the simulator's clock)."""

    def __init__(self, progress: Callable[[], Any], patience: float, *, slice: float = SLICE,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.progress = progress
        self.patience = float(patience)
        self.slice = float(slice)
        self.clock = clock
        self._mark = progress()
        self._last = clock()
        self.idle = 0.0  # credited seconds without progress so far

    def stuck(self) -> bool:
        """Look once (after each wait of about one slice): True when the loop has been idle for ``patience``."""
        now = self.clock()
        waited, self._last = max(0.0, now - self._last), now
        mark = self.progress()
        if mark != self._mark:
            self._mark, self.idle = mark, 0.0
            return False
        # a wake-up far later than asked: the waiter was not scheduled either, so the loop was starved, not stuck
        self.idle += waited if waited <= OVERSLEPT * self.slice else self.slice
        return self.idle > self.patience

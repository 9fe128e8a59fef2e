"""Status objects for long actions (moves, probe cycles), after ophyd's.

A status can be waited on, polled (``done``), given callbacks, or cancelled.
When nobody runs the machine's poll loop in the background (scripts, tests
on the simulator's virtual clock), ``wait`` drives the polling itself.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

from ..nmc.transport import is_virtual

VIRTUAL_CHECK_S = 0.05  # wall s between looks at the virtual clock while the machine loop polls


class MotionError(RuntimeError):
    """A move or probe cycle that could not be done, in an operator's words."""


class Cancelled(MotionError):
    pass


class MoveStatus:
    def __init__(self, description: str, driver: Any = None) -> None:
        self.description = description
        self._driver = driver  # object with .polling (bool), .poll() and .clock
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._callbacks: list[Callable[["MoveStatus"], None]] = []
        self._cancel: Callable[[], None] | None = None
        self.error: BaseException | None = None
        self.result: Any = None

    def __repr__(self) -> str:
        state = "done" if self.done else "running"
        if self.error:
            state = f"failed: {self.error}"
        return f"<MoveStatus {self.description}: {state}>"

    @property
    def done(self) -> bool:
        return self._event.is_set()

    @property
    def success(self) -> bool:
        return self.done and self.error is None

    def on_cancel(self, fn: Callable[[], None]) -> None:
        self._cancel = fn

    def add_callback(self, fn: Callable[["MoveStatus"], None]) -> None:
        with self._lock:
            if not self.done:
                self._callbacks.append(fn)
                return
        fn(self)

    def finish(self, result: Any = None, error: BaseException | None = None) -> None:
        with self._lock:
            if self.done:
                return
            self.result, self.error = result, error
            self._event.set()
            callbacks, self._callbacks = self._callbacks, []
        for fn in callbacks:
            fn(self)

    def cancel(self) -> None:
        if self.done:
            return
        if self._cancel is not None:
            self._cancel()
        self.finish(error=Cancelled(f"{self.description} cancelled"))

    def wait(self, timeout: float | None = None) -> Any:
        """Block until done; return the result or raise the error.

        ``timeout`` is in seconds of the machine's clock when this call drives
        the polling or the clock is the simulator's virtual one, else in wall
        seconds.
        """
        drv = self._driver
        if drv is not None and not drv.polling:
            clock = drv.clock
            deadline = None if timeout is None else clock.now() + timeout
            while not self.done:
                if deadline is not None and clock.now() > deadline:
                    raise TimeoutError(f"{self.description} not finished after {timeout} s")
                drv.poll()
                pause = getattr(drv, "poll_pause", 0.0)
                if pause and not self.done:
                    clock.sleep(pause)
        elif timeout is not None and drv is not None and is_virtual(drv.clock):
            # the machine loop polls on the simulator's virtual clock: the time limit is machine time too. On a
            # busy computer a move took minutes of wall time and was declared a link failure that was not one.
            # A clock that stands still for ``timeout`` wall seconds is a loop that stopped: given up on too.
            seen, still_since = drv.clock.now(), time.monotonic()
            deadline = seen + timeout
            while not self._event.wait(VIRTUAL_CHECK_S):
                now = drv.clock.now()
                if now > deadline:
                    raise TimeoutError(f"{self.description} not finished after {timeout} s of machine time")
                if now != seen:
                    seen, still_since = now, time.monotonic()
                elif time.monotonic() - still_since > timeout:
                    raise TimeoutError(f"{self.description} not finished: the machine's clock stood still for "
                                       f"{timeout} s")
        elif not self._event.wait(timeout):
            raise TimeoutError(f"{self.description} not finished after {timeout} s")
        if self.error is not None:
            raise self.error
        return self.result

"""The narrow machine interface the I++ DME executor drives, and its implementation on the station.

Everything in machine coordinates (mm, tip centre). Blocking calls return
when the motion is over and raise :class:`~cmm.machine.status.MotionError`
(or a subclass) when it failed or was stopped; ``stop()`` from another
thread makes a blocked call return with an error and leaves the machine
stopped.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable, Protocol

import numpy as np

from ..machine.status import MotionError, MoveStatus


class Backend(Protocol):
    config: Any  # MachineConfig: travel, speeds, probe distances
    homed: bool

    def position(self) -> np.ndarray: ...
    def check_target(self, target: np.ndarray) -> np.ndarray: ...
    def move_to(self, target: np.ndarray, speed: float, accel: float) -> np.ndarray: ...
    def probe(self, nominal: np.ndarray, direction: np.ndarray, *, speed: float, accel: float, approach: float,
              search: float, retract: float, rapid_speed: float) -> np.ndarray: ...
    def home(self) -> None: ...
    def stop(self) -> None: ...
    def probes(self) -> list[tuple[str, float]]: ...
    def subscribe_state(self, fn: Callable[[Any], None]) -> Callable[[], None]: ...
    def begin_session(self, client: str) -> str: ...
    def end_session(self) -> None: ...
    def note(self, text: str) -> None: ...


class StationBackend:
    """The I++ DME backend on a started :class:`~cmm.station.Station`.

    The station records every probed point (journal, browser), so the I++
    session is a recorded session like a browser one.
    """

    STALL = 1.0  # s (wall) a blocked call tolerates the machine idle with the motion unfinished (stopped elsewhere)

    def __init__(self, station: Any, probe_name: str = "Probe1") -> None:
        self.station = station
        self.config = station.config
        self.homed = False  # set by Home(); the station keeps it while it runs
        self.probe_name = probe_name
        self._status: MoveStatus | None = None
        self._lock = threading.Lock()
        self._stopped = threading.Event()

    # --- queries --------------------------------------------------------------------
    def position(self) -> np.ndarray:
        return np.asarray(self.station.machine.position, dtype=float)

    def check_target(self, target: np.ndarray) -> np.ndarray:
        return self.station.machine.check_target(target)

    def probes(self) -> list[tuple[str, float]]:
        return [(self.probe_name, float(self.station.prober.settings.tip_radius))]

    def subscribe_state(self, fn: Callable[[Any], None]) -> Callable[[], None]:
        return self.station.subscribe_state(fn)

    # --- motion ---------------------------------------------------------------------
    def _run(self, start: Callable[[], MoveStatus]) -> Any:
        with self._lock:
            self._stopped.clear()
            status = start()
            self._status = status
        try:
            idle_since = None
            while True:
                try:
                    return status.wait(0.1)
                except TimeoutError:
                    pass
                if self._stopped.is_set():
                    status.cancel()
                    raise MotionError("stopped by the I++ DME client (AbortE or disconnect)")
                if self.station.machine.busy:
                    idle_since = None
                elif idle_since is None:
                    idle_since = time.monotonic()
                elif time.monotonic() - idle_since > self.STALL and not status.done:
                    status.cancel()  # the machine was stopped from elsewhere (browser, pendant)
                    raise MotionError("the machine was stopped by the operator")
        finally:
            with self._lock:
                self._status = None

    def move_to(self, target: np.ndarray, speed: float, accel: float) -> np.ndarray:
        return self._run(lambda: self.station.machine.move_to(target, speed, accel))

    def probe(self, nominal: np.ndarray, direction: np.ndarray, *, speed: float, accel: float, approach: float,
              search: float, retract: float, rapid_speed: float) -> np.ndarray:
        """Probe ``nominal`` coming along ``-direction`` (``direction`` points out of the material).

        Returns the latched tip centre (what I++ DME reports); the station records the hit.
        """
        hit = self._run(lambda: self.station.prober.probe(
            nominal, -np.asarray(direction, float), speed=speed, accel=accel, approach_distance=approach,
            search_distance=search, retract_distance=retract, rapid_speed=rapid_speed))
        return np.asarray(hit.machine, dtype=float)

    def home(self) -> None:
        self._run(self.station.machine.home)
        self.homed = True

    def stop(self) -> None:
        """Stop any motion now (AbortE, client gone); a blocked call returns with an error."""
        self._stopped.set()
        with self._lock:
            status = self._status
        if status is not None:
            status.cancel()
        self.station.stop()

    # --- journal ----------------------------------------------------------------------
    def begin_session(self, client: str) -> str:
        path = self.station.new_session(time.strftime("ippdme-%Y%m%d-%H%M%S"))
        self.station.note(f"I++ DME session started by {client}")
        return str(path)

    def end_session(self) -> None:
        self.station.note("I++ DME session ended")

    def note(self, text: str) -> None:
        self.station.note(text)

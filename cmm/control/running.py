"""What runs now on the station (an auto-measure, a routine, a program, a calibration routine) and how to end it.

Every long piece of work registers here while it runs (:meth:`RunningJobs.running`), with the callable that ends
it cleanly: after the hit in progress, its hits kept in the session, the machine left standing. The command API's
``cancel`` verb ends them all, whichever front end started them and whichever front end asks (the access policy
treats ``cancel`` like STOP).
"""

from __future__ import annotations

import itertools
import logging
import threading
from contextlib import contextmanager
from typing import Callable, Iterator

log = logging.getLogger(__name__)


class RunningJobs:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._jobs: dict[int, tuple[str, Callable[[], None]]] = {}
        self._ids = itertools.count(1)

    @contextmanager
    def running(self, description: str, cancel: Callable[[], None]) -> Iterator[None]:
        """Register ``description`` (what the operator is told) with its ``cancel`` while the block runs."""
        with self._lock:
            key = next(self._ids)
            self._jobs[key] = (description, cancel)
        try:
            yield
        finally:
            with self._lock:
                self._jobs.pop(key, None)

    def descriptions(self) -> list[str]:
        with self._lock:
            return [d for d, _ in self._jobs.values()]

    def cancel_all(self) -> list[str]:
        """Ask every running job to end; returns what was asked (none: nothing was running)."""
        with self._lock:
            jobs = list(self._jobs.values())
        asked = []
        for description, cancel in jobs:
            try:
                cancel()
                asked.append(description)
            except Exception:  # noqa: BLE001 - one job's broken cancel must not keep the others running
                log.exception("cancelling %s failed", description)
        return asked


def cancel_flag() -> tuple[Callable[[], None], Callable[[], bool]]:
    """A (cancel, cancelled) pair for work that looks between its steps whether it should end."""
    event = threading.Event()
    return event.set, event.is_set


__all__: list[str] = ["RunningJobs", "cancel_flag"]

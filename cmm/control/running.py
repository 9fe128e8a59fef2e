"""What runs now on the station (an auto-measure, a routine, a program, a calibration routine) and how to end it.

Every long piece of work registers here while it runs (:meth:`RunningJobs.running`), with the callable that ends
it cleanly: after the hit in progress, its hits kept in the session, the machine left standing; work that can
hold and go on (a routine, a probe qualification) also registers its ``pause`` / ``resume`` / ``skip`` callables.
The command API's ``cancel``, ``pause``, ``resume`` and ``skip_step`` verbs reach them, whichever front end started
them and whichever front end asks (the access policy treats ``cancel`` and ``pause`` like STOP; ``resume`` and
``skip_step`` are the control holder's).
"""

from __future__ import annotations

import itertools
import logging
import threading
from contextlib import contextmanager
from typing import Callable, Iterator, Optional

log = logging.getLogger(__name__)
ACTIONS = ("cancel", "pause", "resume", "skip")


class RunningJobs:
    def __init__(self, on_idle: Optional[Callable[[], None]] = None) -> None:
        """``on_idle()`` is called (outside the lock) each time the last registered job ends."""
        self._on_idle = on_idle
        self._lock = threading.Lock()
        self._jobs: dict[int, tuple[str, dict[str, Callable[[], object]]]] = {}
        self._ids = itertools.count(1)
        self._progress: dict[str, tuple[int, int, str]] = {}  # description -> (done, total, step) while it runs

    @contextmanager
    def running(self, description: str, cancel: Callable[[], None], *,
                pause: Optional[Callable[[], object]] = None, resume: Optional[Callable[[], object]] = None,
                skip: Optional[Callable[[], object]] = None) -> Iterator[None]:
        """Register ``description`` (what the operator is told) with its ``cancel`` (and, when it can hold, its
        ``pause``, ``resume``, ``skip``: each returns False when it did nothing) while the block runs."""
        actions = {k: fn for k, fn in zip(ACTIONS, (cancel, pause, resume, skip)) if fn is not None}
        with self._lock:
            key = next(self._ids)
            self._jobs[key] = (description, actions)
        try:
            yield
        finally:
            with self._lock:
                self._jobs.pop(key, None)
                if description not in {d for d, _ in self._jobs.values()}:
                    self._progress.pop(description, None)
                idle = not self._jobs
            if idle and self._on_idle is not None:
                self._on_idle()

    def report(self, description: str, done: int, total: int, step: str = "") -> None:
        """How far the running job ``description`` is (``done`` of ``total`` hits or steps; ``step``: what it does
        now), for the ``job`` query."""
        with self._lock:
            if description in {d for d, _ in self._jobs.values()}:
                self._progress[description] = (int(done), int(total), str(step))

    def snapshot(self) -> list[dict[str, object]]:
        """What runs now, oldest first: description, done, total (0 when it does not say) and step."""
        with self._lock:
            out = []
            for d, _ in self._jobs.values():
                done, total, step = self._progress.get(d, (0, 0, ""))
                out.append({"description": d, "done": done, "total": total, "step": step})
            return out

    def descriptions(self) -> list[str]:
        with self._lock:
            return [d for d, _ in self._jobs.values()]

    def cancel_all(self) -> list[str]:
        """Ask every running job to end; returns what was asked (none: nothing was running)."""
        return self.ask_all("cancel")

    def ask_all(self, action: str, *, unless: Optional[Callable[[Callable[[], object]], bool]] = None) -> list[str]:
        """Call ``action`` (cancel, pause, resume, skip) of every running job that has one; returns the jobs that
        did it (a callable returning False did nothing: not paused, nothing to skip). ``unless(callable)`` True:
        that job's callable is left out."""
        if action not in ACTIONS:
            raise ValueError(f"a running job is asked to {', '.join(ACTIONS)}, not {action!r}")
        with self._lock:
            jobs = [(d, actions[action]) for d, actions in self._jobs.values()
                    if action in actions and not (unless is not None and unless(actions[action]))]
        asked = []
        for description, fn in jobs:
            try:
                if fn() is not False:
                    asked.append(description)
            except Exception:  # noqa: BLE001 - one job's broken callable must not keep the others running
                log.exception("%s of %s failed", action, description)
        return asked


def cancel_flag() -> tuple[Callable[[], None], Callable[[], bool]]:
    """A (cancel, cancelled) pair for work that looks between its steps whether it should end."""
    event = threading.Event()
    return event.set, event.is_set


__all__: list[str] = ["RunningJobs", "cancel_flag"]

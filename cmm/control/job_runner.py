"""The control core's job runner: routines, programs and calibrations run in the machine loop with the machine to
themselves (or beside it, waiting for the operator's hits), registered so that cancel, pause, resume, skip and the
operator's STOP reach them.

A mixin of :class:`cmm.control.core.Controller`.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

from ..machine.motion import Machine
from ..machine.probing import Prober
from .modes import Refused, RunStopped


def _press_name(why: str) -> str:
    return "STOP" if why == "stopped by the operator" else "E-STOP"


class Job:
    """What a routine run by :meth:`Controller.run_routine` (or a set-up change by :meth:`Controller.configure`)
    works with, inside the machine loop: the machine and its prober, handed over by the control core."""

    def __init__(self, machine: Machine, prober: Prober, progress: Callable[[float, str], None] | None) -> None:
        self.machine, self.prober = machine, prober
        self._progress = progress

    def progress(self, fraction: float, message: str) -> None:
        if self._progress is not None:
            self._progress(fraction, message)


class JobRunner:
    """Runs, their registration and their end (a mixin of the controller)."""

    def run_job(self, client: str | None, description: str, fn: Callable[[], Any], *,
                timeout: float | None = None, cancel: Callable[[], None] | None = None,
                pause: Callable[[], Any] | None = None, resume: Callable[[], Any] | None = None,
                skip: Callable[[], Any] | None = None) -> Any:
        """Run a routine (calibration, a measurement program) in the machine loop with the machine to itself.

        ``fn`` may use the machine and prober directly and wait on statuses (they drive the loop); other
        commands are refused while it runs, except STOP / E-STOP, which end its current move. While it runs,
        the ``cancel`` verb calls ``cancel`` (the job ends itself cleanly between hits); a job without one is
        ended by a controlled stop of its current move; ``pause`` / ``resume`` / ``skip`` (when given) are what
        the ``pause``, ``resume`` and ``skip_step`` verbs call.
        """
        def run() -> Any:
            with self._lock:
                self._job = description
            self._publish()
            try:
                result = fn()
            except BaseException as exc:
                why = self._end_run()
                if why is not None and not isinstance(exc, RunStopped):
                    raise RunStopped(f"{description} ended by the operator's {_press_name(why)}: {exc}") from exc
                raise
            why = self._end_run()
            if why is not None:  # the run swallowed its cut-short move: it still says it was stopped
                raise RunStopped(f"{description} ended by the operator's {_press_name(why)}")
            return result

        def stop_it() -> None:  # the cancel verb of a run that cannot end itself: a controlled stop
            self.stop(None)
        stop_it.is_stop = True  # type: ignore[attr-defined]  # not asked again by the stop it is
        with self.jobs.running(description, cancel or stop_it, pause=pause, resume=resume, skip=skip):
            return self._submit(client, "job", run, timeout=timeout)

    def _end_run(self) -> str | None:
        """The run ended (in the loop): the operator's stop that ended it (None: it was not stopped); the inhibit
        that refused its motions is lifted (an E-STOP's latch stays until Reset)."""
        with self._lock:
            self._job = None
            why = self._take_run_stop()
        self._publish()
        return why

    def _take_run_stop(self) -> str | None:
        """Take a stop's mark on the run (None: there was none) and lift the inhibit it set (an E-STOP's latch
        stays until Reset)."""
        with self._lock:
            why, self._run_stopped = self._run_stopped, None
        if why is not None and self.machine.inhibit == f"{why}: the run ends":
            self.machine.inhibit = None
        return why

    def run_routine(self, client: str | None, description: str, routine: Callable[["Job"], Any], *,
                    progress: Callable[[float, str], None] | None = None, timeout: float | None = None,
                    cancel: Callable[[], None] | None = None, **holds: Callable[[], Any] | None) -> Any:
        """A routine that needs the machine itself (calibration): ``routine(job)`` runs as a :meth:`run_job`
        and gets the machine, the prober and ``job.progress(fraction, message)``, which reaches ``progress`` on
        the dispatcher thread (never in the loop); the last report is delivered before this returns."""
        job = Job(self.machine, self.prober, None if progress is None else
                  (lambda fraction, message: self.dispatcher.post(progress, fraction, message)))
        try:
            return self.run_job(client, description, lambda: routine(job), timeout=timeout, cancel=cancel, **holds)
        finally:
            if progress is not None:
                self.dispatcher.flush()

    def run_beside(self, client: str | None, description: str, fn: Callable[[], Any], *,
                   cancel: Callable[[], None], action: str = "job", **holds: Callable[[], Any] | None) -> Any:
        """Work that does not hold the machine (a program waiting for the operator's manual hits: the operator jogs
        and probes meanwhile, each move its own command; an auto-measure, each hit its own command): run in the
        caller's thread, registered with its ``cancel`` (and ``pause`` / ``resume`` / ``skip``) as a running job;
        only the client that may do ``action`` starts it. Ended by a STOP, it says so in the operator's words."""
        why = self.policy.refusal(client, action)
        if why is not None:
            raise Refused(why)
        with self.jobs.running(description, cancel, **holds):
            try:
                result = fn()
            except BaseException as exc:
                why = self._end_beside()
                if why is not None and not isinstance(exc, RunStopped):
                    raise RunStopped(f"{description} ended by the operator's {_press_name(why)}: {exc}") from exc
                raise
            why = self._end_beside()
            if why is not None:
                raise RunStopped(f"{description} ended by the operator's {_press_name(why)}")
            return result

    def _end_beside(self) -> str | None:
        """A run beside the loop ended: the operator's stop that ended it, once no other run goes on (see _end_run)."""
        if self._job is not None or len(self.jobs.descriptions()) > 1:
            return self._run_stopped
        return self._take_run_stop()

    def _runs_ended(self) -> None:
        """The last registered run has ended: a stop's mark on "the run" and the inhibit it set go with it. Runs
        through run_job and run_beside take the mark themselves (their error names the press); this ends it for
        the others (an auto-measure: its next motion stayed inhibited until Reset) and for a press that came while
        the last run was ending (it marked a run that had already taken its mark, and the next run was refused)."""
        with self._lock:  # re-entrant: the check and the take are one step
            if self._job is None and not self.jobs.descriptions():
                self._take_run_stop()

    def cancel_jobs(self, client: str | None) -> dict[str, Any]:
        """End whatever job runs (auto-measure, routine, program, calibration) cleanly: the ``cancel`` verb. Allowed
        to every client the access policy lets stop; a job that was not running is no error."""
        why = self.policy.refusal(client, "cancel")
        if why is not None:
            raise Refused(why)
        asked = self.jobs.cancel_all()
        return {"cancelled": asked,
                "message": ("cancelled: " + "; ".join(asked)) if asked else "nothing was running to cancel"}

    def hold_jobs(self, client: str | None, action: str) -> dict[str, Any]:
        """Pause, resume or skip the step of whatever job runs and can (a routine, a probe qualification): the
        ``pause`` (allowed like STOP), ``resume`` and ``skip_step`` (the control holder) verbs."""
        command, done = {"pause": ("pause", "paused"), "resume": ("resume", "resumed"),
                         "skip": ("skip_step", "skipped")}[action]
        why = self.policy.refusal(client, command)
        if why is not None:
            raise Refused(why)
        asked = self.jobs.ask_all(action)
        what = {"pause": "pause", "resume": "resume (nothing is paused)", "skip": "skip a step of"}[action]
        return {done: asked, "message": f"{done}: " + "; ".join(asked) if asked else f"nothing was running to {what}"}

    def wait_event(self, event: threading.Event, timeout: float) -> bool:
        """Wait for ``event``; from inside the machine loop (a routine waiting for the operator) keep the loop
        running meanwhile, so STOP, E-STOP and the link watch still work."""
        if self._thread is None or threading.current_thread() is not self._thread:
            return event.wait(timeout)
        end = time.monotonic() + timeout
        while not event.is_set() and time.monotonic() < end:
            self.poll()
            time.sleep(0.005)
        return event.is_set()

    def configure(self, client: str | None, change: Callable[["Job"], Any]) -> Any:
        """Change the machine set-up (geometry correction, probe settings, gains) in the loop, while still:
        ``change(setup)`` gets the machine and its prober (``setup.machine``, ``setup.prober``)."""
        return self._submit(client, "configure", lambda: change(Job(self.machine, self.prober, None)))

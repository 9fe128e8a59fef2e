"""One runner for every part program: a taught routine, a TOML program or a DMIS program runs as steps in order,
with the same state, progress count and operator's controls (see docs/architecture.md, "Part programs: one step
model, one runner").

:class:`StepRunner` holds what every format shares and nothing of how a step is carried out:

- the state: ``ready`` -> ``running`` (``waiting`` for the operator's hits, ``paused`` between hits) -> ``done``,
  ``failed`` (a fault stopped step ``faulted``; the run can be resumed from it or restarted) or ``cancelled``;
- the controls, callable from any thread (the command API's ``pause``, ``resume``, ``skip_step`` and ``cancel``
  verbs reach them through the control core's running jobs, :meth:`StepRunner.controls`): :meth:`pause` holds the
  run at its next checkpoint (between hits, between DMIS statements), :meth:`resume` lets it go on, :meth:`skip`
  asks the step in progress to end after its current hit, :meth:`cancel` ends the run at its next checkpoint;
- the progress (:class:`RunProgress`): the step, the hits taken of the hits planned, the message and the prompt,
  told to ``on_progress`` on every change;
- the step loop (:meth:`run_steps`) and its ends: :meth:`fail`, :meth:`finish`.

The format's executor (:class:`cmm.measurement.routine_run.RoutineRun`, :class:`cmm.dmis.executor.Executor`) moves
the machine through the command API and calls the runner at its checkpoints (:meth:`hold`, :meth:`take_skip`,
:meth:`hit_taken`); it decides where a skip takes effect and what a cancel raises, in its own words.
"""

from __future__ import annotations

import threading
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol

STATES = ("ready", "running", "waiting", "paused", "done", "failed", "cancelled")


@dataclass
class RunProgress:
    step: int = 0  # index of the step running
    steps: int = 0
    hits: int = 0  # hits taken so far
    total_hits: int = 0  # hits planned (0: the format cannot say before it runs, as a DMIS loop)
    state: str = "ready"  # one of STATES
    message: str = ""
    prompt: str = ""  # what the operator must do now (manual hits)
    results: dict[str, Any] = field(default_factory=dict)  # step name -> what it made (a feature, a report)
    session: Any = None  # the part's session (path or name)
    part: Any = None  # the trends record of the finished run, when recorded

    @property
    def fraction(self) -> float:
        """How far the run is, 0 .. 1: by hits when the run knows how many it takes, else by steps."""
        if self.total_hits:
            return min(1.0, self.hits / self.total_hits)
        return min(1.0, self.step / self.steps) if self.steps else 0.0


class Jobs(Protocol):
    """Where a run registers its controls while it runs (the control core's running jobs): the command API's
    ``cancel``, ``pause``, ``resume`` and ``skip_step`` verbs reach them there, whichever front end sends them."""

    def running(self, description: str, cancel: Callable[[], None], *, pause: Callable[[], Any] | None = None,
                resume: Callable[[], Any] | None = None,
                skip: Callable[[], Any] | None = None) -> AbstractContextManager[None]: ...

    def report(self, description: str, done: int, total: int, step: str = "") -> None: ...


class StepRunner:
    """The state, controls and progress of one run. ``wait(event, timeout)`` is how a checkpoint waits (the control
    core's ``wait_event`` inside the machine loop keeps STOP served); ``pause_text`` / ``resume_text``: what the
    progress says at once when the operator pauses / resumes (None: the executor says it where it holds)."""

    def __init__(self, *, steps: int = 0, total_hits: int = 0,
                 on_progress: Callable[[RunProgress], None] | None = None,
                 wait: Callable[[threading.Event, float], bool] | None = None,
                 pause_text: str | None = "paused after the hit in progress: Resume to go on",
                 resume_text: str | None = "resumed") -> None:
        self.progress = RunProgress(steps=steps, total_hits=total_hits)
        self.on_progress = on_progress
        # the progress for the command API's ``job`` query (the running jobs' report), while the run is registered
        self.report: Callable[[RunProgress], None] | None = None
        self.wait = wait or (lambda event, timeout: event.wait(timeout))
        self.pause_text, self.resume_text = pause_text, resume_text
        self.faulted: int | None = None  # index of the step a fault stopped
        self._go = threading.Event()  # clear: paused
        self._go.set()
        self._stopped = threading.Event()  # set by cancel: ends every wait at once
        self._skip = threading.Event()

    # --- the operator's controls (any thread) ------------------------------------------------

    def pause(self) -> bool:
        self._go.clear()
        if self.pause_text is not None:
            self.tell(state="paused", message=self.pause_text)
        return True

    def resume(self) -> bool:
        """Go on after a pause; False when the run was not paused."""
        was = not self._go.is_set() or self.progress.state == "paused"
        self._go.set()
        if self.progress.state == "paused" and self.resume_text is not None:
            self.tell(state="running", message=self.resume_text)
        return was

    def skip(self) -> bool:
        """Ask the step in progress to end after its current hit (the executor says where it takes effect); a paused
        run goes on to do it."""
        self._skip.set()
        self._go.set()
        return True

    def cancel(self) -> bool:
        """End the run at its next checkpoint (a run stopped on a fault, where nothing runs to see the flag, is
        cancelled here); True: asked (the running jobs count it)."""
        self._stopped.set()
        self._go.set()
        if self.progress.state == "failed":
            self.tell(state="cancelled", message="cancelled after the fault; the hits taken stay recorded", prompt="")
        return True

    def controls(self) -> dict[str, Callable[[], Any]]:
        """The callables the running jobs register (``Jobs.running``): cancel, pause, resume, skip."""
        return {"cancel": self.cancel, "pause": self.pause, "resume": self.resume, "skip": self.skip}

    @property
    def cancelled(self) -> bool:
        return self._stopped.is_set()

    @property
    def paused(self) -> bool:
        return not self._go.is_set()

    @property
    def skip_asked(self) -> bool:
        return self._skip.is_set()

    def take_skip(self) -> bool:
        """Whether a skip was asked (and it is taken: the next step is not skipped by it)."""
        if self._skip.is_set():
            self._skip.clear()
            return True
        return False

    def clear_skip(self) -> None:
        self._skip.clear()

    # --- progress -------------------------------------------------------------------------------

    def update(self, **changes: Any) -> None:
        """Change the progress without telling (the next tell carries it)."""
        for k, v in changes.items():
            setattr(self.progress, k, v)
        if self.report is not None:
            try:
                self.report(self.progress)
            except Exception:  # noqa: BLE001 - the job query's view never stops the run
                pass

    def tell(self, **changes: Any) -> None:
        """Change the progress and tell ``on_progress``; a front end that fails (a closed page) never stops the run."""
        self.update(**changes)
        if self.on_progress is not None:
            try:
                self.on_progress(self.progress)
            except Exception:  # noqa: BLE001 - a closed page must not stop the run
                pass

    def hit_taken(self, n: int = 1, *, quiet: bool = False) -> None:
        hits = max(0, self.progress.hits + n)
        self.update(hits=hits) if quiet else self.tell(hits=hits)

    # --- checkpoints ----------------------------------------------------------------------------

    def hold(self, message: str | None = None, *, poll: float = 0.05) -> bool:
        """A checkpoint: wait while the run is paused (``message``, when given, tells where it holds); False when
        the run is cancelled (the executor ends it in its own words), True to go on."""
        if self.paused and not self.cancelled and message is not None:
            self.tell(state="paused", message=message)
        while not self._go.is_set() and not self.cancelled:
            self.wait(self._go, poll)
        return not self.cancelled

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` at a person's pace, or less when the run is cancelled."""
        self._stopped.wait(seconds)

    # --- the step loop --------------------------------------------------------------------------

    def run_steps(self, start: int, step: Callable[[int], Any], *, skipped: Callable[[int], bool] = lambda i: False,
                  describe: Callable[[int], str] = lambda i: "") -> None:
        """Run steps ``start`` .. ``steps - 1`` in order (``step(i)``), leaving out those ``skipped(i)``; each
        step's ``describe(i)`` is told as it starts. An exception leaves ``progress.step`` on the step it came
        from (:meth:`fail` records the fault there)."""
        self.faulted = None
        for i in range(start, self.progress.steps):
            self.progress.step = i
            if skipped(i):
                continue
            self.clear_skip()  # a skip asked between two steps is not carried into the next
            self.tell(message=describe(i))
            step(i)

    def fail(self, message: str) -> int:
        """The step in progress stopped on a fault: the run waits for resume, restart or cancel. Returns its index."""
        self.faulted = self.progress.step
        self.tell(state="failed", message=message, prompt="")
        return self.faulted

    def finish(self, message: str) -> None:
        self.tell(state="done", step=self.progress.steps, message=message, prompt="")

    @property
    def can_resume(self) -> bool:
        return self.progress.state == "failed" and self.faulted is not None and not self.cancelled

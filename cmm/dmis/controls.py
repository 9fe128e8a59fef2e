"""The operator's controls on a DMIS run, on the part programs' one runner (:mod:`cmm.program.runner`): Pause holds
the run before its next statement, Cancel ends it there, Skip step ends the measurement in progress (a ``MEAS``
block) after its current hit or leaves out the next one. A mixin of :class:`cmm.dmis.executor.Executor`.
"""

from __future__ import annotations

import threading
from typing import Any

from ..program.runner import RunProgress, StepRunner
from .parser import Statement


class RunControls:
    """The run's :class:`StepRunner` and where DMIS takes its controls (a mixin of the executor)."""

    runner: StepRunner
    on_progress: Any
    target: Any
    skipped: dict[str, str]
    _meas: Any
    _meas_at: int
    _guides: list

    def _controls_init(self, steps: int) -> None:
        # each statement reached is a step; DMIS says where it holds, not the runner
        self.runner = StepRunner(steps=steps, on_progress=self._told, wait=self._wait, pause_text=None,
                                 resume_text=None)

    def _told(self, p: RunProgress) -> None:
        if self.on_progress is not None:
            self.on_progress(p.fraction, p.message)

    def _wait(self, event: threading.Event, _timeout: float) -> bool:
        """A pause holds in the target's wait (the machine standing, the machine loop serving STOP)."""
        self.target.hold(lambda: event.is_set() or self.runner.cancelled)
        return event.is_set()

    def _between(self, s: Statement) -> None:
        """Between two statements: hold while the operator has paused the run; end it when they cancelled."""
        runner = self.runner
        if runner.paused and not runner.cancelled:
            self.log(f"line {s.line}: paused by the operator")
            if runner.hold(f"paused before line {s.line}: {s.name}; Resume to go on"):
                runner.tell(state="running", message=f"line {s.line}: {s.name}")
        if runner.cancelled:
            raise self.fail(s, "the program was cancelled by the operator before this statement")

    def skip(self) -> bool:
        """The operator's Skip step (any thread): the feature measurement in progress (MEAS .. ENDMES) ends after
        its current hit, else the next one is left out; a paused run goes on to do it."""
        return self.runner.skip()

    def _skip(self, pc: int, s: Statement, pairs: dict[int, int]) -> int | None:
        """Where the run goes on when the operator asked to skip before statement ``pc`` (None: no step here to
        skip, the request waits for the next one). The skipped feature is said in the output, the log and the
        journal; the hits it took stay in the session, not fitted."""
        if self._meas is not None:  # inside MEAS .. ENDMES: its remaining hits are not taken
            meas, ids = self._meas
            self._meas, self._guides = None, []
            nxt = pairs[self._meas_at] + 1
            why = f"after {len(ids)} hit{'s' if len(ids) != 1 else ''}"
        elif s.major == "MEAS":
            meas, nxt, why = s, pairs[pc] + 1, "before its first hit"
        else:
            return None
        self.runner.take_skip()
        label = self.labels(meas)[0].name
        self.skipped[label] = f"line {meas.line}, {why}"
        self.result.actuals.pop(label, None)
        self.log(f"line {meas.line}: F({label}) skipped by the operator {why}; it is not fitted")
        self.emit(f"$$ F({label}) skipped by the operator {why} (line {meas.line}): not measured")
        self.target.note(f"DMIS F({label}) skipped by the operator {why} (line {meas.line}); not fitted")
        return nxt


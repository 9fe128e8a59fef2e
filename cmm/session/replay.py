"""Replay a finished session without a machine: the state after each event, for a scrubber.

    replay = Replay(load_session(store, "bracket-7"))   # or Replay.open("sessions/bracket-7.jsonl")
    len(replay)                 # number of events = scrubber positions
    state = replay.at(i)        # SessionState after event i (0 .. len-1); at(-1) = the final state
    replay.event(i)             # the event dict itself (kind, seq, time, ...)
    replay.time_fraction(i)     # 0..1 along the session's wall-clock span (for a time-scaled slider)
    replay.index_at_time(t)     # last event at or before wall time t
    replay.changes(i)           # what event i changed: {"hits_added": [...], "hits_removed": [...], ...}
    for i, state in replay: ... # every state in order (incremental, O(1) per step)

``at(i)`` is O(K) with checkpoints every K = 256 events (more for sessions
of more than 8,192 events: at most 32 checkpoints, each a copy of the state,
so a 200,000-hit session needs a few hundred MB, not tens of GB), so
dragging a slider over a 10,000-hit session stays interactive. States are independent
copies: the UI may keep them. ``SessionState`` (see :mod:`cmm.journal.state`)
has ``hits`` / ``deleted_hits`` (HitRecord: id, counts, machine, approach,
point, ...), ``features`` (FeatureRecord: name, kind, method, hit_ids, fit,
nominal, tolerance, probe: the record the live feature journalled), ``part`` / ``part_pose`` / ``alignments``, ``notes``, ``errors``
and ``last_event``.
"""

from __future__ import annotations

import bisect
from pathlib import Path
from typing import Any, Callable, Iterator

from ..journal.session import Session
from ..journal.state import SessionState
from ..journal.writer import read_events

CHECKPOINT_EVERY = 256
MAX_CHECKPOINTS = 32  # each is a full copy of the state: their number, not their spacing, bounds the memory


class Replay:
    def __init__(self, session: Session, *, progress: Callable[[int, int], None] | None = None) -> None:
        self.session = session
        self._build(progress)

    def _build(self, progress: Callable[[int, int], None] | None) -> SessionState:
        """Checkpoints and times from one pass over the events; returns the final state."""
        self.events = self.session.events
        n = len(self.events)
        self.every = max(CHECKPOINT_EVERY, -(-n // MAX_CHECKPOINTS))
        self._checkpoints: list[SessionState] = [SessionState()]  # state before event k * self.every
        state = SessionState()
        for i, e in enumerate(self.events):
            state.apply(e, i)
            if (i + 1) % self.every == 0:
                self._checkpoints.append(state.copy())
                if progress is not None:
                    progress(i + 1, n)
        self._times = [float(e.get("time", 0.0)) for e in self.events]
        return state

    @classmethod
    def from_events(cls, events: list[dict], name: str = "session", damage: str | None = None, *,
                    progress: Callable[[int, int], None] | None = None) -> "Replay":
        """The replay and its :class:`Session` in one pass over the events (half the work of
        ``Replay(Session.from_events(...))`` on a big journal)."""
        replay = cls.__new__(cls)
        replay.session = Session(name, events, damage)
        replay.session.state = replay._build(progress)
        return replay

    @classmethod
    def open(cls, path: str | Path) -> "Replay":
        contents = read_events(path)
        return cls(Session.from_events(contents.events, Path(path).stem, contents.damage))

    def __len__(self) -> int:
        return len(self.events)

    def event(self, i: int) -> dict:
        return self.events[i]

    def at(self, i: int) -> SessionState:
        """The state after event ``i`` (negative indices count from the end)."""
        n = len(self.events)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"scrubber position {i} is outside the session's {n} events")
        k = (i + 1) // self.every
        state = self._checkpoints[k].copy()
        for j in range(k * self.every, i + 1):
            state.apply(self.events[j], j)
        return state

    def __iter__(self) -> Iterator[tuple[int, SessionState]]:
        state = SessionState()
        for i, e in enumerate(self.events):
            state.apply(e, i)
            yield i, state.copy()

    def time_fraction(self, i: int) -> float:
        if not self._times:
            return 0.0
        t0, t1 = self._times[0], self._times[-1]
        return 0.0 if t1 <= t0 else (self._times[i] - t0) / (t1 - t0)

    def index_at_time(self, t: float) -> int:
        return max(0, bisect.bisect_right(self._times, t) - 1)

    def changes(self, i: int) -> dict[str, Any]:
        before = self.at(i - 1) if i > 0 else SessionState()
        after = self.at(i)
        return {
            "hits_added": [h for h in after.hits if h not in before.hits],
            "hits_removed": [h for h in before.hits if h not in after.hits],
            "features_added": [f for f in after.features if f not in before.features],
            "features_removed": [f for f in before.features if f not in after.features],
            "pose_changed": after.part_pose != before.part_pose,
        }

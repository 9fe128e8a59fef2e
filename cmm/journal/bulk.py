"""Bulk work on big sessions without stalling the rest of the station.

Opening a 200,000-hit journal creates millions of small objects; Python's cyclic
garbage collector then runs full passes over all of them, each holding the
interpreter lock for seconds, which stalls every thread of the station (the
machine loop, the web server). The objects built here hold no reference
cycles, so automatic collection is paused while they are built (and it makes
opening such a session several times faster), and they are then moved out of
the collector's sight (``gc.freeze``; reference counting still frees them).
Freeing them is the same problem the other way round: :func:`dispose` frees
them piece by piece in the background.
"""

from __future__ import annotations

import contextlib
import gc
import threading
import time
from typing import Iterator

_lock = threading.Lock()
_depth = 0
_was_enabled = True


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Pause automatic garbage collection for the block (nested and multi-threaded use is fine)."""
    global _depth, _was_enabled
    with _lock:
        if _depth == 0:
            _was_enabled = gc.isenabled()
            gc.disable()
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _was_enabled:
                # what was built stays out of later collector passes too (freed by reference counting as
                # usual): re-enabling would otherwise start one full pass over all of it at once
                gc.freeze()
                gc.enable()


DISPOSE_CHUNK = 2000  # objects freed between two chances for other threads to run (a few ms of work)


def dispose(*objects: object) -> threading.Thread | None:
    """Free big session structures (Session, Replay, SessionState, lists, dicts) piece by piece in a
    background thread.

    Dropping the last reference to a 200,000-hit replay frees millions of objects in one go, holding the
    interpreter lock for about a second: the machine loop would stand still that long. Call this with the
    structures once nothing else uses them any more; they are emptied in place.
    """
    items = [o for o in objects if o is not None]
    if not items:
        return None
    t = threading.Thread(target=_dispose_all, args=(items,), name="session-dispose", daemon=True)
    t.start()
    return t


def _dispose_all(items: list) -> None:
    while items:
        _drain(items.pop())


def _drain(obj: object) -> None:
    if isinstance(obj, list):
        while obj:
            del obj[-DISPOSE_CHUNK:]
            time.sleep(0)
    elif isinstance(obj, dict):
        while obj:
            for _ in range(min(DISPOSE_CHUNK, len(obj))):
                obj.popitem()
            time.sleep(0)
    elif hasattr(obj, "_checkpoints"):  # a Replay: its states, then its events and session
        checkpoints = obj._checkpoints
        while checkpoints:
            _drain(checkpoints.pop())
        _drain(getattr(obj, "_times", None))
        _drain(getattr(obj, "session", None))
    elif hasattr(obj, "events") and hasattr(obj, "state"):  # a Session
        _drain(obj.state)
        _drain(obj.events)
    elif hasattr(obj, "hits") and hasattr(obj, "hit_pose"):  # a SessionState
        for name in ("hits", "deleted_hits", "hit_pose", "unaligned", "features", "constructed"):
            _drain(getattr(obj, name, None))

"""Bulk work on big sessions without stalling the rest of the station.

Opening a 200,000-hit journal creates millions of small objects; Python's cyclic
garbage collector then runs full passes over all of them, each holding the
interpreter lock for seconds, which stalls every thread of the station (the
machine loop, the web server). The objects built here hold no reference
cycles, so automatic collection is paused while they are built (and it makes
opening such a session several times faster), and they are then moved out of
the collector's sight (``gc.freeze``; reference counting still frees them).
"""

from __future__ import annotations

import contextlib
import gc
import threading
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

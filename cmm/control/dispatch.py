"""The dispatcher: one thread that runs listeners (journal writes, UI notifications) outside the machine loop.

The machine loop only queues; a listener that raises or blocks never stops
the loop. ``inline=True`` runs everything in the posting thread (scripts and
tests without threads).
"""

from __future__ import annotations

import logging
import queue
import threading
from typing import Any, Callable

log = logging.getLogger(__name__)


class Dispatcher:
    def __init__(self, *, inline: bool = False, on_error: Callable[[str], None] | None = None) -> None:
        self.inline = inline
        self.on_error = on_error
        self._queue: queue.SimpleQueue[tuple[Callable[..., Any], tuple[Any, ...]] | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self.errors = 0

    def start(self) -> "Dispatcher":
        if self._thread is None and not self.inline:
            self._thread = threading.Thread(target=self._run, name="control-dispatch", daemon=True)
            self._thread.start()
        return self

    def close(self, timeout: float = 2.0) -> None:
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout)
            self._thread = None

    def post(self, fn: Callable[..., Any], *args: Any) -> None:
        if self.inline or self._thread is None:
            self._call(fn, args)
        else:
            self._queue.put((fn, args))

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until everything posted so far has run (never call it from the machine loop)."""
        if self.inline or self._thread is None or threading.current_thread() is self._thread:
            return True
        done = threading.Event()
        self._queue.put((done.set, ()))
        return done.wait(timeout)

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            self._call(*item)

    def _call(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - contained: logged and reported, the loop goes on
            self.errors += 1
            log.exception("listener %r failed", fn)
            if self.on_error is not None:
                try:
                    self.on_error(f"{getattr(fn, '__qualname__', fn)} failed: {exc}")
                except Exception:  # noqa: BLE001
                    log.exception("dispatcher error hook failed")

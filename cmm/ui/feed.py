"""One tab's subscription to the command API's queries (:meth:`cmm.api.CommandAPI.subscribe`), kept as a snapshot.

The API's hub thread runs the queries at most ``rate`` times a second as the tab's client and delivers only those
whose JSON value changed (the first delivery: all of them). :class:`Feed` keeps the last good value of each, so
the tab draws from a whole snapshot, and calls ``on_update(snapshot)`` on the hub's thread; a viser widget's update
is queued, so drawing never holds the hub up. A query that fails arrives once as ``{"error": message}``: it is
told to ``on_error(query, message)`` and its last good value stays (the bar is not redrawn from half a picture).
"""

from __future__ import annotations

import threading
from typing import Any, Callable

FIRST_DELIVERY_S = 5.0  # a tab waits this long at most for its first snapshot while it builds its widgets


def _failed(value: Any) -> str | None:
    """The message of a failed query's delivery (``{"error": message}``), else None."""
    if isinstance(value, dict) and len(value) == 1 and "error" in value:
        return str(value["error"])
    return None


class Feed:
    """The last snapshot of a tab's subscription (``queries``: {name: params}); ``close()`` ends it."""

    def __init__(self, api: Any, client: Any, queries: dict[str, dict[str, Any]], rate: float,
                 on_update: Callable[[dict[str, Any]], None],
                 on_error: Callable[[str, str], None] = lambda query, message: None) -> None:
        self.queries = {k: dict(v) for k, v in queries.items()}
        self.on_update = on_update
        self.on_error = on_error
        self._values: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._first = threading.Event()
        self.deliveries = 0
        self.closed = False
        self._api, self._client = api, client
        self.subscription = api.subscribe(client, self.queries, self._changed, rate=rate)

    def _changed(self, changed: dict[str, Any]) -> None:
        """The hub's delivery: never raises (the hub would close the subscription), a failure goes to on_error."""
        try:
            failures = []
            with self._lock:
                for name, value in changed.items():
                    message = _failed(value)
                    if message is None:
                        self._values[name] = value
                    else:
                        failures.append((name, message))
                self.deliveries += 1
            for name, message in failures:
                self.on_error(name, message)
            snapshot = self.snapshot()
            if snapshot is not None and not self.closed:
                self.on_update(snapshot)
        except Exception as exc:  # noqa: BLE001 - told, not raised into the API's thread
            self.on_error("update", f"{type(exc).__name__}: {exc}")
        finally:
            self._first.set()

    def snapshot(self) -> dict[str, Any] | None:
        """Every query's last good value; None until each has answered once."""
        with self._lock:
            return dict(self._values) if len(self._values) == len(self.queries) else None

    def query(self, name: str, /, **_params: Any) -> Any:
        """A query function over the snapshot (for the renderers that take one): the value last delivered, or,
        before the first delivery of ``name`` (a tab built while the hub is slow to come round), the query itself
        as this feed's client."""
        with self._lock:
            if name in self._values:
                return self._values[name]
        return self._api.invoke(self._client, name, **self.queries[name])

    def wait(self, timeout: float = FIRST_DELIVERY_S) -> dict[str, Any] | None:
        """The snapshot once the first delivery came (None after ``timeout`` or while a query fails)."""
        self._first.wait(timeout)
        return self.snapshot()

    def close(self) -> None:
        self.closed = True
        self.subscription.close()

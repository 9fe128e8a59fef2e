"""Subscriptions: change streams of the API's queries at a bounded rate (Klipper's ``objects/subscribe``).

A front end that shows the station (the page's status line, an OPC UA server, a dashboard) subscribes to the
queries it draws from instead of reading the station's objects: ``api.subscribe(client, {"state": {},
"position": {"frame": "part"}}, on_change, rate=10)``. One thread serves every subscription: at most ``rate``
times a second it runs each query (a snapshot, taken through the same API and the same role checks as a
call) and hands the subscriber only the queries whose JSON value changed since it last heard, so an idle
station sends nothing and a slow subscriber never holds up the machine or another subscriber. The first
delivery is the whole snapshot. A query that fails is delivered once as ``{"error": message}``.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

log = logging.getLogger(__name__)

MAX_RATE = 50.0  # Hz: no subscriber is served faster (the machine publishes at most this often anyway)
MIN_RATE = 0.1  # Hz

ChangeFn = Callable[[dict[str, Any]], None]


@dataclass(eq=False)
class Subscription:
    """One subscriber's queries, its rate and what it last heard; ``close()`` ends it."""

    client: Any
    queries: dict[str, dict[str, Any]]
    on_change: ChangeFn
    period: float
    _hub: "Subscriptions"
    last: dict[str, Any] = field(default_factory=dict)
    due: float = 0.0
    closed: bool = False

    def close(self) -> None:
        self.closed = True
        self._hub.remove(self)

    def __enter__(self) -> "Subscription":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Subscriptions:
    """The API's subscription hub: one daemon thread, started with the first subscriber, idle without one."""

    def __init__(self, snapshot: Callable[[Any, str, dict[str, Any]], Any]) -> None:
        # snapshot(client, query, params) -> a JSON value (the API runs the query verb and makes it JSON)
        self._snapshot = snapshot
        self._subs: list[Subscription] = []
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None

    def subscribe(self, client: Any, queries: dict[str, dict[str, Any] | None], on_change: ChangeFn, *,
                  rate: float = 10.0) -> Subscription:
        if not queries:
            raise ValueError("a subscription names at least one query")
        if not (MIN_RATE <= float(rate) <= MAX_RATE):  # also refuses NaN
            raise ValueError(f"a subscription's rate is {MIN_RATE:g} to {MAX_RATE:g} updates a second, "
                             f"not {rate!r}")
        sub = Subscription(client, {k: dict(v or {}) for k, v in queries.items()}, on_change, 1.0 / float(rate),
                           self)
        with self._lock:
            self._subs.append(sub)
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._serve, name="api-subscriptions", daemon=True)
                self._thread.start()
        self._wake.set()
        return sub

    def poll(self, sub: Subscription) -> dict[str, Any]:
        """Take the subscription's queries now; returns (and records) what changed since it last heard."""
        changed: dict[str, Any] = {}
        for name, params in sub.queries.items():
            try:
                value = self._snapshot(sub.client, name, params)
            except Exception as exc:  # noqa: BLE001 - a failing query is told to its subscriber, not raised
                value = {"error": str(exc) or type(exc).__name__}
            if name not in sub.last or sub.last[name] != value:
                sub.last[name] = value
                changed[name] = value
        return changed

    def count(self) -> int:
        with self._lock:
            return len(self._subs)

    def remove(self, sub: Subscription) -> None:
        with self._lock:
            if sub in self._subs:
                self._subs.remove(sub)

    def _serve(self) -> None:
        while True:
            with self._lock:
                subs = list(self._subs)
            if not subs:
                self._wake.wait(1.0)
                self._wake.clear()
                continue
            now = time.monotonic()
            for sub in subs:
                if sub.closed or now < sub.due:
                    continue
                sub.due = now + sub.period
                changed = self.poll(sub)
                if changed and not sub.closed:
                    try:
                        sub.on_change(changed)
                    except Exception:  # noqa: BLE001 - a broken subscriber must not end the others' streams
                        log.exception("a subscriber's change handler failed; its subscription is closed")
                        sub.close()
            wait = min((s.due for s in subs if not s.closed), default=now + 1.0) - time.monotonic()
            self._wake.wait(max(0.001, wait))
            self._wake.clear()

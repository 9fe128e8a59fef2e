"""Who may move the machine: one control holder at a time, everybody else observes.

Every browser (viser tab or pendant) starts as an observer. A client becomes
the *holder* with :meth:`Control.take`; only the holder may move the machine
(:meth:`Control.can_move`).

Rules (the station's safety contract, kept in this one place):

- A **local** client (it connects from the loopback interface, i.e. it sits at
  the station PC) may always take control without a code, also from another
  holder: the person at the machine can always see it and must always be able
  to take over.
- A **remote** client needs the access code. The code exists only when the
  server listens on the LAN (``lan=True``); a loopback-only server has no code
  and refuses every remote take. Codes are compared with
  :func:`hmac.compare_digest`. With the right code a remote client may also
  take control from another holder (the code is what the operator hands out).
- Whenever a holder stops being the holder (it releases, disconnects, or
  another client takes over) the ``on_holder_lost(client_id)`` hook is called,
  so the station can end any jog that client started (``station.jog_release``).
- ``on_change(fn)`` callbacks get ``(holder, previous)`` after every change.

Hooks and callbacks run outside the lock, in the caller's thread; an exception
in one of them is swallowed (recorded in :attr:`Control.errors`) so that a
broken UI callback can never keep control stuck.
"""

from __future__ import annotations

import hmac
import secrets
import threading
from typing import Callable

ChangeCallback = Callable[[str | None, str | None], None]


class Control:
    """Thread-safe single-holder control authority."""

    def __init__(self, lan: bool = False, *, access_code: str | None = None,
                 on_holder_lost: Callable[[str], None] | None = None) -> None:
        if access_code is not None and not access_code:
            raise ValueError("an access code must not be empty")
        if access_code is None and lan:
            access_code = secrets.token_urlsafe(8)
        self.access_code: str | None = access_code
        self.on_holder_lost = on_holder_lost
        self._lock = threading.RLock()
        self._holder: str | None = None
        self._callbacks: list[ChangeCallback] = []
        self.failed_attempts = 0
        self.errors: list[str] = []

    # --- queries ------------------------------------------------------------

    @property
    def holder(self) -> str | None:
        with self._lock:
            return self._holder

    def can_move(self, client_id: str) -> bool:
        with self._lock:
            return self._holder is not None and self._holder == client_id

    def code_ok(self, code: str | None) -> bool:
        """True when ``code`` is the access code (always False on a server without one)."""
        if self.access_code is None or not isinstance(code, str):
            return False
        return hmac.compare_digest(code.encode(), self.access_code.encode())

    # --- changes ------------------------------------------------------------

    def on_change(self, fn: ChangeCallback) -> Callable[[], None]:
        """Call ``fn(holder, previous)`` after every change; returns an unsubscribe function."""
        with self._lock:
            self._callbacks.append(fn)

        def unsubscribe() -> None:
            with self._lock:
                if fn in self._callbacks:
                    self._callbacks.remove(fn)
        return unsubscribe

    def take(self, client_id: str, code: str | None = None, is_local: bool = False) -> bool:
        """Make ``client_id`` the holder; False (and nothing changes) when it is not allowed."""
        if not client_id:
            raise ValueError("a client needs a non-empty id")
        allowed = is_local or self.code_ok(code)
        with self._lock:
            if not allowed:
                self.failed_attempts += 1
                return False
            previous = self._holder
            if previous == client_id:
                return True
            self._holder = client_id
        self._changed(client_id, previous)
        return True

    def release(self, client_id: str) -> bool:
        """Give up control; False when ``client_id`` was not the holder."""
        with self._lock:
            if self._holder != client_id:
                return False
            self._holder = None
        self._changed(None, client_id)
        return True

    def disconnected(self, client_id: str) -> None:
        """A client went away: if it held control, control is released (and ``on_holder_lost`` called)."""
        self.release(client_id)

    def _changed(self, holder: str | None, previous: str | None) -> None:
        if previous is not None and self.on_holder_lost is not None:
            self._call(self.on_holder_lost, previous)
        with self._lock:
            callbacks = list(self._callbacks)
        for fn in callbacks:
            self._call(fn, holder, previous)

    def _call(self, fn: Callable[..., object], *args: object) -> None:
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - a broken callback must not keep control stuck
            self.errors.append(f"{getattr(fn, '__name__', fn)!s} failed: {exc}")

"""Who may command the machine: the one access policy of every front end (viser page, pendant, I++ DME, CLI).

Three rules live here and nowhere else:

1. **Which connection is local** (:func:`is_local_connection`): it comes from the loopback interface and,
   for a web page, names a loopback host in its ``Host`` header. A local client sits at the station PC.
2. **Which web page may connect** (:class:`OriginPolicy`): the station's own pages only (no cross-site
   WebSocket, no DNS rebinding).
3. **Who holds control and who may stop** (:class:`Control`, the one holder): only the holder moves the
   machine; STOP / E-STOP / cancel / jog release follow :meth:`Control.may_stop`.

The control core asks a policy once per command (``refusal(client, command) -> str | None``):
:class:`HolderPolicy` over the station's :class:`Control`, :class:`OpenPolicy` for a station driven by
one script. ``client`` is a :class:`Client` (id, local, authenticated) or a plain id string; ``None`` is
the station itself (scripts, the CLI, the homing cycle).

The holder (:class:`Control`)
-----------------------------

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
- Access-code guessing is rate-limited per client (its network address when
  known): after a wrong code the next attempt from that client is accepted
  no sooner than 0.2 s later (at most 5 attempts a second), and from the
  sixth failure on the wait doubles each time, up to 30 s. An attempt made
  while a client must wait is refused without looking at the code. The right
  code resets the count. The same rule holds on every port (viser page,
  pendant, I++ DME), because they all call :meth:`Control.try_take`.
- STOP and E-STOP (:meth:`Control.may_stop`): the holder may always stop; a
  local client (at the station PC) may always stop; a LAN client may stop
  when it has given the access code on its connection, or, as an anonymous
  observer, only when the operator allowed LAN stops (``lan_stop``, the
  ``--lan-stop`` option or the operator's switch on a local page).
- Whenever a holder stops being the holder (it releases, disconnects, or
  another client takes over) the ``on_holder_lost(client_id)`` hook is called,
  so the station can end any jog that client started (``controller.jog_release``).
- ``on_change(fn)`` callbacks get ``(holder, previous)`` after every change.

Hooks and callbacks run outside the lock, in the caller's thread; an exception
in one of them is swallowed (recorded in :attr:`Control.errors`) so that a
broken UI callback can never keep control stuck.

Web pages (:class:`OriginPolicy`)
---------------------------------

Two attacks are closed here, on every port the station serves:

- *Cross-site WebSocket hijacking*: any page open in a browser on the station
  PC (or on the LAN) can open a WebSocket to 127.0.0.1:8080. Browsers always
  send an ``Origin`` header with it; we accept it only when it names the very
  host the browser asked for (``Origin == http://<Host>``), i.e. the page was
  served by the station itself.
- *DNS rebinding*: a page from ``evil.example`` whose name is re-pointed at
  127.0.0.1 passes the test above (its Origin and Host both say
  ``evil.example``). So the ``Host`` itself must be one of the station's own
  names: an IP literal (a page cannot rebind an IP), ``localhost``, this
  computer's host names, or a name the operator allowed (``--allow-host``).

A client that sends no ``Origin`` at all is not a web page (scripts, tests,
the I++ client); it is judged by the access rules like any other client.
"""

from __future__ import annotations

import hmac
import ipaddress
import logging
import secrets
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping, Protocol

from ..api.clients import AccessRefused, Client, client_of  # noqa: F401 - the API's, re-exported here
from .modes import RECORD_COMMANDS, SAFETY_COMMANDS

log = logging.getLogger(__name__)


class AccessPolicy(Protocol):
    def refusal(self, client: Client | None, command: str) -> str | None: ...


class OpenPolicy:
    """Everything allowed: a station driven by one script or the CLI."""

    def refusal(self, client: Client | None, command: str) -> str | None:
        return None


class HolderPolicy:
    """Only the holder of ``control`` (:class:`Control`) moves the machine; STOP, E-STOP, cancel and jog release
    by :meth:`Control.may_stop` (a holder may always release its own jog); the session journal (``record``: a
    note, a routine saved) is written by the holder or a local client."""

    def __init__(self, control: "Control") -> None:
        self.control = control

    def refusal(self, client: Client | None, command: str) -> str | None:
        client = client_of(client)
        if client is None:
            return None
        if command in SAFETY_COMMANDS:
            if self.control.may_stop(client.id, is_local=client.local, authenticated=client.authenticated) \
                    or (command == "jog_release" and self.control.can_move(client.id)):
                return None
            return self.control.stop_refusal()
        if self.control.can_move(client.id):
            return None
        if command in RECORD_COMMANDS:
            if client.local:
                return None
            return ("this client only observes: only the control holder or the station's own computer writes in "
                    "the session journal")
        # the operator's sentence for every front end (the pages' and the pendant's button is "Take control")
        action = "to jog" if command in ("jog", "step") else "first"
        holder = self.control.holder
        if holder is not None:
            return (f"this client only observes (not in control): control is held by {self.control.name(holder)}; "
                    f"press Take control {action}")
        return f"this client only observes (not in control): press Take control {action}"


ChangeCallback = Callable[[str | None, str | None], None]

CODE_INTERVAL = 0.2  # s between access-code attempts of one client (5 a second)
FREE_FAILURES = 5  # wrong codes before the wait starts to double
MAX_WAIT = 30.0  # s, the longest wait after many wrong codes


@dataclass
class _Attempts:
    failures: int = 0
    not_before: float = 0.0


class Control:
    """Thread-safe single-holder control authority."""

    def __init__(self, lan: bool = False, *, access_code: str | None = None,
                 on_holder_lost: Callable[[str], None] | None = None, lan_stop: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
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
        self.lan_stop = lan_stop  # anonymous LAN observers may press STOP / E-STOP
        self._clock = clock
        self._attempts: dict[str, _Attempts] = {}
        self._names: dict[str, str] = {}  # client id -> the person's name, for every message that names a client

    # --- queries ------------------------------------------------------------

    def set_name(self, client_id: str, name: str) -> str:
        """The person behind ``client_id`` ("Maria"); ValueError says what is wrong with the name. Returns it."""
        name = " ".join(str(name or "").split())
        if not name:
            raise ValueError("enter your name (the control messages and the report show it)")
        if len(name) > 40 or any(not c.isprintable() for c in name):
            raise ValueError(f"a name is at most 40 printable characters, got {len(name)}")
        with self._lock:
            self._names[client_id] = name
        return name

    def name(self, client_id: str | None) -> str:
        """How messages name a client: the person's name, else its client id ("nobody" for None)."""
        if client_id is None:
            return "nobody"
        with self._lock:
            return self._names.get(client_id, client_id)

    @property
    def holder_name(self) -> str | None:
        """The holder as messages name it (None: nobody holds control)."""
        holder = self.holder
        return None if holder is None else self.name(holder)

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

    def may_stop(self, client_id: str, *, is_local: bool, authenticated: bool = False) -> bool:
        """The one STOP / E-STOP policy of every front end (see the module text)."""
        return is_local or authenticated or self.can_move(client_id) or self.lan_stop

    def stop_refusal(self) -> str:
        return ("stop refused: this browser is an anonymous LAN observer. Enter the access code, use the "
                "station's own screen or the machine's E-stop (the operator can allow LAN stops)")

    def set_lan_stop(self, allowed: bool, *, is_local: bool) -> None:
        """Allow or forbid STOP from anonymous LAN observers; only the person at the station may."""
        if not is_local:
            raise AccessRefused("only the station's own computer may change who can stop the machine")
        self.lan_stop = bool(allowed)

    def try_take(self, client_id: str, code: str | None = None, is_local: bool = False,
                 peer: str | None = None) -> str | None:
        """Make ``client_id`` the holder; None when it is, else the reason it was refused.

        ``peer`` names the client for the rate limit (its network address); the
        client id is used when it is not known.
        """
        if not client_id:
            raise ValueError("a client needs a non-empty id")
        key = peer or client_id
        now = self._clock()
        with self._lock:
            attempts = self._attempts.get(key)
            if not is_local and attempts is not None and now < attempts.not_before:
                return (f"too many wrong access codes: wait {attempts.not_before - now:.1f} s "
                        "before trying again")
            allowed = is_local or self.code_ok(code)
            if not allowed:
                self.failed_attempts += 1
                attempts = self._attempts.setdefault(key, _Attempts())
                attempts.failures += 1
                extra = max(0, attempts.failures - FREE_FAILURES)
                attempts.not_before = now + min(MAX_WAIT, CODE_INTERVAL * 2 ** extra)
                if len(self._attempts) > 1000:  # a flood of addresses must not grow memory without bound
                    self._attempts.pop(next(iter(self._attempts)))
                if self.access_code is None:
                    return ("this station accepts control only from its own computer: "
                            "start it with --lan to allow control from the network")
                return "enter the access code shown on the station" if not code else "wrong access code: control refused"
            self._attempts.pop(key, None)
            previous = self._holder
            if previous == client_id:
                return None
            self._holder = client_id
        self._changed(client_id, previous)
        return None

    def take(self, client_id: str, code: str | None = None, is_local: bool = False,
             peer: str | None = None) -> bool:
        """Make ``client_id`` the holder; False (and nothing changes) when it is not allowed."""
        return self.try_take(client_id, code, is_local, peer) is None

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


def take_control(control: "Control | None", client: Any, code: str | None = None, peer: str | None = None) -> dict:
    """The ``take_control`` verb: ``client`` becomes the holder (a local client, or one whose listener grants
    control, without a code; a LAN client with the access code); AccessRefused says why not. Without a holder
    (a station driven by one script) every client may move: nothing to take."""
    who = client_of(client)
    if control is None or who is None:
        return {"control": True, "message": "this station has no control holder: every client may command it"}
    why = control.try_take(who.id, code if isinstance(code, str) and code else None,
                           is_local=who.local or who.listener_grants_control or who.user is not None, peer=peer)
    if why is not None:
        raise AccessRefused(why)
    if who.user is not None:  # a user who logged in: messages and records name the person
        control.set_name(who.id, who.user)
    return {"control": True, "message": f"{control.name(who.id)} controls the machine"}


def release_control(control: "Control | None", client: Any) -> dict:
    """The ``release_control`` verb: the holder gives control up (a client that did not hold it: nothing changes)."""
    who = client_of(client)
    if control is None or who is None:
        return {"released": False, "message": "this station has no control holder"}
    released = control.release(who.id)
    return {"released": released, "message": "control released" if released else "this client did not hold control"}


# --- connections: local or not, which web page ---------------------------------------------


def split_host(host_header: str) -> str:
    """The host name of a ``Host`` header, lower case, without port or IPv6 brackets."""
    host = host_header.strip()
    if host.startswith("["):
        host = host[1:host.find("]")] if "]" in host else host[1:]
    elif host.count(":") == 1:
        host = host.split(":", 1)[0]
    return host.lower().rstrip(".")


def is_loopback_host(host_header: str) -> bool:
    """A ``Host`` header (or an address a server listens on) that names this PC only: ``localhost``, a loopback IP."""
    host = split_host(host_header)
    if host == "localhost" or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def is_loopback_peer(address: Any) -> bool:
    """True when a socket peer address ``(ip, port, ...)`` is on the loopback interface."""
    host = address[0] if isinstance(address, (tuple, list)) and address else address
    if not isinstance(host, str):
        return False
    try:
        ip = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return host == "localhost"
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return ip.is_loopback


def own_names() -> set[str]:
    """This computer's host names as LAN browsers may type them."""
    names = set()
    for fn in (socket.gethostname, socket.getfqdn):
        try:
            name = fn().lower().rstrip(".")
        except OSError:
            continue
        if name:
            names.update({name, f"{name.split('.', 1)[0]}.local"})
    return names


class OriginPolicy:
    """Decide whether a WebSocket handshake (its headers) may come in."""

    def __init__(self, *, lan: bool = False, allow_hosts: Iterable[str] = ()) -> None:
        self.lan = lan
        self.names = {"localhost"} | {split_host(h) for h in allow_hosts if h}
        if lan:
            self.names |= own_names()
        self.refused: list[str] = []  # reasons, newest last (shown in logs and tests)
        self.ports: set[int] = set()  # the station's own web ports: its pages on one may connect to another

    def host_allowed(self, host_header: str) -> bool:
        host = split_host(host_header)
        if not host:
            return False
        try:
            ip = ipaddress.ip_address(host)
        except ValueError:
            return host in self.names or host.endswith(".localhost")
        return ip.is_loopback or self.lan  # an IP literal cannot be rebound by a foreign page

    def check(self, headers: Mapping[str, str]) -> str | None:
        """None when the connection may proceed, else the reason it is refused."""
        host = headers.get("Host") or ""
        if not self.host_allowed(host):
            return (f"refused a connection for unknown host {host!r}: open the station by its address "
                    "(or start it with --allow-host NAME)")
        origin = headers.get("Origin")
        name = host.rsplit(":", 1)[0] if not host.endswith("]") else host
        own = {f"{scheme}://{h}".lower() for scheme in ("http", "https")
               for h in [host] + [f"{name}:{p}" for p in self.ports]}  # the same host, a port of the station
        if origin is not None and origin.rstrip("/").lower() not in own:
            return f"refused a connection from another web page ({origin}): only the station's own pages may control it"
        return None

    def refuse(self, reason: str) -> None:
        self.refused.append(reason)
        del self.refused[:-50]
        log.warning("%s", reason)


FORWARDED_FOR = "X-Forwarded-For"  # the header the station's TLS proxy sets to the LAN peer's address


def forwarded_peer(peer: Any, headers: Any, behind_proxy: bool) -> Any:
    """The client's own address: behind the station's TLS proxy (its pages listen on loopback only) the socket
    peer is the proxy on 127.0.0.1, and the proxy names the real one in ``X-Forwarded-For`` (after dropping any the
    client sent); otherwise, or from any other peer, the socket peer itself (a LAN client cannot choose its key)."""
    if not behind_proxy or not is_loopback_peer(peer) or headers is None:
        return peer
    value = headers.get(FORWARDED_FOR) if hasattr(headers, "get") else None
    if not value:
        return peer
    address = str(value).split(",")[0].strip()
    try:
        ipaddress.ip_address(address.split("%", 1)[0])
    except ValueError:
        return peer
    return (address, 0)


def is_local_connection(peer: Any, host_header: str | None = None) -> bool:
    """The one rule for "this client sits at the station PC": its socket peer is on the loopback interface and,
    for a web page, its ``Host`` header names a loopback host (a LAN page cannot pass by naming us)."""
    return is_loopback_peer(peer) and (host_header is None or is_loopback_host(host_header))

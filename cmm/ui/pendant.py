"""The jog pendant server: web/pendant.html + pendant.js over HTTP and a JSON WebSocket, on one port.

One small asyncio loop in a background thread (the ``websockets`` library's
``process_request`` hook serves the two static files; ``/ws`` is the
WebSocket). The server only translates: each message becomes a verb of the
command API (``jog_hold``, ``jog_release``, ``step``, ``stop``, or any verb with
``call``) sent as this pendant's client; the jog-hold pipeline, the access
policy and the machine's state are the control core's, and what it shows comes from the API's queries (the
state, the configured jog speeds, the dead-man; the machine's events, in process). Every API call runs
on one worker thread, in arrival order, so the event loop never waits on the
serial bus and a release can never overtake the jog it ends; a STOP goes to
the stop verb on a thread of its own, not through that worker's queue.

Protocol (JSON text messages)
-----------------------------
client -> server

- ``{"type": "hello"}``: the server answers ``{"type": "hello", "client": id,
  "local": bool, "code_required": bool, "speeds": {"jog_fast", "jog_slow",
  "jog_fine"}, "deadman_ms": 150, "state_hz": 20}``. The connection stays an
  observer. ``hello`` with a ``"code"`` member (``null`` from a local
  pendant) also asks for control, exactly like ``take``. ``hello`` with an
  ``"as"`` member (the station page's grant token, :mod:`cmm.ui.pendant_grants`)
  makes the connection act as that page's client (its control, its standing);
  the answer then has ``"shared": true``, or an error says why the grant was refused.
- ``{"type": "take", "code": "..."}``: take control (:class:`~cmm.control.access.Control`
  rules: local clients need no code, remote clients need the LAN access code).
  Answer ``{"type": "control", "control": true}`` or ``{"type": "error", ...}``.
- ``{"type": "login", "user": "...", "password": "..."}`` (a station with a user file): this connection acts
  as that user from now on (its role is checked by the command API; the name ``token`` with an API token as
  the password logs a program in). Answer ``{"type": "login", "user", "role"}`` or an ``error``.
- ``{"type": "observe"}``: give control back (any jog of this pendant is ended).
- ``{"type": "jog", "v": [vx, vy, vz]}``: velocity jog in mm/s, fed to the core's jog-hold pipeline
  (:mod:`cmm.control.jog`): each component limited to ``speeds.jog_fast`` (a ``notice`` says so); an axis
  at the end of its travel it would jog towards is left out (a ``notice``), a jog of only such axes is
  refused (an ``error``), and a jog the travel clips as it runs gets a ``notice``; all zeros is a release. Only the control holder may jog; it must repeat the message (every 50 ms) while
  the jog lasts.
- ``{"type": "release"}``: end this pendant's jog now (decelerate to a stop); from a pendant that does not
  hold control and was not jogging it is ignored quietly.
- ``{"type": "hold", "button": "hold X +"}``: a station page's jog button is held; only from the page's
  hold refresher (``web/hold_worker.js``, a Web Worker with the page's refresher grant), repeated every
  40 ms; the page says what the button means (its speed, armed or not).
- ``{"type": "step", "axis": 0 | 1 | 2, "mm": signed size}``: one step jog (keyboard step mode), up to
  10 mm; only the control holder.
- ``{"type": "call", "id": n, "method": "...", "params": {...}, "wait": bool}``: any verb of the command
  API (:mod:`cmm.api`: move, probe, home, ...), as this pendant's client; answered with
  ``{"type": "result", "id": n, "result": ...}`` or ``{"type": "result", "id": n, "error": {"code",
  "message"}}``; ``wait`` answers when a motion has ended (with the tip position or the hit).
- ``{"type": "stop"}``: controlled stop of whatever the machine is doing, under
  the station's one STOP policy (:meth:`~cmm.control.access.Control.may_stop`, the
  same as the viser page's): the holder, a local pendant, or one that gave
  the access code on this connection; an anonymous LAN observer only when the
  operator allowed LAN stops. ``{"type": "estop"}``: the emergency stop, under the same policy. Each press runs
  on a thread of its own and reaches the modules at once (the operator's stop notes in the docs folder); the answer, a ``notice``
  ("stopped: every axis stands still") or an ``error``, comes when every axis stands still. The station page's
  STOP and E-STOP buttons and its Esc / Space keys send these through the page's hold refresher.

server -> client

- ``{"type": "state", "pos": [x, y, z], "vel": [...], "moving": bool,
  "jogging": bool, "probe": bool, "control": bool, "holder": "you" | "other" | null, "holder_name": str | null}``
  at ``state_hz`` (20 Hz).
- ``{"type": "error", "message": "..."}`` in an operator's words; ``{"type": "notice", "message": "..."}``
  for what the operator should know but is not refused (a jog speed limited).

Dead-man
--------
The jog-hold pipeline's grace is the machine's dead-man (``[jog] deadman_timeout``, 0.15 s without a jog
refresh, timed next to the bus): a pendant that goes quiet stops 0.15 s after its last message plus the
braking, whatever happens to the network or this process; a closed connection releases at once.

Security
--------
A WebSocket handshake is checked by :class:`~cmm.control.access.OriginPolicy` (the
same rules as the viser port): a foreign ``Origin`` or an unknown ``Host``
(DNS rebinding) is refused with 403. A connection counts as *local* only when
it comes from a loopback address *and* names a loopback host in its ``Host``
header. Access codes are rate-limited per network address by the shared
:class:`~cmm.control.access.Control`.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import itertools
import json
import logging
import math
import os
import sys
import threading
import time
from dataclasses import dataclass
from http import HTTPStatus
from pathlib import Path
from typing import Any, Callable

from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed, InvalidMessage
from websockets.http11 import Request, Response

from ..control import Client, Refused
from ..control.priority import raise_priority_on
from ..control.access import Control, OriginPolicy, forwarded_peer, is_local_connection, is_loopback_host
from .pendant_grants import Grant, Grants

STATE_HZ = 20.0
ERROR_INTERVAL = 0.5  # s between repeated errors for refused jogs

log = logging.getLogger(__name__)


class _QuietHandshakes(logging.Filter):
    """Browsers open spare connections and close them unused; that is not an error worth a traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage().startswith("opening handshake failed") and record.exc_info:
            exc = record.exc_info[1]
            if isinstance(exc, InvalidMessage) and isinstance(exc.__cause__, EOFError):
                return False
        return True


log.addFilter(_QuietHandshakes())

STATIC = {
    "/": ("pendant.html", "text/html; charset=utf-8"),
    "/pendant.html": ("pendant.html", "text/html; charset=utf-8"),
    "/pendant.js": ("pendant.js", "text/javascript; charset=utf-8"),
}


def web_dir() -> Path:
    """Where pendant.html lives: $CMM_WEB_DIR, the repository's web/ (source checkout, editable
    install), or <prefix>/share/cmm/web (wheel install with the data-files entry)."""
    candidates = []
    if os.environ.get("CMM_WEB_DIR"):
        candidates.append(Path(os.environ["CMM_WEB_DIR"]))
    candidates.append(Path(__file__).resolve().parents[2] / "web")
    candidates.append(Path(sys.prefix) / "share" / "cmm" / "web")
    for c in candidates:
        if (c / "pendant.html").is_file():
            return c
    raise FileNotFoundError("the pendant page web/pendant.html was not found in " + ", ".join(map(str, candidates)))


@dataclass(eq=False)
class _Session:
    ws: ServerConnection
    client_id: str
    local: bool
    authenticated: bool = False  # local, or gave the right code on this connection
    jogging: bool = False
    last_note: str | None = None  # the last speed-limit notice sent (said once per jog)
    last_message: float = 0.0
    last_error: float = 0.0
    grant: Grant | None = None  # the embedded pendant of a station page acts as that page's client
    user: str | None = None  # who logged in on this connection (a station with a user file), and their role
    role: str | None = None

    address: Any = None  # where it connected from (behind the TLS proxy: the address the proxy forwarded)

    @property
    def peer(self) -> str | None:
        """The network address this pendant connected from."""
        address = self.address or self.ws.remote_address
        return address[0] if address else None


class PendantServer:
    """Handle returned by :func:`start_pendant_server`: ``url``, ``ws_url``, ``port``, ``close()``."""

    def __init__(self, api: Any, control: Control, host: str = "127.0.0.1", port: int = 0, *,
                 state_hz: float = STATE_HZ, static_dir: Path | None = None,
                 origins: OriginPolicy | None = None, ssl: Any = None, users: Any = None) -> None:
        self.ssl = ssl  # an ssl.SSLContext: the page and its WebSocket over https / wss (cmm.control.tls)
        self.users = users  # cmm.control.users.UserStore: connections log in; None: the local, no-login mode
        self.control = control
        self.origins = origins or OriginPolicy(lan=not is_loopback_host(host))
        self.host = host
        self.behind_tls_proxy = False  # cmm serve --tls: on loopback behind the proxy, which forwards the address
        self.state_hz = state_hz
        root = static_dir or web_dir()
        self._files = {path: ((root / name).read_bytes(), ctype) for path, (name, ctype) in STATIC.items()}
        self._ids = itertools.count(1)
        self._sessions: set[_Session] = set()
        self._worker = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="pendant-station")
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self.port = 0
        self.errors: list[str] = []  # station calls that failed unexpectedly
        self.commands = api  # every command and every read goes through the command API as our client
        self.clock = api.invoke(None, "clock")  # the machine's clock: when a message was heard (the dead-man's start)
        self.grants = Grants()  # station pages' embedded pendants (see revoke)
        if api.invoke(None, "control_policy") is not control:  # the core refuses in its words: it must know who holds control
            raise ValueError("the pendant's Control is not the station's access policy: wire it where both are "
                             "built (the use_policy verb)")
        self._unsubscribe = api.invoke(None, "watch_machine", on_event=self._on_machine_event)
        self._thread = threading.Thread(target=self._run_thread, args=(port,), name="pendant-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(10):
            raise RuntimeError("the pendant server did not start within 10 s")
        if self._error is not None:
            raise self._error

    # --- addresses ------------------------------------------------------------

    @property
    def _url_host(self) -> str:
        host = self.host
        if host in ("", "0.0.0.0", "::"):
            host = "127.0.0.1"  # a wildcard bind is reachable locally through loopback
        return f"[{host}]" if ":" in host else host

    @property
    def url(self) -> str:
        return f"{'https' if self.ssl is not None else 'http'}://{self._url_host}:{self.port}/"

    @property
    def ws_url(self) -> str:
        return f"{'wss' if self.ssl is not None else 'ws'}://{self._url_host}:{self.port}/ws"

    # --- life cycle ----------------------------------------------------------

    def _run_thread(self, port: int) -> None:
        raise_priority_on(self.clock)  # a release reaches the machine loop first, whatever the web load
        try:
            asyncio.run(self._main(port))
        except BaseException as exc:  # noqa: BLE001 - reported to the starting thread
            self._error = exc
            self._ready.set()

    async def _main(self, port: int) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        # open_timeout: the TLS and WebSocket handshakes of a tablet joining a busy station (websockets' 10 s
        # closed a wss handshake without an answer beside two CPU hogs)
        async with serve(self._handler, self.host, port, process_request=self._process_request,
                         ping_interval=5, ping_timeout=5, max_size=4096, compression=None, open_timeout=60,
                         logger=log, ssl=self.ssl) as server:
            self.port = next(iter(server.sockets)).getsockname()[1]
            self._ready.set()
            await self._stop.wait()
            # the connections' finally blocks release their jogs while the server closes them

    def close(self) -> None:
        self._unsubscribe()
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(5)
        self._worker.shutdown(wait=True)

    def __enter__(self) -> "PendantServer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # --- HTTP -----------------------------------------------------------------

    def _process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        path = request.path.split("?", 1)[0]
        if path == "/ws":
            reason = self.origins.check(request.headers)
            if reason is not None:
                self.origins.refuse(reason)
                return connection.respond(HTTPStatus.FORBIDDEN, reason + "\n")
            return None
        if path in self._files:
            body, ctype = self._files[path]
            headers = Headers([("Date", time.strftime("%a, %d %b %Y %H:%M:%S GMT", time.gmtime())),
                               ("Connection", "close"), ("Content-Length", str(len(body))),
                               ("Content-Type", ctype), ("Cache-Control", "no-store"),
                               ("X-Content-Type-Options", "nosniff")])
            return Response(200, "OK", headers, body)
        return connection.respond(HTTPStatus.NOT_FOUND, "not found\n")

    # --- WebSocket -------------------------------------------------------------

    async def _call(self, fn: Callable[..., Any], *args: Any) -> Any:
        assert self._loop is not None
        return await self._loop.run_in_executor(self._worker, fn, *args)

    async def _send(self, session: _Session, message: dict) -> None:
        try:
            await session.ws.send(json.dumps(message))
        except ConnectionClosed:
            pass

    async def _error_msg(self, session: _Session, message: str, *, throttle: bool = False) -> None:
        now = time.monotonic()
        if throttle and now - session.last_error < ERROR_INTERVAL:
            return
        session.last_error = now
        await self._send(session, {"type": "error", "message": message})

    async def _handler(self, ws: ServerConnection) -> None:
        host = ws.request.headers.get("Host", "") if ws.request is not None else ""
        address = forwarded_peer(ws.remote_address, ws.request.headers if ws.request is not None else None,
                                 self.behind_tls_proxy)
        local = is_local_connection(address, host)
        session = _Session(ws, f"pendant-{next(self._ids)}", local, authenticated=local,
                           last_message=time.monotonic(), address=address)
        self._sessions.add(session)
        tasks = [asyncio.create_task(self._send_states(session))]
        try:
            async for raw in ws:
                session.last_message = time.monotonic()
                # the machine's clock as the message arrives: a jog's dead-man runs from here (cmm.control.jog)
                await self._on_message(session, raw, self.clock.now())
        except ConnectionClosed:
            pass
        finally:
            for t in tasks:
                t.cancel()
            self._sessions.discard(session)
            await self._call(self._gone, session)

    def _gone(self, session: _Session) -> None:
        if session.jogging:
            session.jogging = False
            self._release(session)
        if session.grant is not None:
            self.grants.unclaim(session.grant)  # the page keeps its control
            return
        self.commands.invoke(self._own(session), "release_control")  # a holder that goes away gives control up

    def revoke(self, token: str | None) -> None:
        """The station page behind a grant went away: the token dies, its pendant connections are closed."""
        grant = self.grants.revoke(token)
        if grant is None or self._loop is None:
            return
        for session in list(self._sessions):
            if session.grant is grant:
                self._loop.call_soon_threadsafe(lambda ws=session.ws: asyncio.ensure_future(
                    ws.close(1008, "the station page closed")))

    async def _adopt(self, session: _Session, token: Any) -> None:
        grant = self.grants.claim(token, session.peer)
        if isinstance(grant, str):
            return await self._error_msg(session, grant)
        if session.grant is not None:
            self.grants.unclaim(session.grant)
        session.grant = grant
        session.client_id = grant.owner().id

    def _station_call(self, fn: Callable[..., Any], *args: Any) -> str | None:
        """Run a station action; an error comes back as the operator's sentence."""
        try:
            fn(*args)
        except Exception as exc:  # noqa: BLE001 - every station refusal is reported, never raised into the loop
            if not isinstance(exc, RuntimeError):  # MotionError / MeasurementError are RuntimeErrors
                self.errors.append(f"{type(exc).__name__}: {exc}")
            return str(exc) or type(exc).__name__
        return None

    async def _send_states(self, session: _Session) -> None:
        period = 1.0 / self.state_hz
        while True:
            cs = self.commands.invoke(None, "state")
            st = cs.machine
            holder = self.control.holder
            msg: dict[str, Any] = {
                "type": "state",
                "control": holder == session.client_id,
                "holder": None if holder is None else ("you" if holder == session.client_id else "other"),
                # the holder's name when they gave one (the start dialog): "observer: Maria has control"
                "holder_name": None if holder is None or self.control.name(holder) == holder
                else self.control.name(holder),
            }
            msg.update(mode=cs.mode.value, reason=cs.reason, homed=cs.homed)
            if st is not None:
                msg.update(pos=[round(a.mm, 4) for a in st.axes], vel=[round(a.velocity, 3) for a in st.axes],
                           moving=bool(st.moving), jogging=bool(st.jogging), probe=bool(st.probe_triggered))
                if session.jogging and not st.jogging:
                    session.jogging = False  # the machine loop ended it (dead-man, limit, contact, stop)
            await self._send(session, msg)
            await asyncio.sleep(period)

    def _speeds(self) -> dict[str, float]:
        s = self.commands.invoke(None, "machine_config").speeds
        return {"jog_fast": s.jog_fast, "jog_slow": s.jog_slow, "jog_fine": s.jog_fine}

    async def _on_message(self, session: _Session, raw: Any, heard: float | None = None) -> None:
        try:
            msg = json.loads(raw)
        except (TypeError, ValueError):
            return await self._error_msg(session, "a pendant message must be JSON text")
        if not isinstance(msg, dict):
            return await self._error_msg(session, "a pendant message must be a JSON object")
        kind = msg.get("type")
        if kind == "hello":
            if "as" in msg:
                await self._adopt(session, msg.get("as"))
            await self._send(session, {
                "shared": session.grant is not None,
                "type": "hello", "client": session.client_id, "local": session.local,
                "code_required": not session.local, "lan": self.control.access_code is not None,
                "users": self.users is not None,
                "speeds": self._speeds(), "deadman_ms": round(self.commands.invoke(None, "jog_settings")["grace"] * 1000), "state_hz": self.state_hz})
            if "code" in msg:
                await self._take(session, msg.get("code"))
        elif kind == "take":
            await self._take(session, msg.get("code"))
        elif kind == "login":
            await self._login(session, msg.get("user"), msg.get("password"))
        elif kind == "observe":
            if session.jogging:
                session.jogging = False
                self._release(session)
            await self._call(self.commands.invoke, self._own(session), "release_control")
            await self._send(session, {"type": "control", "control": False})
        elif kind == "jog":
            await self._jog(session, msg.get("v"), heard=heard)
        elif kind == "hold":
            await self._hold_button(session, msg.get("button"), heard)
        elif kind == "release":
            self._let_go(session, lapse=msg.get("lapse") is True)
        elif kind == "step":
            await self._step(session, msg.get("axis"), msg.get("mm"))
        elif kind == "call":
            await self._command(session, msg)
        elif kind in ("stop", "estop"):
            session.jogging = False
            # a thread of its own per press, never a pool another call can fill: the press reaches the modules at
            # once (the core sends it from this thread) and its answer comes when every axis stands still
            # the press itself right here, as the message is read (no other thread to be scheduled first)
            try:
                pressed = self.commands.invoke(self._who(session), "press", verb=kind)  # the core checks may_stop
            except Refused as exc:
                return await self._error_msg(session, str(exc))
            except Exception:  # noqa: BLE001 - then the verb, on its own thread, as before
                log.exception("the direct %s failed", kind)
                pressed = None
            report = await self._own_thread(self._stop_machine, self._who(session), kind, pressed)
            if not report["ok"]:
                await self._error_msg(session, report["message"])
            else:
                await self._send(session, {"type": "notice", "message": report["message"]})
        else:
            await self._error_msg(session, f"unknown pendant message type {kind!r}")

    async def _login(self, session: _Session, user: Any, password: Any) -> None:
        if self.users is None:
            return await self._error_msg(session, "this station has no users: no login needed")
        try:
            login = await asyncio.to_thread(self.users.login, str(user or ""), str(password or ""))
        except PermissionError as exc:
            return await self._error_msg(session, str(exc))
        session.user, session.role = login.user, login.role
        await self._send(session, {"type": "login", "user": login.user, "role": login.role})

    async def _command(self, session: _Session, msg: dict) -> None:
        """Any verb of the command API: ``{"type": "call", "id", "method", "params", "wait"}`` ->
        ``{"type": "result", "id", "result" | "error": {"code", "message"}}`` (``wait``: a motion's end)."""
        request = {"id": msg.get("id"), "method": msg.get("method"), "params": msg.get("params")}
        answer = await asyncio.to_thread(self.commands.request, self._who(session), request,
                                         wait=bool(msg.get("wait")), timeout=120.0)
        await self._send(session, {"type": "result", **answer})

    async def _take(self, session: _Session, code: Any) -> None:
        code = code if isinstance(code, str) else None
        answer = await self._call(self.commands.request, self._own(session),
                                  {"method": "take_control", "params": {"code": code, "peer": session.peer}})
        if "error" not in answer:
            session.authenticated = True
            return await self._send(session, {"type": "control", "control": True})
        await self._error_msg(session, answer["error"]["message"])

    async def _hold_button(self, session: _Session, label: Any, heard: float | None = None) -> None:
        """A station page's jog button is held (its hold refresher, web/hold_worker.js, acting as the page):
        the page says what the button means now (speed, armed)."""
        hold = None if session.grant is None else session.grant.hold
        if hold is None:
            return await self._error_msg(session, "only a station page's hold refresher sends button holds",
                                         throttle=True)
        try:
            v, probe = hold(label)
        except ValueError as exc:
            return await self._error_msg(session, str(exc), throttle=True)
        await self._jog(session, [float(x) for x in v], probe=probe, heard=heard)

    async def _jog(self, session: _Session, v: Any, *, probe: bool = False, heard: float | None = None) -> None:
        """A jog refresh (received at ``heard``): fed to the core's jog-hold pipeline (access, clamp, release
        sequence, grace), which never waits for the machine loop, so this connection keeps reading (and answering
        its keepalive pings). All zeros is a let-go; a refusal ends this pendant's jog and is told, throttled."""
        if not (isinstance(v, list) and len(v) == 3
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
            return await self._error_msg(session, "a jog needs three finite velocities in mm/s", throttle=True)
        if not any(v):
            return self._let_go(session)
        try:
            note = self.commands.invoke(self._who(session), "jog_hold", velocity=v, probe=probe, heard=heard,
                                        on_error=lambda text: self._later_error(session, text))
        except Exception as exc:  # noqa: BLE001 - every refusal is the operator's sentence, never raised into the loop
            if session.jogging:  # a jog of this pendant may still run (control taken over, the travel's end)
                session.jogging = False
                self._release(session)
            return await self._error_msg(session, str(exc) or type(exc).__name__, throttle=True)
        session.jogging = any(v)
        if note is not None and note != session.last_note:
            session.last_note = note  # once per limit, not 20 times a second
            await self._send(session, {"type": "notice", "message": note})

    def _on_machine_event(self, kind: str, info: dict) -> None:
        """The control core's events (its dispatcher thread): a jog the travel limit clipped is told to the
        pendants that were jogging, so a jog that stops short of where the operator meant says why."""
        if kind != "limit" or self._loop is None:
            return
        axis = str((info or {}).get("axis", "?")).upper()
        text = f"{axis} reached the end of its travel: the jog stops there"
        for session in list(self._sessions):
            if session.jogging:
                self._loop.call_soon_threadsafe(
                    lambda s=session: asyncio.ensure_future(self._send(s, {"type": "notice", "message": text})))

    def _later_error(self, session: _Session, text: str) -> None:
        """An error the machine loop found in a queued jog (dispatcher thread): to this pendant, throttled."""
        session.jogging = False
        if self._loop is not None:
            self._loop.call_soon_threadsafe(
                lambda: asyncio.ensure_future(self._error_msg(session, text, throttle=True)))

    async def _step(self, session: _Session, axis: Any, mm: Any) -> None:
        """One step jog (keyboard step mode): 1 count .. 10 mm along X, Y or Z (the step verb: holder only)."""
        if not (axis in (0, 1, 2) and isinstance(mm, (int, float)) and not isinstance(mm, bool) and math.isfinite(mm)
                and 0 < abs(mm) <= 10.0):
            return await self._error_msg(session, "a step needs an axis 0..2 and a size of up to 10 mm", throttle=True)
        error = await self._call(self._station_call, lambda: self.commands.invoke(
            self._who(session), "step", axis="xyz"[axis], mm=float(mm)))
        if error:
            await self._error_msg(session, error, throttle=True)

    def _release(self, session: _Session, *, let_go: bool = False, lapse: bool = False) -> None:
        """End this pendant's jog at once (the pipeline's release goes ahead of anything queued). ``let_go``: a
        key let go with no jog of this pendant running: the core ignores it unless this client holds control.
        A refused release has nothing to tell (the jog it would end is not this pendant's)."""
        session.last_note = None
        self._station_call(lambda: self.commands.invoke(self._who(session), "jog_release", let_go=let_go, lapse=lapse))

    def _let_go(self, session: _Session, *, lapse: bool = False) -> None:
        """Every key, button and stick let go: this pendant's jog ends. With none of its jogs known to run, the
        release is a let-go, which the core sends on only for the holder (an observer's key-up never ends the
        holder's jog)."""
        jogging, session.jogging = session.jogging, False
        self._release(session, let_go=not jogging, lapse=lapse)

    @staticmethod
    def _who(session: _Session) -> Any:
        if session.grant is not None:  # the station page's client, with what this connection adds
            page = session.grant.owner()
            return Client(page.id, local=session.local and page.local,
                          authenticated=session.authenticated or page.authenticated,
                          user=getattr(page, "user", None), role=getattr(page, "role", None))
        return PendantServer._own(session)

    @staticmethod
    def _own(session: _Session) -> Any:
        """This connection's own client (taking and releasing control is always the connection's own)."""
        return Client(session.client_id, local=session.local, authenticated=session.authenticated or session.user
                      is not None, user=session.user, role=session.role)

    async def _own_thread(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` on a new thread (no executor's queue in front of it); awaited without blocking the loop."""
        assert self._loop is not None
        future = self._loop.create_future()
        loop = self._loop

        def run() -> None:
            try:
                result = fn(*args)
            except BaseException as exc:  # noqa: BLE001 - handed to the awaiting coroutine
                # bound now: the name ``exc`` is deleted when the except block ends, before the loop runs this
                loop.call_soon_threadsafe(lambda err=exc: future.done() or future.set_exception(err))
            else:
                loop.call_soon_threadsafe(lambda: future.done() or future.set_result(result))
        threading.Thread(target=run, name="pendant-stop", daemon=True).start()
        return await future

    def _stop_machine(self, who: Any, verb: str = "stop", pressed: Any = None) -> dict[str, Any]:
        """The stop (or estop) verb's report ({ok, message, failed_axes}) or, for a press already sent to the modules
        (``pressed``, :meth:`~cmm.control.core.Controller.press`), its answer; a refusal or a failure as a report that
        is not ok."""
        try:
            if pressed is not None:
                return self.commands.invoke(who, "answer", pressed=pressed)
            return self.commands.invoke(who, verb)
        except Refused as exc:
            return {"ok": False, "message": str(exc)}
        except Exception as exc:  # noqa: BLE001 - a failed stop is reported, never hidden
            return {"ok": False, "message": f"{'STOP' if verb == 'stop' else 'E-STOP'} failed: {exc}"}


def start_pendant_server(api: Any, control: Control, host: str = "127.0.0.1", port: int = 0,
                         **options: Any) -> PendantServer:
    """Serve the pendant page and its WebSocket in a background thread for the station behind ``api`` (the command
    API); returns the running handle.

    ``control`` is the station's access policy already (the ``use_policy`` verb, sent where both are built:
    :class:`~cmm.ui.app.StationApp`), so the core's verbs refuse in their own words;
    ``host`` "0.0.0.0" listens on the LAN (pair it with ``Control(lan=True)``);
    ``port`` 0 picks a free port (see ``handle.port``).
    """
    return PendantServer(api, control, host, port, **options)

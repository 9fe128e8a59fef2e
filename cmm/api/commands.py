"""The command API as requests and responses: a method name and named parameters in, a result or an error out.

Shaped like Klipper's webhooks: every front end's adapter turns what it receives (a pendant message, an I++
DME command, a button on the page, a CLI option) into ``call(client, method, params)`` and turns the
:class:`Response` back into its own words. The adapters translate only: access, the machine's state, the
frames, the clearance plane and the jog pipeline are decided behind the verbs, once, for all of them.

A response is ``{"id": ..., "result": ...}`` or ``{"id": ..., "error": {"code": ..., "message": ...}}``;
``message`` is a sentence for the operator, ``code`` one of :data:`ERROR_CODES` for programs. Motion verbs
return their status (``wait=True`` waits for it and returns its result: the tip position, or the Hit).
Front ends in this process may use :meth:`CommandAPI.invoke` instead: the same verbs and checks, the result
returned and the verb's own error raised (the UI and the CLI tell it in their words). A few verbs take Python
callables and so exist in process only (``configure``, ``run_job``, the progress callbacks).

This module is the API's mechanics only: the registry, the calls, the role check, the error codes, the
subscriptions (:mod:`cmm.api.subscriptions`) and the in-process event streams. It knows no machine: each layer
registers its own verbs, queries, streams and error kinds where it lives, with :meth:`CommandAPI.register`,
:meth:`CommandAPI.register_stream` and :meth:`CommandAPI.register_error`: the control core the machine's
(``move``, ``probe``, ``stop``, ``state`` ...: :mod:`cmm.control.verbs`), the measurement (``measure_feature``,
``construct``, ``undo``, ``align``, ``auto_measure``, ``run_program``, the journal's ``new_session``, ``note`` and
``record_event`` ...: :mod:`cmm.measurement.verbs`, its queries :mod:`cmm.measurement.queries`), the calibration
(``qualify``, ``save_calibration``, ``probes`` ...: :mod:`cmm.calibration.verbs`); the station only calls them once
it has built both sides, since the measurement model sits beside the control layer, not under it.
:meth:`CommandAPI.verbs` lists them all with their parameters (the README's table).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, runtime_checkable

from .clients import AccessRefused, client_of
from .subscriptions import Subscription, Subscriptions

# error code -> what it means (the operator's sentence is in the message)
ERROR_CODES = {
    "unknown_method": "no such verb",
    "bad_params": "a parameter is missing, unknown or of the wrong kind",
    "refused": "not allowed now: access (take control first) or the machine's state; nothing moved",
    "contact": "the probe touched something it was not probing; the machine stopped",
    "limit": "a target or a jog would leave the travel",
    "not_found": "a probe found no surface within its search distance",
    "cancelled": "cancelled or stopped by the operator",
    "fault": "the machine is in fault (link or module failure); Reset or Reconnect",
    "motion": "the motion failed (see the message)",
    "failed": "the command failed (see the message)",
}
REQUIRED = object()


class CommandError(ValueError):
    """A call the API cannot make: an unknown verb, a parameter missing or unknown (``code`` says which)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Verb:
    name: str
    fn: Callable[..., Any]  # fn(client, **params)
    params: dict[str, Any]  # name -> default (REQUIRED when it must be given)
    doc: str
    motion: bool = False  # returns its status (Pending) at once
    query: bool = False  # read-only: a snapshot, changes nothing (open to every client, anonymous observers too)


@dataclass(frozen=True)
class Response:
    id: Any = None
    result: Any = None
    error: dict[str, str] | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    def to_dict(self) -> dict[str, Any]:
        if self.error is not None:
            return {"id": self.id, "error": dict(self.error)}
        return {"id": self.id, "result": jsonable(self.result)}


@runtime_checkable
class Pending(Protocol):
    """A motion verb's status while it runs (:class:`cmm.machine.status.MoveStatus`): ``wait`` for its result."""

    description: str

    @property
    def done(self) -> bool: ...

    def wait(self, timeout: float | None = None) -> Any: ...


# an error kind's code: a code of ERROR_CODES, or a function of the error that chooses one
ErrorCode = str | Callable[[BaseException], str]
# a stream's subscribe function: subscribe(fn) starts calling fn with each event and returns the unsubscribe
StreamFn = Callable[[Callable[..., None]], Callable[[], None]]


@dataclass(frozen=True)
class Stream:
    name: str
    subscribe: StreamFn
    doc: str


@dataclass
class CommandAPI:
    _verbs: dict[str, Verb] = field(default_factory=dict)
    # cmm.control.roles.RolePolicy on a station with a user file: each verb checked against the client's role;
    # None: the local, no-login mode (the control holder rule alone)
    roles: Any = None
    REQUIRED = REQUIRED  # the marker, for packages that register verbs without importing this module
    _streams: dict[str, Stream] = field(default_factory=dict)
    # (error kind, its code), checked in the order registered: the first kind the error is an instance of decides
    _errors: list[tuple[type[BaseException], ErrorCode]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._subscriptions = Subscriptions(lambda client, name, params: jsonable(self.invoke(client, name, **params)))

    # --- registry ---------------------------------------------------------------------

    def register(self, name: str, fn: Callable[..., Any], params: dict[str, Any], doc: str, *,
                 motion: bool = False, query: bool = False) -> None:
        """Add a verb: ``fn(client, **params)``; ``params`` maps each name to its default (``REQUIRED``);
        ``query``: a read-only snapshot (changes nothing)."""
        self._verbs[name] = Verb(name, fn, dict(params), doc, motion, query)

    def verbs(self) -> list[Verb]:
        return list(self._verbs.values())

    def register_stream(self, name: str, subscribe: StreamFn, doc: str) -> None:
        """Add an in-process event stream: ``subscribe(fn)`` calls ``fn`` with every event (on the publisher's
        thread, never the machine loop's) and returns the function that ends it."""
        self._streams[name] = Stream(name, subscribe, doc)

    def streams(self) -> list[Stream]:
        return list(self._streams.values())

    def register_error(self, kind: type[BaseException], code: ErrorCode) -> None:
        """Errors of ``kind`` (its subclasses too) answer with ``code`` (a code of :data:`ERROR_CODES`, or
        ``code(error)`` choosing one); kinds are tried in the order registered."""
        self._errors.append((kind, code))

    # --- calls ------------------------------------------------------------------------

    def invoke(self, client: Any, method: str, /, **params: Any) -> Any:
        """Run one verb for ``client`` in this process and return its result; the verb's own error (Refused,
        ContactError, MeasurementError ...) is raised as it is, for front ends that tell their operator in their
        own words. A wrong call (unknown verb, parameters missing or unknown) raises :class:`CommandError`."""
        verb = self._verbs.get(method)
        if verb is None:
            raise CommandError("unknown_method", f"unknown command {method!r}; the commands are "
                               + ", ".join(sorted(self._verbs)))
        unknown = sorted(set(params) - set(verb.params))
        if unknown:
            raise CommandError("bad_params", f"{method} does not take {', '.join(unknown)}; it takes "
                               + (", ".join(verb.params) or "nothing"))
        missing = [k for k, v in verb.params.items() if v is REQUIRED and k not in params]
        if missing:
            raise CommandError("bad_params", f"{method} needs {', '.join(missing)}")
        if self.roles is not None:
            why = self.roles.refusal(client_of(client), method, verb.query)
            if why is not None:
                raise AccessRefused(why)
        return verb.fn(client, **params)

    def queries(self) -> list[Verb]:
        """The read-only verbs: snapshots a front end may query or subscribe to."""
        return [v for v in self._verbs.values() if v.query]

    def subscribe(self, client: Any, queries: dict[str, dict[str, Any] | None], on_change: Callable[[dict], None], *,
                  rate: float = 10.0) -> Subscription:
        """Change streams of query verbs (Klipper's ``objects/subscribe``): ``on_change({query: value})`` first with
        every value, then with those that changed, at most ``rate`` times a second, from the API's own thread.
        Each snapshot is taken as ``client`` (the same role checks as a call). ``close()`` the result to end it."""
        for name in queries:
            verb = self._verbs.get(name)
            if verb is None or not verb.query:
                raise CommandError("bad_params", f"{name!r} is not a query; the queries are "
                                   + ", ".join(sorted(v.name for v in self.queries())))
        try:
            return self._subscriptions.subscribe(client, queries, on_change, rate=rate)
        except ValueError as exc:
            raise CommandError("bad_params", str(exc)) from None

    def listen(self, client: Any, stream: str, fn: Callable[..., None]) -> Callable[[], None]:
        """In process: ``fn`` hears every event of ``stream`` (the control core's ``events``: ``fn(kind, info)``;
        ``state``: ``fn(state)`` after samples, coalesced) until the returned function is called. Like a query,
        open to every client (observing changes nothing)."""
        found = self._streams.get(stream)
        if found is None:
            raise CommandError("bad_params", f"{stream!r} is not a stream; the streams are "
                               + (", ".join(sorted(self._streams)) or "none"))
        return found.subscribe(fn)

    def call(self, client: Any, method: str, params: dict[str, Any] | None = None, *, id: Any = None,
             wait: bool = False, timeout: float | None = None) -> Response:
        """Run one verb for ``client``; never raises for the operator's mistakes or the machine's refusals."""
        params = {} if params is None else params
        if not isinstance(params, dict):
            return _error(id, "bad_params", f"{method}: the parameters must be named (a JSON object)")
        try:
            result = self.invoke(client, method, **params)
            if wait and isinstance(result, Pending):
                result = result.wait(timeout)
        except CommandError as exc:
            return _error(id, exc.code, str(exc))
        except BaseException as exc:  # noqa: BLE001 - every failure becomes the caller's error response
            if not isinstance(exc, Exception):
                raise
            return _error(id, self.error_code(exc), str(exc) or type(exc).__name__)
        return Response(id, result)

    def request(self, client: Any, message: Any, *, wait: bool = False, timeout: float | None = None) -> dict:
        """A request as a JSON object ``{"id", "method", "params"}`` -> the response as a JSON object."""
        if not isinstance(message, dict) or not isinstance(message.get("method"), str):
            return _error(None if not isinstance(message, dict) else message.get("id"), "bad_params",
                          "a request is a JSON object with a method name and its params").to_dict()
        return self.call(client, message["method"], message.get("params"), id=message.get("id"), wait=wait,
                         timeout=timeout).to_dict()

    def error_code(self, exc: BaseException) -> str:
        """The code of :data:`ERROR_CODES` a failed verb answers with."""
        if getattr(exc, "cancelled", False) is True:  # a job that ended itself for the cancel verb (between hits)
            return "cancelled"
        if isinstance(exc, AccessRefused):
            return "refused"
        for kind, code in self._errors:
            if isinstance(exc, kind):
                return code if isinstance(code, str) else code(exc)
        if isinstance(exc, (TypeError, ValueError)):
            return "bad_params"
        return "failed"


def _error(id: Any, code: str, message: str) -> Response:
    return Response(id, None, {"code": code, "message": message})


def jsonable(value: Any) -> Any:
    """Results as JSON: arrays as lists, a Hit as its fields, a status as its description and state."""
    import numpy as np

    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    fields = getattr(value, "__dataclass_fields__", None)
    if fields is not None:
        return {k: jsonable(getattr(value, k)) for k in fields}
    if isinstance(value, Pending):
        return {"status": value.description, "done": value.done}
    return str(value)

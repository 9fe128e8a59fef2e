"""The command API as requests and responses: a method name and named parameters in, a result or an error out.

Shaped like Klipper's webhooks: every front end's adapter turns what it receives (a pendant message, an I++
DME command, a button on the page, a CLI option) into ``call(client, method, params)`` and turns the
:class:`Response` back into its own words. The adapters translate only: access, the machine's state, the
frames, the clearance plane and the jog pipeline are decided here, once, for all of them.

A response is ``{"id": ..., "result": ...}`` or ``{"id": ..., "error": {"code": ..., "message": ...}}``;
``message`` is a sentence for the operator, ``code`` one of :data:`ERROR_CODES` for programs. Motion verbs
return their status (``wait=True`` waits for it and returns its result: the tip position, or the Hit).
Front ends in this process may use :meth:`CommandAPI.invoke` instead: the same verbs and checks, the result
returned and the verb's own error raised (the UI and the CLI tell it in their words). A few verbs take Python
callables and so exist in process only (``configure``, ``run_job``, the progress callbacks).

The machine verbs are registered by the control core; each package registers its own where it lives, with
:meth:`CommandAPI.register`: the measurement (``measure_feature``, ``construct``, ``undo``, ``align``,
``auto_measure``, ``run_program``, the journal's ``new_session``, ``note`` and ``record_event`` ...:
:mod:`cmm.measurement.verbs`, its queries :mod:`cmm.measurement.queries`), the calibration (``qualify``,
``save_calibration`` ...: :mod:`cmm.calibration.verbs`); the station only calls them once it has built both sides,
since the measurement model sits beside the control layer, not under it. :meth:`CommandAPI.verbs` lists them all with their
parameters (the README's table).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from ..machine.motion import ContactError, LimitError
from ..machine.probing import SurfaceNotFound
from ..machine.status import Cancelled, MotionError, MoveStatus
from . import access
from .modes import ControlError, Refused
from .queries import register_control_queries
from .subscriptions import Subscription, Subscriptions
from .rails import RailError

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
    motion: bool = False  # returns a MoveStatus
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


@dataclass
class CommandAPI:
    controller: Any
    _verbs: dict[str, Verb] = field(default_factory=dict)
    # cmm.control.roles.RolePolicy on a station with a user file: each verb checked against the client's role;
    # None: the local, no-login mode (the control holder rule alone)
    roles: Any = None
    REQUIRED = REQUIRED  # the marker, for packages that register verbs without importing this module

    def __post_init__(self) -> None:
        c = self.controller
        self._subscriptions = Subscriptions(lambda client, name, params: jsonable(self.invoke(client, name, **params)))
        self.register("move", c.move, {"target": REQUIRED, "frame": REQUIRED, "path": "clearance", "speed": None,
                                        "accel": None},
                      "move the tip centre to target (X, Y, Z mm) in frame 'machine' or 'part'; path 'clearance' "
                      "(retract, travel, descend) or 'straight' (only when proven free of the part)", motion=True)
        self.register("probe", c.probe, {"target": REQUIRED, "approach": REQUIRED, "frame": REQUIRED,
                                         "path": "clearance", "clearance_z": None, "normal": None, "speed": None,
                                         "accel": None, "approach_distance": None, "search_distance": None,
                                         "retract_distance": None, "rapid_speed": None, "hop_z": None},
                      "a programmed hit at a surface point, coming along approach (into the surface); the rapid "
                      "goes over the clearance plane unless path 'straight' is proven free; with hop_z (machine Z) "
                      "straight or over that height where proven free", motion=True)
        self.register("jog_hold", lambda client, velocity, probe=False, heard=None, settle=0.0, on_error=None:
                      c.jogs.hold(client, velocity, probe=probe, heard=heard, settle=settle, on_error=on_error),
                      {"velocity": REQUIRED, "probe": False, "heard": None, "settle": 0.0, "on_error": None},
                      "the operator holds a jog (mm/s per machine axis); repeat within the dead-man (0.15 s); "
                      "returns a sentence when the speed was limited. heard: when the front end received the "
                      "hold (machine clock; the dead-man counts from then); settle: s after a release in which "
                      "holds are late events and dropped; on_error(text), in process: an error the machine loop "
                      "finds later")
        self.register("jog_release", lambda client, let_go=False, lapse=False: c.jogs.release(
                      client, let_go=let_go, lapse=lapse), {"let_go": False, "lapse": False},
                      "end the jog now (allowed to everyone who may STOP); let_go: the operator let go of a key or "
                      "button with no jog of this front end known to run: ignored quietly (false) unless this client; lapse: the front end's own safety stop (the page went silent), not the operator letting go: a hit taken stays taken (one hit per touch) "
                      "holds control, so an observer's let-go never ends the holder's jog; true when it was sent")
        self.register("step", lambda client, axis, mm: c.step(client, axis, mm), {"axis": REQUIRED, "mm": REQUIRED},
                      "one step along a machine axis x, y or z (1 count .. 10 mm)", motion=True)
        self.register("stop", lambda client: _report(c.stop(client)), {}, "controlled stop of whatever moves")
        self.register("estop", lambda client: _report(c.emergency_stop(client)), {},
                      "emergency stop: abrupt, amplifiers off, latched until reset")
        self.register("press", lambda client, verb="stop": c.press(client, verb), {"verb": "stop"},
                      "in process: the operator's STOP (verb 'stop') or E-STOP ('estop') sent to the modules now from "
                      "the caller's thread; returns the press, which 'answer' finishes (stop and estop do both)")
        self.register("answer", lambda client, pressed: _report(c.answer(pressed)), {"pressed": REQUIRED},
                      "in process: a press's report, once the loop ended the motion it cut short and every axis "
                      "stands still")
        self.register("reset", c.reset, {}, "clear an E-stop latch, a stop or a fault (link answering)")
        self.register("reconnect", c.reconnect, {}, "after a link fault: reopen the link, restart the modules")
        self.register("home", c.home, {}, "the homing cycle (blocks until it ends)")
        self.register("zero", c.zero, {"confirm": False}, "here becomes the home coordinates (confirm=true)")
        self.register("take_control", lambda client, code=None, peer=None: access.take_control(c.holder, client,
                                                                                             code, peer),
                      {"code": None, "peer": None},
                      "this client becomes the control holder (the only one that moves the machine): a client at "
                      "the station PC, or one whose listener grants control (the I++ DME port), without a code; a "
                      "LAN client with the access code (code); peer: its network address (the wrong-code rate limit)")
        self.register("release_control", lambda client: access.release_control(c.holder, client), {},
                      "this client gives control up (after a disconnect too); a client that did not hold it changes "
                      "nothing")
        self.register("position", lambda client, frame="machine": c.frame_position(frame), {"frame": "machine"},
                      "where the tip centre is, in frame 'machine' or 'part'", query=True)
        self.register("state", lambda client: c.state, {},
                      "the machine's state: mode and why, homed, link, the commands allowed now, the last sample",
                      query=True)
        self.register("link_health", lambda client: c.link_health(), {},
                      "the link's counters (transactions, retries, late replies recovered, the last minute's retry "
                      "rate) and the Diagnostics tab's words for them", query=True)
        self.register("job", lambda client: c.jobs.snapshot(), {},
                      "what runs now (auto-measure, routine, program, calibration), oldest first: description, "
                      "done and total (hits of a program; 0 when the job does not say) and step", query=True)
        self.register("cancel", c.cancel_jobs, {},
                      "end whatever job runs (auto-measure, routine, program, calibration) after the hit in "
                      "progress; its hits stay recorded; allowed to everyone who may STOP")
        self.register("pause", lambda client: c.hold_jobs(client, "pause"), {},
                      "hold whatever job runs and can (a routine, a probe qualification) after the hit in progress; "
                      "allowed to everyone who may STOP")
        self.register("resume", lambda client: c.hold_jobs(client, "resume"), {},
                      "a paused job goes on (a paused qualification lifts to the clearance height first); the "
                      "control holder only")
        self.register("skip_step", lambda client: c.hold_jobs(client, "skip"), {},
                      "a running routine leaves the step in progress after its current hit (its feature is not "
                      "fitted) and goes on; the control holder only")
        self.register("cancel_move", lambda client, status: c.cancel(client, status), {"status": REQUIRED},
                      "in process: cancel one move or probe cycle (its status, as move or probe returned it); it "
                      "decelerates to a stop")
        self.register("configure", c.configure, {"change": REQUIRED},
                      "in process: change the set-up while the machine is still; change(setup) gets "
                      "setup.machine and setup.prober (probe settings, geometry correction, servo gains)")
        self.register("run_job", lambda client, description, work, progress=None, cancel=None, timeout=None,
                      pause=None, resume=None, skip=None, hold_machine=True: c.run_routine(
                          client, description, work, progress=progress, cancel=cancel, timeout=timeout, pause=pause,
                          resume=resume, skip=skip) if hold_machine else c.run_beside(
                          client, description, lambda: work(None), cancel=cancel or (lambda: c.stop(None)),
                          pause=pause, resume=resume, skip=skip),
                      {"description": REQUIRED, "work": REQUIRED, "progress": None, "cancel": None, "timeout": None,
                       "pause": None, "resume": None, "skip": None, "hold_machine": True},
                      "in process: work(job) runs in the machine loop with the machine to itself (job.machine, "
                      "job.prober, job.progress); cancel() ends it cleanly when the cancel verb is sent; pause(), "
                      "resume(), skip() (when given) are what the pause, resume and skip_step verbs call; "
                      "hold_machine false: work(None) runs in the caller's thread beside the machine loop (a program "
                      "waiting for the operator's manual hits), registered the same way")
        register_control_queries(self, c)  # the set-up, the link, access, and the in-process clock and events

    # --- registry ---------------------------------------------------------------------

    def register(self, name: str, fn: Callable[..., Any], params: dict[str, Any], doc: str, *,
                 motion: bool = False, query: bool = False) -> None:
        """Add a verb: ``fn(client, **params)``; ``params`` maps each name to its default (``REQUIRED``);
        ``query``: a read-only snapshot (changes nothing)."""
        self._verbs[name] = Verb(name, fn, dict(params), doc, motion, query)

    def verbs(self) -> list[Verb]:
        return list(self._verbs.values())

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
            why = self.roles.refusal(access.client_of(client), method, verb.query)
            if why is not None:
                raise access.AccessRefused(why)
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

    def call(self, client: Any, method: str, params: dict[str, Any] | None = None, *, id: Any = None,
             wait: bool = False, timeout: float | None = None) -> Response:
        """Run one verb for ``client``; never raises for the operator's mistakes or the machine's refusals."""
        params = {} if params is None else params
        if not isinstance(params, dict):
            return _error(id, "bad_params", f"{method}: the parameters must be named (a JSON object)")
        try:
            result = self.invoke(client, method, **params)
            if wait and isinstance(result, MoveStatus):
                result = result.wait(timeout)
        except CommandError as exc:
            return _error(id, exc.code, str(exc))
        except BaseException as exc:  # noqa: BLE001 - every failure becomes the caller's error response
            if not isinstance(exc, Exception):
                raise
            return _error(id, error_code(exc), str(exc) or type(exc).__name__)
        return Response(id, result)

    def request(self, client: Any, message: Any, *, wait: bool = False, timeout: float | None = None) -> dict:
        """A request as a JSON object ``{"id", "method", "params"}`` -> the response as a JSON object."""
        if not isinstance(message, dict) or not isinstance(message.get("method"), str):
            return _error(None if not isinstance(message, dict) else message.get("id"), "bad_params",
                          "a request is a JSON object with a method name and its params").to_dict()
        return self.call(client, message["method"], message.get("params"), id=message.get("id"), wait=wait,
                         timeout=timeout).to_dict()


def error_code(exc: BaseException) -> str:
    if getattr(exc, "cancelled", False) is True:  # a job that ended itself for the cancel verb (between hits)
        return "cancelled"
    if isinstance(exc, (Refused, RailError, access.AccessRefused)):
        return "refused"
    if isinstance(exc, ContactError):
        return "contact"
    if isinstance(exc, LimitError):
        return "limit"
    if isinstance(exc, SurfaceNotFound):
        return "not_found"
    if isinstance(exc, Cancelled):
        return "cancelled"
    if isinstance(exc, ControlError):
        return "fault"
    if isinstance(exc, MotionError):
        return "refused" if "outside the travel" in str(exc) else "motion"
    if isinstance(exc, (TypeError, ValueError)):
        return "bad_params"
    return "failed"


def _error(id: Any, code: str, message: str) -> Response:
    return Response(id, None, {"code": code, "message": message})


def _report(report: Any) -> dict[str, Any]:
    return {"ok": bool(report.ok), "message": report.message, "failed_axes": list(report.failed_axes)}


def jsonable(value: Any) -> Any:
    """Results as JSON: arrays as lists, a Hit as its fields, a status as its description and state."""
    import numpy as np

    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, MoveStatus):
        return {"status": value.description, "done": value.done}
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    fields = getattr(value, "__dataclass_fields__", None)
    if fields is not None:
        return {k: jsonable(getattr(value, k)) for k in fields}
    return str(value)

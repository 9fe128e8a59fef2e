"""The control core's verbs of the command API: the machine's commands and event streams, registered where
the machine's control lives (the measurement registers its own in :mod:`cmm.measurement.verbs`, the calibration in
:mod:`cmm.calibration.verbs`).

:func:`register_machine_verbs` is called by the :class:`~cmm.control.core.Controller` when it builds its API
(``controller.commands``): ``move``, ``probe``, ``jog_hold``, ``stop``, ``estop``, ``home``, ``take_control`` ...,
the streams a front end follows it with (``events``, ``state``) and the error codes of the machine's and the
core's errors; its queries (``state``, ``position``, ``machine_config``, ``control``, ``job`` ...) are in
:mod:`cmm.control.queries`.
"""

from __future__ import annotations

from typing import Any

from ..api import REQUIRED, CommandAPI
from ..machine.motion import ContactError, LimitError
from ..machine.probing import SurfaceNotFound
from ..machine.status import Cancelled, MotionError
from . import access
from .modes import ControlError, Refused
from .queries import register_control_queries
from .rails import RailError


def register_machine_verbs(api: CommandAPI, c: Any) -> None:
    """The machine's verbs, queries, streams and error codes on ``api``, for the control core ``c``."""
    api.register("move", c.move, {"target": REQUIRED, "frame": REQUIRED, "path": "clearance", "speed": None,
                                   "accel": None},
                 "move the tip centre to target (X, Y, Z mm) in frame 'machine' or 'part'; path 'clearance' "
                 "(retract, travel, descend) or 'straight' (only when proven free of the part)", motion=True)
    api.register("probe", c.probe, {"target": REQUIRED, "approach": REQUIRED, "frame": REQUIRED,
                                    "path": "clearance", "clearance_z": None, "normal": None, "speed": None,
                                    "accel": None, "approach_distance": None, "search_distance": None,
                                    "retract_distance": None, "rapid_speed": None, "hop_z": None},
                 "a programmed hit at a surface point, coming along approach (into the surface); the rapid "
                 "goes over the clearance plane unless path 'straight' is proven free; with hop_z (machine Z) "
                 "straight or over that height where proven free", motion=True)
    api.register("jog_hold", lambda client, velocity, probe=False, heard=None, settle=0.0, on_error=None:
                 c.jogs.hold(client, velocity, probe=probe, heard=heard, settle=settle, on_error=on_error),
                 {"velocity": REQUIRED, "probe": False, "heard": None, "settle": 0.0, "on_error": None},
                 "the operator holds a jog (mm/s per machine axis); repeat within the dead-man (0.15 s); "
                 "returns a sentence when the speed was limited. heard: when the front end received the "
                 "hold (machine clock; the dead-man counts from then); settle: s after a release in which "
                 "holds are late events and dropped; on_error(text), in process: an error the machine loop "
                 "finds later")
    api.register("jog_release", lambda client, let_go=False, lapse=False: c.jogs.release(
                 client, let_go=let_go, lapse=lapse), {"let_go": False, "lapse": False},
                 "end the jog now (allowed to everyone who may STOP); let_go: the operator let go of a key or "
                 "button with no jog of this front end known to run: ignored quietly (false) unless this client; lapse: the front end's own safety stop (the page went silent), not the operator letting go: a hit taken stays taken (one hit per touch) "
                 "holds control, so an observer's let-go never ends the holder's jog; true when it was sent")
    api.register("step", lambda client, axis, mm: c.step(client, axis, mm), {"axis": REQUIRED, "mm": REQUIRED},
                 "one step along a machine axis x, y or z (1 count .. 10 mm)", motion=True)
    api.register("stop", lambda client: _report(c.stop(client)), {}, "controlled stop of whatever moves")
    api.register("estop", lambda client: _report(c.emergency_stop(client)), {},
                 "emergency stop: abrupt, amplifiers off, latched until reset")
    api.register("press", lambda client, verb="stop": c.press(client, verb), {"verb": "stop"},
                 "in process: the operator's STOP (verb 'stop') or E-STOP ('estop') sent to the modules now from "
                 "the caller's thread; returns the press, which 'answer' finishes (stop and estop do both)")
    api.register("answer", lambda client, pressed: _report(c.answer(pressed)), {"pressed": REQUIRED},
                 "in process: a press's report, once the loop ended the motion it cut short and every axis "
                 "stands still")
    api.register("reset", c.reset, {}, "clear an E-stop latch, a stop or a fault (link answering)")
    api.register("reconnect", c.reconnect, {}, "after a link fault: reopen the link, restart the modules")
    api.register("home", c.home, {}, "the homing cycle (blocks until it ends)")
    api.register("zero", c.zero, {"confirm": False}, "here becomes the home coordinates (confirm=true)")
    api.register("take_control", lambda client, code=None, peer=None: access.take_control(c.holder, client,
                                                                                        code, peer),
                 {"code": None, "peer": None},
                 "this client becomes the control holder (the only one that moves the machine): a client at "
                 "the station PC, or one whose listener grants control (the I++ DME port), without a code; a "
                 "LAN client with the access code (code); peer: its network address (the wrong-code rate limit)")
    api.register("release_control", lambda client: access.release_control(c.holder, client), {},
                 "this client gives control up (after a disconnect too); a client that did not hold it changes "
                 "nothing")
    api.register("cancel", c.cancel_jobs, {},
                 "end whatever job runs (auto-measure, routine, program, calibration) after the hit in "
                 "progress; its hits stay recorded; allowed to everyone who may STOP")
    api.register("pause", lambda client: c.hold_jobs(client, "pause"), {},
                 "hold whatever job runs and can (a routine, a probe qualification) after the hit in progress; "
                 "allowed to everyone who may STOP")
    api.register("resume", lambda client: c.hold_jobs(client, "resume"), {},
                 "a paused job goes on (a paused qualification lifts to the clearance height first); the "
                 "control holder only")
    api.register("skip_step", lambda client: c.hold_jobs(client, "skip"), {},
                 "a running routine leaves the step in progress after its current hit (its feature is not "
                 "fitted) and goes on; the control holder only")
    api.register("cancel_move", lambda client, status: c.cancel(client, status), {"status": REQUIRED},
                 "in process: cancel one move or probe cycle (its status, as move or probe returned it); it "
                 "decelerates to a stop")
    api.register("configure", c.configure, {"change": REQUIRED},
                 "in process: change the set-up while the machine is still; change(setup) gets "
                 "setup.machine and setup.prober (probe settings, geometry correction, servo gains)")
    api.register("run_job", lambda client, description, work, progress=None, cancel=None, timeout=None,
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

    api.register_stream("events", c.subscribe,
                        "fn(kind, info) on the dispatcher thread: 'mode', 'fault', 'stop', 'estop', 'contact', "
                        "'deadman', 'limit', 'homed', 'hit', 'error' ... (info's message is for people)")
    api.register_stream("state", c.subscribe_state,
                        "fn(state) with the latest state after samples (coalesced: a slow listener sees fewer, "
                        "never stale, states)")
    for kind, code in ((Refused, "refused"), (RailError, "refused"), (ContactError, "contact"),
                       (LimitError, "limit"), (SurfaceNotFound, "not_found"), (Cancelled, "cancelled"),
                       (ControlError, "fault"), (MotionError, _motion_code)):
        api.register_error(kind, code)
    register_control_queries(api, c)  # the set-up, the link, access, and the in-process clock and events


def _motion_code(exc: BaseException) -> str:
    return "refused" if "outside the travel" in str(exc) else "motion"


def _report(report: Any) -> dict[str, Any]:
    return {"ok": bool(report.ok), "message": report.message, "failed_axes": list(report.failed_axes)}

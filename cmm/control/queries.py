"""The control core's read-only queries of the command API, beside its verbs (:mod:`cmm.control.verbs`): the
machine's state (where the tip is, its mode, the link's health and byte trace, what runs, who holds control), the
set-up (configuration, probe settings, the link), who may send what, the jog's dead-man, the planned paths of a
preview, where a run ends, and, in process, the objects a front end needs to keep time with the machine (its
clock, the access holder, the machine's events). A front end (the page, the pendant, I++) reads the machine
through these, never through the control core itself.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..api import client_of
from .access import Control

ABOVE = 1e-3  # mm: a tip at the clearance plane within this is at the plane


def register_control_queries(api: Any, controller: Any) -> None:
    """Register the control core's queries on ``api`` (a :class:`~cmm.api.CommandAPI`)."""
    c = controller
    REQUIRED = api.REQUIRED  # noqa: N806 - the API's marker of a parameter that must be given

    api.register("position", lambda client, frame="machine": c.frame_position(frame), {"frame": "machine"},
                 "where the tip centre is, in frame 'machine' or 'part'", query=True)
    api.register("state", lambda client: c.state, {},
                 "the machine's state: mode and why, homed, link, the commands allowed now, the last sample",
                 query=True)
    api.register("link_health", lambda client: c.link_health(), {},
                 "the link's counters (transactions, retries, late replies recovered, the last minute's retry "
                 "rate) and the Diagnostics tab's words for them", query=True)
    api.register("trace", lambda client, last=30: c.trace_text(last=int(last)), {"last": 30},
                 "the last packets on the link (the NMC byte trace, Tx and Rx) as text, for the Diagnostics tab; "
                 "the link process's on a real port", query=True)
    api.register("job", lambda client: c.jobs.snapshot(), {},
                 "what runs now (auto-measure, routine, program, calibration), oldest first: description, "
                 "done and total (hits of a program; 0 when the job does not say) and step", query=True)
    api.register("probe_settings", lambda client: c.probe_settings, {},
                 "the probe settings in force (tip radius, pre-travel model); change them with configure",
                 query=True)
    api.register("link_info", lambda client: c.link_info(), {},
                 "the link as the front ends show it: port, baud, firmware and the modules found at start-up "
                 "(address, type, version)", query=True)
    api.register("samples", lambda client: c.samples, {},
                 "how many machine samples the control core has taken (a front end's link meter counts them)",
                 query=True)
    api.register("access", lambda client, command="measure": c.policy.refusal(client, command),
                 {"command": "measure"},
                 "whether this client may send command now (the access policy: the control holder, the role): "
                 "None when it may, else the sentence of the refusal", query=True)
    api.register("jog_settings", lambda client: {"grace": float(c.jogs.grace)}, {},
                 "the jog's dead-man: grace (s), how soon a jog stops when its holds stop coming", query=True)
    api.register("probe_paths", lambda client, targets, frame="machine", path="clearance", start=None:
                 c.probe_paths(list(targets), frame=frame, path=path, start=start),
                 {"targets": REQUIRED, "frame": "machine", "path": "clearance", "start": None},
                 "the paths programmed hits would take (targets: point, approach, clearance Z or None[, hop Z]), "
                 "each from where the one before retracted, the first from start (default: here); moves nothing; "
                 "refused for a target the probe verb would refuse", query=True)
    api.register("control_policy", lambda client: c.holder, {},
                 "in process: the access holder the core checks (cmm.control.access.Control), None without one "
                 "(a script)", query=True)
    api.register("clock", lambda client: c.clock, {},
                 "in process: the machine's clock (now(); a front end notes when it heard an event on it)",
                 query=True)
    api.register("watch_machine", lambda client, on_event: c.subscribe(on_event), {"on_event": REQUIRED},
                 "in process: on_event(kind, info) for every machine event ('state', 'fault', 'estop', 'stop', "
                 "'contact', 'deadman', 'limit', 'homed' ...), on the dispatcher thread; returns the function "
                 "that ends it", query=True)

    def control(client: Any) -> dict[str, Any]:
        holder = c.holder  # the station's Control, None while the station runs without one (scripts)
        held = None if holder is None else holder.holder
        me = client_of(client)
        return {"holder": None if held is None else holder.name(held),
                "yours": held is not None and me is not None and me.id == held}
    api.register("control", control, {},
                 "who holds control: holder (as messages name the person; None: nobody, or a station without a "
                 "holder) and yours (true when the asking client holds it)", query=True)
    api.register("machine_config", lambda client: c.config, {},
                 "in process: the machine's configuration (axes and their travel, speeds, probe distances, homing)",
                 query=True)
    api.register("check_target", lambda client, target: c.check_target(target), {"target": REQUIRED},
                 "target (X, Y, Z machine mm) inside the travel, returned; an error naming the axis it leaves "
                 "otherwise (nothing moves)", query=True)
    api.register("tip_radius", lambda client: c.tip_radius, {},
                 "the radius (mm) of the probe tip the machine compensates with now", query=True)

    def clearance_target(client: Any, here: Any = None) -> list[float] | None:
        ws = c.workspace
        plane = None if ws is None else ws.clearance_z()
        at = c.frame_position("machine") if here is None else np.asarray(here, float)
        if plane is None or at is None:
            return None
        z = min(float(plane), float(c.config.axis("z").max))
        return None if float(at[2]) >= z - ABOVE else [float(at[0]), float(at[1]), z]
    api.register("clearance_target", clearance_target, {"here": None},
                 "straight above the tip (or above here, machine mm) at the part's clearance plane, where a run ends "
                 "(machine mm); None when the tip is at or above it or there is no part", query=True)
    api.register("loop_wait", lambda client, event, timeout: c.wait_event(event, float(timeout)),
                 {"event": REQUIRED, "timeout": REQUIRED},
                 "in process: wait for event (a threading.Event) at most timeout s, for a run waiting on its operator; "
                 "inside the machine loop the loop goes on serving STOP, E-STOP and the link watch meanwhile; True "
                 "when the event was set", query=True)
    api.register("job_reporter", lambda client: c.jobs.report, {},
                 "in process: report(description, done, total, step): how far a running job is, for the job query",
                 query=True)

    def use_policy(client: Any, control: Any) -> None:
        if not isinstance(control, Control):  # only an in-process front end hands the one access holder over
            raise ValueError("use_policy takes the station's access holder (cmm.control.access.Control)")
        c.use_policy_of(control)
    api.register("use_policy", use_policy, {"control": REQUIRED},
                 "in process: the page's access holder (cmm.control.access.Control) becomes the core's access policy, "
                 "shared with the pendant; machine commands are checked there, once")

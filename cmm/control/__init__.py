"""The control core: one machine loop owns the bus; every front end sends commands through one API.

Layers (imports go down only; see README "Architecture")::

    ui (viser panels, pendant), cli, I++ DME, OPC UA     front ends: they receive the command API
    station                                              composition root: builds and wires
    control      <- this package: the machine loop, the state model, access policy, the machine's verbs
    api          the command API's mechanics (cmm.api): verbs, calls, error codes, subscriptions
    machine      axes in mm, moves, horizon jogs, probing cycles, homing
    nmc          PIC-SERVO protocol and bus

The API (:class:`Controller`)
------------------------------
Commands in, state and errors out. Every command takes the front end's
``client`` first: a :class:`Client` (id, local?, authenticated?) or an id
string; ``None`` is the station itself (scripts, CLI, homing). The same verbs
as requests and responses (a method name and named parameters in, a result or
an error with a code and the operator's sentence out): ``controller.commands``,
a :class:`cmm.api.CommandAPI` on which the core registers the machine's verbs
(:mod:`.verbs`), and which the pendant, the I++ and the OPC UA servers map to.

===================================  =========================================================================
``move(client, xyz, frame=, path=)``  to a point in 'machine' or 'part' coordinates, over the clearance plane
                                      (``path='straight'`` only when proven free of the part) -> MoveStatus
``probe(client, p, u, frame=, ...)``  programmed hit, approach/search/retract distances, speeds; the rapid goes
                                      over the clearance plane (or straight when proven free); result: the Hit
``jogs.hold(client, v) / release``    the jog-hold pipeline (:mod:`.jog`): clamp, release sequence, dead-man
``jog / jog_release``                 the pipeline's primitives (a jog repeats within ``deadman_timeout``)
``cancel(client, status)``            cancel one move or probe cycle
``step(client, axis, mm)``            one-axis step (1 count .. 10 mm)
``home(client)``                      the homing cycle of ``[homing]`` (blocks; STOP aborts it)
``zero(client, confirm=)``            here becomes the home coordinates: only with ``confirm=True``, probe free
``stop(client)``                      controlled stop -> :class:`StopReport` (``ok`` only if every module acknowledged)
``emergency_stop(client)``            abrupt stop, amplifiers off, latched -> :class:`StopReport`
``reset(client)``                     clear the E-stop latch / a stop / a fault (when the link answers)
``reconnect(client)``                 after a link fault: reopen the link, restart the modules (home again)
``run_job(client, name, fn, cancel=)`` a routine (calibration, program) run in the loop with the machine to itself
``configure(client, change)``         change the set-up while still: ``change(setup)`` gets setup.machine / .prober
``cancel_jobs(client)``               the ``cancel`` verb: end whatever job runs (``jobs``: what runs, with its cancel)
===================================  =========================================================================

Motion rails (:mod:`.rails`): every move and probe names its frame; moves go
over the clearance plane; a restart after a fault or a contact backs off first.

Refusals raise :class:`Refused` (a ``MotionError``) with a sentence for the
operator, before anything is sent. Link failures raise :class:`ControlError`
and leave the machine in ``fault``.

State: ``controller.state`` is a :class:`ControlState` (``mode``: not homed /
homing / idle / moving / jogging / probing / stopped / e-stopped / fault, the
``reason``, ``activity``, ``homed``, ``link_ok``, ``allowed`` commands, the
last :class:`~cmm.machine.motion.MachineState` with positions).
``subscribe(fn)`` gets events ``fn(kind, info)`` ('mode', 'fault', 'stop',
'estop', 'contact', 'deadman', 'limit', 'homed', 'hit', 'error', ...; ``info``
has a ``message`` for people), ``subscribe_state(fn)`` the latest state
(coalesced), ``on_hit(fn)`` records hits (the journal) before the probe's
status completes. All of these run on the dispatcher thread, never in the
machine loop: a listener that fails is logged and skipped; a hit recorder that
fails (disk full) puts the machine in fault.

Access (:mod:`.access`): one policy object (``refusal(client, command) -> str | None``),
checked once per command here. :class:`HolderPolicy` adapts the station's one
control holder (:class:`cmm.control.access.Control`); STOP / E-STOP / jog release
follow its ``may_stop``; the session journal (``record``: notes) the holder or a local client.

Threads: ``start()`` runs the machine loop (the only thread that talks to the
bus) and the dispatcher. Without ``start()`` commands run in the caller's
thread and statuses drive the loop when waited on (tests on the virtual clock).
The loop thread raises its own CPU priority (nice -10, :mod:`cmm.control.priority`;
``loop_priority_raised`` says whether it could), and heavy session work runs in
another process (:mod:`cmm.session.worker`), so web and report load do not
delay a jog release.

Safe state: any exception in the loop, a link error, a timeout storm, a STOP
that is not acknowledged, or a hit that cannot be recorded -> every axis is
stopped abruptly, mode ``fault`` with the reason; Reset (link up) or
Reconnect (link down; positions lost, home again) is the way back.
"""

from ..machine.motion import ContactError, LimitError
from ..machine.probing import SurfaceNotFound
from ..machine.status import Cancelled, MotionError, MoveStatus
from .access import AccessPolicy, Client, HolderPolicy, OpenPolicy
from ..api import ERROR_CODES, CommandAPI, CommandError, Response, Verb  # the API's home is cmm.api
from .core import Controller
from .jog import JogHolds
from .modes import ALLOWED, COMMANDS, ControlError, ControlState, CutShort, Mode, Refused, RunStopped, StopReport

__all__ = ["ALLOWED", "AccessPolicy", "COMMANDS", "Cancelled", "Client", "CommandAPI", "CommandError", "ContactError",
           "ControlError", "CutShort", "ControlState", "Controller", "JogHolds", "Response", "HolderPolicy",
           "LimitError", "Mode", "MotionError", "MoveStatus", "OpenPolicy", "Refused", "RunStopped", "StopReport",
           "SurfaceNotFound", "ERROR_CODES", "Verb"]

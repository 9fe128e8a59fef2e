"""The control core: one machine loop that alone talks to the bus, and the command API every front end uses.

See the package docstring (:mod:`cmm.control`) for the API and its rules.
"""

from __future__ import annotations

import collections
import logging
import sys
import threading
import time
from concurrent.futures import Future
from dataclasses import replace
from typing import Any, Callable

import numpy as np

from ..machine.motion import Machine
from ..machine.probing import CyclePath, Hit, Prober
from ..machine.status import MotionError, MoveStatus
from ..nmc.link_health import health_text
from .access import AccessPolicy, HolderPolicy, OpenPolicy
from .dispatch import Dispatcher
from . import rails
from .modes import ControlState, Mode, Refused
from ..api import CommandAPI
from .jog import JogHolds
from .job_runner import Job, JobRunner  # noqa: F401 - Job: what run_routine hands a routine
from .loop import _NOBODY, COMMAND_TIMEOUT, STATE_INTERVAL, MachineLoop, _Command  # noqa: F401 - re-exported
from .rails import Workspace
from .running import RunningJobs
from .verbs import register_machine_verbs
from .safety import STILL_TIMEOUT, STOP_PATIENCE, STOP_TIMEOUT, SafetyCore  # noqa: F401 - re-exported

log = logging.getLogger(__name__)

SWITCH_INTERVAL = 0.001  # s: how long another Python thread may hold the interpreter lock when the loop waits
ABSURD = 1e6  # mm: a probe target this far out is refused by the travel check before any path is computed

EventFn = Callable[[str, dict], None]


class Controller(MachineLoop, SafetyCore, JobRunner):
    """Owns one :class:`Machine` (and its :class:`Prober`); see :mod:`cmm.control`. The facade of the control core:
    the loop (:mod:`.loop`), the safety state machine (:mod:`.safety`) and the job runner (:mod:`.job_runner`) are its
    parts; motion verbs and observation are here."""

    def __init__(self, machine: Machine, prober: Prober | None = None, *, policy: AccessPolicy | None = None) -> None:
        self.machine = machine
        self.prober = prober or Prober(machine)
        self.config = machine.config
        self.policy: AccessPolicy = policy or OpenPolicy()
        self.dispatcher = Dispatcher(inline=True, on_error=lambda msg: self._event("error", message=msg))
        self._lock = threading.RLock()  # guards the small state below (never held during bus I/O)
        self._queue: collections.deque[_Command] = collections.deque()
        self._urgent: collections.deque[_Command] = collections.deque()
        self._thread: threading.Thread | None = None
        self._running = False
        self._steps = 0  # loop steps begun (samples and commands): how a waiting front end tells slow from stuck
        self.command_timeout = COMMAND_TIMEOUT
        self._fault: str | None = None
        self._link_ok = True
        self._warnings_seen = 0  # the bus's link warnings already told (see _link_warning)
        self._estop: str | None = None
        self._stopped: str | None = None
        # the operator's STOP / E-STOP during a run (routine, program, DMIS, auto-measure, calibration): the whole
        # run ends, not only its current move. Every further motion of the run is refused until it has ended
        self._run_stopped: str | None = None
        self._homed = self.config.homing.method == "none"
        self._homing = False
        self._job: str | None = None
        self._probing = 0  # probe cycles in progress (rapids included)
        self._seq = 0
        self._state = ControlState(Mode.NOT_HOMED if not self._homed else Mode.IDLE)
        self._listeners: list[EventFn] = []
        self._state_listeners: list[Callable[[ControlState], None]] = []
        self._hit_listeners: list[Callable[[Hit], None]] = []
        self._state_posted = False
        self._posted_key: tuple | None = None  # what the last state sent to listeners showed (see _publish)
        self._posted_time = -1e9  # its sample's machine time
        self._allowed: dict[tuple[Mode, bool], frozenset[str]] = {}
        self.loop_errors = 0
        self.loop_priority_raised: bool | None = None  # set by the loop thread when it starts
        self._releases: dict[Any, int] = {}  # per client: jog releases so far (jogs queued before one are dropped)
        self._queued_jogs: dict[Any, _Command] = {}  # per client: the jog queued and not run yet (see jog)
        self._touched: dict[Any, int] = {}  # per client: its release count when its armed jog took a hit
        self._armed_jogger: Any = _NOBODY  # the client whose armed jog ran last (None: scripts, tests)
        self._release_epoch = 0  # all clients' releases: the link process refuses a jog sent before the last one
        self._in_poll = False
        self.workspace: Workspace | None = None  # the part, for the motion rails (set_workspace)
        self.jogs = JogHolds(self)  # the one jog-hold pipeline every front end feeds
        # what runs now (auto-measure, routine, program, calibration): the cancel verb; the last run's end
        # drops a stop's mark on the run
        self.jobs = RunningJobs(on_idle=self._runs_ended)
        self.commands = CommandAPI()  # the same verbs as requests and responses, for the adapters
        register_machine_verbs(self.commands, self)
        self._restart: str | None = None  # a fault or a contact stopped the machine: the next move retracts first
        self._backoff: np.ndarray | None = None  # ... backing off this way first (after a contact)
        self._contact_at: np.ndarray | None = None  # where that contact was (machine mm)
        machine.driver = self
        machine.subscribe(self._on_sample)
        machine.on_event(self._on_machine_event)
        self.prober.listeners.append(self._on_hit)

    # --- life cycle ------------------------------------------------------------------

    def connect(self) -> None:
        """Start the modules (in the caller's thread, before :meth:`start`)."""
        self.machine.connect()
        self._homed = self.config.homing.method == "none"
        self._publish()

    def start(self) -> "Controller":
        """Run the machine loop and the dispatcher in their own threads."""
        if self._thread is None:
            # the loop needs the interpreter lock after every bus reply; with web and report threads busy the
            # default 5 ms switch interval per waiting thread adds up to a slow loop
            sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL))
            self.dispatcher = Dispatcher(on_error=self.dispatcher.on_error).start()
            self._running = True
            self._thread = threading.Thread(target=self._loop, name="machine-loop", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the loop; the machine is stopped and its servos switched off by ``machine.close``. A motion still
        running (the command line's Ctrl-C in the middle of a run) gets the operator's STOP first, straight to the
        modules, before the loop is asked to end."""
        if self.machine.motion is not None or self._job is not None:
            try:
                self._halt_now("stop")
            except Exception:  # noqa: BLE001 - a dead link: machine.close below does what it can
                log.exception("the stop on close failed")
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=3)
            self._thread = None
        self.dispatcher.close()
        try:
            self.machine.close()
        except Exception:  # noqa: BLE001 - a dead link: nothing more to do
            log.exception("closing the machine failed")

    @property
    def clock(self) -> Any:
        return self.machine.clock

    @property
    def polling(self) -> bool:
        """For MoveStatus.wait: True when another thread runs the loop (wait on the event), False to drive it."""
        return self._thread is not None and threading.current_thread() is not self._thread

    @property
    def threaded(self) -> bool:
        return self._thread is not None

    def use_policy_of(self, control: Any) -> None:
        """Adopt the station's one control holder (:class:`~cmm.control.access.Control`) as the access policy."""
        if not (isinstance(self.policy, HolderPolicy) and self.policy.control is control):
            self.policy = HolderPolicy(control)

    @property
    def holder(self) -> Any:
        """The one control holder every front end shares (None while the station runs without one: scripts)."""
        return self.policy.control if isinstance(self.policy, HolderPolicy) else None

    # --- observation ------------------------------------------------------------------

    @property
    def state(self) -> ControlState:
        return self._state

    def subscribe(self, fn: EventFn) -> Callable[[], None]:
        """Events ``fn(kind, info)`` on the dispatcher thread: 'state', 'fault', 'estop', 'stop', 'contact',
        'deadman', 'limit', 'homed', 'error', 'hit' ... A failing listener is logged and skipped."""
        self._listeners.append(fn)
        return lambda: self._listeners.remove(fn) if fn in self._listeners else None

    def subscribe_state(self, fn: Callable[[ControlState], None]) -> Callable[[], None]:
        """The latest state after samples (coalesced: a slow listener sees fewer, never stale, states)."""
        self._state_listeners.append(fn)
        return lambda: self._state_listeners.remove(fn) if fn in self._state_listeners else None

    def on_hit(self, fn: Callable[[Hit], None]) -> None:
        """Hit recorder (the session journal): runs on the dispatcher before the probe's status completes.

        If it raises (disk full), the machine goes to fault: a hit that cannot be recorded stops measuring.
        """
        self._hit_listeners.append(fn)

    def allowed(self, command: str) -> bool:
        return command in self._state.allowed

    def check_access(self, client: Any, command: str) -> None:
        """Refused (the operator's sentence) unless the access policy lets ``client`` send ``command``; for verbs
        registered beside the machine's (measurement: only the control holder changes it)."""
        why = self.policy.refusal(client, command)
        if why is not None:
            raise Refused(why)

    # --- commands (any thread) ------------------------------------------------------------

    def release_seq(self, client: Any) -> int:
        """How many jog releases this client has sent: a front end that queues jog messages passes the value
        it saw when a message arrived (``jog(..., after=)``), so a release is never undone by an older jog."""
        return self._releases.get(getattr(client, "id", client), 0)

    def jog(self, client: str | None, velocity: Any, *, probe: bool = False, after: int | None = None,
            wait: bool = True, on_error: Callable[[str], None] | None = None, heard: float | None = None) -> None:
        """Jog (mm/s per axis); repeat within ``[jog] deadman_timeout`` or it stops. ``probe``: a touch is a hit.

        Front ends jog through :class:`~cmm.control.jog.JogHolds` (clamp, release sequence, grace). With
        ``wait=False`` (threaded loop) the access and mode checks run here and now (Refused), the jog is queued
        without waiting for the loop (a newer jog of the same client replaces one still queued), and an error
        the loop finds goes to ``on_error``. ``heard``: when the front end received it (machine clock; default
        now): the dead-man counts from then, however long the jog waits here."""
        v = np.asarray(velocity, dtype=np.float64)
        key = getattr(client, "id", client)
        seq = self._releases.get(key, 0) if after is None else after
        epoch = self._release_epoch
        heard = self.clock.now() if heard is None else heard
        if probe and np.any(v) and self._touched.get(key) == seq:
            return None  # one hit per touch (see touched): the still-held jog starts nothing, is refused nothing
        if np.any(v) and self.policy.refusal(client, "jog") is None:
            self.machine.jog_alive(epoch, heard)  # with a link process: its dead-man hears the operator at once

        def start() -> None:
            if self._releases.get(key, 0) != seq:
                return  # released while this jog waited: a release is never undone by an older jog
            if probe:
                if self._touched.get(key) == seq:
                    return  # it took its hit since the operator last let go: the next needs a new press
                self._armed_jogger = key
                self.prober.jog_probe(v, release_epoch=epoch, heard=heard)
            else:
                self.machine.jog(v, release_epoch=epoch, heard=heard)
        if wait or self._thread is None or threading.current_thread() is self._thread:
            return self._submit(client, "jog", start)
        self._check(client, "jog")
        cmd = _Command(client, "jog", start)
        older = self._queued_jogs.get(key)
        self._queued_jogs[key] = cmd
        if older is not None:
            older.future.cancel()  # not run yet: this newer one replaces it

        def done(f: Future) -> None:
            if self._queued_jogs.get(key) is cmd:
                self._queued_jogs.pop(key, None)
            if on_error is not None and not f.cancelled() and f.exception() is not None:
                self.dispatcher.post(on_error, str(f.exception()))  # never a front end's call in the loop
        cmd.future.add_done_callback(done)
        self._queue.append(cmd)
        return None

    def jog_release(self, client: str | None, *, wait: bool = False, keep_touch: bool = False) -> None:
        """End the jog now. Does not wait for the loop unless ``wait``: a release must never queue behind
        anything (it goes first in the loop's next step)."""
        key = getattr(client, "id", client)
        touched = self.touched(client)
        self._releases[key] = self._releases.get(key, 0) + 1
        if keep_touch and touched:  # not the operator letting go (a front end's own stop): the touch stays taken
            self._touched[key] = self._releases[key]
        self._release_epoch += 1
        # with a link process: it stops the jog now, whatever this process is doing, and refuses jogs sent before
        self.machine.release_now(self._release_epoch)
        if wait or self._thread is None or threading.current_thread() is self._thread:
            return self._submit(client, "jog_release", self.machine.jog_release, urgent=True)
        self._urgent.append(_Command(client, "jog_release", self.machine.jog_release))

    def cancel(self, client: str | None, status: MoveStatus) -> None:
        """Cancel one move or probe cycle (decelerates); STOP stops whatever moves."""
        self._submit(client, "cancel", status.cancel, urgent=True)

    def set_workspace(self, workspace: Workspace | None) -> None:
        """The part as the motion rails see it (:mod:`cmm.control.rails`); the station wires its model's."""
        self.workspace = workspace

    def move(self, client: str | None, target: Any, *, frame: str, path: str = "clearance",
             speed: float | None = None, accel: float | None = None) -> MoveStatus:
        """Move the tip centre to ``target`` in ``frame`` ('machine' or 'part'). ``path`` 'clearance' retracts to
        the clearance height, travels and descends; 'straight' only when the line is proven free of the part.
        After a fault or a contact the move backs off and takes the clearance route first (:mod:`.rails`)."""
        goal = self._to_machine(target, frame)
        self.machine.check_target(goal)  # before the rails measure the line: a 1e308 is a sentence, not an overflow
        rails.check_path(path)

        def start() -> MoveStatus:
            legs = self._legs(goal, path)
            if len(legs) == 1 and self._restart is None:
                status = self.machine.move_to(legs[0], speed, accel)
            else:
                status = self.machine.move_path(legs, speed)
            status.add_callback(self._moved)
            return status
        return self._submit(client, "move", start)

    def _to_machine(self, point: Any, frame: str, *, direction: bool = False) -> np.ndarray:
        try:
            return rails.to_machine(point, frame, self.workspace, direction=direction)
        except rails.RailError as exc:
            raise Refused(str(exc)) from None

    def _legs(self, goal: np.ndarray, path: str) -> list[np.ndarray]:
        """Loop side: the legs of a move from where the tip is now (raises Refused for an unproven straight)."""
        here = self.machine.position
        backoff = self._backoff_here(here) if self._restart is not None else None
        try:
            return rails.route(here, goal, path=path, workspace=self.workspace,
                               radius=float(self.prober.settings.tip_radius), z_max=self.config.axis("z").max,
                               backoff=backoff, restart=self._restart is not None)
        except rails.RailError as exc:
            raise Refused(str(exc)) from None

    def _backoff_here(self, here: np.ndarray) -> np.ndarray | None:
        """The back-off after a contact, while the tip is still where it touched (an operator who jogged away
        since has backed off already: backing off again from elsewhere could move towards something)."""
        if self._backoff is None or self._contact_at is None:
            return None
        near = float(np.linalg.norm(np.asarray(here, float) - self._contact_at)) <= 2 * float(np.linalg.norm(self._backoff))
        return self._backoff if near or self.machine.state is not None and self.machine.state.probe_triggered else None

    def _moved(self, status: MoveStatus) -> None:
        if status.error is None:
            with self._lock:
                self._restart, self._backoff = None, None

    def check_target(self, target: Any) -> np.ndarray:
        """``target`` (machine mm) inside the travel, or a MotionError saying which axis it leaves."""
        return self.machine.check_target(target)

    @property
    def tip_radius(self) -> float:
        return float(self.prober.settings.tip_radius)

    @property
    def probe_settings(self) -> Any:
        """The probe settings in force (tip radius, pre-travel model): read them, change them with ``configure``."""
        return self.prober.settings

    def link_info(self) -> dict[str, Any]:
        """The link as the front ends show it: port, baud, the modules found at start-up (address, type, version)."""
        bus = self.machine.bus
        return {"port": str(getattr(bus, "port_name", "")), "baud": int(getattr(bus, "baud", self.config.link.baud)),
                "firmware": self.config.link.firmware,
                "modules": [(m.address, m.module_type, m.version) for m in (getattr(bus, "modules", None) or [])]}

    def link_health(self) -> dict:
        """The link's counters (transactions, retries, late replies recovered, the last minute's rate) and the
        Diagnostics tab's words for them; a retry that succeeded is counted here, not shouted."""
        stats = dict(getattr(self.machine.bus, "stats", {}) or {})
        return {"stats": stats, "text": health_text(stats)}

    def trace_text(self, last: int = 30) -> str:
        """The last packets on the link (the byte trace), for the diagnostics view."""
        return self.machine.bus.trace.dump(last=last)

    @property
    def samples(self) -> int:
        """Samples taken so far (every axis read once each): the link's sample rate for the status bar."""
        return int(self.machine.samples)

    def frame_position(self, frame: str) -> np.ndarray | None:
        """Where the tip centre is in ``frame`` (None: part coordinates without a part, or no sample yet)."""
        pos = self._state.position
        return None if pos is None else rails.to_frame(pos, frame, self.workspace)

    def step(self, client: str | None, axis: str, step_mm: float) -> MoveStatus:
        """One step along a machine axis (1 count .. 10 mm): a jog in small, along the machine axes."""
        return self._submit(client, "step", lambda: self.machine.step(axis, step_mm))

    def probe(self, client: str | None, target: Any, approach: Any, *, frame: str, path: str = "clearance",
              clearance_z: float | None = None, normal: Any = None, speed: float | None = None,
              accel: float | None = None, approach_distance: float | None = None,
              search_distance: float | None = None, retract_distance: float | None = None,
              rapid_speed: float | None = None, hop_z: float | None = None) -> MoveStatus:
        """A programmed hit at ``target`` (a nominal surface point in ``frame``), coming along ``approach`` (into the
        surface, same frame). The rapid to the pre-hit point goes over the clearance plane (``clearance_z``,
        default: the part's, else the higher of here and the pre-hit point) unless ``path`` is 'straight' and
        the line is proven free of the part. With ``hop_z`` (machine Z; a feature's hits after its first) the rapid
        goes straight or over that lower height where the rails prove it free of the part. Distances (mm), speeds
        (mm/s) and the probing acceleration default to the configuration's. The status completes with the
        :class:`Hit` once the hit recorders stored it."""
        p = self._to_machine(target, frame)
        if not np.all(np.abs(p) < ABSURD):  # far beyond any travel: the travel's sentence, before any path is measured
            self.machine.check_target(p)
        u = self._to_machine(approach, frame, direction=True)
        if not np.linalg.norm(u):
            raise Refused("a probe needs an approach direction that is not zero")
        n = None if normal is None else self._to_machine(normal, frame, direction=True)
        rails.check_path(path)
        distances = {"approach_distance": approach_distance, "search_distance": search_distance,
                     "retract_distance": retract_distance}

        def start() -> MoveStatus:
            here = self.machine.position
            restart = self._restart is not None
            cz = self._cycle(here, p, u, path=path, clearance_z=clearance_z, restart=restart, hop_z=hop_z,
                             **distances)[0]
            backoff = self._backoff_here(here) if restart else None
            # a contact stopped the last motion: back off the way it came first; beside the reference sphere: out
            # from it before the rapid climbs
            firsts = self._first_legs(here, backoff, p, climbs=cz is not None)
            first = None if not firsts else (self.machine.move_to(firsts[0]) if len(firsts) == 1
                                             else self.machine.move_path(firsts))
            outer = MoveStatus("probe at X={:.3f} Y={:.3f} Z={:.3f}".format(*p), self)
            with self._lock:
                self._probing += 1

            def cycle(s: MoveStatus | None = None) -> None:
                if s is not None and s.error is not None:
                    return finish_inner(s)
                try:
                    inner = self.prober.probe(p, u, clearance_z=cz, normal=n, speed=speed, accel=accel,
                                              approach_distance=approach_distance, search_distance=search_distance, retract_distance=retract_distance,
                                              rapid_speed=rapid_speed)
                except BaseException as exc:  # noqa: BLE001 - reported through the status
                    err = MoveStatus("probe", self)
                    err.finish(error=exc)
                    return finish_inner(err)
                outer.on_cancel(inner.cancel)
                inner.add_callback(finish_inner)

            def finish_inner(s: MoveStatus) -> None:  # loop thread: the hit was posted before this
                with self._lock:
                    self._probing -= 1
                    if s.error is None:
                        self._restart, self._backoff = None, None
                self.dispatcher.post(self._finish_probe, outer, s)
            if first is None:
                cycle()
            else:
                outer.on_cancel(first.cancel)
                first.add_callback(cycle)
            return outer
        return self._submit(client, "probe", start)

    def _cycle(self, here: np.ndarray, p: np.ndarray, u: np.ndarray, *, path: str, clearance_z: float | None,
               restart: bool = False, hop_z: float | None = None,
               **distances: float | None) -> tuple[float | None, CyclePath]:
        """The clearance height (None: straight) and the path of one programmed hit from ``here`` (machine mm):
        the rails decide the height, the prober's cycle the points; :meth:`probe` and :meth:`probe_paths` both
        ask here."""
        pre = self.prober.cycle_path(here, p, u, **distances).pre
        try:
            cz = rails.probe_clearance(here, pre, path=path, workspace=self.workspace, radius=self.tip_radius,
                                       clearance_z=clearance_z, restart=restart, hop_z=hop_z)
        except rails.RailError as exc:
            raise Refused(str(exc)) from None
        return cz, self.prober.cycle_path(here, p, u, clearance_z=cz, **distances)

    def _first_legs(self, here: np.ndarray, backoff: Any, toward: np.ndarray, *, climbs: bool) -> list[np.ndarray]:
        """What a probe cycle moves before its own path: the back-off after a contact, then, when its rapid climbs
        (not a straight one), out of a reference sphere's post (:func:`rails.leave_posts`)."""
        legs = [] if backoff is None else [np.asarray(here, float) + backoff]
        if not climbs:
            return legs
        start = legs[-1] if legs else np.asarray(here, float)
        out = rails.leave_posts(start, rails.posts(self.workspace, self.tip_radius), toward)
        return legs if out is None else [*legs, out]

    def probe_paths(self, targets: Any, *, frame: str = "machine", path: str = "clearance",
                    start: Any = None) -> list[CyclePath]:
        """The paths a sequence of programmed hits will take, for a preview before they run: ``targets`` are
        (nominal point, approach, clearance Z or None[, hop Z or None]) in ``frame`` (the heights are machine Z) as
        :meth:`probe` gets them; each cycle starts where the previous one retracted to (the surface taken where
        its nominal says), the first from ``start`` (default: where the tip is now). From where the tip is now
        after an unexpected contact, the first cycle backs off the way it came first (its first rapid corner)
        and never takes a straight rapid, as :meth:`probe` will. Moves nothing; raises Refused for a target it
        would refuse (outside the travel, an unproven straight line)."""
        rails.check_path(path)
        if start is None and self._state.position is None:
            raise Refused("the machine has not reported its position yet: wait a moment")
        here = np.asarray(self._state.position if start is None else start, dtype=np.float64)
        restart = start is None and self._restart is not None
        backoff = self._backoff_here(here) if restart else None
        out: list[CyclePath] = []
        for target, approach, clearance_z, *hop in targets:
            hop_z = hop[0] if hop else None
            p = self._to_machine(target, frame)
            u = self._to_machine(approach, frame, direction=True)
            try:
                cz, cycle = self._cycle(here, p, u, path=path, clearance_z=clearance_z, restart=restart, hop_z=hop_z)
                firsts = self._first_legs(here, backoff, p, climbs=cz is not None)
                if firsts:  # probe(): the back-off and the step out of a sphere's post, then the cycle from there
                    cycle = self.prober.cycle_path(firsts[-1], p, u, clearance_z=cz)
                    cycle = replace(cycle, start=here, rapid=(*firsts, *cycle.rapid))
                for point in (*cycle.rapid, cycle.end, cycle.retract):
                    self.machine.check_target(point)
            except MotionError as exc:
                raise Refused(f"hit {len(out) + 1}: {exc}") from None
            out.append(cycle)
            here, restart, backoff = cycle.retract, False, None
        return out

    def move_legs(self, target: Any, *, frame: str = "machine", path: str = "clearance") -> list[np.ndarray]:
        """The corners a :meth:`move` to ``target`` would pass from where the tip is now, for a preview: after an
        unexpected contact the back-off first, then the clearance route (machine mm). Moves nothing."""
        goal = self._to_machine(target, frame)
        rails.check_path(path)
        if self._state.position is None:
            raise Refused("the machine has not reported its position yet: wait a moment")
        here = np.asarray(self._state.position, dtype=np.float64)
        restart = self._restart is not None
        try:
            return rails.route(here, goal, path=path, workspace=self.workspace, radius=self.tip_radius,
                               z_max=self.config.axis("z").max, backoff=self._backoff_here(here) if restart else None,
                               restart=restart)
        except rails.RailError as exc:
            raise Refused(str(exc)) from None

    def home(self, client: str | None) -> None:
        """Run the homing cycle (blocks until it ends; STOP aborts it). Raises MotionError when it fails."""
        self._submit(client, "home", self._home, timeout=None)

    def zero(self, client: str | None, *, confirm: bool = False) -> None:
        """The thesis's "Cero": here becomes the home coordinates. Needs ``confirm`` and a free probe."""
        if not confirm:
            raise Refused("Zero redefines the machine origin at the present position: confirm it first")

        def do() -> None:
            if self.machine.sample().probe_triggered:
                raise Refused("cannot zero while the probe is deflected: jog it clear of the part first")
            self.machine.zero()
            self._homed = True
        self._submit(client, "zero", do)

def wait_until(pred: Callable[[], bool], timeout: float, step: float = 0.005) -> bool:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            return False
        time.sleep(step)
    return True

"""The control core: one machine loop that alone talks to the bus, and the command API every front end uses.

See the package docstring (:mod:`cmm.control`) for the API and its rules.
"""

from __future__ import annotations

import collections
import logging
import sys
import threading
import time
from dataclasses import replace
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any, Callable, Literal

import numpy as np

from ..machine.homing import home_axes
from ..machine.motion import Machine, MachineState
from ..machine.probing import CyclePath, Hit, Prober
from ..machine.status import MotionError, MoveStatus
from ..nmc.link_health import health_text
from ..nmc.bus import IDLE_PATIENCE, NmcError, Preempted
from ..nmc.transport import rest
from .access import AccessPolicy, HolderPolicy, OpenPolicy
from .dispatch import Dispatcher
from . import rails
from .liveness import Liveness
from .modes import ALLOWED, ControlError, ControlState, Mode, Refused, RunStopped, StopReport, refusal
from .api import CommandAPI
from .jog import JogHolds
from .rails import Workspace
from .running import RunningJobs
from .priority import raise_priority_on

log = logging.getLogger(__name__)

SWITCH_INTERVAL = 0.001  # s: how long another Python thread may hold the interpreter lock when the loop waits
FAULT_RETRY = 0.25  # s between attempts to reach the modules while in fault
# s a front end waits without the loop taking a step (a sample, or a command started) before it gives up: the loop
# is stuck. A busy computer makes the loop slow, not stuck: the wait goes on while it steps (it was a flat 5 s and
# an auto-measure failed beside two CPU hogs).
COMMAND_TIMEOUT = 20.0
STOP_TIMEOUT = 0.5  # s a STOP waits for the loop before it talks to the bus itself
STILL_TIMEOUT = 3.0  # s of machine time a STOP / E-STOP waits for every axis to stand still before it answers
STOP_PATIENCE = IDLE_PATIENCE + 2.0  # s a STOP the loop is carrying out may take (its own patient retries)
STATE_INTERVAL = 0.01  # s of machine time between states sent to state listeners while nothing but positions change
ABSURD = 1e6  # mm: a probe target this far out is refused by the travel check before any path is computed
WARNING_SHOWN = 10.0  # s a link warning stays in the state (the status bar) after the last one
LINK_ERRORS = (NmcError, OSError)  # SerialException and socket errors are OSErrors

EventFn = Callable[[str, dict], None]
_NOBODY = object()


def _press_name(why: str) -> str:
    return "STOP" if why == "stopped by the operator" else "E-STOP"


class _Command:
    __slots__ = ("client", "name", "fn", "future")

    def __init__(self, client: str | None, name: str, fn: Callable[[], Any]) -> None:
        self.client, self.name, self.fn = client, name, fn
        self.future: Future = Future()


class Job:
    """What a routine run by :meth:`Controller.run_routine` (or a set-up change by :meth:`Controller.configure`)
    works with, inside the machine loop: the machine and its prober, handed over by the control core."""

    def __init__(self, machine: Machine, prober: Prober, progress: Callable[[float, str], None] | None) -> None:
        self.machine, self.prober = machine, prober
        self._progress = progress

    def progress(self, fraction: float, message: str) -> None:
        if self._progress is not None:
            self._progress(fraction, message)


class Controller:
    """Owns one :class:`Machine` (and its :class:`Prober`); see :mod:`cmm.control`."""

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
        self.jobs = RunningJobs()  # what runs now (auto-measure, routine, program, calibration): the cancel verb
        self.commands = CommandAPI(self)  # the same verbs as requests and responses, for the adapters
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
            if backoff is not None:  # a contact stopped the last motion: back off the way it came first
                first = self.machine.move_to(here + backoff)
            else:
                first = None
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
                if backoff is not None:  # probe(): the back-off, then the cycle from there at the same height
                    cycle = self.prober.cycle_path(here + backoff, p, u, clearance_z=cz)
                    cycle = replace(cycle, start=here, rapid=(here + backoff, *cycle.rapid))
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

    def stop(self, client: str | None) -> StopReport:
        """Controlled stop of whatever moves; says whether every module acknowledged it.

        The press goes to the modules from the caller's thread at once (:meth:`press`: nothing queued in the
        machine loop, the web pages or the reports delays it); the loop then ends the motion that ran, and the
        answer comes when every axis stands still (:meth:`answer`; the operator's stop notes in the docs folder)."""
        return self.answer(self.press(client, "stop"))

    def emergency_stop(self, client: str | None) -> StopReport:
        """Abrupt stop and amplifiers off, latched until :meth:`reset`; says whether every module acknowledged."""
        return self.answer(self.press(client, "estop"))

    def press(self, client: str | None, verb: str) -> tuple[Any, str, float, bool]:
        """The operator's STOP (``verb`` "stop") or E-STOP ("estop"), sent to the modules now from this thread (a
        front end's own thread calls this as the press arrives; it waits for nothing but the bus's stop-all);
        Refused for a client the access policy does not let stop. :meth:`answer` with what it returns finishes it."""
        if verb not in ("stop", "estop"):
            raise ValueError(f"a press is 'stop' or 'estop', not {verb!r}")
        self._may(client, verb)
        at = self.clock.now()
        if verb == "estop":
            with self._lock:
                self._estop = self._estop or "emergency stop pressed"
            self.machine.inhibit = "emergency stop latched"
        failed = self._halt_now(verb)
        self._stop_runs("stopped by the operator" if verb == "stop" else "emergency stop")
        return client, verb, at, failed is not None and not failed

    def _stop_runs(self, why: str) -> None:
        """A stop pressed while a run goes on ends the whole run: its next motion is refused (the control core's
        checks and the machine's inhibit, for runs that move the machine directly) and its cancel is asked for
        (a run waiting for the operator's hits ends its wait). Nothing moves on its own after the press."""
        if self._job is None and not self.jobs.descriptions():
            return
        with self._lock:
            self._run_stopped = self._run_stopped or why
        if self.machine.inhibit is None:
            self.machine.inhibit = f"{why}: the run ends"
        if self._job is None:  # a run beside the loop (waiting for the operator's hits) is ended by its cancel
            self.jobs.ask_all("cancel", unless=lambda fn: getattr(fn, "is_stop", False))

    def answer(self, pressed: tuple[Any, str, float, bool]) -> StopReport:
        """The loop ends the motion the press cut short; the report once every axis stands still."""
        client, verb, at, sent = pressed
        do = (lambda: self._do_stop(sent=sent)) if verb == "stop" else (lambda: self._do_estop(sent=sent))
        report = self._stop(client, verb, do, sent=sent)
        return self._when_still(report, at, verb)

    def _run_stopped_words(self) -> str:
        why = self._run_stopped or ""
        return "stopped by the operator (STOP)" if why == "stopped by the operator" else f"ended by {why}"

    def _may(self, client: str | None, name: str) -> None:
        why = self.policy.refusal(client, name)
        if why is not None:
            raise Refused(why)

    def _halt_now(self, name: str) -> list[str] | None:
        """The operator's STOP / E-STOP, straight to the modules from the caller's thread: the motion latch first
        (no motion starts, in this process or in the link process, until the loop has carried the stop out), then
        the bus's stop-all (STOP: decelerate at the loaded acceleration; E-STOP: the modules' abrupt stop, then
        motors off). With a link process it goes over its urgent pipe; in process it takes the bus between two
        of the loop's transactions (a retry in progress gives the link up to it). Returns the axes that did not
        acknowledge (None: no bus stop-all, the loop stops them)."""
        why = "stopped by the operator" if name == "stop" else "emergency stop"
        self.machine.halted = why
        stop_all = getattr(self.machine.bus, "stop_all", None)
        if stop_all is None:
            return None
        failed: set[int] = set()
        for mode in (("smooth",) if name == "stop" else ("abrupt", "off")):
            try:
                report = stop_all(mode, latch=why)
            except Exception:  # noqa: BLE001 - it never should; then the loop stops them as before
                log.exception("the direct stop failed")
                return None
            failed |= set(report.silent)
        return [a.name.upper() for a in self.config.axes if a.address in failed]

    def _when_still(self, report: StopReport, press: float, name: str) -> StopReport:
        """The stop's answer once every axis stands still (a sample taken after the press shows no velocity): no
        message says "stopped" while an axis still moves. Told as the 'stop' / 'estop' event."""
        still = self._wait_still(press)
        if report.ok and still is not None:
            report = StopReport(True, ("stopped: every axis stands still" if name == "stop" else
                                       "emergency stop: every axis stands still, amplifiers off. Reset re-enables "
                                       "the servos."), report.failed_axes)
        elif report.ok:
            report = StopReport(True, f"{'STOP' if name == 'stop' else 'E-STOP'} acknowledged by every axis, but an "
                                f"axis was still moving {STILL_TIMEOUT:g} s after the press", report.failed_axes)
        self._event(name, ok=report.ok, message=report.message, still=still)
        self._publish()
        return report

    def _wait_still(self, press: float) -> float | None:
        """The machine time of the first sample after ``press`` in which every axis stands still (None: not within
        STILL_TIMEOUT of machine time). Drives the loop when nobody else does; never waits in the loop itself."""
        end = press + STILL_TIMEOUT
        wall_end = time.monotonic() + STILL_TIMEOUT + COMMAND_TIMEOUT
        inline = self._thread is None
        if not inline and threading.current_thread() is self._thread:
            return None
        while True:
            st = self._state.machine
            if st is not None and st.time > press and all(abs(a.velocity) < 1e-9 for a in st.axes):
                return float(st.time)
            if self.clock.now() > end or time.monotonic() > wall_end:
                return None
            if inline:
                self.poll()
                self.clock.sleep(self.poll_pause)
            else:
                time.sleep(0.002)

    def reset(self, client: str | None) -> None:
        """Clear an E-stop latch, a stop or a fault (when the link answers): servos on where the axes stand."""
        self._submit(client, "reset", self._reset)

    def reconnect(self, client: str | None) -> None:
        """After a link fault: open the link again and restart the modules (positions are lost: home again)."""
        self._submit(client, "reconnect", self._reconnect, timeout=30.0)

    def run_job(self, client: str | None, description: str, fn: Callable[[], Any], *,
                timeout: float | None = None, cancel: Callable[[], None] | None = None,
                pause: Callable[[], Any] | None = None, resume: Callable[[], Any] | None = None,
                skip: Callable[[], Any] | None = None) -> Any:
        """Run a routine (calibration, a measurement program) in the machine loop with the machine to itself.

        ``fn`` may use the machine and prober directly and wait on statuses (they drive the loop); other
        commands are refused while it runs, except STOP / E-STOP, which end its current move. While it runs,
        the ``cancel`` verb calls ``cancel`` (the job ends itself cleanly between hits); a job without one is
        ended by a controlled stop of its current move; ``pause`` / ``resume`` / ``skip`` (when given) are what
        the ``pause``, ``resume`` and ``skip_step`` verbs call.
        """
        def run() -> Any:
            with self._lock:
                self._job = description
            self._publish()
            try:
                result = fn()
            except BaseException as exc:
                why = self._end_run()
                if why is not None and not isinstance(exc, RunStopped):
                    raise RunStopped(f"{description} ended by the operator's {_press_name(why)}: {exc}") from exc
                raise
            why = self._end_run()
            if why is not None:  # the run swallowed its cut-short move: it still says it was stopped
                raise RunStopped(f"{description} ended by the operator's {_press_name(why)}")
            return result

        def stop_it() -> None:  # the cancel verb of a run that cannot end itself: a controlled stop
            self.stop(None)
        stop_it.is_stop = True  # type: ignore[attr-defined]  # not asked again by the stop it is
        with self.jobs.running(description, cancel or stop_it, pause=pause, resume=resume, skip=skip):
            return self._submit(client, "job", run, timeout=timeout)

    def _end_run(self) -> str | None:
        """The run ended (in the loop): the operator's stop that ended it (None: it was not stopped); the inhibit
        that refused its motions is lifted (an E-STOP's latch stays until Reset)."""
        with self._lock:
            self._job = None
            why, self._run_stopped = self._run_stopped, None
        if why is not None and self.machine.inhibit == f"{why}: the run ends":
            self.machine.inhibit = None
        self._publish()
        return why

    def run_routine(self, client: str | None, description: str, routine: Callable[["Job"], Any], *,
                    progress: Callable[[float, str], None] | None = None, timeout: float | None = None,
                    cancel: Callable[[], None] | None = None, **holds: Callable[[], Any] | None) -> Any:
        """A routine that needs the machine itself (calibration): ``routine(job)`` runs as a :meth:`run_job`
        and gets the machine, the prober and ``job.progress(fraction, message)``, which reaches ``progress`` on
        the dispatcher thread (never in the loop); the last report is delivered before this returns."""
        job = Job(self.machine, self.prober, None if progress is None else
                  (lambda fraction, message: self.dispatcher.post(progress, fraction, message)))
        try:
            return self.run_job(client, description, lambda: routine(job), timeout=timeout, cancel=cancel, **holds)
        finally:
            if progress is not None:
                self.dispatcher.flush()

    def run_beside(self, client: str | None, description: str, fn: Callable[[], Any], *,
                   cancel: Callable[[], None], **holds: Callable[[], Any] | None) -> Any:
        """Work that does not hold the machine (a program waiting for the operator's manual hits: the operator jogs
        and probes meanwhile, each move its own command): run in the caller's thread, registered with its
        ``cancel`` (and ``pause`` / ``resume`` / ``skip``) as a running job; only the client that may start a job
        starts it."""
        why = self.policy.refusal(client, "job")
        if why is not None:
            raise Refused(why)
        with self.jobs.running(description, cancel, **holds):
            try:
                result = fn()
            except BaseException as exc:
                why = self._end_beside()
                if why is not None and not isinstance(exc, RunStopped):
                    raise RunStopped(f"{description} ended by the operator's {_press_name(why)}: {exc}") from exc
                raise
            why = self._end_beside()
            if why is not None:
                raise RunStopped(f"{description} ended by the operator's {_press_name(why)}")
            return result

    def _end_beside(self) -> str | None:
        """A run beside the loop ended: the operator's stop that ended it, once no other run goes on (see _end_run)."""
        if self._job is not None or len(self.jobs.descriptions()) > 1:
            return self._run_stopped
        with self._lock:
            why, self._run_stopped = self._run_stopped, None
        if why is not None and self.machine.inhibit == f"{why}: the run ends":
            self.machine.inhibit = None
        return why

    def cancel_jobs(self, client: str | None) -> dict[str, Any]:
        """End whatever job runs (auto-measure, routine, program, calibration) cleanly: the ``cancel`` verb. Allowed
        to every client the access policy lets stop; a job that was not running is no error."""
        why = self.policy.refusal(client, "cancel")
        if why is not None:
            raise Refused(why)
        asked = self.jobs.cancel_all()
        return {"cancelled": asked,
                "message": ("cancelled: " + "; ".join(asked)) if asked else "nothing was running to cancel"}

    def hold_jobs(self, client: str | None, action: str) -> dict[str, Any]:
        """Pause, resume or skip the step of whatever job runs and can (a routine, a probe qualification): the
        ``pause`` (allowed like STOP), ``resume`` and ``skip_step`` (the control holder) verbs."""
        command, done = {"pause": ("pause", "paused"), "resume": ("resume", "resumed"),
                         "skip": ("skip_step", "skipped")}[action]
        why = self.policy.refusal(client, command)
        if why is not None:
            raise Refused(why)
        asked = self.jobs.ask_all(action)
        what = {"pause": "pause", "resume": "resume (nothing is paused)", "skip": "skip a step of"}[action]
        return {done: asked, "message": f"{done}: " + "; ".join(asked) if asked else f"nothing was running to {what}"}

    def wait_event(self, event: threading.Event, timeout: float) -> bool:
        """Wait for ``event``; from inside the machine loop (a routine waiting for the operator) keep the loop
        running meanwhile, so STOP, E-STOP and the link watch still work."""
        if self._thread is None or threading.current_thread() is not self._thread:
            return event.wait(timeout)
        end = time.monotonic() + timeout
        while not event.is_set() and time.monotonic() < end:
            self.poll()
            time.sleep(0.005)
        return event.is_set()

    def configure(self, client: str | None, change: Callable[["Job"], Any]) -> Any:
        """Change the machine set-up (geometry correction, probe settings, gains) in the loop, while still:
        ``change(setup)`` gets the machine and its prober (``setup.machine``, ``setup.prober``)."""
        return self._submit(client, "configure", lambda: change(Job(self.machine, self.prober, None)))

    def fault(self, reason: str) -> None:
        """Put the machine in the safe state (any thread): all axes stopped abruptly, mode fault."""
        cmd = _Command(None, "fault", lambda: self._enter_fault(reason))
        if self._thread is None or threading.current_thread() is self._thread:
            self._run_command(cmd, check=False)
        else:
            self._urgent.append(cmd)

    # --- submission ----------------------------------------------------------------------

    def _check(self, client: str | None, name: str, internal: bool = False) -> None:
        why = self.policy.refusal(client, name)
        if why is not None:
            raise Refused(why)
        st = self._current_mode()
        if internal:  # a routine's own moves: a fault, the E-stop latch or the operator's stop of the run stop them
            if st[0] in (Mode.FAULT, Mode.ESTOPPED):
                raise Refused(refusal(name, st[0], st[1]) or "refused")
            if self._run_stopped is not None:
                raise RunStopped(f"{name} refused: the run was {self._run_stopped_words()}")
            return
        why = refusal(name, st[0], st[1], st[2])
        if why is None and name in ("move", "probe", "job") and not self._homed:
            why = refusal(name, Mode.NOT_HOMED)
        if why is None and name == "reset" and self._fault is not None and not self._link_ok:
            why = "the link to the modules is down: Reconnect first"
        if why is not None:
            raise Refused(why)

    def _submit(self, client: str | None, name: str, fn: Callable[[], Any], *, urgent: bool = False,
                timeout: float | None | Literal["command"] = "command") -> Any:
        cmd = _Command(client, name, fn)
        if self._thread is None or threading.current_thread() is self._thread:
            return self._run_command(cmd, internal=self._job is not None and name != "job")
        (self._urgent if urgent else self._queue).append(cmd)
        return self._await(cmd, self.command_timeout if timeout == "command" else timeout)

    def _await(self, cmd: _Command, timeout: float | None) -> Any:
        """The result of ``cmd`` from the loop; gives up when the loop has made no progress for ``timeout`` s (stuck)
        or has stopped, never while it is only slow (:mod:`.liveness`)."""
        live = None if timeout is None else Liveness(self._progress, timeout)
        while True:
            try:
                return cmd.future.result(0.25 if live is None else live.slice)
            except FutureTimeout:
                pass
            thread = self._thread
            if thread is None or not thread.is_alive():
                raise ControlError(f"{cmd.name}: the machine loop has stopped")
            if live is not None and live.stuck():
                raise ControlError(f"{cmd.name}: the machine loop took no step for {timeout:g} s (it is stuck)")

    def _progress(self) -> tuple[int, int, int, int]:
        """What changes whenever the loop does anything: steps begun, and the link's transactions, retries and
        resynchronisations (a loop patiently retrying a slow module is working, not stuck)."""
        stats = getattr(self.machine.bus, "stats", None) or {}
        return (self._steps, int(stats.get("transactions", 0)), int(stats.get("retries", 0)),
                int(stats.get("resyncs", 0)))

    def _run_command(self, cmd: _Command, check: bool = True, internal: bool = False) -> Any:
        """Check and execute one command in the loop (or inline); link failures put the machine in fault."""
        try:
            if check:
                self._check(cmd.client, cmd.name, internal)
            if cmd.name in ("jog", "move", "step", "probe", "home", "job"):
                with self._lock:
                    self._stopped = None
            return cmd.fn()
        except Preempted as exc:  # a STOP took the link first: nothing failed, this command was not done
            raise ControlError(f"{cmd.name} was cut short by a STOP ({exc})") from exc
        except LINK_ERRORS as exc:
            self._enter_fault(f"link failure during {cmd.name}: {exc}", link=True)
            raise ControlError(f"{cmd.name} failed: the link to the modules failed ({exc}); "
                               "the machine is in fault") from exc
        finally:
            self._publish()

    # --- stops -------------------------------------------------------------------------------

    def _stop(self, client: str | None, name: str, fn: Callable[[], StopReport], *, sent: bool = False) -> StopReport:
        """The loop's part of a stop: it ends the motion that ran (and stops the axes itself when the direct stop
        could not: ``sent`` False). The answer is told by :meth:`_when_still`."""
        cmd = _Command(client, name, fn)
        if self._thread is None or threading.current_thread() is self._thread:
            return fn()
        self._urgent.appendleft(cmd)
        preempt = getattr(self.machine.bus, "preempt", None)
        if preempt is not None:  # a loop patiently retrying a missed reply (all standing) comes back at once
            preempt()
        if sent:  # the axes have their stop and motion is latched off: a slow loop only ends the motion late
            try:
                return self._await(cmd, self.command_timeout)
            except ControlError:  # stuck: end the motion from here
                report = fn()
                self.fault("the machine loop stopped answering")
                return report
        # the direct stop was not confirmed by every module: the loop stops them, unless it is stuck. Judged by its
        # progress (a busy computer makes it slow, not stuck); while it carries the stop out (a module slow to
        # confirm it is retried patiently) it gets STOP_PATIENCE, and never a second stop beside it
        live = Liveness(self._progress, STOP_TIMEOUT)
        while True:
            try:
                return cmd.future.result(live.slice)
            except FutureTimeout:
                pass
            if cmd.future.running():
                live.patience = STOP_PATIENCE
            thread = self._thread
            if thread is None or not thread.is_alive() or live.stuck():
                break
        if cmd.future.cancel():  # the loop never took it (nor will): this one time the caller talks to the bus
            report = fn()
        else:
            try:
                return cmd.future.result(STOP_PATIENCE)
            except FutureTimeout:
                report = fn()
        report = StopReport(report.ok, report.message + " (sent directly: the machine loop was not answering)",
                            report.failed_axes)
        self.fault("the machine loop stopped answering")
        return report

    def _halt_all(self, mode: str) -> list[str]:
        """Stop every axis however bad the link is (the bus's stop-all: a no-reply burst, then an acknowledged
        stop per module); returns the axes that did not acknowledge."""
        stop_all = getattr(self.machine.bus, "stop_all", None)
        if stop_all is not None:
            try:
                report = stop_all(mode)
                silent = set(report.silent)
                return [a.name.upper() for a in self.config.axes if a.address in silent]
            except Exception:  # noqa: BLE001 - it never should; then axis by axis below
                log.exception("stop_all failed")
        failed = []
        for axis, mod in zip(self.config.axes, self.machine.modules):
            try:
                mod.stop(mode)
            except Exception:  # noqa: BLE001 - try every axis; report the ones that did not answer
                failed.append(axis.name.upper())
        return failed

    def _do_stop(self, sent: bool = False) -> StopReport:
        try:
            if sent:  # every module acknowledged the direct stop: end the motion that ran, send nothing more
                self.machine.finish_halted(MotionError("stopped by the operator"))
            else:
                self.machine.stop()
                self.machine.finish_halted(MotionError("stopped by the operator"))
            with self._lock:
                self._stopped = "stopped by the operator"
            return StopReport(True, "stopped: every axis acknowledged")
        except Exception as exc:  # noqa: BLE001
            failed = self._halt_all("abrupt")
            ok = not failed
            self._enter_fault(f"STOP failed on the link ({exc})", link=not ok)
            return StopReport(ok, "stopped abruptly after a link error" if ok else
                              f"STOP NOT CONFIRMED by axis {', '.join(failed)}: the link failed ({exc}). "
                              "Use the machine's emergency stop button.", tuple(failed))

    def _do_estop(self, sent: bool = False) -> StopReport:
        failed = [] if sent else sorted(set(self._halt_all("abrupt")) | set(self._halt_all("off")))
        self.machine.abort(MotionError("emergency stop"))
        try:
            self.machine.finish_halted(MotionError("emergency stop"))  # the latch: the E-stop's inhibit stays
        except LINK_ERRORS as exc:
            failed = failed or [a.name.upper() for a in self.config.axes]
            log.error("clearing the stop latch failed: %s", exc)
        if failed:
            self._enter_fault(f"E-STOP not acknowledged by axis {', '.join(failed)}", link=True)
            return StopReport(False, f"E-STOP NOT CONFIRMED by axis {', '.join(failed)}: the link failed. "
                              "Use the machine's emergency stop button.", tuple(failed))
        return StopReport(True, "emergency stop: every axis stopped, amplifiers off. Reset re-enables the servos.")

    # --- loop-side actions ---------------------------------------------------------------------

    def _enter_fault(self, reason: str, link: bool = False) -> None:
        """The safe state: every axis stopped abruptly (amplifiers stay as they are), the reason kept."""
        first = self._fault is None
        self.machine.inhibit = f"fault: {reason}"
        with self._lock:
            self._restart = self._restart or "fault"
            if first:
                self._fault = reason
            if link:
                self._link_ok = False
        failed = self._halt_all("abrupt")
        if failed:
            with self._lock:
                self._link_ok = False
        self.machine.abort(MotionError(f"fault: {reason}"))
        if first:
            log.error("machine fault: %s", reason)
            self._event("fault", reason=reason, stopped=not failed,
                        message=f"FAULT: {reason}. " + ("All axes stopped." if not failed else
                                                        f"Axis {', '.join(failed)} did not confirm the stop."))
        self._publish()

    def _reset(self) -> None:
        if self.machine.halted is not None:  # a stop the loop never carried out: its latch ends here
            self.machine.finish_halted(MotionError("reset"))
        with self._lock:
            was_fault = self._fault is not None
        for mod in self.machine.modules:
            mod.clear_bits()
            mod.enable()
        self.machine.sample()
        with self._lock:
            self._estop = None
            self._stopped = None
            self._fault = None
            self._run_stopped = None
        self.machine.inhibit = None
        if was_fault:
            self._event("reset", message="fault cleared: servos on where the axes stand")

    def _reconnect(self) -> None:
        kept = False
        reopen = getattr(self.machine.bus, "reopen", None)
        if reopen is not None:
            try:  # the same modules, addresses, rate and positions: nothing was reset
                reopen()
                self._halt_all("abrupt")
                self.machine.sample()
                kept = True
            except Exception as exc:  # noqa: BLE001 - they were reset or replaced: start them again
                log.warning("reopening the link failed (%s): restarting the modules", exc)
        if not kept:
            self.machine.reconnect()
        self.machine.inhibit = None
        with self._lock:
            self._fault = None
            self._estop = None
            self._stopped = None
            self._link_ok = True
            if not kept:
                self._homed = self.config.homing.method == "none"
        self._event("reconnect", message="link restored; positions kept" if kept else
                    "link restored by restarting the modules; positions were lost: home the machine")

    def _home(self) -> None:
        with self._lock:
            self._homing = True
            self._homed = False
        self._publish()
        try:
            home_axes(self.machine, tick=self._homing_tick)
        except Exception as exc:
            # the press cut a search move short: the cycle was stopped, its switch was not missing
            why = self._fault or self._estop or self._stopped or self.machine.halted
            if why and not str(exc).startswith("homing aborted"):
                raise MotionError(f"homing aborted: {why}") from exc
            raise
        finally:
            with self._lock:
                self._homing = False
        with self._lock:
            self._homed = True
        self._event("homed", message="homing cycle done")

    def _homing_tick(self) -> None:
        """Between homing samples: serve STOP / E-STOP (which abort the cycle); other commands are answered
        at once (refused: the machine is homing)."""
        if self._urgent:
            self._serve(self._urgent)
        if self._queue:
            self._serve(self._queue)
        if self._estop is not None or self._stopped is not None or self._fault is not None:
            self.machine.halt("abrupt")
            raise MotionError("homing aborted: " + (self._fault or self._estop or self._stopped or ""))

    # --- the loop -------------------------------------------------------------------------------

    def _serve(self, q: collections.deque[_Command], *, waiting_only: bool = False) -> None:
        """Carry out the commands in ``q``; with ``waiting_only`` only those waiting when the step began: commands
        that arrive meanwhile wait for the next step, after its sample. A front end that sends holds faster than a
        slowly-scheduled loop carries them out would otherwise keep the loop from ever sampling again (the state
        froze, the watchers stopped, and each hold re-targeted the jog from that stale sample: it never started)."""
        left = len(q) if waiting_only else -1  # -1: until the queue is empty
        while q and left != 0:
            left -= 1
            try:
                cmd = q.popleft()
            except IndexError:
                return
            if not cmd.future.set_running_or_notify_cancel():
                continue
            self._steps += 1
            try:
                result = self._run_command(cmd, check=cmd.name not in ("fault", "stop", "estop"))
            except BaseException as exc:  # noqa: BLE001 - the caller gets it
                cmd.future.set_exception(exc)
            else:
                cmd.future.set_result(result)

    def poll(self) -> MachineState | None:
        """One loop step: urgent commands, queued commands, one sample with its watchers; never raises."""
        self._steps += 1
        try:
            if self._urgent:
                self._serve(self._urgent)
            if self._queue:  # while a routine runs they are refused by their checks (busy)
                self._serve(self._queue, waiting_only=True)
            if self._fault is not None:
                return self._poll_in_fault()
            self._in_poll = True
            try:
                state = self.machine.poll()
            finally:
                self._in_poll = False
            self._publish()  # after the watchers: a finished move is idle in the same sample
            return state
        except Preempted:  # a STOP is waiting for the link (urgent): it goes first in the next step
            return self.machine.state
        except LINK_ERRORS as exc:
            self._enter_fault(f"link failure: {exc}", link=True)
        except Exception as exc:  # noqa: BLE001 - a bug must stop the machine, not the loop
            self.loop_errors += 1
            log.exception("machine loop error")
            self._enter_fault(f"machine loop error: {type(exc).__name__}: {exc}")
        return self.machine.state

    def _poll_in_fault(self) -> MachineState | None:
        now = self.clock.now()
        if now - getattr(self, "_fault_tried", -1e9) < FAULT_RETRY:
            self.clock.sleep(0.005)  # time goes on (also on a virtual clock, so waits can time out)
            return self.machine.state
        self._fault_tried = now
        try:
            state = self.machine.sample()  # still answering? show live positions; stop again if it moves
            if any(abs(a.velocity) > 0 for a in state.axes) and self.machine.motion is None:
                self._halt_all("abrupt")
            with self._lock:
                self._link_ok = True
            self._publish()
            return state
        except Exception:  # noqa: BLE001 - still down
            with self._lock:
                was = self._link_ok
                self._link_ok = False
            if was:
                self._publish()
            return self.machine.state

    @property
    def poll_pause(self) -> float:
        return self.machine.poll_pause  # longer on the virtual clock, where samples cost CPU only

    def _loop(self) -> None:
        # the CPU goes to the loop first (priority.py); not on the virtual clock, where the loop never sleeps
        self.loop_priority_raised = raise_priority_on(self.clock)
        while self._running:
            self.poll()
            if self._idle():
                rest(self.clock, self.poll_pause)  # on an uncapped simulator clock: no racing ahead at full CPU
            else:
                self.clock.sleep(self.poll_pause)

    def _idle(self) -> bool:
        """Nothing moves and nothing waits on the machine: no motion, job, homing or probe cycle."""
        return self.machine.motion is None and self._job is None and not self._homing and not self._probing

    def run_for(self, seconds: float) -> None:
        """Drive the loop for ``seconds`` of machine time (no thread: scripts and tests on the virtual clock)."""
        end = self.clock.now() + seconds
        while self.clock.now() < end:
            self.poll()
            self.clock.sleep(0.01 if self._fault is not None else self.poll_pause)

    # --- state ----------------------------------------------------------------------------------

    def _current_mode(self) -> tuple[Mode, str, str]:
        m = self.machine
        motion = m.motion
        if self._fault is not None:
            return Mode.FAULT, self._fault, ""
        if self._estop is not None:
            return Mode.ESTOPPED, self._estop, ""
        if self._homing:
            return Mode.HOMING, "", "homing cycle"
        if self._job is not None and self._run_stopped is not None:  # the run unwinds after the operator's stop
            st = m.state
            if motion is not None or st is not None and any(abs(a.velocity) >= 1e-9 for a in st.axes):
                return Mode.MOVING, "", "stopping (STOP pressed)"  # never "stopped" while an axis still moves
            return Mode.STOPPED, f"{self._job}: {self._run_stopped}", ""
        if self._job is not None:
            return (Mode.PROBING if self._probing or (motion is not None and motion.kind == "probe") else Mode.MOVING,
                    "", self._job)
        if motion is not None:
            if motion.kind == "jog":
                return Mode.JOGGING, "", "jog"
            if motion.kind == "probe" or self._probing:
                return Mode.PROBING, "", motion.status.description
            return Mode.MOVING, "", motion.status.description
        if self._probing:
            return Mode.PROBING, "", "probe cycle"
        if self._stopped is not None:
            st = m.state
            if st is not None and any(abs(a.velocity) >= 1e-9 for a in st.axes):
                return Mode.MOVING, "", "stopping (STOP pressed)"  # never "stopped" while an axis still moves
            return Mode.STOPPED, self._stopped, ""
        if not self._homed:
            return Mode.NOT_HOMED, "", ""
        return Mode.IDLE, "", ""

    def _publish(self) -> None:
        """Update ``state`` (every sample); tell the listeners what they can use: mode changes at once, states
        to state listeners at once when anything but the positions changed (a move ending, the probe, the
        mode), else at most every STATE_INTERVAL of machine time. Nothing is posted for nobody."""
        mode, reason, activity = self._current_mode()
        machine = self.machine.state
        warning = self._link_warning()
        with self._lock:
            self._seq += 1
            homed = self._homed
            allowed = self._allowed.get((mode, homed))
            if allowed is None:
                allowed = self._allowed[(mode, homed)] = frozenset(
                    c for c, modes in ALLOWED.items() if mode in modes and not (c in ("move", "probe", "job") and not homed))
            old = self._state
            self._state = ControlState(mode, reason, activity, homed, self._link_ok, machine, self._seq, allowed, warning)
            changed = old.mode != mode or old.reason != reason or old.link_ok != self._link_ok or old.homed != homed
            post = False
            if self._state_listeners and not self._state_posted:
                key = (mode, reason, activity, homed, self._link_ok, warning) if machine is None else \
                    (mode, reason, activity, homed, self._link_ok, warning, machine.moving, machine.jogging,
                     machine.probe_triggered)
                t = -1e9 if machine is None else machine.time
                post = key != self._posted_key or not 0 <= t - self._posted_time < STATE_INTERVAL
                if post:
                    self._state_posted = True
                    self._posted_key, self._posted_time = key, t
        if changed:
            self._event("mode", mode=mode.value, reason=reason, message=f"machine {mode.value}"
                        + (f": {reason}" if reason else ""))
        if post:
            self.dispatcher.post(self._deliver_state)

    def _link_warning(self) -> str:
        """The bus's last link warning while recent (a 'link_warning' event for each new one), else ''."""
        count, text, at = getattr(self.machine.bus, "warning", None) or (0, "", 0.0)
        if not count:
            return ""
        if count != self._warnings_seen:
            self._warnings_seen = count
            log.warning("link: %s", text)
            self._event("link_warning", message=f"link warning: {text}", count=count)
        return text if self.machine.bus.clock.now() - at < WARNING_SHOWN else ""

    def _deliver_state(self) -> None:
        with self._lock:
            self._state_posted = False
            state = self._state
        for fn in list(self._state_listeners):
            try:
                fn(state)
            except Exception:  # noqa: BLE001
                log.exception("state listener %r failed", fn)

    def _on_sample(self, _state: MachineState) -> None:
        if not self._in_poll:  # samples outside poll (homing, commands); poll publishes after its watchers
            self._publish()

    def _event(self, kind: str, **info: Any) -> None:
        self.dispatcher.post(self._deliver, kind, info)

    def _deliver(self, kind: str, info: dict) -> None:
        for fn in list(self._listeners):
            try:
                fn(kind, info)
            except Exception:  # noqa: BLE001 - contained
                log.exception("control listener %r failed on %s", fn, kind)

    def _on_machine_event(self, kind: str, info: dict) -> None:
        if kind == "contact":
            way = info.get("direction")
            with self._lock:
                self._restart = "contact"
                self._contact_at = np.asarray(info.get("position", (np.nan,) * 3), float)
                self._backoff = None if way is None else \
                    -np.asarray(way, float) * float(self.config.probe.retract_distance)
            info = {**info, "message": "unexpected probe contact at X={:.3f} Y={:.3f} Z={:.3f}: the machine stopped"
                    .format(*info.get("position", (float("nan"),) * 3))}
        self._event(kind, **info)

    def _finish_probe(self, outer: MoveStatus, inner: MoveStatus) -> None:
        """Dispatcher: after the hit recorders ran; a fault meanwhile (disk full) fails the probe."""
        fault = self._fault
        if inner.error is None and fault is not None:
            outer.finish(error=ControlError(f"the probe cycle ended in a fault: {fault}"))
        else:
            outer.finish(inner.result, inner.error)

    def _on_hit(self, hit: Hit) -> None:
        jogger = self._armed_jogger
        if hit.mode == "manual" and jogger is not _NOBODY:  # one hit per touch: this jog stays stopped until let go
            self._touched[jogger] = self._releases.get(jogger, 0)
        self.dispatcher.post(self._record_hit, hit)

    def touched(self, client: Any) -> bool:
        """Has this client's armed jog taken a hit since the client last let go? Then its holds start nothing (one
        hit per touch: the still-held button must not drive back in for another); a release ends that."""
        key = getattr(client, "id", client)
        return key in self._touched and self._touched[key] == self._releases.get(key, 0)

    def _record_hit(self, hit: Hit) -> None:
        for fn in list(self._hit_listeners):
            try:
                fn(hit)
            except Exception as exc:  # noqa: BLE001 - a hit that cannot be stored stops the measurement
                log.exception("hit recorder failed")
                self.fault(f"the hit could not be recorded ({exc}); measuring stopped so nothing is lost")
                return
        self._deliver("hit", {"hit": hit})


def wait_until(pred: Callable[[], bool], timeout: float, step: float = 0.005) -> bool:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            return False
        time.sleep(step)
    return True

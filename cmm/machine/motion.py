"""The CMM machine: three PIC-SERVO axes in millimetres.

One object owns the bus. ``poll()`` samples every axis once and runs the
watchers (move completion, jog dead-man and horizon, soft limits while
jogging, probe contacts); the control core's machine loop
(:mod:`cmm.control`) calls it, or a status's ``wait()`` drives it (scripts,
tests on the virtual clock). ``driver`` is what statuses drive when they
wait: the machine itself, or the control core that owns it.

Subscribers and event listeners are called from the polling thread, some of
them with the motion lock held: they must be cheap and do no I/O (the control
core only queues what they get). A failing one is logged, never propagated.

Protections on the modules themselves, so they hold when the station dies:
every jog and every protected move arms home capture on the probe input with
stop-abrupt, and a horizon jog (``[jog] mode = "horizon"``) commands position
goals at most ``horizon`` seconds of travel ahead, clamped to the travel.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..nmc import codec
from ..nmc.bus import LinkError, ModuleInfo, NmcError, Preempted
from ..nmc.link_process import GuardAxis, GuardHeld, GuardSpec, open_bus
from ..nmc.module import Module
from ..nmc.trace import ByteTrace
from ..nmc.transport import is_virtual
from .config import AXES, MachineConfig, counts_to_mm
from .geometry import GeometryCorrection
from .status import MotionError, MoveStatus
from ..metrology.numbers_text import num

GROUP = 0x80  # all three axes; X is the leader, so a group START_MOVE is acknowledged
POLL_PAUSE = 0.0002  # between samples: lets UI threads take the machine lock; the link is the limit
# On the simulator's virtual clock a sample costs CPU, not wall time: sampling every 4 ms of machine time
# instead of every servo tick makes the simulated station about 2x cheaper to run (tests, calibration);
# probe triggers are latched by the modules, so nothing measured depends on the sample rate.
VIRTUAL_POLL_PAUSE = 0.004
DEFLECTED_JOG_MM = 0.5  # travel a jog started with the probe deflected may make while it stays deflected (a probe
# freed by jogging off the surface is free within micrometres; further in, the stylus bends and then breaks)
JOG_LOOKAHEAD = 0.03  # s of travel allowed for sampling latency before a jog reaches a travel limit
STEP_MIN_COUNTS = 1
STEP_MAX_MM = 10.0
STOP_MARGIN_S = 0.02  # s of travel added to a horizon stop's goal (sampling and command latency)
RETARGET_MIN_S = 0.03  # a horizon jog is re-targeted when its goal would move by more than this much travel

log = logging.getLogger(__name__)


class LimitError(MotionError):
    """A target outside the travel, refused before anything moves."""


class ContactError(MotionError):
    """The probe touched something during a move that was not a probing move."""


@dataclass(frozen=True)
class AxisState:
    counts: int
    mm: float
    following_error: int | None  # counts; None when the firmware cannot report it
    velocity: float  # mm/s (integer counts per tick, as the module reports it)
    status: int
    aux: int
    current: int | None = None  # motor current sense, raw A/D (0..255)

    @property
    def words(self) -> list[str]:
        return codec.status_words(self.status, self.aux)


@dataclass(frozen=True)
class MachineState:
    time: float
    axes: tuple[AxisState, AxisState, AxisState]
    probe_triggered: bool
    jogging: bool
    moving: bool

    @property
    def position(self) -> np.ndarray:
        return np.array([a.mm for a in self.axes])

    @property
    def counts(self) -> tuple[int, int, int]:
        return tuple(a.counts for a in self.axes)  # type: ignore[return-value]


@dataclass
class _Motion:
    """What the machine is doing, so ``poll`` knows what to watch."""

    status: MoveStatus
    kind: str  # "move", "probe", "jog"
    armed: bool = False  # home capture armed on the probe input
    on_capture: Callable[[tuple[int, int, int]], None] | None = None
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class MotionView:
    """What the machine is doing, read-only (for the control core): the kind and its status."""

    kind: str  # "move", "probe", "jog"
    status: MoveStatus


def _jog_stopped(motion: _Motion) -> np.ndarray:
    """A jog was told to stop (release, dead-man, link process): no velocity, no goal to re-target."""
    motion.extra["v"] = v = np.zeros(3)
    motion.extra.pop("goal", None)
    return v


class Machine:
    def __init__(self, config: MachineConfig, port: Any, *, trace: ByteTrace | None = None) -> None:
        self.config = config
        self._port = port
        # a real port gets a link process of its own, which also runs the jog dead-man and release
        self.bus = open_bus(port, firmware=config.link.firmware, trace=trace, process=config.link.process)
        self.clock = self.bus.clock
        self.modules = [Module(self.bus, a.address) for a in config.axes]
        # position, motor current (A/D), velocity, aux and following error: 16 bytes a transaction
        # at 115200 baud fill three servo ticks (a command executes at the end of its tick), so the
        # current costs no sample rate
        self.items = codec.SEND_POS | codec.SEND_AD | codec.SEND_VEL | codec.SEND_AUX
        if config.link.read_following_error:
            self.items |= codec.SEND_PERROR
        self.state: MachineState | None = None
        self._talked = False  # connect() was tried: close() has modules to stop and release
        self.polling = False
        self._thread: threading.Thread | None = None
        self._lock = threading.RLock()
        self._motion: _Motion | None = None
        self._jog_refreshed = 0.0
        self._subscribers: list[Callable[[MachineState], None]] = []
        self._event_listeners: list[Callable[[str, dict], None]] = []
        self._probe_mask = codec.LIMIT1 if config.probe.input == "limit1" else codec.LIMIT2
        self.samples = 0
        self.poll_pause = VIRTUAL_POLL_PAUSE if is_virtual(self.clock) else POLL_PAUSE  # s between samples
        self.correction = GeometryCorrection()  # the calibration routine sets it
        self.driver: Any = self  # what MoveStatus.wait drives: this machine or the control core owning it
        self._contact_dir: np.ndarray | None = None  # direction of the last jog that touched
        self.inhibit: str | None = None  # set by the control core (fault, E-stop): every new motion is refused
        # set by the control core the moment the operator presses STOP / E-STOP (any thread, before the modules are
        # told): no motion starts, and the motion running ends cut short (never "done") at the next sample, until
        # the machine loop has carried the stop out (finish_halted)
        self.halted: str | None = None

    # --- connection -------------------------------------------------------

    def connect(self) -> list[ModuleInfo]:
        """Initialise the network and every axis: gains, status items, inputs, group, servo on."""
        with self._lock:
            self._talked = True
            # a truncated chain (a module that missed its address under load) is retried, not accepted
            infos = self.bus.initialize(self.config.link.baud,
                                        expected_modules=max(a.address for a in self.config.axes))
            found = {m.address for m in infos}
            for axis in self.config.axes:
                if axis.address not in found:
                    raise NmcError(f"axis {axis.name.upper()} expects a module at address {axis.address}, "
                                   f"found modules {sorted(found)}", axis.address)
            for axis, mod in zip(self.config.axes, self.modules):
                self._define_status(axis, mod)
                mod.set_gains(axis.gains)
                mod.plain_inputs()  # probe and home switches are captured, never acted on by the firmware
                mod.clear_bits()
                mod.enable()
                mod.set_group(GROUP, leader=axis.name == "x")
            self.sample()
            return infos

    def _define_status(self, axis: Any, mod: Module) -> None:
        """DEF_STAT with the configured items. If it fails: the firmware, or the link? The status without the
        following error (item 0x40) tells: a module that answers that and refuses the longer one again lacks
        the item; one that answers nothing has a link problem, said as it is (never "needs SC firmware" on SC
        firmware)."""
        try:
            mod.define_status(self.items)
            return
        except NmcError as exc:
            if not self.items & codec.SEND_PERROR:
                raise
            first = exc
        name = f"module {axis.address} ({axis.name.upper()})"
        try:
            mod.define_status(self.items & ~codec.SEND_PERROR)
        except NmcError as exc:
            raise NmcError(f"{name} did not answer while its status items were set up: {first}",
                           axis.address) from exc
        try:
            mod.define_status(self.items)
            return  # it was the link after all, and it answers again
        except NmcError as exc:
            refused = exc
        try:  # so the replies are understood again (the close that follows stops the motors)
            mod.define_status(self.items & ~codec.SEND_PERROR)
        except NmcError:
            pass
        raise NmcError(f"{name} does not answer with the status items the configuration reads (it answers without "
                       "the following error): reading the following error "
                       "(status item 0x40) needs SC firmware. For original PIC-SERVO modules set [link] firmware = "
                       f"\"pic-servo\" and read_following_error = false (the link said: {refused})",
                       axis.address) from refused

    def reconnect(self) -> list[ModuleInfo]:
        """Open the link again and restart the modules (after a link failure); positions are lost."""
        with self._lock:
            try:
                self.bus.close()
            except Exception:  # noqa: BLE001 - it is broken already
                pass
            self.bus = open_bus(self._port, firmware=self.config.link.firmware, trace=self.bus.trace,
                                process=self.config.link.process)
            self.clock = self.bus.clock
            self.modules = [Module(self.bus, a.address) for a in self.config.axes]
            motion, self._motion = self._motion, None
            if motion is not None:
                motion.status.finish(error=MotionError("the link was restarted"))
            return self.connect()

    def close(self) -> None:
        """Stop every axis (motor off), leave the modules in their power-up state and close the port.

        The modules are reset (HARD_RESET to their addresses and groups), so
        the next start-up, this driver's or Kerr's, finds a fresh chain. On a
        dead link nothing is raised: what could not be done is logged.
        """
        self.stop_polling()
        with self._lock:
            motion, self._motion = self._motion, None
            if motion is not None:
                motion.status.finish(error=MotionError("the machine was closed"))
            if not self._talked:  # never started: nothing was commanded, the modules are as they were
                self.bus.close()
                return
            try:
                for mod in self.modules:
                    mod.stop("off")
            except NmcError as exc:
                report = self.bus.stop_all("off")  # never raises
                log.warning("closing the machine: motor off was not confirmed (%s); %s", exc, report.sentence())
            try:
                if not self.bus.link_up:
                    raise LinkError(f"the link {self.bus.port_name} is down")
                self.bus.release()
            except LinkError as exc:
                log.warning("closing the machine: the modules were not reset to their power-up state (%s); the "
                            "next start-up resets them", exc)
            self.bus.close()

    # --- sampling ---------------------------------------------------------

    def probe_active(self, status: int) -> bool:
        """Is the probe deflected, from one module's status byte?"""
        level = bool(status & self._probe_mask)
        return level if self.config.probe.active_level == "high" else not level

    def sample(self) -> MachineState:
        """Read every axis once and publish the state to subscribers."""
        with self._lock:
            sts = [m.nop() for m in self.modules]
            now = self.clock.now()
            axes = []
            mm = self.counts_to_mm([st.position for st in sts])
            for axis, st, p in zip(self.config.axes, sts, mm):
                tick = codec.tick_seconds(axis.gains.sr)
                vel = axis.rate_to_mm(st.velocity / tick) if st.velocity is not None else 0.0
                axes.append(AxisState(st.position, float(p), st.position_error, vel, st.status, st.aux or 0, st.ad))
            self.state = MachineState(
                now, tuple(axes), any(self.probe_active(s.status) for s in sts),  # type: ignore[arg-type]
                self._motion is not None and self._motion.kind == "jog",
                self._motion is not None,
            )
            self.samples += 1
            subscribers = list(self._subscribers)
        for fn in subscribers:
            try:
                fn(self.state)
            except Exception:  # noqa: BLE001 - a broken subscriber must never stop the machine
                log.exception("machine state subscriber %r failed", fn)
        return self.state

    def counts_to_mm(self, counts: Any) -> np.ndarray:
        """Raw axis counts -> machine coordinates (mm), geometry correction applied."""
        return counts_to_mm(counts, self.config.axes, self.correction)

    def mm_to_counts(self, position: Any) -> list[int]:
        """Machine coordinates (mm) -> the axis counts that reach them."""
        return [a.to_counts(r) for a, r in zip(self.config.axes, self.correction.invert(position))]

    def subscribe(self, fn: Callable[[MachineState], None]) -> Callable[[], None]:
        """Call ``fn`` with every new state; returns an unsubscribe function."""
        self._subscribers.append(fn)
        return lambda: self._subscribers.remove(fn) if fn in self._subscribers else None

    def on_event(self, fn: Callable[[str, dict], None]) -> None:
        """Events: 'contact' (unexpected), 'deadman', 'limit', 'hit', 'error'."""
        self._event_listeners.append(fn)

    def emit(self, kind: str, **info: Any) -> None:
        """Tell the event listeners (see :meth:`on_event`); a failing listener is logged."""
        for fn in list(self._event_listeners):
            try:
                fn(kind, info)
            except Exception:  # noqa: BLE001 - a broken listener must never stop the machine
                log.exception("machine event listener %r failed", fn)

    # --- the poll loop ----------------------------------------------------

    def poll(self) -> MachineState:
        with self._lock:
            state = self.sample()
            motion = self._motion
            if motion is None:
                return state
            try:
                self._watch(motion, state)
            except Preempted:
                pass  # a stop took the link (the link process's jog stop): the next sample watches again
            except NmcError as exc:
                self._finish(motion, error=exc)
            return state

    def _watch(self, motion: _Motion, state: MachineState) -> None:
        if self.halted is not None:  # the operator's stop reached the modules: this motion was cut short
            self._finish(motion, error=MotionError(self.halted))
            return
        captured = motion.armed and any(not (a.status & codec.HOME_IN_PROG) for a in state.axes)
        if captured:
            latched = tuple(m.home_position() for m in self.modules)
            motion.armed = False
            if motion.on_capture is not None:
                motion.on_capture(latched)  # type: ignore[arg-type]
            else:
                self.halt("abrupt")
                pos = self.counts_to_mm(latched).tolist()
                goal = motion.extra.get("to")  # the line it was on: a restart backs off the way it came
                way = None if goal is None else np.asarray(goal, float) - np.asarray(pos)
                self.emit("contact", position=pos, direction=None if way is None or not np.linalg.norm(way) else
                          (way / np.linalg.norm(way)).tolist())
                self._finish(motion, error=ContactError(
                    "unexpected probe contact at X={:.3f} Y={:.3f} Z={:.3f} mm: the machine stopped and no hit was "
                    "recorded".format(*pos)))
            return
        if any(a.status & codec.POS_ERROR for a in state.axes) and motion.kind != "jog":
            bad = [n.upper() for n, a in zip(AXES, state.axes) if a.status & codec.POS_ERROR]
            self.halt("abrupt")
            self._finish(motion, error=MotionError(f"position error limit tripped on axis {', '.join(bad)}: "
                                                   "servo disabled (collision?)"))
            return
        if motion.kind == "jog":
            self._watch_jog(motion, state)
        elif all(a.status & codec.MOVE_DONE for a in state.axes):
            done = motion.extra.get("on_done")
            if done is not None:
                done(state)
            else:
                self._finish(motion, result=state.position)

    def _finish(self, motion: _Motion, result: Any = None, error: BaseException | None = None) -> None:
        if self._motion is motion:
            self._motion = None
        if motion.kind == "jog" and self.guarded:
            try:
                self.bus.guard_clear()  # nothing left to guard; motion starts pass again
            except NmcError as exc:
                log.warning("the jog ended but the link process did not hear it: %s", exc)
        motion.status.finish(result, error)

    def start_polling(self) -> None:
        """Sample continuously in a background thread (scripts; the station uses the control core's loop).

        Any failure stops every axis abruptly and fails the running move; the thread goes on sampling."""
        if self._thread is not None:
            return
        self.polling = True

        def loop() -> None:
            while self.polling:
                try:
                    self.poll()
                except Exception as exc:  # noqa: BLE001 - never a dead poll thread under a moving machine
                    self.emit("error", message=str(exc))
                    self._safe_stop(exc)
                    self.clock.sleep(0.05)
                self.clock.sleep(self.poll_pause)

        self._thread = threading.Thread(target=loop, name="machine-poll", daemon=True)
        self._thread.start()

    def _safe_stop(self, exc: BaseException) -> None:
        try:
            self.bus.stop_all("abrupt")
        except Exception:  # noqa: BLE001 - stop_all never raises; a broken bus object might
            pass
        motion, self._motion = self._motion, None
        if motion is not None:
            motion.status.finish(error=MotionError(f"stopped after a failure: {exc}"))

    def stop_polling(self) -> None:
        self.polling = False
        if self._thread is not None:
            self._thread.join(timeout=2)
            self._thread = None

    def run_for(self, seconds: float) -> None:
        """Poll for ``seconds`` of machine time (scripts and tests without the background thread)."""
        end = self.clock.now() + seconds
        while self.clock.now() < end:
            self.poll()
            self.clock.sleep(self.poll_pause)

    # --- checks -------------------------------------------------------------

    def check_target(self, target: Any) -> np.ndarray:
        t = np.asarray(target, dtype=np.float64).reshape(-1)
        if t.shape != (3,):
            raise LimitError(f"a target needs X, Y and Z, got {t.size} values")
        for axis, v in zip(self.config.axes, t):
            if not math.isfinite(v):
                raise LimitError(f"target {axis.name.upper()} is {num(v)}: give a number of mm within the travel "
                                 f"{axis.min:g}..{axis.max:g} mm")
            if not axis.min <= v <= axis.max:
                raise LimitError(f"target {axis.name.upper()}={num(v)} mm is outside the travel "
                                 f"{axis.min:g}..{axis.max:g} mm")
        return t

    def fastest(self) -> float:
        """The highest speed (mm/s) every axis's module can be given (Kerr's 16.16 velocity register)."""
        return min(codec.fixed_to_velocity(0x7FFFFFFF, a.counts_per_mm, a.gains.sr) for a in self.config.axes)

    def check_rates(self, speed: float, accel: float) -> None:
        """A speed and an acceleration the modules can be given, else one sentence (formatted numbers)."""
        if not (math.isfinite(speed) and speed > 0 and math.isfinite(accel) and accel > 0):
            raise MotionError(f"speed and acceleration must be positive numbers, got {num(speed)} mm/s and "
                              f"{num(accel)} mm/s²")
        top = self.fastest()
        if speed > top:
            raise MotionError(f"the speed {num(speed)} mm/s is more than this machine can move: at most "
                              f"{top:,.0f} mm/s")

    def _require_idle(self) -> None:
        if self._motion is not None:
            raise MotionError(f"the machine is busy ({self._motion.status.description}); stop it first")
        st = self.state
        if st is not None and any(a.status & codec.POS_ERROR for a in st.axes):
            raise MotionError("an axis has its servo disabled after a position error: clear it with Reset first")

    @property
    def position(self) -> np.ndarray:
        return (self.state or self.sample()).position

    @property
    def busy(self) -> bool:
        return self._motion is not None

    @property
    def motion(self) -> MotionView | None:
        """The motion running (kind and status), or None when the machine stands idle."""
        motion = self._motion
        return None if motion is None else MotionView(motion.kind, motion.status)

    def abort(self, error: BaseException) -> bool:
        """Finish the running motion with ``error`` (its waiter sees it); the caller has stopped the axes.
        False if nothing was running. Takes no lock: the control core calls it on its E-stop and fault paths,
        also when the loop is stuck with the lock held; only the motion read here is cleared."""
        motion = self._motion
        if motion is None:
            return False
        self._finish(motion, error=error)
        return True

    # --- motion -------------------------------------------------------------

    def _arm(self, action: str = "abrupt") -> bool:
        """Arm home capture on the probe input of every axis, unless the probe is already deflected."""
        if self.sample().probe_triggered:
            return False
        for m in self.modules:
            m.arm_home(self.config.probe.input, action)
        return True

    def _load_line(self, target: np.ndarray, speed: float, accel: float) -> float:
        """Load a straight line on every axis (buffered) and start them with one group START_MOVE.

        Per-axis speed and acceleration are scaled by the axis share of the
        path so all axes start on the same tick and arrive together.
        """
        if self.inhibit is not None:
            raise MotionError(f"motion inhibited: {self.inhibit}")
        if self.halted is not None:
            raise MotionError(self.halted)
        # shares come from what each axis really travels (encoder counts): with a geometry
        # correction a move along one machine axis also moves the others a little
        here = (self.state or self.sample()).counts
        goals = self.mm_to_counts(target)
        travel = np.array([a.to_mm(g) - a.to_mm(c) for a, g, c in zip(self.config.axes, goals, here)])
        length = float(np.linalg.norm(travel))
        for axis, mod, d, goal, now in zip(self.config.axes, self.modules, travel, goals, here):
            share = abs(d) / length if length > 0 else 0.0
            if goal == now:  # no travel, but after a stop the trajectory may lack a few counts: full rate for those
                share = 1.0
            vel = codec.velocity_to_fixed(speed * share, axis.counts_per_mm, axis.gains.sr)
            acc = codec.acceleration_to_fixed(accel * share, axis.counts_per_mm, axis.gains.sr)
            if goal != now:  # a tiny share still has to arrive: at least the smallest non-zero rate
                vel, acc = max(vel, 1), max(acc, 1)
            mod.load_position(goal, vel, acc, start=False)
        self.bus.start_move(GROUP)
        return length

    def move_to(self, target: Any, speed: float | None = None, accel: float | None = None,
                *, protect: bool = True) -> MoveStatus:
        """Coordinated straight-line move; returns a status to wait on, poll or cancel."""
        t = self.check_target(target)
        speed = self.config.speeds.positioning if speed is None else speed
        accel = self.config.accelerations.positioning if accel is None else accel
        self.check_rates(speed, accel)
        with self._lock:
            self._require_idle()
            status = MoveStatus("move to X={:.3f} Y={:.3f} Z={:.3f}".format(*t), self.driver)
            armed = self._arm() if protect else False
            return self._start_line(_Motion(status, "move", armed=armed), t, speed, accel)

    def probing_move(self, target: Any, speed: float, accel: float, *,
                     description: str = "probing move") -> MoveStatus:
        """The guarded move of a probing cycle: a straight line with the probe armed on every axis.

        The modules stop abruptly on the servo tick of a trigger and latch the
        three positions. The status's result is the latched raw counts
        ``(x, y, z)``, or None when the line ended without a trigger. Its
        callbacks run in the polling thread with the motion lock held: they may
        start the next move (a retract), nothing slow. Raises
        :class:`ContactError` before anything moves if the probe is deflected.
        """
        t = self.check_target(target)
        self.check_rates(speed, accel)
        with self._lock:
            self._require_idle()
            if not self._arm("abrupt"):
                raise ContactError("the probe is deflected at the start of the probing move: clear it first")
            status = MoveStatus(description, self.driver)
            motion = _Motion(status, "probe", armed=True)
            motion.on_capture = lambda latched: self._finish(motion, result=tuple(latched))
            motion.extra["on_done"] = lambda state: self._finish(motion, result=None)
            return self._start_line(motion, t, speed, accel)

    def _start_line(self, motion: _Motion, target: np.ndarray, speed: float, accel: float) -> MoveStatus:
        """Make ``motion`` the current one and send its straight line (lock held); a failed send finishes it."""
        self._motion = motion
        motion.extra["to"] = target
        motion.status.on_cancel(lambda: self._cancel(motion))
        try:
            self._load_line(target, speed, accel)
        except BaseException as exc:
            self._finish(motion, error=exc)
            raise
        return motion.status

    def move_path(self, points: list[Any], speed: float | None = None) -> MoveStatus:
        """Straight moves through ``points`` in turn (all checked first); one status for the whole path."""
        targets = [self.check_target(p) for p in points]
        status = MoveStatus(f"path of {len(targets)} moves", self.driver)

        def next_leg(i: int) -> None:
            if i == len(targets):
                return status.finish(self.position)
            try:
                leg = self.move_to(targets[i], speed)
            except MotionError as exc:
                return status.finish(error=exc)
            except Exception as exc:  # noqa: BLE001 - the link failing as a leg is sent
                if i == 0:
                    raise  # sent from the caller's thread: the caller hears it
                return status.finish(error=exc)  # at the end of the previous leg: the path ends with it
            status.on_cancel(leg.cancel)
            leg.add_callback(lambda s: status.finish(error=s.error) if s.error else next_leg(i + 1))

        next_leg(0)
        return status

    def step(self, axis: str, step_mm: float, speed: float | None = None) -> MoveStatus:
        """Incremental step jog of one axis, from 1 count to 10 mm."""
        cfg = self.config.axis(axis)
        one_count = 1.0 / cfg.counts_per_mm
        if not math.isfinite(step_mm) or not one_count - 1e-12 <= abs(step_mm) <= STEP_MAX_MM:
            raise MotionError(f"a step must be between one count ({one_count * 1000:g} um) and {STEP_MAX_MM:g} mm, "
                              f"got {num(step_mm, 4)}" + (" mm" if math.isfinite(step_mm) else ""))
        # steps go along the axis from its count grid, so repeated 1-count steps do not drift
        readings = self.correction.invert(self.position)
        idx = AXES.index(axis)
        readings[idx] = cfg.to_mm(cfg.to_counts(readings[idx])) + step_mm
        return self.move_to(self.correction.apply(readings), speed or self.config.speeds.jog_slow)

    def _cancel(self, motion: _Motion) -> None:
        with self._lock:
            self.halt("smooth")
            if self._motion is motion:
                self._motion = None

    def halt(self, mode: str) -> None:
        """STOP_MOTOR to every axis ("abrupt", "smooth", "off"); what is running is not finished (see ``stop``)."""
        with self._lock:
            for m in self.modules:
                m.stop(mode)

    def stop(self) -> None:
        """Controlled stop of whatever is moving (decelerates)."""
        with self._lock:
            motion = self._motion
            if motion is not None and motion.kind == "jog":
                self._jog_stop_axes(range(3))
            else:
                self.halt("smooth")
            if motion is not None:
                self._finish(motion, error=MotionError("stopped by the operator"))

    def finish_halted(self, error: BaseException) -> None:
        """The operator's stop was sent to the modules from another thread (the control core's stop path): end the
        motion running with ``error`` (no command sent: the modules have theirs) and let motion start again."""
        with self._lock:
            motion = self._motion
            if motion is not None:
                self._finish(motion, error=error)
            self.halted = None
            clear = getattr(self.bus, "clear_halt", None)
            if clear is not None:
                clear()

    def emergency_stop(self) -> None:
        """Abrupt stop, then amplifiers off. Motion needs ``reset()`` afterwards."""
        with self._lock:
            self.halt("abrupt")
            self.halt("off")
            motion = self._motion
            if motion is not None:
                self._finish(motion, error=MotionError("emergency stop"))
            self.emit("estop")

    def reset(self) -> None:
        """Clear sticky error bits and re-enable the servos at the present position."""
        with self._lock:
            for m in self.modules:
                m.clear_bits()
                m.enable()
            self.sample()

    def home(self) -> MoveStatus:
        """Go to the configured home coordinates: Z up first, then X and Y."""
        home = np.array([a.home for a in self.config.axes])
        here = self.position
        return self.move_path([[here[0], here[1], max(here[2], home[2])], [home[0], home[1], max(here[2], home[2])],
                               home])

    def zero(self) -> None:
        """The thesis's "Cero": the present position becomes the configured home coordinates."""
        with self._lock:
            self._require_idle()
            for m in self.modules:
                m.reset_position()
            self.sample()

    # --- jogging ------------------------------------------------------------

    def jog(self, velocity: Any, *, manual_probe: Callable[[tuple[int, int, int], np.ndarray], None] | None = None,
            release_epoch: int | None = None, heard: float | None = None) -> None:
        """Jog, mm/s per axis. Must be refreshed (called again) within the dead-man timeout.

        The probe input is armed on every axis (stop abruptly on contact); a
        contact stops the jog, or with ``manual_probe`` latches a hit with the
        motion direction as approach direction (thesis experiment 2). In horizon
        mode the modules never hold a goal more than ``jog.horizon`` s of travel
        ahead, nor outside the travel. ``release_epoch``: the releases the sender had seen (the control core's
        count); the link process refuses a jog sent before a later release. ``heard``: when the operator's
        front end received this refresh (this clock; default now): the dead-man runs from then, so a refresh
        that waited (a busy station) never extends the jog past ``heard + deadman_timeout``, and one heard longer
        ago than that is dropped (it neither starts nor refreshes a jog).
        """
        v = np.asarray(velocity, dtype=np.float64).reshape(-1)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise MotionError(f"a jog needs three finite axis velocities, got {velocity!r}")
        if self.inhibit is not None:
            raise MotionError(f"motion inhibited: {self.inhibit}")
        if self.halted is not None and np.any(v):
            raise MotionError(self.halted)
        limit = self.config.speeds.jog_fast
        if np.any(np.abs(v) > limit + 1e-9):
            raise MotionError(f"jog speed {np.max(np.abs(v)):.1f} mm/s is above jog_fast ({limit:g} mm/s)")
        now = self.clock.now()
        heard = now if heard is None else min(float(heard), now)
        if np.any(v) and now - heard >= self.config.deadman_timeout:
            return  # the operator may have let go since: a refresh this old is not an operator holding the jog
        with self._lock:
            motion = self._motion
            if motion is not None and motion.kind != "jog":
                raise MotionError(f"the machine is busy ({motion.status.description}); stop it first")
            pos = self.position
            for i, axis in enumerate(self.config.axes):  # never jog further out of the travel
                if (v[i] > 0 and pos[i] >= axis.max) or (v[i] < 0 and pos[i] <= axis.min):
                    v[i] = 0.0
            self._jog_refreshed = heard if motion is None else max(self._jog_refreshed, heard)
            if motion is None:
                if not np.any(v):
                    return
                touched = self._contact_dir
                if touched is not None and self.state is not None and self.state.probe_triggered \
                        and float(v @ touched) > 0:
                    raise ContactError("the probe is deflected: jog away from the part (against the direction "
                                       "that touched it) first")
                status = MoveStatus("jog", self.driver)
                motion = _Motion(status, "jog")
                self._motion = motion
                motion.armed = self._arm("abrupt")  # a deflected probe may jog (off the part), unarmed
                if not motion.armed:  # watched: armed once the probe is free, stopped if it stays deflected
                    motion.extra["deflected_at"] = np.array(pos, dtype=np.float64)
                motion.on_capture = lambda latched: self._jog_contact(motion, latched, manual_probe)
            if np.any(v):  # the way it goes: a touch while it brakes (no velocity left) still has a direction
                motion.extra["dir"] = v / float(np.linalg.norm(v))
            if self.guarded:
                if not np.any(v):  # all zeros: a release
                    self._guard_stop(motion)
                    return
            try:
                if self.guarded:
                    spec = self._guard_spec(v)
                    motion.extra["v"] = v.copy()
                    motion.extra["epoch"] = self.bus.guard_jog(spec, release_epoch, heard)
                    if spec.drive:
                        return  # the link process runs the horizon (and its dead-man) from here
                self._command_jog(motion, v)
            except GuardHeld:  # released (link process) while this refresh was on its way: the release wins
                self._guard_stop(motion)

    def _command_jog(self, motion: _Motion, v: np.ndarray) -> None:
        if self.config.jog.mode == "horizon":
            motion.extra["v"] = v.copy()
            self._retarget(motion, force=True)
            return
        prev = motion.extra.get("v")
        acc = self.config.accelerations
        for i, (axis, mod, vi) in enumerate(zip(self.config.axes, self.modules, v)):
            old = 0.0 if prev is None else prev[i]
            if prev is not None and vi == old:
                continue
            a = acc.jog if abs(vi) >= abs(old) and vi * old >= 0 else acc.stop
            fixed = codec.velocity_to_fixed(vi, axis.counts_per_mm, axis.gains.sr)
            mod.load_velocity(int(math.copysign(fixed, vi * axis.direction)) if vi else 0,
                              codec.acceleration_to_fixed(a, axis.counts_per_mm, axis.gains.sr))
        motion.extra["v"] = v.copy()

    # --- the link process's jog guard (real ports: cmm/nmc/link_process.py) ---------------

    @property
    def guarded(self) -> bool:
        """True when the jog dead-man and release run in the link process (not in this loop)."""
        return bool(getattr(self.bus, "guarded", False))

    def _guard_spec(self, v: np.ndarray) -> GuardSpec:
        """The jog as the link process runs it: in horizon mode it re-targets the goals itself (``drive``)."""
        speed = float(np.linalg.norm(v))
        acc = self.config.accelerations
        horizon = self.config.jog.mode == "horizon"
        axes = []
        for axis, vi in zip(self.config.axes, v):
            share = abs(vi) / speed if horizon and speed > 0 else 1.0  # a line runs and stops as a line
            lo, hi = sorted((axis.to_counts(axis.min), axis.to_counts(axis.max)))
            # plain floats: a numpy scalar in the spec would make the link process import numpy to unpickle
            # the first jog (0.4-0.9 s on a busy computer: a short press was released before its jog started)
            axes.append(GuardAxis(axis.address, float(vi * axis.counts_per_mm * axis.direction),
                                  float(max(acc.stop * share * axis.counts_per_mm, 1.0)), lo, hi, axis.gains.sr,
                                  float(max(acc.jog * share * axis.counts_per_mm, 1.0))))
        return GuardSpec(tuple(axes), self.config.deadman_timeout, self.config.jog.mode,
                         STOP_MARGIN_S, self.config.jog.horizon)

    def _guard_stop(self, motion: _Motion) -> None:
        """Stop the jog from the link process (it has the freshest readings) and stop re-targeting it."""
        self.bus.guard_release()
        _jog_stopped(motion)

    def jog_alive(self, release_epoch: int | None = None, heard: float | None = None) -> None:
        """Any thread, no wait: the operator still holds the jog (heard then); the link process's dead-man
        restarts from ``heard`` (the loop's own refresh follows). Does nothing without a link process."""
        if self.guarded:
            self.bus.alive_now(release_epoch, heard)

    def release_now(self, release_epoch: int | None = None) -> None:
        """Any thread, no lock, no wait: the link process stops the jog at once (the loop's release follows)
        and from then on refuses jogs sent before release number ``release_epoch``.

        Without a link process this does nothing: the loop's own release is the only one."""
        if self.guarded:
            self.bus.release_now(release_epoch)

    def horizon_target(self, position: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, str | None]:
        """Where a horizon jog from ``position`` at ``v`` may aim: ``horizon`` s ahead, inside the travel.

        Also returns the axis whose travel limit shortened the step (None when none did).
        """
        t, limiting = self.config.jog.horizon, None
        for i, axis in enumerate(self.config.axes):  # shorten the whole step so the line stays in the box
            room = (axis.max - position[i]) / v[i] if v[i] > 0 else (axis.min - position[i]) / v[i] if v[i] < 0 else t
            if max(0.0, room) < t:
                t, limiting = max(0.0, room), axis.name
        target = position + v * t
        return np.clip(target, [a.min for a in self.config.axes], [a.max for a in self.config.axes]), limiting

    def _retarget(self, motion: _Motion, force: bool = False) -> None:
        """Horizon jog: load a goal ``horizon`` s of travel ahead (clamped to the travel) on every axis."""
        v = motion.extra["v"]
        speed = float(np.linalg.norm(v))
        if speed == 0:
            self.halt("smooth")
            motion.extra.pop("goal", None)
            return
        here = self.state.position if self.state is not None else self.position
        target, limiting = self.horizon_target(here, v)
        self._tell_limit(motion, limiting)
        goal = motion.extra.get("goal")
        if not force and goal is not None and np.linalg.norm(target - goal) < speed * RETARGET_MIN_S:
            return
        motion.extra["goal"] = target
        self._load_line(target, speed, self.config.accelerations.jog)

    def _tell_limit(self, motion: _Motion, limiting: str | None) -> None:
        """Once per jog: the travel limit of axis ``limiting`` shortens the horizon."""
        if limiting is not None and not motion.extra.get("limit_told"):
            motion.extra["limit_told"] = True
            self.emit("limit", axis=limiting)

    def _horizon_stop(self, motion: _Motion | None) -> None:
        """Stop a horizon jog at the stop deceleration: re-target to where it can stand still."""
        v = None if motion is None else motion.extra.get("v")
        speed = 0.0 if v is None else float(np.linalg.norm(v))
        if speed == 0 or self.state is None or self.inhibit is not None or self.halted is not None:
            self.halt("smooth")  # a stop is never inhibited
            return
        a = self.config.accelerations.stop
        # where the axes are now: the last sample moved on by the time since it was taken (at most the horizon)
        here = self.state.position + v * min(max(self.clock.now() - self.state.time, 0.0), self.config.jog.horizon)
        # the stopping distance, plus a margin for the commands' own latency: a goal short of where the axes
        # can stop would make them overshoot and come back
        distance = speed * speed / (2 * a) + speed * STOP_MARGIN_S
        target, _ = self.horizon_target(here, v * (distance / speed) / self.config.jog.horizon)
        self._load_line(target, speed, a)

    def _jog_stop_axes(self, axes: Any) -> None:
        if self.config.jog.mode == "horizon":
            self._horizon_stop(self._motion)
            return
        for i in axes:
            axis = self.config.axes[i]
            self.modules[i].load_velocity(0, codec.acceleration_to_fixed(self.config.accelerations.stop,
                                                                         axis.counts_per_mm, axis.gains.sr))

    def jog_release(self) -> None:
        """End a jog now (button or key released): decelerate."""
        with self._lock:
            motion = self._motion
            if motion is not None and motion.kind == "jog":
                if self.guarded:
                    self._guard_stop(motion)
                    return
                self._jog_stop_axes(range(3))
                _jog_stopped(motion)

    def _watch_jog(self, motion: _Motion, state: MachineState) -> None:
        if "deflected_at" in motion.extra and self._watch_deflected(motion, state):
            return
        v = motion.extra.get("v", np.zeros(3))
        if self.guarded:  # the dead-man runs in the link process: did it (or a release) stop this jog?
            epoch, fired = self.bus.guard
            if fired is not None and epoch == motion.extra.get("epoch") and np.any(v):
                v = _jog_stopped(motion)
                if fired == "deadman":
                    self.emit("deadman", after=state.time - self._jog_refreshed)
        elif np.any(v) and state.time - self._jog_refreshed > self.config.deadman_timeout:
            self._jog_stop_axes(range(3))
            v = _jog_stopped(motion)
            self.emit("deadman", after=state.time - self._jog_refreshed)
        if self.config.jog.mode == "horizon":
            if np.any(v) and self.guarded:  # the link process drives it: only say when the travel limits it
                self._tell_limit(motion, self.horizon_target(state.position, v)[1])
            elif np.any(v):
                self._retarget(motion)
            elif all(a.status & codec.MOVE_DONE for a in state.axes) and all(abs(a.velocity) < 1e-9
                                                                          for a in state.axes):
                self._finish(motion, result=state.position)
            return
        for i, (axis, a) in enumerate(zip(self.config.axes, state.axes)):
            if v[i] == 0:
                continue
            # braking distance, plus the travel until the next samples see it (a few link round trips)
            stopping = a.velocity ** 2 / (2 * self.config.accelerations.stop) + abs(a.velocity) * JOG_LOOKAHEAD + 0.05
            if (v[i] > 0 and a.mm + stopping >= axis.max) or (v[i] < 0 and a.mm - stopping <= axis.min):
                self._jog_stop_axes([i])
                v = v.copy()
                v[i] = 0
                motion.extra["v"] = v
                self.emit("limit", axis=axis.name)
        if not np.any(v) and all(abs(a.velocity) < 1e-9 for a in state.axes):
            self._finish(motion, result=state.position)

    def _watch_deflected(self, motion: _Motion, state: MachineState) -> bool:
        """A jog that started with the probe deflected runs unarmed (a deflected probe cannot be armed). Once the
        probe is free it is armed, so the next touch stops it; if the probe stays deflected over DEFLECTED_JOG_MM of
        travel the jog goes into the part, not off it: stopped (True)."""
        if not state.probe_triggered:
            del motion.extra["deflected_at"]
            motion.armed = self._arm("abrupt")
            return False
        if float(np.linalg.norm(state.position - motion.extra["deflected_at"])) <= DEFLECTED_JOG_MM:
            return False
        self.halt("abrupt")
        way = motion.extra.get("dir")
        self._contact_dir = None if way is None else np.asarray(way, dtype=np.float64)
        self._finish(motion, error=ContactError(
            f"the probe stayed deflected over {DEFLECTED_JOG_MM:g} mm of jog: the machine stopped; jog the other way, "
            "off the part"))
        return True

    def _jog_contact(self, motion: _Motion, latched: tuple[int, int, int],
                     record: Callable[[tuple[int, int, int], np.ndarray], None] | None) -> None:
        """The probe touched during a jog: the modules stopped on that tick; a manual hit or a contact stop."""
        v = np.array(motion.extra.get("v", np.zeros(3)), dtype=np.float64)
        self.halt("abrupt")
        way = motion.extra.get("dir")  # the way it went, also when it touched while braking (no velocity left)
        self._contact_dir = None if way is None else np.asarray(way, dtype=np.float64)
        if record is not None and np.any(v):
            self._finish(motion, result=latched)
            record(latched, v)  # the jog velocity gives the approach direction and the probing speed
            return
        pos = self.counts_to_mm(latched).tolist()
        self.emit("contact", position=pos, direction=None if way is None else self._contact_dir.tolist())
        self._finish(motion, error=ContactError(
            "probe contact while jogging at X={:.3f} Y={:.3f} Z={:.3f} mm: the machine stopped; "
            "jog away from the part".format(*pos)))

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
from typing import Any, Callable

import numpy as np

from ..metrology.numbers_text import num
from ..nmc import codec
from ..nmc.bus import NmcError, Preempted
from ..nmc.link_process import open_bus
from ..nmc.module import Module
from ..nmc.trace import ByteTrace
from ..nmc.transport import is_virtual
from .config import AXES, MachineConfig, counts_to_mm
from .connection import Connection
from .geometry import GeometryCorrection
from .jogging import Jogging
from .machine_state import GROUP, AxisState, ContactError, LimitError, MachineState, MotionView, _Motion
from .status import MotionError, MoveStatus

POLL_PAUSE = 0.0002  # between samples: lets UI threads take the machine lock; the link is the limit
# On the simulator's virtual clock a sample costs CPU, not wall time: sampling every 4 ms of machine time
# instead of every servo tick makes the simulated station about 2x cheaper to run (tests, calibration);
# probe triggers are latched by the modules, so nothing measured depends on the sample rate.
VIRTUAL_POLL_PAUSE = 0.004
# ... and every 20 ms during a programmed move or probing move, which the modules run to its goal or latch by
# themselves: a third less CPU per machine second again. A jog (dead-man, deflected-probe watch) and an idle
# station keep 4 ms, so what the operator's hands feel is sampled as before.
VIRTUAL_MOVE_POLL_PAUSE = 0.02
# ... and every 20 ms while the station is idle (nothing moves, no job, homing or probe cycle): an idle
# simulated station polled every 4 ms spent a tenth of a core on nothing; a command does not wait for the
# loop (it goes to the modules at once), and the first sample of a jog comes back to 4 ms.
VIRTUAL_IDLE_POLL_PAUSE = 0.02
STEP_MIN_COUNTS = 1
STEP_MAX_MM = 10.0

log = logging.getLogger(__name__)


class Machine(Connection, Jogging):
    """The CMM machine: three PIC-SERVO axes in millimetres (see the module's text). Its connection
    (:mod:`~cmm.machine.connection`) and its jogs (:mod:`~cmm.machine.jogging`) are parts of it."""

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
        self._release_posted: float | None = None  # when a release was posted to the loop (release_now)
        self._subscribers: list[Callable[[MachineState], None]] = []
        self._event_listeners: list[Callable[[str, dict], None]] = []
        self._probe_mask = codec.LIMIT1 if config.probe.input == "limit1" else codec.LIMIT2
        self.samples = 0
        self._rest: tuple[float, list[int]] | None = None  # (since, counts) where the axes came to rest
        self._virtual = is_virtual(self.clock)
        self._poll_pause: float | None = None  # set: this pause always (scripts, tests); else see poll_pause
        self.correction = GeometryCorrection()  # the calibration routine sets it
        self.driver: Any = self  # what MoveStatus.wait drives: this machine or the control core owning it
        self._contact_dir: np.ndarray | None = None  # direction of the last jog that touched
        self.inhibit: str | None = None  # set by the control core (fault, E-stop): every new motion is refused
        # set by the control core the moment the operator presses STOP / E-STOP (any thread, before the modules are
        # told): no motion starts, and the motion running ends cut short (never "done") at the next sample, until
        # the machine loop has carried the stop out (finish_halted)
        self.halted: str | None = None

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
                axes.append(AxisState(st.position, float(p), st.position_error, vel, st.status, st.aux or 0, st.ad,
                                      int(st.velocity or 0)))
            self.state = MachineState(
                now, tuple(axes), any(self.probe_active(s.status) for s in sts),  # type: ignore[arg-type]
                self._motion is not None and self._motion.kind == "jog",
                self._motion is not None, self._resting(now, axes),
            )
            self.samples += 1
            subscribers = list(self._subscribers)
        for fn in subscribers:
            try:
                fn(self.state)
            except Exception:  # noqa: BLE001 - a broken subscriber must never stop the machine
                log.exception("machine state subscriber %r failed", fn)
        return self.state

    def _resting(self, now: float, axes: list[AxisState]) -> float:
        """Machine s every trajectory has been done and every axis within a count of where it came to rest (0: not
        at rest in this sample; it rests from here on if it stays)."""
        rest = self._rest
        counts = [a.counts for a in axes]
        if all(a.trajectory_done for a in axes):
            if rest is not None and all(abs(c - r) <= 1 for c, r in zip(counts, rest[1])):
                return now - rest[0]
            self._rest = (now, counts)
        else:
            self._rest = None
        return 0.0

    def counts_to_mm(self, counts: Any) -> np.ndarray:
        """Raw axis counts -> machine coordinates (mm), geometry correction applied."""
        return counts_to_mm(counts, self.config.axes, self.correction)

    def mm_to_counts(self, position: Any) -> list[int]:
        """Machine coordinates (mm) -> the axis counts that reach them."""
        return [a.to_counts(r) for a, r in zip(self.config.axes, self.correction.invert(position))]

    @property
    def poll_pause(self) -> float:
        """Seconds between samples: the link is the limit on a real port; on the virtual clock see
        VIRTUAL_POLL_PAUSE and VIRTUAL_MOVE_POLL_PAUSE."""
        if self._poll_pause is not None:
            return self._poll_pause
        if not self._virtual:
            return POLL_PAUSE
        motion = self._motion
        return VIRTUAL_MOVE_POLL_PAUSE if motion is not None and motion.kind != "jog" else VIRTUAL_POLL_PAUSE

    @property
    def idle_poll_pause(self) -> float:
        """Seconds between samples while the station is idle (see VIRTUAL_IDLE_POLL_PAUSE)."""
        if self._poll_pause is not None or not self._virtual:
            return self.poll_pause
        state = self.state
        if state is not None and not state.standing:  # braking or settling after a stop: its rest seen at 4 ms
            return VIRTUAL_POLL_PAUSE
        return VIRTUAL_IDLE_POLL_PAUSE

    @poll_pause.setter
    def poll_pause(self, seconds: float) -> None:
        self._poll_pause = float(seconds)

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

"""The link process: on a real serial link, one process of its own talks to the modules.

Why: the station process also serves the web pages, draws sessions and writes reports. Its threads share
one interpreter lock, so a jog release or a dead-man that waits for that process can come hundreds of ms
late under web load. Here the port and the whole :class:`~cmm.nmc.bus.Bus` (resync,
lost-reply recovery, stop-all) live in a small child process that does nothing else; the station's machine
loop sends it transactions over a pipe (:class:`RemoteBus`, the same interface as ``Bus``).

The child also holds the *jog guard*, which acts between two of the station's transactions:
- the jog: a horizon jog (``guard_jog``; ``GuardSpec.drive``) is re-targeted here, from the replies the child sees
  (it reads the axes itself when the station's samples are late); a probe contact ends it;
- the jog dead-man: no refresh for ``deadman`` s (``guard_jog`` from the loop, ``alive_now`` straight from a
  front end's thread) and it stops the axes; each refresh carries when its front end heard it (the station and
  this process share the monotonic clock), and the dead-man runs from then: a refresh the station passed on
  late never keeps a jog going longer;
- the release: ``release_now`` (any station thread, its own pipe, no reply awaited) stops them at once, and
  jogs sent before it are refused; STOP's stop-all takes that pipe too;
- a dead station: when the station's pipe closes (crash, ``kill -9``) it stops every axis and exits.
A guard stop re-targets each moving axis to where it can stand still at the stop deceleration (from the last
reply's position and velocity, clamped to the travel and never past the jog's own goal); after it motion
starts to the jog's axes are refused (:class:`GuardHeld`) until the station has seen the stop.

The in-process simulator (``sim://``) keeps its bus in the station's process: it runs on the virtual clock
that the tests drive, and stands for hardware whose timing needs no such protection.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import socket
import subprocess
import sys
import threading
from multiprocessing.connection import Connection
from dataclasses import dataclass, field
from typing import Any

from . import codec
from .bus import Bus, LinkError, NmcError, Preempted, StopReport
from .trace import ByteTrace
from .transport import TransportError, WallClock

log = logging.getLogger(__name__)

START_TIMEOUT = 30.0  # s for the child to start and open the port
CALL_TIMEOUT = 10.0  # s for one call (a transaction takes ms; a resync with retries well under a second)
LONG_CALLS = {"initialize": 120.0, "reopen": 60.0, "release": 30.0, "change_baud": 30.0}  # discovery retries
FORWARDED = {"transact", "define_status", "set_group", "initialize", "release", "start_move",
             "reopen", "change_baud", "flush_input", "resync", "clear_halt"}
MIRRORED = ("items", "link_up", "baud", "modules", "leaders", "groups", "warning")
STILL = 0.5  # counts per servo tick: below this an axis is taken as standing
RUN_PERIOD = 0.01  # s between the link process's looks at a jog it drives (re-target, dead-man)
FRESH = 0.015  # s: a reading older than this is taken again by the link process itself (the station is slow)
RETARGET_MIN_S = 0.03  # a driven jog is re-targeted when its goal would move by more than this much travel


class GuardHeld(Exception):
    """The jog guard stopped the jog; the station's re-target of it is refused until it has seen the stop."""


@dataclass(frozen=True)
class GuardAxis:
    address: int
    velocity: float  # counts/s the jog commands (signed)
    accel: float  # counts/s^2: this axis's share of the stop deceleration
    lo: int  # travel, counts
    hi: int
    sr: int = 1  # servo rate divisor (the module's tick)
    jog_accel: float = 0.0  # counts/s^2: this axis's share of the jog acceleration (a driven jog)


@dataclass(frozen=True)
class GuardSpec:
    """What the guard needs to stop one jog."""

    axes: tuple[GuardAxis, ...]
    deadman: float  # s without a refresh before it stops the jog
    mode: str = "horizon"  # "horizon" (position goals) or "velocity"
    margin: float = 0.02  # s of travel added to a stop goal (latency between the reading and the command)
    horizon: float = 0.12  # s: the longest extrapolation of the last reading; a driven jog's goal distance

    @property
    def drive(self) -> bool:
        """A horizon jog is re-targeted by the link process itself (the station only refreshes it)."""
        return self.mode == "horizon"


@dataclass
class GuardState:
    epoch: int = 0  # bumped by every new jog (or a refresh after a stop)
    fired: str | None = None  # why the guard stopped this epoch's jog: "release", "deadman", "station gone"
    stops: int = 0
    errors: list[str] = field(default_factory=list)


# --- the child ------------------------------------------------------------------------------------------------

class JogGuard:
    """The dead-man, the release and the last-resort stop, run next to the bus (child process)."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.cond = threading.Condition()
        self.spec: GuardSpec | None = None
        self.deadline = math.inf
        self.held = False
        self.state = GuardState()
        self.running = True
        self.released = 0  # the station's release count at the last release: older jogs are refused
        self.goals: dict[int, int] = {}  # address -> goal of a driven jog last sent

    # station calls (through the pipe, in order with its transactions)
    def _heard(self, heard: float | None) -> float:
        now = self.bus.clock.now()
        return now if heard is None else min(float(heard), now)

    def arm(self, spec: GuardSpec, release_epoch: int | None = None, heard: float | None = None) -> int:
        """A jog (re)started by the station; ``heard``: when the operator's front end received the hold it
        carries out (the machine clock, shared with the station): the dead-man runs from then."""
        with self.cond:
            if release_epoch is not None and release_epoch < self.released:
                raise GuardHeld("this jog was sent before the operator's last release: it is not carried out")
            heard = self._heard(heard)
            new = self.spec is None or self.state.fired is not None
            if new and heard + spec.deadman <= self.bus.clock.now():
                raise GuardHeld("this jog was heard longer ago than the dead-man: it is not carried out")
            if new:
                self.state.epoch += 1
                self.state.fired = None
            if new or spec != self.spec:
                # a new direction or speed, or a restart after a stop: re-target at once. The goals kept from
                # before a stop are not what the modules hold now (the stop loaded its own), and a restart
                # whose first goal fell near the old one would not be sent: the jog would never start again
                self.goals.clear()
            self.spec = spec
            self.held = False
            self.deadline = heard + spec.deadman if new else max(self.deadline, heard + spec.deadman)
            self.cond.notify_all()
            epoch = self.state.epoch
        if spec.drive:
            self.drive(spec)  # the first goal now, not one period later
        return epoch

    def refresh(self, release_epoch: int | None, heard: float | None = None) -> None:
        """The operator still holds the jog (a front end's message, straight from its thread, heard then): the
        dead-man runs from ``heard``, unless the jog was stopped or the message is older than the last release."""
        with self.cond:
            if self.spec is None or self.state.fired is not None:
                return
            if release_epoch is not None and release_epoch < self.released:
                return
            self.deadline = max(self.deadline, self._heard(heard) + self.spec.deadman)

    def drive(self, spec: GuardSpec) -> None:
        """One step of a driven horizon jog: goals ``horizon`` s of travel ahead of fresh readings, the line
        kept inside the travel; nothing after a probe contact (the modules stopped on it: never push on)."""
        with self.bus.lock:
            with self.cond:
                if self.spec != spec or self.state.fired is not None:
                    return
            now = self.bus.clock.now()
            pos: dict[int, int] = {}
            for ax in spec.axes:
                reading = self.bus.last_reading(ax.address)
                if reading is None or now - reading.time > FRESH:
                    self.bus.transact(codec.nop(ax.address))  # the station is slow to sample: look ourselves
                    reading = self.bus.last_reading(ax.address)
                if reading is None:
                    return
                if self._touched(ax.address, reading.status):
                    self._contact()  # the probe touched: the station takes it from here
                    return
                pos[ax.address] = reading.position
            t = spec.horizon
            for ax in spec.axes:  # shorten the whole step so the line stays inside the travel
                if ax.velocity:
                    room = ((ax.hi if ax.velocity > 0 else ax.lo) - pos[ax.address]) / ax.velocity
                    t = min(t, max(room, 0.0))
            for ax in spec.axes:
                if not ax.velocity:
                    continue
                goal = int(round(min(max(pos[ax.address] + ax.velocity * t, ax.lo), ax.hi)))
                last = self.goals.get(ax.address)
                if last is not None and abs(goal - last) < abs(ax.velocity) * RETARGET_MIN_S:
                    continue
                self.goals[ax.address] = goal
                if self._send_goal(ax, goal, ax.velocity, ax.jog_accel, spec):
                    return

    def _send_goal(self, ax: GuardAxis, goal: int, speed: float, accel: float, spec: GuardSpec) -> bool:
        """Load a position goal (``speed`` counts/s, ``accel`` counts/s^2) and start it. True when its reply shows
        the probe's capture had fired just before it arrived: then every jog axis is stopped again at once."""
        vel = max(codec.velocity_to_fixed(speed, 1.0, ax.sr), 1)  # counts: one count per "mm"
        acc = max(codec.acceleration_to_fixed(accel, 1.0, ax.sr), 1)
        st = self.bus.transact(codec.load_traj(ax.address, position=goal, velocity=vel, acceleration=acc))
        if st is not None and self._touched(ax.address, st.status):
            self._contact(spec)
            return True
        return False

    def _touched(self, address: int, status: int) -> bool:
        """Has the probe's capture fired on ``address`` (armed, and the status byte says no longer in progress)?"""
        return self.bus.capture_armed(address) and not status & codec.HOME_IN_PROG

    def _contact(self, undo: GuardSpec | None = None) -> None:
        """A probe contact ends the jog here. The modules stopped abruptly on that tick; a goal sent after it
        (``undo``: its reply showed the capture had fired) would push on, so every jog axis is stopped again."""
        with self.cond:
            if self.state.fired is None:
                self.state.fired = "contact"
            self.held = True
            self.deadline = math.inf
        if undo is not None:
            for ax in undo.axes:
                if self.bus.servoing(ax.address):
                    self.bus.transact(codec.stop_motor(ax.address, codec.STOP_ABRUPT | codec.AMP_ENABLE))

    def clear(self) -> None:
        """The station saw the jog end: nothing to guard, nothing held."""
        with self.cond:
            self.goals.clear()
            self.spec = None
            self.held = False
            self.deadline = math.inf
            self.cond.notify_all()

    def halted(self, reason: str) -> None:
        """A stop from the station (STOP_MOTOR, stop-all) ends the jog here too: never re-target after it."""
        with self.cond:
            if self.spec is not None and self.state.fired is None:
                self.state.fired = reason
                self.held = True
                self.deadline = math.inf

    def check(self, name: str, args: tuple) -> None:
        """Refuse a motion start while a guard stop holds (the station has not yet seen it); a stop the
        station sends ends a jog this process drives."""
        if name == "transact" and args and len(args[0]) > 2 and args[0][2] & 0x0F == codec.STOP_MOTOR:
            self.halted("stop")
            return
        if not self.held:
            return
        if name == "start_move":
            raise GuardHeld("the jog was stopped (released or dead-man); the station has not yet seen it")
        if name == "transact" and args:
            packet = args[0]
            if len(packet) > 3 and packet[2] & 0x0F == codec.LOAD_TRAJ and packet[3] & codec.START_NOW:
                try:
                    lt = codec.parse_load_traj(bytes(packet[3:-1]))
                except codec.CodecError:
                    return
                stop = lt.control & codec.VEL_MODE and not lt.velocity
                if not stop and self.spec is not None and packet[1] in {a.address for a in self.spec.axes}:
                    raise GuardHeld("the jog was stopped (released or dead-man); the station has not yet seen it")

    # the stop itself
    def stop(self, reason: str, release_epoch: int | None = None) -> None:
        with self.cond:
            if release_epoch is not None:
                self.released = max(self.released, release_epoch)
            spec = self.spec
            if spec is not None and reason == "release":
                self.held = True  # also after a dead-man stop: a re-target on its way must not restart it
            if spec is None or self.state.fired is not None:
                return
            self.state.fired = reason
            self.held = True
            self.deadline = math.inf
        try:
            self.bus.preempt(urgent=True)  # a transaction retrying a lost reply gives up the link to this stop
            with self.bus.lock:  # between two of the station's transactions
                self._send_stop(spec)
            self.state.stops += 1
        except Exception as exc:  # noqa: BLE001 - the link failed: stop however it can
            self.state.errors.append(f"{reason}: {exc}")
            log.error("jog guard: the %s stop failed (%s): stopping every axis abruptly", reason, exc)
            self.bus.stop_all("abrupt")

    def _send_stop(self, spec: GuardSpec) -> None:
        now = self.bus.clock.now()
        for ax in spec.axes:
            if ax.velocity == 0 or not self.bus.servoing(ax.address):
                continue  # a stop command would switch a motor-off axis's servo back on
            if spec.mode != "horizon":
                acc = max(codec.acceleration_to_fixed(ax.accel, 1.0, ax.sr), 1)
                self.bus.transact(codec.load_traj(ax.address, velocity=0, acceleration=acc, velocity_mode=True))
                continue
            reading = self.bus.last_reading(ax.address)
            if reading is not None and self._touched(ax.address, reading.status):
                continue  # the probe touched: the module stopped on that tick by itself
            if reading is None or reading.velocity is None or abs(reading.velocity) < STILL:
                # standing (or unknown): a smooth stop never starts a motion
                self.bus.transact(codec.stop_motor(ax.address, codec.STOP_SMOOTH | codec.AMP_ENABLE))
                continue
            v = reading.velocity / codec.tick_seconds(ax.sr)  # counts/s, signed
            sign = 1.0 if v > 0 else -1.0
            ahead = v * min(max(now - reading.time, 0.0), spec.horizon)
            goal = reading.position + ahead + sign * (v * v / (2 * ax.accel) + abs(v) * spec.margin)
            pending = self.goals.get(ax.address)
            if pending is not None and (pending - goal) * sign < 0:
                goal = pending  # it was going to stand still nearer than that anyway
            if self._send_goal(ax, int(round(min(max(goal, ax.lo), ax.hi))), abs(v), ax.accel, spec):
                return

    def station_gone(self) -> None:
        """The station that commanded the axes is gone: stop the jog, then every axis as it is (servo holds
        where it stands; an axis without servo, in PWM or motor off, gets motor off: never servo on)."""
        self.stop("station gone")
        with self.bus.lock:
            for info in self.bus.modules:
                a = info.address
                control = codec.STOP_ABRUPT | codec.AMP_ENABLE if self.bus.servoing(a) else codec.MOTOR_OFF
                try:
                    self.bus.transact(codec.stop_motor(a, control))
                except NmcError as exc:
                    log.error("link process: module %d did not confirm the stop: %s", a, exc)

    # threads
    def run_deadman(self) -> None:
        """The dead-man on a thread of its own: it wakes at the deadline whatever the driver is doing (a
        re-target waiting for the link, a slow reply), and its stop pre-empts a retry in progress."""
        while self.running:
            with self.cond:
                spec = self.spec if self.state.fired is None else None
                wait = 1.0 if spec is None else self.deadline - self.bus.clock.now()
                if wait > 0:
                    self.cond.wait(min(wait, 1.0))
                    continue
            self.stop("deadman")

    def run(self) -> None:
        """The re-targets of a jog this process drives (every RUN_PERIOD)."""
        while self.running:
            with self.cond:
                spec = self.spec if self.state.fired is None else None
                if spec is None or not spec.drive:
                    self.cond.wait(1.0)
                    continue
            try:
                self.drive(spec)
            except Preempted:
                pass  # a stop of this jog took the link
            except Exception as exc:  # noqa: BLE001 - a jog that cannot be driven is stopped
                log.error("link process: driving the jog failed (%s): stopping it", exc)
                self.stop("link error")
            with self.cond:
                if self.running and self.spec is spec and self.state.fired is None:
                    self.cond.wait(RUN_PERIOD)

    def run_urgent(self, urgent: Any) -> None:
        """The station's second pipe: releases (no reply) and stop-all (replied), never behind its loop's calls."""
        while self.running:
            try:
                msg = urgent.recv()
            except (EOFError, OSError):
                return
            if isinstance(msg, tuple) and msg[0] == "release":
                self.stop("release", msg[1])
            elif isinstance(msg, tuple) and msg[0] == "alive":
                self.refresh(*msg[1:])
            elif isinstance(msg, tuple) and msg[0] == "preempt":
                self.bus.preempt()
            elif isinstance(msg, tuple) and msg[0] == "stop_all":
                self.halted("stop")
                # the operator's STOP / E-STOP latches: no motion starts (the jog driver's goals included) until
                # the station has carried it out (clear_halt, through the calls pipe, in order with its calls)
                report = self.bus.stop_all(msg[1], latch=msg[2] if len(msg) > 2 else None)  # never raises
                try:
                    urgent.send(report)
                except (EOFError, OSError):
                    return


class _Mirror:
    """What the station's RemoteBus keeps a copy of: the bus attributes it reads, sent only when they changed
    (they change at start-up and on reconnects, not per transaction), and the guard's state, always."""

    def __init__(self, bus: Bus, guard: JogGuard) -> None:
        self.bus, self.guard = bus, guard
        self.sent: tuple | None = None

    def __call__(self) -> dict:
        b = self.bus
        now = (dict(b.items), b.link_up, b.baud, list(b.modules), dict(b.leaders), dict(b.groups), b.warning)
        m = {} if now == self.sent else dict(zip(MIRRORED, now))
        self.sent = now
        m["guard"] = (self.guard.state.epoch, self.guard.state.fired)
        return m


def _raise_priority() -> None:
    try:
        os.setpriority(os.PRIO_PROCESS, 0, -10)
    except OSError:
        pass  # not permitted: normal priority, still a process of its own


def serve(port: str, firmware: str, conn: Any, urgent: Any) -> None:
    """The child's main: open the port, then serve the station's calls until its pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the station, which closes us in order
    _raise_priority()
    try:
        bus = Bus(port, firmware=firmware)
    except Exception as exc:  # noqa: BLE001 - told to the station, which raises it
        conn.send(("err", type(exc).__name__, str(exc), None, {}))
        return
    guard = JogGuard(bus)
    mirror = _Mirror(bus, guard)
    conn.send(("ok", None, mirror()))
    threading.Thread(target=guard.run, name="jog-driver", daemon=True).start()
    threading.Thread(target=guard.run_deadman, name="jog-deadman", daemon=True).start()
    threading.Thread(target=guard.run_urgent, args=(urgent,), name="jog-release", daemon=True).start()
    try:
        while True:
            try:
                op, name, args, kwargs = conn.recv()
            except (EOFError, OSError):
                log.error("link process: the station is gone; stopping every axis")
                guard.station_gone()
                return
            if op == "exit":
                return
            try:
                if op == "call" and name in FORWARDED:
                    with bus.lock:  # checked and sent with no guard stop in between
                        guard.check(name, args)
                        result = getattr(bus, name)(*args, **kwargs)
                elif op == "get" and name == "stats":
                    result = dict(bus.stats)
                elif op == "trace":
                    result = bus.trace.entries(*args)
                elif op == "guard_jog":
                    result = guard.arm(*args)
                elif op == "guard_clear":
                    result = guard.clear()
                elif op == "guard_release":
                    guard.stop("release")
                    result = guard.state.epoch
                elif op == "close":
                    guard.clear()
                    result = bus.close(**kwargs)
                else:
                    raise NmcError(f"link process: unknown request {op} {name}")
                reply: tuple = ("ok", result, mirror())
            except BaseException as exc:  # noqa: BLE001 - every failure goes back to the caller
                reply = ("err", type(exc).__name__, str(exc), getattr(exc, "address", None), mirror())
            try:
                conn.send(reply)
            except (EOFError, OSError):
                guard.station_gone()
                return
    finally:
        guard.running = False
        with guard.cond:
            guard.cond.notify_all()
        bus.close()


# --- the station's side ---------------------------------------------------------------------------------------

class RemoteBus:
    """A :class:`Bus` that lives in the link process; same interface, plus the jog guard's calls."""

    guarded = True

    def __init__(self, port: str, *, firmware: str = "pic-servo", trace: ByteTrace | None = None) -> None:
        self.firmware = firmware
        self.port_name = str(port)
        self.clock = WallClock()
        self.trace = _RemoteTrace(self)  # the bytes are traced where they pass: in the link process
        self.lock = threading.RLock()  # one call at a time on the pipe
        self._urgent_lock = threading.Lock()
        self.items: dict[int, int] = {}
        self.link_up = False
        self.baud = codec.POWER_UP_BAUD
        self.modules: list = []
        self.leaders: dict[int, int] = {}
        self.groups: dict[int, int] = {}
        self.warning: tuple[int, str, float] = (0, "", 0.0)  # the bus's link warnings (its clock: monotonic, as ours)
        self.guard: tuple[int, str | None] = (0, None)
        self._dead: str | None = None
        self._clear_due = False  # a guard_clear that could not be sent at once: sent before the next call
        # a fresh interpreter (never a fork of a process full of threads, and unlike multiprocessing's spawn
        # it does not re-run the caller's main script), joined by two socket pairs: calls and releases
        calls, child_calls = socket.socketpair()
        urgent, child_urgent = socket.socketpair()
        self._conn, self._urgent = Connection(calls.detach()), Connection(urgent.detach())
        fds = (child_calls.fileno(), child_urgent.fileno())
        self._proc = subprocess.Popen([sys.executable, "-m", "cmm.nmc.link_process", str(port), firmware, *map(str, fds)],
                                      pass_fds=fds, stdin=subprocess.DEVNULL)
        child_calls.close()
        child_urgent.close()
        try:
            self._reply(START_TIMEOUT, "starting the link process")
        except Exception:
            self._kill()
            raise

    # --- calls --------------------------------------------------------------------

    def _reply(self, timeout: float, what: str) -> Any:
        if not self._conn.poll(timeout):
            self._dead = f"the link process did not answer {what} within {timeout:g} s"
            self._kill()
            raise LinkError(self._dead, None, self.port_name)
        try:
            reply = self._conn.recv()
        except (EOFError, OSError) as exc:
            self._dead = f"the link process ended ({exc or 'pipe closed'})"
            self.link_up = False
            raise LinkError(self._dead, None, self.port_name) from exc
        if reply[0] == "ok":
            self._update(reply[2])
            return reply[1]
        _, cls, message, address, mirror = reply
        self._update(mirror)
        raise _rebuild(cls, message, address, self.port_name)

    def _update(self, mirror: dict) -> None:
        for name in MIRRORED:
            if name in mirror:
                setattr(self, name, mirror[name])
        self.guard = mirror.get("guard", self.guard)

    def _request(self, op: str, name: str = "", *args: Any, timeout: float = CALL_TIMEOUT, **kwargs: Any) -> Any:
        with self.lock:
            if self._dead is not None:
                self.link_up = False
                raise LinkError(self._dead, None, self.port_name)
            if self._clear_due and op != "guard_clear":
                self._clear_due = False
                self._request("guard_clear")
            try:
                self._conn.send((op, name, args, kwargs))
            except (OSError, ValueError) as exc:
                self._dead = f"the link process is gone ({exc})"
                self.link_up = False
                raise LinkError(self._dead, None, self.port_name) from exc
            return self._reply(timeout, f"{op} {name}".strip())

    def __getattr__(self, name: str) -> Any:
        if name in FORWARDED:
            timeout = LONG_CALLS.get(name, CALL_TIMEOUT)
            return lambda *args, **kwargs: self._request("call", name, *args, timeout=timeout, **kwargs)
        raise AttributeError(name)

    @property
    def stats(self) -> dict:
        try:
            return self._request("get", "stats")
        except LinkError:
            return {}

    # --- the jog guard ----------------------------------------------------------------

    def guard_jog(self, spec: GuardSpec, release_epoch: int | None = None, heard: float | None = None) -> int:
        """A jog started or was refreshed (its hold heard at ``heard``): (re)arm the dead-man; returns the jog's
        epoch. Raises :class:`GuardHeld` if it was sent before a later release (``release_epoch`` older than the
        last) or heard longer ago than the dead-man."""
        return self._request("guard_jog", "", spec, release_epoch, heard)

    def guard_clear(self) -> None:
        """The jog ended (the station saw it): disarm, and let motion starts through again. Never waits for
        another thread's call (an E-stop or fault path may run while the loop waits on the link): then it is
        sent first thing with the next call."""
        if not self.lock.acquire(blocking=False):
            self._clear_due = True
            return
        try:
            self._clear_due = False
            self._request("guard_clear")
        finally:
            self.lock.release()

    def stop_all(self, mode: str = "abrupt", *, latch: str | None = None) -> StopReport:
        """The bus's stop-all, over the second pipe: STOP and E-STOP never wait behind the loop's calls."""
        with self._urgent_lock:
            try:
                self._urgent.send(("stop_all", mode, latch))
                if self._urgent.poll(LONG_CALLS["release"]):
                    return self._urgent.recv()
                why = "the link process did not answer the stop"
            except (EOFError, OSError, ValueError) as exc:
                why = f"the link process is gone ({exc or 'pipe closed'})"
        addresses = tuple(m.address for m in self.modules)
        return StopReport((), addresses, why)

    def preempt(self) -> None:
        """A stop is coming: the link process cuts short a patient retry in progress (:meth:`Bus.preempt`)."""
        self._urgent_send(("preempt",), wait=0.05)

    def guard_release(self) -> None:
        """Stop the jog now and wait until the stop was sent (machine loop)."""
        self._request("guard_release")

    def alive_now(self, release_epoch: int | None = None, heard: float | None = None) -> None:
        """The operator still holds the jog (heard at ``heard``, this clock: monotonic, as the link process's):
        the dead-man runs from then; from any thread, without waiting."""
        self._urgent_send(("alive", release_epoch, heard))

    def release_now(self, release_epoch: int | None = None) -> None:
        """Stop the jog now, from any thread, without waiting for anything (not even for the pipe's lock);
        jogs sent before release number ``release_epoch`` are refused from then on."""
        self._urgent_send(("release", release_epoch), wait=0.05)

    def _urgent_send(self, msg: tuple, wait: float = 0.0) -> None:
        # another thread's message takes microseconds; a stop-all holds the pipe longer, and stops the jog too
        if not (self._urgent_lock.acquire(timeout=wait) if wait else self._urgent_lock.acquire(blocking=False)):
            return
        try:
            self._urgent.send(msg)
        except (OSError, ValueError):
            pass  # the process is gone: the station's next call says so
        finally:
            self._urgent_lock.release()

    # --- life cycle --------------------------------------------------------------------

    def close(self, *, release: bool = False) -> None:
        try:
            if self._dead is None:
                self._request("close", timeout=LONG_CALLS["release"], release=release)
        except LinkError:
            pass
        finally:
            self.link_up = False
            self._stop_process()

    def _stop_process(self) -> None:
        with self.lock:
            try:
                if self._dead is None:
                    self._conn.send(("exit", "", (), {}))
            except (OSError, ValueError):
                pass
            self._dead = self._dead or "the link is closed"
        try:
            self._proc.wait(5)
        except subprocess.TimeoutExpired:
            pass
        self._kill()
        for c in (self._conn, self._urgent):
            c.close()

    def _kill(self) -> None:
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait(2)

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        return self._proc.pid


class _RemoteTrace(ByteTrace):
    """The link process's byte trace, read on demand (the UI's snapshot and live view)."""

    def __init__(self, bus: RemoteBus) -> None:
        super().__init__()
        self._bus = bus

    def entries(self, last: int | None = None) -> list:
        try:
            return self._bus._request("trace", "", last)
        except LinkError:
            return []


def _rebuild(cls: str, message: str, address: int | None, port: str) -> Exception:
    if cls == "GuardHeld":
        return GuardHeld(message)
    if cls == "Preempted":
        return Preempted(message, address)
    if cls == "LinkError":
        return LinkError(message, address, port)
    if cls == "TransportError":
        return TransportError(message)
    if cls in ("NmcError", "CodecError"):
        return NmcError(message, address)
    return NmcError(f"link process: {cls}: {message}", address)


def separate_process(port: Any, setting: str) -> bool:
    """Does this port get a link process? ``setting``: "auto" (real ports yes, in-process simulator no; on
    POSIX systems) or "same"."""
    if setting == "same" or not isinstance(port, str) or port.lower().startswith(("sim://", "loop://")):
        return False
    return os.name == "posix"  # the child is joined by inherited socket fds (pass_fds): POSIX only


def open_bus(port: Any, *, firmware: str, trace: ByteTrace | None, process: str = "auto") -> Bus | RemoteBus:
    if separate_process(port, process):
        return RemoteBus(port, firmware=firmware, trace=trace)
    return Bus(port, firmware=firmware, trace=trace)


__all__ = ["GuardAxis", "GuardHeld", "GuardSpec", "JogGuard", "RemoteBus", "StopReport", "open_bus",
           "separate_process"]


def main(argv: list[str]) -> None:
    """``python -m cmm.nmc.link_process PORT FIRMWARE CALLS_FD URGENT_FD`` (started by :class:`RemoteBus`)."""
    logging.basicConfig(level=logging.WARNING, format="cmm-link: %(levelname)s %(message)s")
    port, firmware, calls, urgent = argv
    serve(port, firmware, Connection(int(calls)), Connection(int(urgent)))


if __name__ == "__main__":
    main(sys.argv[1:])

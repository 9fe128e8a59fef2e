"""One I++ DME client connection: the queues, the error model, the session state and the command set.

``receive(line)`` is called for each command line in arrival order (the
connection's reader thread). Fast-queue commands (their names end in E) run
at once in that thread, so they are answered while a move runs; the others
are acknowledged and queued for a worker thread that runs them in order.
Responses go out through ``send(line)``, which must be thread-safe.

Error model (spec 6.2.5, 6.3.1.5): an error of severity >= 2 aborts the
pending commands ("Transaction aborted") and puts the server in the error
state, where everything but ClearAllErrors, GetErrStatusE, GetXtdErrStatus,
GetErrorInfo and EndSession is refused with 0514 until ClearAllErrors.
"""

from __future__ import annotations

import functools
import math
import queue
import threading
from typing import Any, Callable

import numpy as np

from ..control import ContactError, ControlError, CutShort, LimitError, MotionError, SurfaceNotFound
from . import protocol as P
from .backend import Backend
from .csy import CoordinateSystems
from .errors import ERRORS, IppError
from .setup_commands import DME_VERSION, HANDLERS, one, props  # noqa: F401  (DME_VERSION: still importable from here)
from .status import IppStatus
from .tools import Limits, ToolChanger

MAX_PENDING = 64  # queued commands before acknowledgements are delayed (spec 6.2.3)
ALLOWED_IN_ERROR = {"ClearAllErrors", "GetErrStatusE", "GetXtdErrStatus", "GetErrorInfo", "EndSession", "AbortE"}
OUTSIDE_SESSION = {"StartSession", "EndSession", "ClearAllErrors", "GetErrStatusE", "AbortE"}
AXES = ("X", "Y", "Z")
ANGLES = ("Tool.A", "Tool.B", "Tool.C", "R")  # a fixed stylus and no rotary table: always 0
REPORT_ITEMS = set(AXES) | set(ANGLES)
PTMEAS_ITEMS = REPORT_ITEMS | {"IJK", "ER", "Q"}
MIN_REPORT_INTERVAL = 0.1  # s: OnMoveReportE sends at most 10 reports a second
DRIFT = 0.05  # mm: within this the last commanded position stands in for the actual one (no drift)


class _Aborted(Exception):
    pass


class Dme:
    def __init__(self, backend: Backend, send: Callable[[str], None], *, client: str = "client",
                 status: IppStatus | None = None, tools: ToolChanger | None = None,
                 csy: CoordinateSystems | None = None) -> None:
        self.backend = backend
        self.send = send
        self.client = client
        self.status = status or IppStatus()
        # tools and coordinate systems outlive a session (spec 6.3.1.2): the server passes them in
        self.tools = tools or ToolChanger.build(Limits.from_config(backend.config), backend.probes())
        self.csy = csy or CoordinateSystems()
        self.in_session = False
        self.error_state = False
        self.last_errors: list[IppError] = []
        self.user_enabled = False
        self.report_format: tuple[str, ...] = ("X", "Y", "Z")
        self.nominal: np.ndarray | None = None  # last commanded machine position
        self._queue: queue.Queue[P.Command | None] = queue.Queue()
        self._active: set[str] = set()  # tags acknowledged and not yet complete
        self._lock = threading.RLock()
        self._idle = threading.Condition(self._lock)
        self._running: P.Command | None = None
        self._aborting = False
        self._closed = False
        self._daemon: _MoveDaemon | None = None
        # an E-stop from any front end is an unsolicited error 0500 (spec 6.2.4.1), severity 3: error state
        self._unsubscribe_estop = backend.on_emergency_stop(
            lambda message: self._report(P.UNSOLICITED, IppError(500, "EmergencyStop", message)))
        self._worker = threading.Thread(target=self._work, name=f"ippdme-{client}", daemon=True)
        self._worker.start()

    # --- the reader side -------------------------------------------------------------

    @classmethod
    def handles(cls, name: str) -> bool:
        """Is ``name`` a command this server implements?"""
        return hasattr(cls, f"_do_{name}") or name in HANDLERS

    def receive(self, line: str) -> None:
        try:
            cmd = P.parse_line(line)
        except P.ParseError as exc:
            self._reject(exc.tag, exc.error, line)
            return
        with self._lock:
            if cmd.tag in self._active:
                self._report(P.UNSOLICITED, IppError(1, cmd.name, f"tag {cmd.tag} is still in use"))
                return
            if cmd.is_event_tag and not cmd.fast:
                self._report(P.UNSOLICITED, IppError(1, cmd.name, f"{cmd.name} is not an event command"))
                return
            self._active.add(cmd.tag)
        if cmd.fast:
            self.send(P.ack(cmd.tag))
            self._execute(cmd)
            return
        with self._idle:  # delay the acknowledgement while the queue is full
            while self._queue.qsize() >= MAX_PENDING and not self._closed:
                self._idle.wait(0.2)
            # acknowledged and queued in one step under the lock: an error takes the queue under the
            # same lock, so a command is either pending when the error happens or comes after it
            self.send(P.ack(cmd.tag))
            self._queue.put(cmd)

    def _reject(self, tag: str, err: IppError, line: str) -> None:
        """A malformed line: answered on its tag if it has a usable one, else as an unsolicited error."""
        err.detail = f"{err.detail} in {line[:80]!r}"
        if tag == P.UNSOLICITED:
            self._report(tag, err)
            return
        with self._lock:
            if tag in self._active:
                self._report(P.UNSOLICITED, IppError(1, "", f"tag {tag} is still in use"))
                return
        self.send(P.ack(tag))
        self._report(tag, err)
        self.send(P.complete(tag))

    def _report(self, tag: str, err: IppError) -> None:
        # the error state is set before the error goes out: whatever the client sends once it has
        # read the error (ClearAllErrors, GetErrStatusE) already meets that state
        if err.severity >= 2 and err.sticky:
            with self._lock:
                self.error_state = True
                self.last_errors.append(err)
                del self.last_errors[:-10]
        self.send(P.error(tag, err))
        self.status.failed(str(err))
        if self.in_session and err.severity >= 2 and err.number not in (6, 514):  # the cause, not its echoes
            try:
                self.backend.note(f"I++ DME error on {tag} {err.method}: {err}")
            except Exception:  # noqa: BLE001 - the journal may be closing; the client has its answer
                pass

    # --- the worker side ---------------------------------------------------------------

    def _work(self) -> None:
        while True:
            cmd = self._queue.get()
            if cmd is None:
                return
            with self._lock:
                self._running = cmd
            try:
                self._execute(cmd)
            finally:
                with self._idle:
                    self._running = None
                    self._idle.notify_all()

    def _execute(self, cmd: P.Command) -> None:
        self.status.running(cmd.text)
        try:
            with self._lock:
                aborted = self._aborting or self._closed
                outside = not self.in_session and cmd.name not in OUTSIDE_SESSION
                refused = self.error_state and cmd.name not in ALLOWED_IN_ERROR
            if aborted:
                raise IppError(6, cmd.name, "aborted before it started")
            if outside:  # refused, but no error state: there is no session to protect
                err = IppError(507, cmd.name, "no session: send StartSession() first")
                err.sticky = False
                raise err
            if refused:
                raise IppError(514, cmd.name)
            handler = getattr(self, f"_do_{cmd.name}", None)
            if handler is None and cmd.name in HANDLERS:  # properties, tools, coordinate systems
                handler = functools.partial(HANDLERS[cmd.name], self)
            if handler is None:
                raise IppError(501, cmd.name, f"{cmd.name} is not supported by this server")
            for body in handler(cmd) or ():
                if not self._aborting or cmd.fast:  # (d): no more data of an aborted command
                    self.send(P.data(cmd.tag, body))
        except IppError as err:
            if not err.method:
                err.method = cmd.name
            # spec 6.2.5: severity >= 2 aborts the pending transactions. They are taken from the queue
            # before the error goes out, so a command the client sends after reading the error (most
            # of all ClearAllErrors) is not among them: it meets the error state (0514) or clears it.
            # A 0514 refusal is the error state's echo, not a new error: the commands behind it meet
            # the state each on its own, and a ClearAllErrors among them clears it.
            new_error = err.severity >= 2 and err.number not in (6, 514)
            pending = self._take_pending() if new_error and not cmd.fast else []
            self._report(cmd.tag, err)
            self._abort_commands(pending, "aborted after an earlier error")
        except _Aborted:
            self._report(cmd.tag, IppError(6, cmd.name, "stopped by AbortE"))
        except Exception as exc:  # noqa: BLE001 - a server bug must still close the transaction
            self._report(cmd.tag, IppError(511, cmd.name, f"{type(exc).__name__}: {exc}"))
        finally:
            self.status.running("")
            self.send(P.complete(cmd.tag))
            with self._lock:
                self._active.discard(cmd.tag)
                daemon = self._daemon
            if daemon is not None and daemon.tag == cmd.tag:
                daemon.start()  # its reports follow the transaction complete

    def _take_pending(self) -> list[P.Command]:
        """The queued commands, taken in one step (the close marker stays in the queue)."""
        taken: list[P.Command] = []
        with self._lock:
            while True:
                try:
                    cmd = self._queue.get_nowait()
                except queue.Empty:
                    break
                if cmd is None:
                    self._queue.put(None)
                    break
                taken.append(cmd)
            self._idle.notify_all()  # acknowledgements delayed by a full queue may go on
        return taken

    def _abort_commands(self, commands: list[P.Command], why: str) -> None:
        """Answer taken commands with 0006 "Transaction aborted" (spec 6.2.5 and AbortE (c))."""
        for cmd in commands:
            self._report(cmd.tag, IppError(6, cmd.name, why))
            self.send(P.complete(cmd.tag))
            with self._lock:
                self._active.discard(cmd.tag)

    def close(self) -> None:
        """The client went away: stop the machine if it moves, stop daemons, drop pending commands."""
        with self._lock:
            self._closed = True
            self._aborting = True
            busy = self._running is not None
        self._unsubscribe_estop()
        self._stop_daemon()
        if busy:
            self.backend.stop()
        while True:  # drop pending commands silently: nobody reads the answers
            try:
                self._queue.get_nowait()
            except queue.Empty:
                break
        self._queue.put(None)
        self._worker.join(timeout=10)
        if self.in_session:
            self.in_session = False
            try:
                self.backend.note(f"I++ DME client {self.client} disconnected" + (" during a move: stopped"
                                                                                    if busy else ""))
            except Exception:  # noqa: BLE001 - the journal may be closing with the station
                pass
        self.status.disconnected()

    # --- helpers --------------------------------------------------------------------------

    def _motion(self, fn: Callable[[], Any], method: str) -> Any:
        """Run a blocking backend motion, mapping its failures to I++ errors."""
        if self._aborting:
            raise _Aborted()
        self.user_enabled = False  # moves imply DisableUser() (6.3.2.4)
        self.nominal = None  # until the move ends where it was sent, the commanded position is unknown
        try:
            return fn()
        except LimitError as exc:
            raise IppError(1008, method, str(exc)) from None
        except ContactError as exc:
            raise IppError(1001, method, str(exc)) from None
        except SurfaceNotFound as exc:
            raise IppError(1006, method, str(exc)) from None
        except ControlError as exc:
            if not isinstance(exc, CutShort):  # the link to the modules failed: the machine is in fault
                raise IppError(503, method, str(exc)) from None
            raise self._ended(method, exc) from None  # a STOP or E-STOP took the link before the move's command
        except MotionError as exc:
            raise self._ended(method, exc) from None

    def _ended(self, method: str, exc: MotionError) -> Exception:
        """What a move that ended early is to the client: aborted by it, ended by somebody's E-STOP (0500), or
        stopped otherwise (1011)."""
        if self._aborting:
            return _Aborted()
        return IppError(500 if self.backend.estopped else 1011, method, str(exc))

    def _tool_for_motion(self, method: str, measuring: bool = False):
        if not self.backend.homed:
            raise IppError(507, method, "the machine is not homed: send Home() first")
        tool = self.tools.tool
        if tool is None:
            raise IppError(1503, method, "the active tool is UnDefTool: ChangeTool first")
        if measuring and tool.ptmeas is None:
            raise IppError(507, method, f"{tool.name} cannot measure")
        return tool

    def _here(self) -> np.ndarray:
        """The position moves start from (machine): the last commanded one unless the machine was moved."""
        actual = self.backend.position()
        if self.nominal is not None and np.linalg.norm(actual - self.nominal) < DRIFT:
            return self.nominal
        return actual

    def _value(self, name: str, method: str, machine_pos: np.ndarray | None = None) -> float:
        if self.tools.tool is None:
            raise IppError(1503, method, "the active tool is UnDefTool")
        if name in ANGLES:
            return 0.0
        p = self.csy.from_machine(self.backend.position() if machine_pos is None else machine_pos)
        return float(p[AXES.index(name)])

    _props = staticmethod(props)
    _one = staticmethod(one)

    # --- server methods (6.3.1) -------------------------------------------------------------

    def _do_StartSession(self, cmd: P.Command):
        if self.in_session:
            raise IppError(8, cmd.name, "a session is already active: EndSession() first")
        self._stop_daemon()
        with self._lock:
            self.error_state = False
            self.last_errors.clear()
        self.report_format = ("X", "Y", "Z")
        for name, radius in self.backend.probes():  # a re-qualification since the last session changes the radius
            if name in self.tools.tools:
                self.tools.tools[name].radius = radius
            else:  # a probe added to the station's list since: listed from this session on
                self.tools.add(Limits.from_config(self.backend.config), name, radius)
        self.in_session = True
        self.status.in_session = True
        self.backend.begin_session(self.client)

    def _do_EndSession(self, cmd: P.Command):
        self._stop_daemon()
        with self._lock:
            self.error_state = False  # the session is over; the next one starts clean (StartSession clears too)
        if self.in_session:
            self.in_session = False
            self.status.in_session = False
            self.backend.end_session()

    def _do_ClearAllErrors(self, cmd: P.Command):
        with self._lock:
            self.error_state = False

    def _do_GetErrorInfo(self, cmd: P.Command):
        number = self._one(cmd, float)
        if number != int(number) or int(number) not in ERRORS:
            raise IppError(504, cmd.name, f"{number:g} is not an I++ DME error number")
        yield P.quote(ERRORS[int(number)][1])

    def _do_GetErrStatusE(self, cmd: P.Command):
        yield P.prop("ErrStatus", int(self.error_state))

    def _do_GetXtdErrStatus(self, cmd: P.Command):
        yield P.prop("IsHomed", int(self.backend.homed))
        yield P.prop("IsUserEnabled", int(self.user_enabled))
        if self.error_state:
            for err in self.last_errors:
                yield f"Error({err.severity}, {err.number:04d}, {P.quote(err.method)}, {P.quote(err.text)})"

    def _do_AbortE(self, cmd: P.Command):
        """Stop motion, abort the running and pending commands, answer when they are answered (6.3.1.5)."""
        with self._idle:
            self._aborting = True
            busy = self._running is not None
        if busy:
            self.backend.stop()
        with self._idle:
            while self._running is not None:
                self._idle.wait(0.2)
                if self._running is not None:
                    self.backend.stop()
            self._abort_commands(self._take_pending(), "aborted by AbortE")
            self._aborting = False
            self.error_state = True  # the next command must be ClearAllErrors (0514 otherwise)
            self.last_errors.append(IppError(6, cmd.name, "AbortE"))
        return ()

    # --- DME methods (6.3.2) ----------------------------------------------------------------------

    def _do_Home(self, cmd: P.Command):
        self._motion(self.backend.home, cmd.name)
        self.nominal = self.backend.position()

    def _do_Get(self, cmd: P.Command):
        props = self._props(cmd, REPORT_ITEMS, nargs=0)
        if not props:
            raise IppError(502, cmd.name, "Get needs at least one of X(), Y(), Z(), Tool.A(), ...")
        here = self.backend.position()
        yield ", ".join(P.prop(p.name, round(self._value(p.name, cmd.name, here), 5)) for p in props)

    def _do_GoTo(self, cmd: P.Command):
        props = self._props(cmd, REPORT_ITEMS, nargs=1)
        if not props:
            raise IppError(502, cmd.name, "GoTo needs at least one of X(..), Y(..), Z(..)")
        tool = self._tool_for_motion(cmd.name)
        target = self.csy.from_machine(self._here())
        for p in props:
            if p.name in AXES:
                target[AXES.index(p.name)] = p.args[0]
        machine = self.csy.to_machine(target)
        try:
            self.backend.check_target(machine)
        except LimitError as exc:
            raise IppError(1008, cmd.name, str(exc)) from None
        angles = [p.name for p in props if p.name in ANGLES and p.args[0] != 0.0]
        if any(p.name in AXES for p in props):
            g = tool.goto
            self._motion(lambda: self.backend.move_to(machine, g["Speed"].act, g["Accel"].act), cmd.name)
            self.nominal = machine
        if angles:  # a fixed stylus and no rotary table: the angles stay 0 (like a clamped property)
            raise IppError(504, cmd.name, f"{', '.join(angles)}: this machine has no rotary axes (0 only)")

    def _do_OnPtMeasReport(self, cmd: P.Command):
        props = self._props(cmd, PTMEAS_ITEMS, nargs=0)
        if not props:
            raise IppError(502, cmd.name, "the report format may not be empty")
        self.report_format = tuple(p.name for p in props)

    def _do_PtMeas(self, cmd: P.Command):
        props = {p.name: p for p in self._props(cmd, set(AXES) | {"IJK"})}
        if not any(a in props for a in AXES):
            raise IppError(502, cmd.name, "PtMeas needs at least one of X(..), Y(..), Z(..)")
        for name, p in props.items():
            if len(p.args) != (3 if name == "IJK" else 1):
                raise IppError(502, cmd.name, f"{name} takes {3 if name == 'IJK' else 1} value(s)")
        tool = self._tool_for_motion(cmd.name, measuring=True)
        here = self._here()
        nominal = self.csy.from_machine(here)
        for a in AXES:
            if a in props:
                nominal[AXES.index(a)] = props[a].args[0]
        nominal_m = self.csy.to_machine(nominal)
        if "IJK" in props:
            direction = self.csy.vector_to_machine(np.array(props["IJK"].args, dtype=float))
        else:  # from the nominal point towards where the tool is (6.3.2.13)
            direction = here - nominal_m
        norm = float(np.linalg.norm(direction))
        if not math.isfinite(norm) or norm < 1e-9:
            raise IppError(1010, cmd.name, "the approach direction has no length")
        direction = direction / norm
        try:  # the nominal point within the travel before anything moves (a 1e308 got a bare 0511 / 0507)
            self.backend.check_target(nominal_m)
        except LimitError as exc:
            raise IppError(1008, cmd.name, str(exc)) from None
        t, g = tool.ptmeas, tool.goto
        assert t is not None
        centre = self._motion(lambda: self.backend.probe(
            nominal_m, direction, speed=t["Speed"].act, accel=t["Accel"].act, approach=t["Approach"].act,
            search=t["Search"].act, retract=t["Retract"].act, rapid_speed=g["Speed"].act), cmd.name)
        self.nominal = None
        self.status.measured(centre)
        p = self.csy.from_machine(centre)
        ijk = self.csy.vector_from_machine(direction)
        items = []
        for name in self.report_format:
            if name in AXES:
                items.append(P.prop(name, round(float(p[AXES.index(name)]), 5)))
            elif name == "IJK":
                items.append(P.prop(name, *(round(float(v), 6) for v in ijk)))
            elif name == "ER":
                items.append(P.prop(name, tool.radius))
            else:  # Q (a touch-trigger point is good), R, Tool.A/B/C
                items.append(P.prop(name, 0))
        yield ", ".join(items)

    # --- daemons -------------------------------------------------------------------------------

    def _do_OnMoveReportE(self, cmd: P.Command):
        period = distance = None
        items = []
        for p in self._props(cmd):
            if p.name in ("Time", "Dis"):
                if len(p.args) != 1 or not math.isfinite(p.args[0]):
                    raise IppError(502, cmd.name, f"{p.name} takes one number")
                if p.name == "Time":
                    if p.args[0] < MIN_REPORT_INTERVAL:
                        raise IppError(510, cmd.name, "Time must be at least 0.1 s")
                    period = p.args[0]
                else:
                    if p.args[0] <= 0:
                        raise IppError(510, cmd.name, "Dis must be positive")
                    distance = p.args[0]
            elif p.name in REPORT_ITEMS and not p.args:
                items.append(p.name)
            else:
                raise IppError(510, cmd.name, f"{p.name}() cannot be reported")
        with self._lock:
            if self._daemon is not None and self._daemon.tag == cmd.tag:
                raise IppError(515, cmd.name, f"the daemon {cmd.tag} runs already")
        self._stop_daemon()  # one move report at a time: a new one replaces the old (the client should stop it)
        with self._lock:
            self._daemon = _MoveDaemon(self, cmd.tag, items, period, distance)
        return ()

    def _do_StopDaemon(self, cmd: P.Command):
        tag = self._one(cmd, P.ETag)
        with self._lock:
            if self._daemon is None or self._daemon.tag != tag.tag:
                raise IppError(513, cmd.name, f"no daemon {tag.tag}")
        self._stop_daemon()

    def _do_StopAllDaemons(self, cmd: P.Command):
        if not self._stop_daemon():
            raise IppError(512, cmd.name)

    def _stop_daemon(self) -> bool:
        with self._lock:
            daemon, self._daemon = self._daemon, None
        if daemon is not None:
            daemon.stop()
        return daemon is not None

    def _refresh_daemon(self) -> None:
        with self._lock:
            daemon = self._daemon
        if daemon is not None:
            daemon.report_now()


class _MoveDaemon:
    """OnMoveReportE: reports the position every ``period`` s of machine time or ``distance`` mm of travel.

    Driven by the machine's state updates (so it runs on the simulator's
    virtual clock as on hardware); at most one report per 0.1 s.
    """

    def __init__(self, dme: Dme, tag: str, items: list[str], period: float | None, distance: float | None) -> None:
        self.dme, self.tag, self.items = dme, tag, items
        self.period, self.distance = period, distance
        self._lock = threading.Lock()
        self._running = True
        self._last_time: float | None = None
        self._last_pos: np.ndarray | None = None
        self._first = True
        self._unsubscribe: Callable[[], None] | None = None

    def start(self) -> None:
        if self._unsubscribe is None:
            self._unsubscribe = self.dme.backend.subscribe_state(self._on_state)

    def _line(self, machine_pos: np.ndarray) -> str:
        return P.data(self.tag, ", ".join(
            P.prop(n, round(self.dme._value(n, "OnMoveReportE", machine_pos), 5)) for n in self.items))

    def _on_state(self, state: Any) -> None:
        """``state``: the machine's latest sample (time in machine seconds, position in mm)."""
        if not self.items:
            return
        pos = np.asarray(state.position, dtype=float)
        with self._lock:
            if not self._running:
                return
            if self._first:  # the first report once the daemon is established
                due = True
            else:
                dt = state.time - self._last_time
                if dt < MIN_REPORT_INTERVAL:
                    return
                due = (self.period is not None and dt >= self.period) or \
                    (self.distance is not None and float(np.linalg.norm(pos - self._last_pos)) >= self.distance)
            if not due:
                return
            self._first = False
            self._last_time, self._last_pos = state.time, pos
            try:
                self.dme.send(self._line(pos))
            except IppError:  # UnDefTool: nothing to report
                pass

    def report_now(self) -> None:
        with self._lock:
            self._first = True

    def stop(self) -> None:
        if self._unsubscribe is not None:
            self._unsubscribe()
        with self._lock:  # after this no report with our tag goes out
            self._running = False

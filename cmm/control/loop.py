"""The control core's machine loop: commands submitted from any thread and carried out in the one thread that talks
to the bus, the loop's step (urgent commands, queued commands, one sample), and the state it publishes.

A mixin of :class:`cmm.control.core.Controller`.
"""

from __future__ import annotations

import collections
import logging
import threading
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any, Callable, Literal

import numpy as np

from ..machine.motion import MachineState
from ..machine.probing import Hit
from ..machine.status import MoveStatus
from ..nmc.bus import NmcError, Preempted
from ..nmc.transport import rest
from .liveness import Liveness
from .modes import ALLOWED, ControlError, ControlState, CutShort, Mode, Refused, RunStopped, STOPPING, refusal
from .priority import raise_priority_on

log = logging.getLogger(__name__.rsplit(".", 1)[0] + ".core")  # the core's log, as before the split

FAULT_RETRY = 0.25  # s between attempts to reach the modules while in fault
# s a front end waits without the loop making progress (a step, a transaction) before it gives up: the loop is stuck.
# A busy computer makes the loop slow, not stuck: the wait goes on while it progresses (:mod:`.liveness`).
COMMAND_TIMEOUT = 20.0
STATE_INTERVAL = 0.01  # s of machine time between states sent to state listeners while nothing but positions change
WARNING_SHOWN = 10.0  # s a link warning stays in the state (the status bar) after the last one
LINK_ERRORS = (NmcError, OSError)  # SerialException and socket errors are OSErrors
_NOBODY = object()  # no client's armed jog ran yet


class _Command:
    __slots__ = ("client", "name", "fn", "future")

    def __init__(self, client: str | None, name: str, fn: Callable[[], Any]) -> None:
        self.client, self.name, self.fn = client, name, fn
        self.future: Future = Future()


class MachineLoop:
    """Submission, the loop's step and the published state (a mixin of the controller)."""

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
            raise CutShort(f"{cmd.name} was cut short by a STOP ({exc})") from exc
        except LINK_ERRORS as exc:
            self._enter_fault(f"link failure during {cmd.name}: {exc}", link=True)
            raise ControlError(f"{cmd.name} failed: the link to the modules failed ({exc}); "
                               "the machine is in fault") from exc
        finally:
            self._publish()

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
                rest(self.clock, self.machine.idle_poll_pause)  # on an uncapped simulator clock: no racing ahead at full CPU
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
            if motion is not None or st is not None and not st.standing:
                return Mode.MOVING, "", STOPPING  # never "stopped" while an axis still moves
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
            if st is not None and not st.standing:
                return Mode.MOVING, "", STOPPING  # never "stopped" while an axis still moves
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

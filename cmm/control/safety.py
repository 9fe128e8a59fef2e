"""The control core's safety state machine: STOP and E-STOP (the press from the caller's thread, the loop's part, the
answer once every axis stands), the end of a run a stop cut short, fault, reset, reconnect and the homing cycle.

A mixin of :class:`cmm.control.core.Controller`: the state it reads and writes is the controller's.
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any, Callable

from ..machine.homing import home_axes
from ..machine.status import MotionError
from ..nmc.bus import IDLE_PATIENCE, NmcError
from .liveness import Liveness
from .loop import COMMAND_TIMEOUT, _Command
from .modes import ControlError, Refused, StopReport

log = logging.getLogger(__name__.rsplit(".", 1)[0] + ".core")  # the core's log, as before the split

STOP_TIMEOUT = 0.5  # s of the loop's standstill (no step, no transaction) before a STOP talks to the bus itself
STILL_TIMEOUT = 3.0  # s of machine time a STOP / E-STOP waits for every axis to stand still before it answers
STOP_PATIENCE = IDLE_PATIENCE + 2.0  # s a STOP the loop is carrying out may take (its own patient retries)
LINK_ERRORS = (NmcError, OSError)  # SerialException and socket errors are OSErrors


class SafetyCore:
    """STOP, E-STOP, fault, reset, reconnect and homing (a mixin of the controller)."""

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
        self._stop_runs("stopped by the operator" if verb == "stop" else "emergency stop", estop=verb == "estop")
        failed = self._halt_now(verb)
        if self._job is None and self.jobs.descriptions():  # a run beside the loop is ended by its cancel
            self.jobs.ask_all("cancel", unless=lambda fn: getattr(fn, "is_stop", False))
        return client, verb, at, failed is not None and not failed

    def _stop_runs(self, why: str, estop: bool) -> None:
        """A stop pressed while a run goes on ends the whole run: its next motion is refused (the control core's
        checks and the machine's inhibit, for runs that move the machine directly); a run beside the loop is then
        asked to cancel (see press). Nothing moves on its own after the press. The run is marked stopped in the
        same breath as the E-STOP latch and before the modules get the stop: a run that meets the stop's effects
        (a move cut short, a probe refused under the latch) always finds itself ended by the operator's press."""
        with self._lock:
            if estop:
                self._estop = self._estop or "emergency stop pressed"
            running = self._job is not None or bool(self.jobs.descriptions())
            if running:
                self._run_stopped = self._run_stopped or why
        if estop:
            self.machine.inhibit = "emergency stop latched"
        if running and self.machine.inhibit is None:
            self.machine.inhibit = f"{why}: the run ends"

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
        """The stop's answer once every axis stands still (a sample taken after the press that is
        ``MachineState.standing``: every braking ramp ended, every axis at rest for 10 ms of machine time): no
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
            if st is not None and st.time > press and st.standing:
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

    def fault(self, reason: str) -> None:
        """Put the machine in the safe state (any thread): all axes stopped abruptly, mode fault."""
        cmd = _Command(None, "fault", lambda: self._enter_fault(reason))
        if self._thread is None or threading.current_thread() is self._thread:
            self._run_command(cmd, check=False)
        else:
            self._urgent.append(cmd)

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

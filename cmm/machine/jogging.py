"""Jogging the machine: velocity and horizon jogs, the dead-man, soft limits while jogging, a jog started with
the probe deflected, a touch while jogging (a manual hit or a contact stop), and the link process's jog guard
on real ports (:mod:`cmm.nmc.link_process`). A part of :class:`~cmm.machine.motion.Machine`."""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from ..nmc import codec
from ..nmc.link_process import GuardAxis, GuardHeld, GuardSpec
from .machine_state import ContactError, MachineState, _Motion
from .status import MotionError, MoveStatus

DEFLECTED_JOG_MM = 0.5  # travel a jog started with the probe deflected may make while it stays deflected (a probe
# freed by jogging off the surface is free within micrometres; further in, the stylus bends and then breaks)
JOG_LOOKAHEAD = 0.03  # s of travel allowed for sampling latency before a jog reaches a travel limit
STOP_MARGIN_S = 0.02  # s of travel added to a horizon stop's goal (sampling and command latency)
RETARGET_MIN_S = 0.03  # a horizon jog is re-targeted when its goal would move by more than this much travel


def _jog_stopped(motion: _Motion) -> np.ndarray:
    """A jog was told to stop (release, dead-man, link process): no velocity, no goal to re-target."""
    motion.extra["v"] = v = np.zeros(3)
    motion.extra.pop("goal", None)
    return v


class Jogging:
    """Jogs of the machine and what watches them while they run."""

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

        Without a link process it only notes that a release is on its way: the loop serves it before its next
        sample, and the dead-man does not fire meanwhile (a release that came while a sample was read would
        otherwise be overtaken by the dead-man, and the operator told "Jog stopped" for letting go). For one
        dead-man time at most: a release that never came would not keep the dead-man from a later jog."""
        self._release_posted = self.clock.now()
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
        self._release_posted = None
        with self._lock:
            motion = self._motion
            if motion is not None and motion.kind == "jog":
                if self.guarded:
                    self._guard_stop(motion)
                    return
                self._jog_stop_axes(range(3))
                _jog_stopped(motion)

    def _release_coming(self, state: MachineState) -> bool:
        posted = self._release_posted
        return posted is not None and state.time - posted < self.config.deadman_timeout

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
        elif np.any(v) and not self._release_coming(state) and \
                state.time - self._jog_refreshed > self.config.deadman_timeout:
            self._jog_stop_axes(range(3))
            v = _jog_stopped(motion)
            self.emit("deadman", after=state.time - self._jog_refreshed)
        if self.config.jog.mode == "horizon":
            if np.any(v) and self.guarded:  # the link process drives it: only say when the travel limits it
                self._tell_limit(motion, self.horizon_target(state.position, v)[1])
            elif np.any(v):
                self._retarget(motion)
            elif state.ramps_done:
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
        if not np.any(v) and state.ramps_done:  # its braking ramps ended (a trapezoid may only start from rest)
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

"""Touch-trigger probing cycles on top of the machine's motion.

The probe's switch drives a LIMIT input of every axis module; home capture
armed on that input with stop-abrupt latches all three axis positions on the
servo tick of the trigger. A hit keeps the raw counts (the truth) beside the
millimetres derived from them.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..metrology.compensation import PretravelModel, compensate
from .motion import ContactError, Machine
from .status import Cancelled, MotionError, MoveStatus


class SurfaceNotFound(MotionError):
    pass


@dataclass(frozen=True)
class Hit:
    counts: tuple[int, int, int]  # latched raw encoder counts
    machine: tuple[float, float, float]  # latched tip centre, machine mm
    approach: tuple[float, float, float]  # unit approach direction (into the surface)
    speed: float  # probing speed, mm/s
    time: float  # wall-clock seconds since the epoch
    point: tuple[float, float, float]  # compensated surface point, machine mm
    mode: str = "programmed"  # or "manual"
    normal: tuple[float, float, float] | None = None  # normal used for the radius offset, if not the approach


@dataclass
class ProbeSettings:
    """What compensation uses now; the calibration routine replaces these."""

    tip_radius: float
    pretravel: PretravelModel = field(default_factory=PretravelModel)
    # the qualification record these come from (cmm.calibration.records.ProbeRecord; its uncertainties feed the
    # measurement uncertainty budget), None for nominal settings
    record: Any = field(default=None, compare=False, repr=False)

    def compensate(self, centre: np.ndarray, approach: np.ndarray, normal: np.ndarray | None = None) -> np.ndarray:
        return compensate(centre, approach, self.tip_radius, self.pretravel, normal)


@dataclass(frozen=True)
class CyclePath:
    """The tip-centre path of one programmed hit, known before it runs (machine mm).

    :meth:`Prober.probe` moves along exactly these points: ``rapid`` (over the clearance height when one is
    given) to ``pre``, then the guarded move towards ``end`` that stops where the probe triggers (``contact``
    when the surface is where its nominal says), then back to ``retract``. A path preview draws the same."""

    start: np.ndarray  # where the cycle starts
    rapid: tuple[np.ndarray, ...]  # the rapid's corners, ending at the pre-hit point
    pre: np.ndarray  # the pre-hit point: the approach distance out from the contact
    contact: np.ndarray  # the tip centre touching the nominal surface point
    end: np.ndarray  # the end of the search: no trigger up to here is "surface not found"
    retract: np.ndarray  # where the tip goes back to after a trigger at ``contact``

    def polyline(self) -> np.ndarray:
        """Start, rapid corners, the contact and the retract point, in the order the tip passes them."""
        return np.array([self.start, *self.rapid, self.contact, self.retract], dtype=np.float64)


def cycle_path(here: np.ndarray, nominal: np.ndarray, approach: np.ndarray, *, tip_radius: float,
               approach_distance: float, search_distance: float, retract_distance: float,
               clearance_z: float | None) -> CyclePath:
    """The path of a programmed hit at ``nominal`` along ``approach`` (into the surface) from ``here``.

    A negative ``retract_distance`` goes back to the pre-hit point. With ``clearance_z`` the rapid climbs to that
    height (never down from higher), crosses and descends to the pre-hit point; without it, straight there."""
    u = _unit(approach)
    p = np.asarray(nominal, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise MotionError(f"a nominal point needs three finite coordinates, got {nominal!r}")
    here = np.asarray(here, dtype=np.float64)
    contact = p - tip_radius * u
    pre = contact - approach_distance * u
    end = contact + search_distance * u
    if clearance_z is None:
        rapid: tuple[np.ndarray, ...] = (pre,)
    else:
        rapid = (np.array([here[0], here[1], max(clearance_z, here[2])]),
                 np.array([pre[0], pre[1], max(clearance_z, pre[2])]), pre)
    retract = pre if retract_distance < 0 else contact - retract_distance * u
    return CyclePath(here, rapid, pre, contact, end, retract)


def _floats(v: np.ndarray) -> tuple[float, ...]:
    return tuple(float(x) for x in np.asarray(v).reshape(-1))


def _unit(direction: np.ndarray) -> np.ndarray:
    d = np.asarray(direction, dtype=np.float64).reshape(-1)
    n = float(np.linalg.norm(d)) if d.shape == (3,) else 0.0
    if not math.isfinite(n) or n < 1e-9:
        raise MotionError(f"an approach direction needs three finite components, not all zero; got {direction!r}")
    return d / n


class Prober:
    """Programmed and manual probing for one machine with the current probe settings."""

    def __init__(self, machine: Machine, settings: ProbeSettings | None = None) -> None:
        self.machine = machine
        cfg = machine.config.probe
        self.settings = settings or ProbeSettings(cfg.tip_radius, PretravelModel.constant(cfg.pretravel))
        self.listeners: list[Callable[[Hit], None]] = []

    def _make_hit(self, latched: tuple[int, int, int], approach: np.ndarray, speed: float, mode: str,
                  normal: np.ndarray | None = None) -> Hit:
        centre = self.machine.counts_to_mm(latched)
        point = self.settings.compensate(centre, approach, normal)
        hit = Hit(tuple(int(c) for c in latched), _floats(centre), _floats(approach), float(speed), _time.time(),  # type: ignore[arg-type]
                  _floats(point), mode, None if normal is None else _floats(normal))  # type: ignore[arg-type]
        for fn in list(self.listeners):
            fn(hit)
        return hit

    def probe(self, nominal: np.ndarray, approach: np.ndarray, *, speed: float | None = None,
              normal: np.ndarray | None = None, clearance_z: float | None = None,
              approach_distance: float | None = None, search_distance: float | None = None,
              retract_distance: float | None = None, accel: float | None = None,
              rapid_speed: float | None = None) -> MoveStatus:
        """Programmed hit at a nominal surface point along an approach direction (into the surface).

        Rapid to the pre-hit point at the approach distance, arm capture, move
        at probing speed for at most approach + search distance, read the
        latched positions, retract. The status's result is the :class:`Hit`.
        With ``clearance_z`` the rapid climbs to that height, crosses, and
        descends to the pre-hit point, so it clears features in between.
        The distances, the probing acceleration and the rapid speed default to
        the configuration's (an I++ DME client sets its own per tool).
        """
        m = self.machine
        speed = m.config.speeds.probing if speed is None else speed
        accel = m.config.accelerations.probing if accel is None else accel
        plan = self.cycle_path(m.position, nominal, approach, clearance_z=clearance_z,
                               approach_distance=approach_distance, search_distance=search_distance,
                               retract_distance=retract_distance)
        u, p = _unit(approach), np.asarray(nominal, dtype=np.float64).reshape(-1)
        pre = m.check_target(plan.pre)
        end = m.check_target(plan.end)
        status = MoveStatus("probe at X={:.3f} Y={:.3f} Z={:.3f}".format(*p), m.driver)

        def fail(error: BaseException) -> None:
            status.finish(error=error)

        def step(fn: Callable[[MoveStatus], None]) -> Callable[[MoveStatus], None]:
            """A stage of the cycle, run when the previous move ends: whatever it raises (the link
            failing as the next move is sent) ends the cycle with that error, never leaves it hanging."""
            def run(s: MoveStatus) -> None:
                try:
                    fn(s)
                except Exception as exc:  # noqa: BLE001 - reported through the status
                    fail(exc)
            return run

        @step
        def after_rapid(s: MoveStatus) -> None:
            if isinstance(s.error, Cancelled):
                return status.cancel()  # cancelled as a whole, in the cycle's own words
            if s.error is not None:
                return fail(s.error)
            try:
                guarded = m.probing_move(end, speed, accel)
            except ContactError:
                return fail(MotionError("the probe is deflected at the pre-hit point: clear it first"))
            except BaseException as exc:  # noqa: BLE001 - reported through the status
                return fail(exc)
            status.on_cancel(guarded.cancel)
            guarded.add_callback(after_guarded)

        @step
        def after_guarded(s: MoveStatus) -> None:
            if isinstance(s.error, Cancelled):
                return status.cancel()  # cancelled as a whole, in the cycle's own words
            if s.error is not None:
                return fail(s.error)
            if s.result is None:
                return not_found()
            latched = s.result
            hit = self._make_hit(latched, u, speed, "programmed", normal)
            if retract_distance is not None and retract_distance < 0:  # back to the pre-hit point
                self._retract(u, hit_status=status, result=hit, target=pre)
            else:
                self._retract(u, hit_status=status, result=hit, distance=retract_distance)

        def not_found() -> None:
            back = m.move_to(pre, protect=False)  # a failure to send it fails the cycle (after_guarded's step)
            back.add_callback(lambda s: fail(SurfaceNotFound(
                "surface not found: no trigger within {:.1f} mm of the nominal point X={:.3f} Y={:.3f} Z={:.3f}"
                .format(float(np.linalg.norm(plan.end - plan.pre)), *p))))

        rapid = m.move_path(list(plan.rapid), rapid_speed)
        status.on_cancel(rapid.cancel)
        rapid.add_callback(after_rapid)
        return status

    def cycle_path(self, here: np.ndarray, nominal: np.ndarray, approach: np.ndarray, *,
                   clearance_z: float | None = None, approach_distance: float | None = None,
                   search_distance: float | None = None, retract_distance: float | None = None) -> CyclePath:
        """The path :meth:`probe` takes from ``here`` with these options (the configuration's distances and the
        present tip radius by default): what a path preview draws."""
        cfg = self.machine.config.probe
        return cycle_path(here, nominal, approach, tip_radius=float(self.settings.tip_radius),
                          approach_distance=cfg.approach_distance if approach_distance is None else approach_distance,
                          search_distance=cfg.search_distance if search_distance is None else search_distance,
                          retract_distance=cfg.retract_distance if retract_distance is None else retract_distance,
                          clearance_z=clearance_z)

    def _retract(self, u: np.ndarray, *, hit_status: MoveStatus, result: Hit, distance: float | None = None,
                 target: np.ndarray | None = None) -> None:
        m = self.machine
        try:
            if target is None:
                target = m.position - (m.config.probe.retract_distance if distance is None else distance) * u
            back = m.move_to(target, m.config.speeds.probing * 5, protect=False)
        except Exception as exc:  # noqa: BLE001 - the hit is latched and recorded: the cycle ends with it
            hit_status.finish(result, None)
            m.emit("error", message=f"retract after the hit failed: {exc}")
            return

        def done(s: MoveStatus) -> None:
            try:
                if s.error is None and m.sample().probe_triggered:
                    m.emit("error", message="the probe is still deflected after the retract")
            finally:
                hit_status.finish(result, None)

        back.add_callback(done)

    def jog_probe(self, velocity: np.ndarray, *, release_epoch: int | None = None,
                  heard: float | None = None) -> None:
        """Jog in velocity mode with the probe armed (thesis experiment 2): a trigger records a manual hit."""

        def record(latched: tuple[int, int, int], v: np.ndarray) -> None:
            speed = float(np.linalg.norm(v))
            direction = v / speed
            hit = self._make_hit(latched, direction, speed, "manual")
            self._retract(direction, hit_status=MoveStatus("manual hit retract"), result=hit)

        self.machine.jog(velocity, manual_probe=record, release_epoch=release_epoch, heard=heard)

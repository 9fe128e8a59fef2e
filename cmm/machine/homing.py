"""The homing cycle: find each axis's home switch and make its edge the axis's ``home`` coordinate.

Per group of axes (``[homing] order``, Z first by default): seek the switch at
``speed`` with home capture armed (stop abruptly on the switch edge, and on the
probe too), back off ``backoff`` mm, approach again at ``latch_speed`` to latch
the edge precisely, move onto the latched count and zero the counter there
(RESET_POS: works on every firmware). Moves are relative in counts, so they
do not depend on positions that are not known yet.

It blocks: the control core runs it in its machine loop, and ``tick`` (called
between samples) is where STOP and E-STOP get in: it raises to abort.
"""

from __future__ import annotations

from typing import Callable

from ..nmc import codec
from ..nmc.transport import is_virtual
from .config import AXES
from .motion import VIRTUAL_MOVE_POLL_PAUSE, Machine
from .status import MotionError


class HomingError(MotionError):
    pass


def _toward_max(axis) -> bool:  # noqa: ANN001 - AxisConfig
    return axis.home >= (axis.min + axis.max) / 2


def home_axes(machine: Machine, tick: Callable[[], None] | None = None) -> None:
    """Run the configured homing cycle; returns when every axis reads its home coordinate at its switch."""
    cfg = machine.config
    h = cfg.homing
    if h.method == "none":
        return
    mask = codec.LIMIT1 if h.input == "limit1" else codec.LIMIT2
    tick = tick or (lambda: None)
    virtual = is_virtual(machine.clock)

    def switch_on(status: int) -> bool:
        return bool(status & mask) == (h.active_level == "high")

    def sample() -> list:
        tick()
        return list(machine.sample().axes)

    def fixed(axis, speed: float, accel: float) -> tuple[int, int]:  # noqa: ANN001
        return (max(1, codec.velocity_to_fixed(speed, axis.counts_per_mm, axis.gains.sr)),
                max(1, codec.acceleration_to_fixed(accel, axis.counts_per_mm, axis.gains.sr)))

    def move(idx: list[int], distances_mm: dict[int, float], speed: float, *, capture: bool,
             timeout: float) -> dict[int, int | None]:
        """Relative moves of ``idx``; with ``capture`` stop on the switch (or probe) and return latched counts."""
        axes = sample()
        for i in idx:
            axis, mod = cfg.axes[i], machine.modules[i]
            if capture:
                mod.arm_home((h.input, cfg.probe.input), "abrupt")
            goal = axes[i].counts + round(distances_mm[i] * axis.counts_per_mm * axis.direction)
            mod.load_position(goal, *fixed(axis, speed, cfg.accelerations.positioning))
        latched: dict[int, int | None] = {i: None for i in idx}
        end = machine.clock.now() + timeout
        while True:
            axes = sample()
            for i in idx:
                if capture and latched[i] is None and not axes[i].status & codec.HOME_IN_PROG:
                    if machine.probe_active(axes[i].status):
                        machine.halt("abrupt")
                        raise HomingError(f"the probe touched something while homing {AXES[i].upper()}: "
                                          "the machine stopped; clear the probe and home again")
                    latched[i] = machine.modules[i].home_position()
            if all(axes[i].status & codec.MOVE_DONE for i in idx):
                return latched
            if machine.clock.now() > end:
                machine.halt("abrupt")
                raise HomingError(f"homing {''.join(AXES[i] for i in idx).upper()} took longer than {timeout:.0f} s")
            if virtual:  # a sample costs CPU, not wall time: as a programmed move's samples (the modules latch the
                # switch edge and stop on it by themselves; back to back, three transactions, was 3x the ticks' cost)
                machine.clock.sleep(VIRTUAL_MOVE_POLL_PAUSE)

    for group in h.order:
        idx = [AXES.index(a) for a in group]
        sign = {i: 1.0 if _toward_max(cfg.axes[i]) else -1.0 for i in idx}
        travel = {i: h.search or (cfg.axes[i].max - cfg.axes[i].min + 10.0) for i in idx}
        axes = sample()
        seek = [i for i in idx if not switch_on(axes[i].status)]
        if seek:  # fast towards the switch
            got = move(seek, {i: sign[i] * travel[i] for i in seek}, h.speed, capture=True,
                       timeout=max(travel.values()) / h.speed + 5)
            missing = [AXES[i].upper() for i in seek if got[i] is None]
            if missing:
                raise HomingError(f"home switch of {', '.join(missing)} not found within "
                                  f"{max(travel.values()):.0f} mm: check the switch and its wiring ({h.input})")
        # off the switch, then slowly back onto its edge
        move(idx, {i: -sign[i] * h.backoff for i in idx}, h.speed, capture=False, timeout=h.backoff / h.speed + 5)
        axes = sample()
        stuck = [AXES[i].upper() for i in idx if switch_on(axes[i].status)]
        if stuck:
            raise HomingError(f"home switch of {', '.join(stuck)} still active {h.backoff} mm off it: "
                              "check the switch (stuck?) or raise [homing] backoff")
        got = move(idx, {i: sign[i] * 3 * h.backoff for i in idx}, h.latch_speed, capture=True,
                   timeout=3 * h.backoff / h.latch_speed + 5)
        missing = [AXES[i].upper() for i in idx if got[i] is None]
        if missing:
            raise HomingError(f"home switch of {', '.join(missing)} not found again on the slow approach")
        for i in idx:  # onto the latched edge, then that count becomes 0 = the home coordinate
            axis = cfg.axes[i]
            machine.modules[i].load_position(got[i], *fixed(axis, h.latch_speed, cfg.accelerations.positioning))
        end = machine.clock.now() + 5
        while not all(a.status & codec.MOVE_DONE for a in (sample()[i] for i in idx)):
            if machine.clock.now() > end:
                raise HomingError("the axes did not settle on the home switch edge")
        for i in idx:
            machine.modules[i].reset_position()
    machine.sample()

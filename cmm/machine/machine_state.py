"""What the machine is and does, as plain data: its sampled state, the motion it runs, and the errors a
motion refuses or ends with (shared by :mod:`cmm.machine.motion`, its connection and its jogging)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..nmc import codec
from .status import MotionError, MoveStatus

GROUP = 0x80  # all three axes; X is the leader, so a group START_MOVE is acknowledged
REST_S = 0.01  # machine s within a count of where the axes came to rest, trajectories done: they stand still


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
    counts_per_tick: int = 0  # the module's velocity as it reports it: counts its encoder moved in the last servo tick

    @property
    def words(self) -> list[str]:
        return codec.status_words(self.status, self.aux)

    @property
    def trajectory_done(self) -> bool:
        """The module's move has ended (move done): a trapezoid at its goal, a velocity ramp (a smooth stop
        included) at its target, or the servo off."""
        return bool(self.status & codec.MOVE_DONE)


@dataclass(frozen=True)
class MachineState:
    time: float
    axes: tuple[AxisState, AxisState, AxisState]
    probe_triggered: bool
    jogging: bool
    moving: bool
    resting: float = 0.0  # machine s every trajectory has been done and every axis within a count of where it rested

    @property
    def position(self) -> np.ndarray:
        return np.array([a.mm for a in self.axes])

    @property
    def counts(self) -> tuple[int, int, int]:
        return tuple(a.counts for a in self.axes)  # type: ignore[return-value]

    @property
    def ramps_done(self) -> bool:
        """Every axis's trajectory has ended and its encoder moved no count in the last tick: a jog may end, a
        trapezoid may start (they start from rest)."""
        return all(a.trajectory_done and a.counts_per_tick == 0 for a in self.axes)

    # "Stands still" is judged over a little time, not from one sample: an axis braking under one count per servo tick
    # reads 0 counts on most ticks, and a servo catching up its following error (or ringing) after its trajectory
    # ended passes through 0 counts a tick at each turn. Within a count of where the axes came to rest (a servo holding
    # its place may move a count either way) for REST_S of machine time, they stand.
    @property
    def standing(self) -> bool:
        """Every axis stands: its trajectory has ended and it has stayed within a count of where it came to rest for
        REST_S of machine time."""
        return self.resting >= REST_S


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

"""What the machine is and does, as plain data: its sampled state, the motion it runs, and the errors a
motion refuses or ends with (shared by :mod:`cmm.machine.motion`, its connection and its jogging)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..nmc import codec
from .status import MotionError, MoveStatus

GROUP = 0x80  # all three axes; X is the leader, so a group START_MOVE is acknowledged


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

"""The machine state model: modes, which commands each mode accepts, and the state every front end sees."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any

from ..machine.status import MotionError


class Mode(str, enum.Enum):
    NOT_HOMED = "not homed"
    HOMING = "homing"
    IDLE = "idle"
    MOVING = "moving"
    JOGGING = "jogging"
    PROBING = "probing"
    STOPPED = "stopped"
    ESTOPPED = "e-stopped"
    FAULT = "fault"


class Refused(MotionError):
    """A command the control core does not accept now, in an operator's words (nothing was sent to the machine)."""


class RunStopped(MotionError):
    """A run (routine, program, DMIS, auto-measure, calibration) ended by the operator's STOP or E-STOP: the whole run
    ends, not only its current move, and it says so."""


class ControlError(MotionError):
    """The machine loop could not carry a command out (it is not answering, or the link failed)."""


class CutShort(ControlError):
    """A command a STOP or E-STOP took the link from first: nothing failed, the command was not done."""


SAFETY_COMMANDS = frozenset({"stop", "estop", "jog_release", "cancel", "pause"})  # open to every client the policy lets stop
# writing in the session journal (a note, a routine saved): part of the record, so the control holder or a client
# at the station's own computer, never an anonymous observer on the LAN
RECORD_COMMANDS = frozenset({"record"})

_STILL = {Mode.IDLE, Mode.STOPPED}
ALLOWED: dict[str, frozenset[Mode]] = {
    "jog": frozenset({Mode.IDLE, Mode.NOT_HOMED, Mode.STOPPED, Mode.JOGGING}),
    "move": frozenset(_STILL),
    "step": frozenset(_STILL | {Mode.NOT_HOMED}),
    "probe": frozenset(_STILL),
    "home": frozenset(_STILL | {Mode.NOT_HOMED}),
    "zero": frozenset(_STILL | {Mode.NOT_HOMED}),
    "job": frozenset(_STILL),
    "configure": frozenset(_STILL | {Mode.NOT_HOMED, Mode.FAULT, Mode.ESTOPPED}),
    "reset": frozenset({Mode.ESTOPPED, Mode.STOPPED, Mode.FAULT, Mode.IDLE, Mode.NOT_HOMED}),
    "reconnect": frozenset({Mode.FAULT}),
    "stop": frozenset(Mode),
    "estop": frozenset(Mode),
    "jog_release": frozenset(Mode),
    "cancel": frozenset(Mode),
}
COMMANDS = tuple(ALLOWED)


def refusal(command: str, mode: Mode, reason: str = "", activity: str = "") -> str | None:
    """Why ``command`` is refused in ``mode`` (None when it is accepted)."""
    if mode in ALLOWED[command]:
        return None
    what = {"jog": "jog", "move": "move", "step": "step", "probe": "probe", "home": "home the machine",
            "zero": "zero the axes", "job": "start a routine", "configure": "change the machine set-up",
            "reset": "reset", "reconnect": "reconnect"}.get(command, command)
    if mode is Mode.FAULT:
        return f"cannot {what}: the machine is in fault ({reason}). Reset (or reconnect) first."
    if mode is Mode.ESTOPPED:
        return f"cannot {what}: the emergency stop is latched. Press Reset to re-enable the servos."
    if mode is Mode.NOT_HOMED:
        return f"cannot {what}: the machine is not homed. Run the homing cycle (Home) first."
    if mode is Mode.HOMING:
        return f"cannot {what} while the machine is homing; wait for it or press STOP."
    if mode in (Mode.MOVING, Mode.JOGGING, Mode.PROBING):
        return f"cannot {what}: the machine is busy ({activity or mode.value}); wait or press STOP."
    if command == "reconnect":
        return "reconnect is only needed after a fault of the link"
    return f"cannot {what} while the machine is {mode.value}"


@dataclass(frozen=True)
class StopReport:
    """What a STOP or E-STOP did: ``ok`` only when every module acknowledged it."""

    ok: bool
    message: str
    failed_axes: tuple[str, ...] = ()


# the activity while the axes brake after the operator's STOP (mode MOVING: never "stopped" while an axis still moves)
STOPPING = "stopping (STOP pressed)"


@dataclass(frozen=True)
class ControlState:
    """One consistent picture for every front end (position, mode and why)."""

    mode: Mode
    reason: str = ""  # why the machine is in fault / e-stopped / stopped
    activity: str = ""  # what it is doing (move description, routine name)
    homed: bool = False
    link_ok: bool = True
    machine: Any = None  # cmm.machine.motion.MachineState of the last sample (None before the first)
    seq: int = 0
    allowed: frozenset[str] = field(default_factory=frozenset)
    link_warning: str = ""  # a recent link warning (a reply late or missing, retried): nothing was stopped for it

    @property
    def position(self) -> Any:
        return None if self.machine is None else self.machine.position

    @property
    def stop_in_force(self) -> bool:
        """The operator's STOP holds the machine: still braking (moving, :data:`STOPPING`) or standing stopped."""
        return self.mode is Mode.STOPPED or self.activity == STOPPING

    def to_dict(self) -> dict[str, Any]:
        m = self.machine
        return {"mode": self.mode.value, "reason": self.reason, "activity": self.activity, "homed": self.homed,
                "link_ok": self.link_ok, "link_warning": self.link_warning, "allowed": sorted(self.allowed),
                "position": None if m is None else [float(v) for v in m.position],
                "probe": None if m is None else bool(m.probe_triggered)}

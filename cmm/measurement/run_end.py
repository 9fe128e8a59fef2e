"""Runs end safe: every routine, DMIS program and auto-measure leaves the tip at the clearance plane.

A run's last hit retracts only a few millimetres from the surface (the probing cycle's retract); left there (a
routine ended with the tip beside the cone at part Z 43), the next run's first straight move was refused ("the
straight line passes 0.29 mm from the part"). :func:`end_at_clearance` climbs straight up to the part's clearance
plane (the motion rails' own, :meth:`Workspace.clearance_z`) through the command API as the run's client, so the
access policy, STOP and the rails apply as to any move. It moves nothing when the tip is at or above the plane,
without a part, or when the machine is not idle (a stop, a fault or an E-STOP ended the run: the operator's
stop stands, nothing moves on its own after it).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def clearance_target(api: Any, here: Any = None) -> np.ndarray | None:
    """Straight above the tip (or ``here``, machine mm: where a previewed run ends) at the clearance plane; None
    when no climb is needed or possible (the control core's ``clearance_target`` query)."""
    target = api.invoke(None, "clearance_target", here=None if here is None else [float(v) for v in here])
    return None if target is None else np.asarray(target, float)


def end_at_clearance(api: Any, client: Any, timeout: float = 120.0) -> float | None:
    """Climb to the clearance plane after a run (see the module docstring), through the command API ``api`` as
    ``client``. Returns the machine Z reached, None when nothing moved. A refused or failed climb raises the
    command API's error (the caller tells it)."""
    state = api.invoke(client, "state")
    mode = str(getattr(state.mode, "value", state.mode))
    if state.stop_in_force or mode in ("e-stopped", "fault", "not homed"):  # a stop ended the run: it stands (or
        return None  # still brakes: it will stand, and nothing moves on its own after the press)
    target = clearance_target(api)
    if target is None:
        return None
    api.invoke(client, "move", target=[float(x) for x in target], frame="machine", path="clearance").wait(timeout)
    return float(target[2])

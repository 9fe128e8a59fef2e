"""The one jog-hold pipeline: front ends feed it hold and release events; it clamps, sequences and times out.

Every front end that jogs (the viser page's hold buttons, the pendant page, a gamepad or keyboard through
the pendant) does only this: while the operator holds a jog, call :meth:`JogHolds.hold` with the velocity
each time the front end hears it is still held; when it is let go, :meth:`JogHolds.release`. The pipeline
does the rest, the same for everyone:

- **Speed clamp.** Each axis to ``speeds.jog_fast``; an armed jog (manual probing) to the speed the probe was
  qualified at (``probe_speed``). A clamped jog runs, and ``hold`` says so in a sentence (shown once).
  Non-finite or malformed velocities are refused with a sentence. An axis at the end of its travel it would
  jog towards is left out and the operator told so; a jog of only such axes is refused with that sentence.
- **Release sequence.** A release ends the jog at once, ahead of anything queued (the control core's
  ``jog_release``: the link process hears it first); a let-go from a client that may not jog (it has no jog
  running) is ignored, so an observer's key-up never ends the holder's jog. Each hold carries the count of
  releases its client had seen when the event arrived; a hold queued before a later release is dropped, so a
  late refresh never restarts a released jog. ``settle`` drops holds that arrive that soon after the client's release (a front
  end whose events can run out of order, like viser's thread pool).
- **Grace.** A held jog must be refreshed within the machine's dead-man, ``[jog] deadman_timeout``
  (0.15 s): front ends refresh at 20-25 Hz. The timer runs next to the bus (the link process on a real port,
  the machine loop on the in-process simulator), so a silent front end stops whatever this process is doing;
  there is no second timer here to drift from it. Each hold carries the moment its front end *heard* it
  (``heard``, the machine clock; the front end stamps it as its message arrives): the dead-man runs from
  that moment, wherever the hold is taken later. A hold that waited in this process (a busy station, a
  thread pool, the machine loop's queue) can never extend a jog past ``heard + grace``, and one heard longer
  ago than the grace neither starts nor refreshes a jog.
- **One hit per touch.** After an armed jog took a hit (and backed off), the client's holds start nothing until
  it lets go (a release: button, key, stick back to centre); ``hold`` says so once (:data:`TOUCHED`). Only a
  new press takes the next hit, on every front end alike.
- **Never waits.** ``hold`` checks access and the machine's mode at once (a refusal comes back as a
  sentence), tells the link process the operator is still there, and queues the jog for the machine loop
  without waiting for it: a front end's event loop never blocks on the machine. A newer hold of the same
  client replaces one still queued. Errors the machine loop finds later (a deflected probe, a fault) go to
  the hold's ``on_error``.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable

import numpy as np

from .modes import Refused

ErrorFn = Callable[[str], None]
TOUCHED = "hit taken: let go, then press again for the next hit"
AT_END = 0.005  # mm: an axis this close to the end of its travel counts as at it (a jog there would not start)


class JogHolds:
    def __init__(self, controller: Any, *, probe_speed: Callable[[], float] | None = None) -> None:
        self.controller = controller
        self.config = controller.config
        self.probe_speed = probe_speed or (lambda: float(self.config.speeds.probing))
        self._released_at: dict[Any, float] = {}

    @property
    def grace(self) -> float:
        """Seconds a held jog lasts after its newest hold: the machine's dead-man."""
        return float(self.config.deadman_timeout)

    def clamp(self, velocity: Any, *, probe: bool = False) -> tuple[np.ndarray, str | None]:
        """The velocity the machine may run (mm/s per axis) and, when it had to be limited, why."""
        try:
            v = np.asarray(velocity, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise Refused("a jog needs three finite velocities in mm/s (X, Y, Z)") from None
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise Refused("a jog needs three finite velocities in mm/s (X, Y, Z)")
        fast = float(self.config.speeds.jog_fast)
        note = None
        if np.any(np.abs(v) > fast):
            note = (f"jog speed {float(np.max(np.abs(v))):.4g} mm/s limited to the fastest jog speed, "
                    f"{fast:g} mm/s")
            v = np.clip(v, -fast, fast)
        if probe:
            limit = float(self.probe_speed())
            speed = float(np.linalg.norm(v))
            if speed > limit > 0:
                v = v * (limit / speed)
                note = note or (f"armed jog limited to the speed the probe was qualified at, {limit:g} mm/s")
        return v, note

    def travel(self, v: np.ndarray) -> tuple[np.ndarray, str | None]:
        """``v`` without the axes that stand at the end of their travel they would jog towards, and why.

        The machine would not move them (it never jogs further out of the travel): the operator is told
        which axis is at which end instead of a jog that silently does not start.
        """
        state = getattr(self.controller.state, "machine", None)
        if state is None:
            return v, None
        pos = state.position
        v = np.array(v, dtype=np.float64)
        blocked = []
        for i, axis in enumerate(self.config.axes):
            name = axis.name.upper()
            if v[i] > 0 and pos[i] >= axis.max - AT_END:
                blocked.append(f"{name} is at the end of its travel ({axis.max:g} mm): it can only jog -{name}")
            elif v[i] < 0 and pos[i] <= axis.min + AT_END:
                blocked.append(f"{name} is at the end of its travel ({axis.min:g} mm): it can only jog +{name}")
            else:
                continue
            v[i] = 0.0
        if not blocked:
            return v, None
        why = "; ".join(blocked)
        return v, (why if not np.any(v) else f"{why}. The jog runs on the other axes.")

    def ticket(self, client: Any) -> int:
        """The release count of ``client`` now: a front end that queues events takes it when one arrives."""
        return self.controller.release_seq(client)

    def hold(self, client: Any, velocity: Any, *, probe: bool = False, after: int | None = None,
             settle: float = 0.0, on_error: ErrorFn | None = None, heard: float | None = None) -> str | None:
        """The operator still holds this jog (refresh it within :attr:`grace`). Returns a sentence when the
        velocity was limited; raises Refused (with the operator's sentence) when the jog is not allowed now.
        All zeros is a release. ``heard``: when the front end received this hold (machine clock; default now)."""
        key = getattr(client, "id", client)
        if settle > 0 and time.monotonic() - self._released_at.get(key, -math.inf) < settle:
            return None  # an event from before the release, run late
        v, note = self.clamp(velocity, probe=probe)
        if not np.any(v):
            self.release(client, let_go=True)
            return note
        self.controller.check_access(client, "jog")  # an observer is told to take control, not where the axes stand
        if probe and self.controller.touched(client):
            return TOUCHED  # one hit per touch: the held jog stays stopped until the operator lets go
        v, at_end = self.travel(v)
        if not np.any(v):  # every axis asked for stands at the end it would jog to
            raise Refused(at_end)
        note = note or at_end
        self.controller.jog(client, v, probe=probe, after=self.ticket(client) if after is None else after,
                            wait=False, on_error=on_error, heard=heard)
        return note

    def release(self, client: Any, *, let_go: bool = False, lapse: bool = False) -> bool:
        """The operator let go (or went away): the jog ends now, whatever is queued. ``let_go``: a key or button
        let go with no jog of this client known to run; it ends the jog only when ``client`` may jog (holds
        control): an observer's let-go is ignored quietly, so it never ends the holder's jog. True when the
        release was sent."""
        if let_go and self.controller.policy.refusal(client, "jog") is not None:
            return False
        self._released_at[getattr(client, "id", client)] = time.monotonic()
        self.controller.jog_release(client, keep_touch=lapse)  # a lapse is no let-go: a hit taken stays taken
        return True

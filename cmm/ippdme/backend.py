"""The narrow machine interface the I++ DME executor drives, and its implementation on the station.

Everything in machine coordinates (mm, tip centre). Blocking calls return
when the motion is over and raise :class:`~cmm.machine.status.MotionError`
(or a subclass) when it failed or was stopped; ``stop()`` from another
thread makes a blocked call return with an error and leaves the machine
stopped.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Protocol

import numpy as np

from ..api import Client, CommandError
from ..control import Mode
from ..control.access import is_local_connection


class Backend(Protocol):
    config: Any  # MachineConfig: travel, speeds, probe distances
    homed: bool
    estopped: bool  # latched until the operator resets it

    def position(self) -> np.ndarray: ...
    def check_target(self, target: np.ndarray) -> np.ndarray: ...
    def move_to(self, target: np.ndarray, speed: float, accel: float) -> np.ndarray: ...
    def probe(self, nominal: np.ndarray, direction: np.ndarray, *, speed: float, accel: float, approach: float,
              search: float, retract: float, rapid_speed: float) -> np.ndarray: ...
    def home(self) -> None: ...
    def stop(self) -> None: ...
    def probes(self) -> list[tuple[str, float]]: ...
    def subscribe_state(self, fn: Callable[[Any], None]) -> Callable[[], None]: ...
    def on_emergency_stop(self, fn: Callable[[str], None]) -> Callable[[], None]: ...
    def begin_session(self, client: str) -> str: ...
    def for_client(self, peer: str) -> "Backend": ...
    def acquire(self) -> str | None: ...
    def release(self) -> None: ...
    def end_session(self) -> None: ...
    def note(self, text: str) -> None: ...


MOVING_MODES = ("moving", "jogging", "probing", "homing")


def busy_holder(api: Any, client: Any) -> str | None:
    """Why an I++ client may not take control now, naming the holder; None when it may (the API's queries).

    The rule (docs/reliability.md): a connecting I++ client takes control only from nobody, or from a holder whose
    machine stands still with nothing running (no jog, move, probe, homing, routine, program, auto-measure or
    qualification). A pendant operator jogging, or a routine running, keeps control: the client gets an I++
    error naming the holder and what the machine does, and connects again after the holder has released
    control (Release in the page, or the pendant closed) or stopped. Nothing waits: a client is never left
    hanging on a connection the operator does not know about."""
    control = api.invoke(client, "control")
    holder = control["holder"]
    if holder is None or control["yours"]:
        return None
    state = api.invoke(client, "state")
    mode = str(getattr(state.mode, "value", state.mode))
    machine = state.machine
    turning = machine is not None and any(abs(a.velocity) > 0 for a in machine.axes)
    jobs = [job["description"] for job in api.invoke(client, "job")]
    if mode not in MOVING_MODES and not turning and not jobs:
        return None
    doing = f"{jobs[0]} is running" if jobs else (f"the machine is {mode}" if mode in MOVING_MODES
                                                   else "the machine is moving")
    return (f"{holder} holds the station's control and {doing}: an I++ client does not take "
            f"control from them. Ask {holder} to stop and release control (Release in the page), "
            "then connect again")


class StationBackend:
    """The I++ DME backend on a started station's command API (:class:`cmm.api.CommandAPI`), the only object it gets.

    An adapter that only translates: every command goes to the command API
    (its verbs, queries and event streams) with this connection's client id, so the
    core's access policy and motion rails apply: the I++ client takes the
    station's one control holder (browsers then observe and can still stop the
    machine). GoTo is a straight ``move`` and PtMeas a ``probe`` with the
    client's GoToPar/PtMeasPar (speeds, acceleration, approach, search and
    retract distances) and a straight rapid, both refused when the line is not
    proven free of the part. The station records every probed point
    (journal, browser), so an I++ session is recorded like a browser one.
    """

    def __init__(self, api: Any, client: str = "ippdme", *, local: bool = True, peer: str | None = None,
                 probe_name: str = "Probe1", grants_control: bool = False,
                 user: tuple[str, str] | None = None) -> None:
        self.commands = api  # the verbs every front end sends
        # grants_control: the listener was opened by the operator for I++ clients (its address chosen at start-up),
        # so its clients take control without the access code they have no way to give
        self.grants_control = grants_control
        # user: (name, role) the operator named at start-up (--ippdme-user): I++ DME has no login of its own
        self.user = user
        self.client = Client(client, local=local, authenticated=local or user is not None,
                             listener_grants_control=grants_control, user=None if user is None else user[0],
                             role=None if user is None else user[1])
        self.peer = peer
        self.probe_name = probe_name
        self.config = api.invoke(self.client, "machine_config")  # travel, speeds, probe distances, homing

    def for_client(self, peer: str) -> "StationBackend":
        """The backend of one connection: its own client id for the control core (``peer`` is host:port)."""
        host = peer.rsplit(":", 1)[0].strip("[]")
        local = is_local_connection(host)
        return StationBackend(self.commands, f"ippdme {peer}", local=local, peer=host, probe_name=self.probe_name,
                              grants_control=self.grants_control, user=self.user)

    # --- control --------------------------------------------------------------------
    def acquire(self) -> str | None:
        """Take the station's control for this client (the take_control verb); the reason when refused. Never
        from a holder whose machine is moving or running something (docs/reliability.md): the holder is named."""
        busy = busy_holder(self.commands, self.client)
        if busy is not None:
            return busy
        try:
            self.commands.invoke(self.client, "take_control", peer=self.peer)
        except Exception as exc:  # noqa: BLE001 - the refusal is told to the I++ client in its words
            return str(exc) or type(exc).__name__
        return None

    def release(self) -> None:
        try:
            self.commands.invoke(self.client, "release_control")
        except Exception:  # noqa: BLE001 - a connection that ends releases what it can; nothing to tell
            pass

    # --- queries --------------------------------------------------------------------
    @property
    def homed(self) -> bool:
        return bool(self.commands.invoke(self.client, "state").homed)

    def position(self) -> np.ndarray:
        return np.asarray(self.commands.invoke(self.client, "position", frame="machine"), dtype=float)

    def check_target(self, target: np.ndarray) -> np.ndarray:
        return self.commands.invoke(self.client, "check_target", target=target)

    def _probe_list(self) -> dict[str, Any]:
        """The calibration's ``probes`` query (a station without a calibration service has none: no list)."""
        try:
            return self.commands.invoke(self.client, "probes")
        except CommandError as exc:
            if exc.code != "unknown_method":
                raise
            return {"probes": [], "folder": None, "problem": ""}

    def probes(self) -> list[tuple[str, float]]:
        """The station's probe list (the Calibration tab's): each probe's qualified radius (the one in use: the live
        radius; one never qualified: its nominal radius). Without a calibration service, or with a list that cannot
        be read: one probe, the one in use."""
        rows = self._probe_list()["probes"]
        live = float(self.commands.invoke(self.client, "tip_radius"))
        if not rows:
            return [(self.probe_name, live)]
        return [(r["name"], live if r["selected"] else
                 float(r["tip_radius"] if r["tip_radius"] is not None else r["tip_diameter"] / 2)) for r in rows]

    def change_tool(self, name: str) -> None:
        """ChangeTool to one of the station's probes: it becomes the probe in use (as *Use this probe* in the
        Calibration tab). Tools that are not station probes (RefTool, NoTool ...) and a station without a
        calibration folder change nothing here; a list that cannot be read is an error (the client is told)."""
        listing = self._probe_list()
        if listing["folder"] is None:
            return
        if listing["problem"]:
            raise ValueError(listing["problem"])
        selected = next((r["name"] for r in listing["probes"] if r["selected"]), None)
        if name != selected and name in {r["name"] for r in listing["probes"]}:
            self.commands.invoke(self.client, "select_probe", name=name)

    def subscribe_state(self, fn: Callable[[Any], None]) -> Callable[[], None]:
        """``fn(machine_state)`` (time, position) after samples, on the core's dispatcher thread."""
        def forward(state: Any) -> None:
            if state.machine is not None:
                fn(state.machine)
        return self.commands.listen(self.client, "state", forward)

    def on_emergency_stop(self, fn: Callable[[str], None]) -> Callable[[], None]:
        """``fn(message)`` when anyone (browser, pendant, this or another client) E-stops the machine."""
        def forward(kind: str, info: dict) -> None:
            if kind == "estop":
                fn(str(info.get("message") or "emergency stop"))
        return self.commands.listen(self.client, "events", forward)

    @property
    def estopped(self) -> bool:
        return self.commands.invoke(self.client, "state").mode is Mode.ESTOPPED

    # --- motion: the command API's move and probe, straight lines as I++ DME means them ---------
    def move_to(self, target: np.ndarray, speed: float, accel: float) -> np.ndarray:
        return self.commands.invoke(self.client, "move", target=target, frame="machine", path="straight", speed=speed,
                                    accel=accel).wait()

    def probe(self, nominal: np.ndarray, direction: np.ndarray, *, speed: float, accel: float, approach: float,
              search: float, retract: float, rapid_speed: float) -> np.ndarray:
        """Probe ``nominal`` coming along ``-direction`` (``direction`` points out of the material).

        Returns the latched tip centre (what I++ DME reports); the station records the hit.
        """
        hit = self.commands.invoke(
            self.client, "probe", target=nominal, approach=-np.asarray(direction, float), frame="machine",
            path="straight", speed=speed, accel=accel, approach_distance=approach, search_distance=search,
            retract_distance=retract, rapid_speed=rapid_speed).wait()
        return np.asarray(hit.machine, dtype=float)

    def home(self) -> None:
        """The homing cycle; on a machine without home switches, a move to the home coordinates (Z up first)."""
        if self.config.homing.method == "none":
            home = [a.home for a in self.config.axes]
            self.commands.invoke(self.client, "move", target=home, frame="machine").wait()
        else:
            self.commands.invoke(self.client, "home")

    def stop(self) -> None:
        """Stop any motion now (AbortE, client gone); a blocked call returns with an error."""
        self.commands.invoke(None, "stop")  # the station's own stop: never refused

    # --- journal ----------------------------------------------------------------------
    def begin_session(self, client: str) -> str:
        path = self.commands.invoke(self.client, "new_session", name=time.strftime("ippdme-%Y%m%d-%H%M%S"))
        self.note(f"I++ DME session started by {client}")
        return str(path)

    def end_session(self) -> None:
        self.note("I++ DME session ended")

    def note(self, text: str) -> None:
        """What the server saw (session start/end, an error, a disconnect), written as the station's own note:
        a remote client that lost control to a browser still has its end in the journal."""
        self.commands.invoke(None, "note", text=text)

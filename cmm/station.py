"""The station: the composition root. It builds the machine, the control core, the part and the session.

Motion goes through the control core (:mod:`cmm.control`, ``station.controller``):
front ends call ``station.controller.<command>(client_id, ...)`` so the access
policy and the state model are checked in one place. The motion methods here
(``move_to``, ``jog``, ``probe`` ...) are the same commands for scripts and
tests, sent as the station itself (client ``None``). Measurement actions (hits,
features, sessions) live here. Thread-safe: the UI calls it from several
client threads; hits are journalled on the control core's dispatcher thread.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .calibration.service import CalibrationService
from .control import Controller, ControlState, StopReport
from .machine.config import ConfigError, MachineConfig, load
from .machine.config import load as load_config  # front ends read the machine configuration through the station
from .machine.motion import Machine, MachineState
from .machine.probing import Hit, Prober
from .machine.status import MotionError, MoveStatus
from .metrology.features import FitError, FitResult
from .metrology.mesh import signed_deviation
from .metrology.pick import NominalFeature, PickResult, pick, suggest_feature
from .nmc.trace import ByteTrace
from .session.journal import Journal
from .session.reevaluate import feature_fields, fit_hit_records
from .session.model import file_sha256, machine_snapshot, mesh_sha256
from .session.store import check_name, is_url, open_store

FEATURE_KINDS = ("point", "line", "plane", "circle", "sphere", "cylinder", "cone")


class StationError(RuntimeError):
    """An action the station refuses, in an operator's words."""


@dataclass
class Part:
    name: str
    mesh: Any  # trimesh.Trimesh in part coordinates
    pose: np.ndarray  # part -> machine (the station's belief; alignment refines it)
    nominal_features: dict[str, NominalFeature] = field(default_factory=dict)


@dataclass
class Feature:
    id: int
    name: str
    kind: str
    method: str
    hit_ids: list[int]
    result: FitResult
    nominal: NominalFeature | None = None
    tolerance: dict[str, float] | None = None  # {"size", "form", "location", "position"}: DEFAULT_TOLERANCE otherwise

    def summary(self) -> dict[str, Any]:
        return {"id": self.id, "name": self.name, "hit_ids": self.hit_ids, **self.result.summary(),
                "nominal": None if self.nominal is None else self.nominal.to_dict(), "tolerance": self.tolerance}


@dataclass
class ConstructedFeature:
    """A feature constructed from two others (intersection, distance, angle, mid-point)."""

    id: int
    name: str
    operation: str
    operands: tuple[int, int]
    result: Any  # cmm.metrology.construct.Constructed
    nominal: Any = None  # the same construction on the operands' nominals (Constructed) or None
    tolerance: dict[str, float] | None = None

    def to_event(self) -> dict[str, Any]:
        return {"id": self.id, "name": self.name, "operation": self.operation, "operands": list(self.operands),
                "result": self.result.summary(), "nominal": None if self.nominal is None else self.nominal.summary(),
                "tolerance": self.tolerance}


INFO_FIELDS = ("part_number", "drawing", "operator", "machine_name", "temperature", "remarks")
TOLERANCE_KEYS = ("size", "form", "location", "position", "angle")


class Station:
    """Wire machine, probe, part and session together.

    ``port`` None or "sim" starts the simulated CMM served in real time over
    TCP on loopback, and the driver talks to it through that byte stream.
    A ``sim://?cmm=1`` URL opens it in-process instead, on the virtual clock
    by default (tests) or ``&clock=realtime``; ``self.sim`` is the simulated CMM.
    """

    def __init__(self, config: MachineConfig | None = None, *, port: str | None = None, baud: int | None = None,
                 part_path: str | Path | None = None, session_dir: str | Path = "sessions",
                 sim_settings: Any = None, calibration_dir: str | Path | None = None) -> None:
        self.config = config or load()
        if baud is not None:
            self.config = self.config.with_link(baud=baud)
        self.trace = ByteTrace()
        self.sim = None
        self._served = None
        self.lock = threading.RLock()
        self._sim_world_url: str | None = None
        port = port or self.config.link.port
        if port == "sim" or (isinstance(port, str) and port.startswith("sim://")):
            self.part: Part | None
            self.part, port = self._start_simulator(port, sim_settings, part_path)
        else:
            self.part = None
        self.port = port
        self.machine = Machine(self.config, port, trace=self.trace)
        self.prober = Prober(self.machine)
        self.controller = Controller(self.machine, self.prober)
        self.controller.on_hit(self._on_hit)
        self.hits: dict[int, Hit] = {}
        self.deleted: dict[int, Hit] = {}
        self._undo: list[tuple[str, int]] = []
        self.features: dict[int, Feature] = {}
        self.constructed: dict[int, ConstructedFeature] = {}
        self._next_hit = 1
        self._next_feature = 1
        self.last_hit: Hit | None = None
        self.events: list[tuple[float, str, str]] = []  # (time, kind, message) for the UI
        self._listeners: list[Callable[[str, Any], None]] = []
        self.session_dir = session_dir if is_url(session_dir) else Path(session_dir)  # or a postgresql:// URL
        self.journal: Journal | None = None
        self.controller.subscribe(self._notify)
        self.calibration_log: list[str] = []
        self.calibration_status: dict[str, Any] = {"probe": None, "machine": None, "problems": []}
        self.info: dict[str, Any] = {}  # report header: part number, drawing, operator, temperature ...
        self.aligned = False  # an alignment was made since the part was loaded
        self.calibration_dir = None if calibration_dir is None else Path(calibration_dir)  # records are read and written here
        self.calibration = CalibrationService(self)  # the routines, records and results, for every front end
        if calibration_dir is not None:
            self.load_calibration(calibration_dir)
        if part_path is not None and self.sim is None:
            self.load_part(part_path)

    def _start_simulator(self, port: str, settings: Any, part_path: str | Path | None) -> tuple[Part, str]:
        """The simulated CMM ("sim": served over TCP on loopback in real time; "sim://...": in-process
        on the world that URL names); a user's part is placed on its table. Returns (part, port URL).

        The part lies where the station believes it is (its lowest corner at the
        nominal set-up position) up to the simulator's deliberate set-up error.
        """
        from dataclasses import replace

        from .metrology.mesh import load_part
        from .sim.cmm_sim import NOMINAL_PART_POSE, TRUE_PART_POSE, CmmSimSettings, SimulatedCMM
        from .sim.serve import serve_tcp

        settings = settings or CmmSimSettings()
        nominal_pose = NOMINAL_PART_POSE.copy()
        name = "sample part"
        if part_path is not None:
            mesh = load_part(part_path)
            shift = np.eye(4)
            shift[:3, 3] = -mesh.bounds[0]
            nominal_pose = nominal_pose @ shift
            settings = replace(settings, part_mesh=mesh, part_pose=TRUE_PART_POSE @ shift)
            name = Path(part_path).name
        if port == "sim":
            self.sim = SimulatedCMM(self.config, settings, wire_time=True, realtime=True)
            self._add_home_switches()
            self._served = serve_tcp(self.sim.network, "127.0.0.1", 0)
            port = self._served.url
        else:
            from .sim.url import open_world, parse

            if not parse(port).cmm:
                raise StationError(f"the station needs the simulated CMM: add cmm=1 to {port!r}")
            world = open_world(port, config=self.config, settings=settings)
            if not parse(port).name:  # a world made for this station goes with it; a named one is its owner's
                self._sim_world_url = world.url
            self.sim, port = world.cmm, world.url
            self._add_home_switches()
        return Part(name, self.sim.part_mesh, nominal_pose, dict(self.sim.nominal_features)), port

    def _add_home_switches(self) -> None:
        """The simulated machine gets the home switches the configuration's homing cycle looks for."""
        if not getattr(self.sim, "home_switches", None):
            from .sim.home_switches import for_homing

            self.sim.home_switches = for_homing(self.sim, self.config.homing)

    @property
    def simulated(self) -> bool:
        return self.sim is not None

    def place_sim_artifacts(self, spheres: list) -> None:
        """On the simulator: the operator sets up artifacts [(centre, diameter)]; under the simulator's lock, so
        its servo ticks never see the world half changed."""
        if self.sim is None:
            raise StationError("there is no simulator: place the artifact by hand")
        with self.sim.network.lock:
            self.sim.place_artifacts(spheres)

    # --- life cycle -----------------------------------------------------------

    def start(self, session_name: str | None = None, *, home: bool = False) -> "Station":
        """Connect the modules, run the machine loop, open a session; ``home`` runs the homing cycle too."""
        self.controller.connect()
        self.controller.start()
        self.new_session(session_name)
        if home:
            self.home()
        return self

    def close(self) -> None:
        self.controller.close()
        if self._served is not None:
            self._served.close()
        if self._sim_world_url is not None:
            from .sim.url import release

            release(self._sim_world_url)
        if self.journal is not None:
            self.journal.close()

    def __enter__(self) -> "Station":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def subscribe(self, fn: Callable[[str, Any], None]) -> None:
        """Station events: 'hit', 'hits', 'feature', 'features', 'part', plus the control core's events
        ('mode', 'fault', 'stop', 'estop', 'contact', 'deadman', 'limit', 'homed', 'error' ...)."""
        self._listeners.append(fn)

    def _notify(self, kind: str, info: Any) -> None:
        if kind == "hit" and isinstance(info, dict):
            return  # the control core's hit event: _on_hit has notified already, with the hit id
        if kind in ("contact", "deadman", "limit", "error", "estop", "fault", "stop", "reset", "reconnect"):
            from .session.wording import event_text

            text = event_text(kind, info)
            self.events.append((time.time(), kind, text))
            try:
                self._record("error" if kind in ("contact", "error", "fault", "estop") else "event",
                             source=f"machine:{kind}", message=text)
            except Exception:  # noqa: BLE001 - the session may be closing or the disk full; the event is still shown
                pass
        for fn in list(self._listeners):
            try:
                fn(kind, info)
            except Exception as exc:  # a broken listener must not stop the machine
                self.events.append((time.time(), "error", f"listener failed: {exc}"))

    def subscribe_state(self, fn: Callable[[ControlState], None]) -> Callable[[], None]:
        """The control state (mode, reason, positions in ``.machine``) after samples, coalesced."""
        return self.controller.subscribe_state(fn)

    @property
    def state(self) -> MachineState | None:
        return self.machine.state

    @property
    def control_state(self) -> ControlState:
        return self.controller.state

    @property
    def probe_settings(self) -> Any:
        """The probe in use (stylus radius, pre-travel), for front ends to show (read only)."""
        return self.prober.settings

    def link_modules(self) -> list[Any]:
        """The modules found on the link at start-up (address, type, version), for front ends to show."""
        return list(getattr(self.machine.bus, "modules", None) or [])

    @property
    def samples(self) -> int:
        """Samples read from the modules so far (the status bar's link rate)."""
        return int(getattr(self.machine, "samples", 0))

    @property
    def link_baud(self) -> int:
        return int(getattr(self.machine.bus, "baud", self.config.link.baud))

    def link_trace(self, last: int = 30) -> str:
        """The last NMC bytes sent and received (read from the link process on a real port)."""
        return self.machine.bus.trace.dump(last=last)

    def load_calibration(self, directory: str | Path = "calibration") -> list[str]:
        """Apply calibration/probe.toml (ProbeSettings) and calibration/machine.toml (machine.correction).

        A missing record leaves the nominal settings; a malformed one is reported and not applied.
        """
        from .calibration.records import apply_calibration, load_station_calibration

        self.calibration_dir = Path(directory)
        loaded = load_station_calibration(directory)
        with self.lock:
            applied = self.controller.configure(None, lambda: apply_calibration(loaded, self.machine, self.prober))
        for problem in loaded.problems:
            self.events.append((time.time(), "error", f"calibration record refused: {problem}"))
        self.calibration_log = applied + [f"refused: {p}" for p in loaded.problems]
        self.calibration_status = {
            "probe": None if loaded.probe is None else {"date": loaded.probe.date, "tip_radius": loaded.probe.tip_radius,
                                                        "artifact": loaded.probe.artifact,
                                                        "probing_speed": loaded.probe.probing_speed},
            "machine": None if loaded.machine is None else {"date": loaded.machine.date,
                                                            "scale_ppm": list(loaded.machine.scale_ppm),
                                                            "squareness_urad": list(loaded.machine.squareness_urad)},
            "problems": list(loaded.problems)}
        return self.calibration_log

    def apply_calibration(self, loaded: Any, client: str | None = None) -> list[str]:
        """Apply loaded calibration records to the live machine and probe (in the machine loop, while still)."""
        from .calibration.records import apply_calibration

        with self.lock:
            return self.controller.configure(client, lambda: apply_calibration(loaded, self.machine, self.prober))

    # --- session ----------------------------------------------------------------

    def new_session(self, name: str | None = None) -> Path | str:
        stamp = time.strftime("session-%Y%m%d-%H%M%S")
        name = stamp if name is None else check_name(name)  # whatever the caller: no "../x", no absolute paths
        with self.lock:
            if self.journal is not None:
                self.journal.close()
            if is_url(self.session_dir):
                self.journal = open_store(self.session_dir).create(name, append=True)  # type: ignore[assignment]
                path: Path | str = f"{name}"
            else:
                path = self.session_dir / f"{name}.jsonl"
                for n in range(2, 100):  # two stations started in the same second get their own sessions
                    if name != stamp or not path.exists():
                        break
                    path = self.session_dir / f"{stamp}-{n}.jsonl"
                self.journal = Journal(path)
            part = self.part
            self.journal.append("start", port=str(self.port),  # configuration + calibration snapshot
                                **machine_snapshot(self.config, self.machine.correction, self.prober.settings),
                                calibration=self.calibration_status,
                                part=None if part is None else part.name,
                                part_pose=None if part is None else part.pose,
                                part_sha256=None if part is None else mesh_sha256(part.mesh),
                                part_path=None if part is None else part.mesh.metadata.get("path"))
            if self.info:
                self.journal.append("info", **self.info)
            return path

    def set_info(self, **fields: Any) -> dict[str, Any]:
        """Report header fields (part_number, drawing, operator, machine_name, temperature in deg C, remarks)."""
        unknown = sorted(set(fields) - set(INFO_FIELDS))
        if unknown:
            raise StationError(f"unknown report field(s) {', '.join(unknown)}; use {', '.join(INFO_FIELDS)}")
        clean: dict[str, Any] = {}
        for k, v in fields.items():
            if k == "temperature" and v not in (None, ""):
                try:
                    t = float(v)
                except (TypeError, ValueError):
                    raise StationError(f"the temperature must be a number of degrees Celsius, got {v!r}") from None
                if not -50.0 <= t <= 100.0:
                    raise StationError(f"a temperature of {t} °C is not plausible for a measuring room")
                clean[k] = t
            else:
                clean[k] = "" if v is None else str(v).strip()
        with self.lock:
            self.info.update(clean)
            self._record("info", **clean)
        self._notify("info", dict(self.info))
        return dict(self.info)

    def _record(self, kind: str, **data: Any) -> None:
        if self.journal is not None:
            self.journal.append(kind, **data)

    # --- part -------------------------------------------------------------------

    def load_part(self, path: str | Path, pose: np.ndarray | None = None) -> Part:
        from .metrology.mesh import load_part

        mesh = load_part(path)
        mesh.metadata["sha256"], mesh.metadata["path"] = file_sha256(path), str(Path(path).resolve())
        with self.lock:
            self.part = Part(Path(path).name, mesh, np.eye(4) if pose is None else np.asarray(pose, float))
            self.aligned = False
            self._record("part", name=self.part.name, pose=self.part.pose, sha256=mesh.metadata["sha256"],
                         path=mesh.metadata["path"]) if self.journal else None
        self._notify("part", self.part)
        return self.part

    def pick(self, origin: Any, direction: Any) -> tuple[PickResult, NominalFeature | None] | None:
        """Ray pick on the part: hit point and normal (machine coordinates) and a suggested nominal feature."""
        if self.part is None:
            raise StationError("no part is loaded")
        hit = pick(self.part.mesh, self.part.pose, origin, direction)
        if hit is None:
            return None
        try:
            suggestion = suggest_feature(self.part.mesh, hit.face_id, self.part.pose)
            nominal = suggestion.feature if suggestion is not None else None
        except Exception:  # noqa: BLE001 - a suggestion is optional help
            nominal = None
        return hit, nominal

    # --- motion (the station's own commands: client None; front ends call self.controller with their id) ----

    def move_to(self, target: Any, speed: float | None = None, client: str | None = None) -> MoveStatus:
        return self.controller.move_to(client, target, speed)

    def above_point(self, point: Any, normal: Any, clearance: float | None = None) -> np.ndarray:
        """The tip position ``clearance`` mm above a surface point along its normal."""
        clearance = self.config.probe.approach_distance + self.prober.settings.tip_radius if clearance is None else clearance
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        return np.asarray(point, float) + clearance * n

    def move_above(self, point: Any, normal: Any, clearance: float | None = None,
                   client: str | None = None) -> MoveStatus:
        """Move the tip to ``clearance`` mm above a picked surface point along its normal, over the clearance
        height of the part (never straight through it)."""
        target = self.above_point(point, normal, clearance)
        here = self.controller.state.position if self.controller.state.machine is not None else self.machine.position
        z = max(self.clearance_z(), float(here[2]), float(target[2]))
        z = min(z, self.config.axis("z").max)
        return self.controller.move_path(client, [[here[0], here[1], z], [target[0], target[1], z], target])

    def clearance_z(self, margin: float = 10.0) -> float:
        """A height that clears the part (its top + ``margin``), or the present height without a part."""
        if self.part is None:
            return float(self.machine.position[2])
        corners = np.array([[x, y, z] for x in self.part.mesh.bounds[:, 0] for y in self.part.mesh.bounds[:, 1]
                            for z in self.part.mesh.bounds[:, 2]])
        top = float((corners @ self.part.pose[:3, :3].T + self.part.pose[:3, 3])[:, 2].max())
        return min(top + margin + self.prober.settings.tip_radius, self.config.axis("z").max)

    def jog(self, velocity: Any, client: str | None = None) -> None:
        self.controller.jog(client, velocity)

    def jog_release(self, client: str | None = None) -> None:
        self.controller.jog_release(client)

    def step(self, axis: str, step_mm: float, client: str | None = None) -> MoveStatus:
        return self.controller.step(client, axis, step_mm)

    def stop(self, client: str | None = None) -> StopReport:
        return self.controller.stop(client)

    def emergency_stop(self, client: str | None = None) -> StopReport:
        return self.controller.emergency_stop(client)

    def reset(self, client: str | None = None) -> None:
        self.controller.reset(client)

    def home(self, client: str | None = None) -> None:
        """The homing cycle of the machine configuration (blocks until done)."""
        self.controller.home(client)

    def zero(self, client: str | None = None, *, confirm: bool = False) -> None:
        self.controller.zero(client, confirm=confirm)

    # --- probing -----------------------------------------------------------------

    def probe(self, point: Any, approach: Any, clearance_z: float | None = None,
              client: str | None = None) -> MoveStatus:
        """Programmed hit at a surface point; ``approach`` points into the surface. The rapid climbs to
        ``clearance_z`` (default: clear of the part) before it crosses."""
        if clearance_z is None and self.part is not None:
            clearance_z = self.clearance_z()
        return self.controller.probe(client, point, approach, clearance_z=clearance_z)

    def probe_here(self, point: Any, normal: Any, client: str | None = None) -> MoveStatus:
        """Probe a picked point along its (outward) mesh normal, via the clearance height."""
        n = np.asarray(normal, float)
        return self.probe(point, -n, client=client)

    @property
    def qualified_probing_speed(self) -> float:
        """The speed the probe was qualified at (its record), else the configured probing speed (mm/s)."""
        probe = self.calibration_status.get("probe") or {}
        speed = float(probe.get("probing_speed") or 0.0)
        return speed if speed > 0 else float(self.config.speeds.probing)

    def manual_probe_velocity(self, velocity: Any) -> np.ndarray:
        """A manual-probing jog velocity, limited to the qualified probing speed (the pre-travel calibration
        holds only at that speed)."""
        v = np.asarray(velocity, dtype=np.float64).reshape(3)
        speed = float(np.linalg.norm(v))
        limit = self.qualified_probing_speed
        return v * (limit / speed) if speed > limit else v

    def jog_probe(self, velocity: Any, client: str | None = None) -> None:
        """Jog with the probe armed: a trigger takes a manual hit, at no more than the qualified probing speed."""
        self.controller.jog(client, self.manual_probe_velocity(velocity), probe=True)

    def hit_id(self, hit: Hit) -> int:
        """The session id of a recorded hit."""
        with self.lock:
            for hid in reversed(list(self.hits)):
                if self.hits[hid] is hit:
                    return hid
        raise StationError("the hit was not recorded")

    def _on_hit(self, hit: Hit) -> None:
        with self.lock:
            hid = self._next_hit
            self._next_hit += 1
            self._record("hit", id=hid, counts=hit.counts, machine=hit.machine, approach=hit.approach,
                         speed=hit.speed, hit_time=hit.time, point=hit.point, mode=hit.mode, normal=hit.normal)
            self.hits[hid] = hit  # on disk before anyone is shown it
            self.last_hit = hit
            self._undo.append(("add", hid))
        self._notify("hit", (hid, hit))

    def delete_hit(self, hid: int) -> None:
        with self.lock:
            if hid not in self.hits:
                raise StationError(f"there is no hit {hid}")
            self.deleted[hid] = self.hits.pop(hid)
            self._undo.append(("delete", hid))
            self._record("hit_deleted", id=hid)
        self._notify("hits", None)

    def undo(self) -> str:
        """Undo the last hit added or deleted."""
        with self.lock:
            if not self._undo:
                raise StationError("nothing to undo")
            action, hid = self._undo.pop()
            if action == "add":
                self.deleted[hid] = self.hits.pop(hid)
                self._record("hit_deleted", id=hid, undo=True)
                message = f"removed hit {hid}"
            else:
                self.hits[hid] = self.deleted.pop(hid)
                self._record("hit_restored", id=hid, undo=True)
                message = f"restored hit {hid}"
        self._notify("hits", None)
        return message

    # --- features ----------------------------------------------------------------

    def fit_feature(self, kind: str, hit_ids: list[int], method: str = "ls", name: str | None = None,
                    nominal: NominalFeature | None = None, tolerance: dict[str, float] | None = None,
                    *, feature_id: int | None = None) -> Feature:
        """Fit a feature to hits: fit the pre-travel-corrected tip centres, then offset by the tip radius.

        Without a ``nominal`` the part's CAD surface the hits lie on gives it
        (:func:`cmm.metrology.nominal_match.nominal_for_points`). ``feature_id``
        refits an existing feature in place (a hit deleted or re-taken).
        """
        tolerance = check_tolerance(tolerance)
        if kind not in FEATURE_KINDS:
            raise StationError(f"unknown feature kind {kind!r}; choose one of {', '.join(FEATURE_KINDS)}")
        with self.lock:
            missing = [h for h in hit_ids if h not in self.hits]
            if missing:
                raise StationError(f"no hits with ids {missing}")
            hits = [self.hits[h] for h in hit_ids]
        part = self.part
        if nominal is None and part is not None:
            from .metrology.nominal_match import nominal_for_points

            try:
                nominal = nominal_for_points(part.mesh, part.pose, [h.point for h in hits], kind)
            except Exception:  # noqa: BLE001 - a nominal is help; the fit stands without one
                nominal = None
        try:
            result = fit_hit_records(kind, method, hits, self.prober.settings, nominal)
        except FitError as exc:
            raise StationError(str(exc)) from None
        with self.lock:
            if feature_id is None:
                fid = self._next_feature
                self._next_feature += 1
            else:
                fid = feature_id
            feature = Feature(fid, name or f"{kind} {fid}", kind, method, list(hit_ids), result, nominal, tolerance)
            self.features[fid] = feature
            self._record_feature(feature)
        self._notify("feature", feature)
        return feature

    def _record_feature(self, feature: Feature) -> None:
        extra = {} if feature.tolerance is None else {"tolerance": feature.tolerance}
        self._record("feature", id=feature.id, name=feature.name, hit_ids=list(feature.hit_ids),
                     **feature_fields(feature.result),
                     nominal=None if feature.nominal is None else feature.nominal.to_dict(), **extra)

    def refit_feature(self, fid: int, hit_ids: list[int]) -> Feature:
        """Fit feature ``fid`` again to other hits (one deleted or re-taken); keeps its name, nominal, tolerance."""
        with self.lock:
            f = self.features.get(fid)
            if f is None:
                raise StationError(f"there is no feature {fid}")
        return self.fit_feature(f.kind, list(hit_ids), f.method, f.name, f.nominal, f.tolerance, feature_id=fid)

    def set_feature_nominal(self, fid: int, nominal: NominalFeature | None = None,
                            tolerance: dict[str, float] | None = None) -> Feature:
        """Edit a feature's nominal and/or tolerance (typed or from a CAD pick); recorded as a new fit event."""
        tolerance = check_tolerance(tolerance)
        with self.lock:
            f = self.features.get(fid)
            if f is None:
                raise StationError(f"there is no feature {fid}")
            if nominal is not None:
                f.nominal = nominal
            if tolerance is not None:
                f.tolerance = {**(f.tolerance or {}), **tolerance}
            self._record_feature(f)
        self._notify("feature", f)
        return f

    def construct_feature(self, operation: str, a: int, b: int, name: str | None = None,
                          tolerance: dict[str, float] | None = None) -> ConstructedFeature:
        """Construct a feature from features ``a`` and ``b`` (see :mod:`cmm.metrology.construct`)."""
        from .metrology.construct import construct, nominal_geometry

        tolerance = check_tolerance(tolerance)
        with self.lock:
            fa, fb = self.features.get(a), self.features.get(b)
            if fa is None or fb is None:
                raise StationError(f"there is no feature {a if fa is None else b}")
            if a == b:
                raise StationError("a construction needs two different features")
        try:
            result = construct(operation, (fa.kind, fa.result.geometry()), (fb.kind, fb.result.geometry()))
        except (FitError, ValueError, KeyError) as exc:
            raise StationError(str(exc)) from None
        nominal = None
        na = nominal_geometry(fa.kind, None if fa.nominal is None else fa.nominal.to_dict())
        nb = nominal_geometry(fb.kind, None if fb.nominal is None else fb.nominal.to_dict())
        if na is not None and nb is not None:
            try:
                nominal = construct(operation, na, nb)
            except (FitError, ValueError, KeyError, np.linalg.LinAlgError):
                nominal = None
        with self.lock:
            fid = self._next_feature
            self._next_feature += 1
            feature = ConstructedFeature(fid, name or f"{operation} {fa.name} / {fb.name}", operation, (a, b), result,
                                         nominal, tolerance)
            self.constructed[fid] = feature
            self._record("constructed", **feature.to_event())
        self._notify("feature", feature)
        return feature

    def delete_feature(self, fid: int) -> None:
        with self.lock:
            if self.constructed.pop(fid, None) is not None:
                self._record("feature_deleted", id=fid)
                self._notify("features", None)
                return
            if self.features.pop(fid, None) is None:
                raise StationError(f"there is no feature {fid}")
            self._record("feature_deleted", id=fid)
        self._notify("features", None)

    def hit_deviations(self) -> dict[int, float]:
        """Signed deviation of each compensated hit from the part mesh (+ = material outside nominal)."""
        with self.lock:
            items = list(self.hits.items())
        if self.part is None or not items:
            return {}
        result = signed_deviation(self.part.mesh, np.array([h.point for _, h in items]), self.part.pose)
        return {hid: float(d) for (hid, _), d in zip(items, result.deviations)}

    def note(self, text: str) -> None:
        self._record("note", text=text)

    def set_alignment(self, pose: Any, method: str = "manual", **info: Any) -> None:
        """Adopt a part -> machine pose from an alignment (3-2-1, best fit) and record it."""
        if self.part is None:
            raise StationError("load a part before aligning it")
        with self.lock:
            self.part.pose = np.asarray(pose, dtype=np.float64).reshape(4, 4)
            self.aligned = True
            self._record("alignment", pose=self.part.pose, method=method, **info)
        self._notify("part", self.part)

    def run_program(self, program: Any, part_pose: Any = None) -> Any:
        """Run a taught measurement program (cmm.session.program) on the aligned part."""
        from .session.program import load, run_program

        prog = load(program) if isinstance(program, (str, Path)) else program
        return self.controller.run_job(None, f"program {prog.name!r}", lambda: run_program(prog, self, part_pose))

    def wait_idle(self, timeout: float = 60.0) -> None:
        end = time.monotonic() + timeout
        while self.machine.busy or self.controller.state.mode.value in ("moving", "jogging", "probing", "homing"):
            if time.monotonic() > end:
                raise MotionError("the machine is still busy")
            time.sleep(0.01)


def check_tolerance(tolerance: dict[str, float] | None) -> dict[str, float] | None:
    """Validate a feature tolerance: known keys, positive finite mm (degrees for ``angle``)."""
    if tolerance is None:
        return None
    out: dict[str, float] = {}
    for k, v in tolerance.items():
        if k not in TOLERANCE_KEYS:
            raise StationError(f"unknown tolerance {k!r}; use {', '.join(TOLERANCE_KEYS)}")
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise StationError(f"the {k} tolerance must be a number, got {v!r}") from None
        if not (x > 0 and x < 1e3):
            raise StationError(f"the {k} tolerance must be a positive number, got {v!r}")
        out[k] = x
    return out

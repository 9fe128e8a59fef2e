"""The station: the composition root. It builds the machine, the control core, the measurement model and the
calibration service, and wires them together.

Front ends command the machine and change the measurement with the command API's verbs
(``station.controller.commands.invoke(client, verb, ...)``, :mod:`cmm.control.api`), so the access policy and the
state model are checked in one place. Each package registers its own verbs and queries where it lives
(:mod:`cmm.measurement.verbs` and :mod:`cmm.measurement.queries`: fit, construct, nominal, datum, GD&T, align,
auto-measure, programs, the session journal; :mod:`cmm.calibration.verbs`: qualify, save, accept gains, select
probe); the station calls them on what it built. Front ends read the measurement model
(:mod:`cmm.measurement`) through the API's queries. The control core's hit recorder is the model's ``add_hit`` (a hit is journalled on the dispatcher
thread before its probe completes), its events go to the model's journal and listeners, and the model probes
through the control core.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from .calibration.service import CalibrationService
from .calibration.verbs import register_calibration_verbs
from .control import Controller
from .machine.config import ConfigError, MachineConfig, load
from .machine.config import load as load_config  # front ends read the machine configuration through the station
from .machine.motion import Machine
from .machine.probing import Prober
from .measurement.model import MeasurementError, MeasurementModel, Part
from .measurement.queries import register_queries
from .measurement.verbs import register_measurement_verbs
from .nmc.trace import ByteTrace
from .session.report import write_part_report
from .sim.placement import PlacementError, part_pose_of  # noqa: F401 - --part-pose of the front ends

StationError = MeasurementError  # the station's refusals and the model's are one kind of operator sentence
__all__ = ["ConfigError", "Station", "StationError", "load_config"]


def pose_param(pose: Any) -> np.ndarray:
    """A part pose as front ends send it: "X,Y,Z[,RZ]" (mm, degrees), [X, Y, Z(, RZ)] or a 4x4 matrix."""
    from .sim.placement import parse_pose

    if isinstance(pose, str):
        return parse_pose(pose)
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape in ((3,), (4,)):
        return parse_pose(",".join(repr(float(v)) for v in arr))
    if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
        raise StationError(f"a part pose is X,Y,Z[,RZ] or a 4x4 matrix, not an array of shape {arr.shape}")
    return arr


class PartWorkspace:
    """The measurement model's part as the control core's motion rails see it (:class:`cmm.control.rails.Workspace`)."""

    def __init__(self, measurement: MeasurementModel) -> None:
        self.measurement = measurement

    def part_pose(self) -> np.ndarray | None:
        part = self.measurement.part
        return None if part is None else np.asarray(part.pose, float)

    def clearance_z(self) -> float | None:
        return None if self.measurement.part is None else self.measurement.clearance_z()

    def surface_distance(self, points: np.ndarray) -> np.ndarray:
        from .metrology.mesh import signed_deviation

        part = self.measurement.part
        return signed_deviation(part.mesh, points, part.pose).deviations


class Station:
    """Build the machine, the control core, the measurement model and the calibration service; wire them.

    ``trends`` (:class:`cmm.session.trends.Trends`, opened by the caller, who closes it): every program run is
    recorded there as a part of its series.

    ``port`` None or "sim" starts the simulated CMM in a process of its own
    (cmm/sim/sim_process.py), served in real time over TCP on loopback, and the
    driver talks to it through that byte stream (and its link process).
    A ``sim://?cmm=1`` URL opens it in-process instead, on the virtual clock
    by default (tests) or ``&clock=realtime``; ``self.sim`` is the simulated CMM.
    """

    def __init__(self, config: MachineConfig | None = None, *, port: str | None = None, baud: int | None = None,
                 part_path: str | Path | None = None, session_dir: str | Path = "sessions",
                 sim_settings: Any = None, calibration_dir: str | Path | None = None, trends: Any = None,
                 part_pose: Any = None) -> None:
        self.config = config or load()
        if baud is not None:
            self.config = self.config.with_link(baud=baud)
        self.trace = ByteTrace()
        self.sim = None
        self._served = None
        self.lock = threading.RLock()
        self._sim_world_url: str | None = None
        port = port or self.config.link.port
        part: Part | None = None
        if port == "sim" or (isinstance(port, str) and port.startswith("sim://")):
            part, port = self._start_simulator(port, sim_settings, part_path, part_pose)
        self.port = port
        self.machine = Machine(self.config, port, trace=self.trace)
        self.prober = Prober(self.machine)
        self.controller = Controller(self.machine, self.prober)
        self.measurement = MeasurementModel(
            self.machine, self.prober, lambda point, approach, clearance_z, client, hop_z=None: self.controller.probe(
                client, point, approach, frame="machine", clearance_z=clearance_z, hop_z=hop_z),
            part=part, session_dir=session_dir, lock=self.lock,
            start_fields=lambda: {"port": str(self.port), "calibration": self.calibration.status})
        self.measurement.trends = trends  # cmm.session.trends.Trends: each program run is recorded there as a part
        self.measurement.reporter = write_part_report  # a routine's report step: the part's report beside its journal
        self.ippdme: Any = None  # the I++ DME server's status (cmm.ippdme.status.IppStatus) once one serves this station
        self.controller.on_hit(self.measurement.add_hit)
        self.controller.set_workspace(PartWorkspace(self.measurement))
        # routines, records and results, for every front end; the probe it selects is the model's probe in use
        self.calibration = CalibrationService(self, calibration_dir, use_probe=self.measurement.use_probe,
                                              tell=self.measurement.log)
        self.controller.jogs.probe_speed = lambda: self.calibration.qualified_probing_speed  # armed jogs: the qualified speed
        register_measurement_verbs(self.controller, self.measurement, self.calibration)
        register_calibration_verbs(self.controller.commands, self.controller.check_access, self.calibration)
        self._register_part_verbs()
        register_queries(self.controller.commands, self.measurement, self.calibration)
        # a station with users (the API checks roles): every journal event names the person who held control
        self.measurement.holder_name = lambda: (getattr(self.controller.holder, "holder_name", None)
                                                if self.controller.commands.roles is not None else None)
        self.controller.subscribe(self.measurement.machine_event)
        if calibration_dir is not None:
            self.calibration.load(calibration_dir)
        else:  # no records yet: the probe in use is the list's first (Probe1), named on the status bar and the hits
            try:
                self.calibration.use_listed_probe()
            except self.calibration.errors:
                pass  # a probe list that cannot be read: said when the calibration tab opens it
        if part_path is not None and self.sim is None:
            self.measurement.load_part(part_path, None if part_pose is None else np.asarray(part_pose, float))

    def _start_simulator(self, port: str, settings: Any, part_path: str | Path | None,
                         part_pose: Any = None) -> tuple[Part, str]:
        """The simulated CMM ("sim": a child process serving it over TCP on loopback in real time; "sim://...": in-process
        on the world that URL names); a user's part is placed on its table. Returns (part, port URL).

        Without ``part_pose`` the part lies where the station believes it is (its lowest corner at the
        nominal set-up position) up to the simulator's deliberate set-up error; with it (4x4 part -> machine,
        ``--part-pose``) the part's CAD origin sits exactly there and the station believes so. A part that would
        collide with the reference sphere or leave the table raises a PlacementError.
        """
        from dataclasses import replace

        from .metrology.mesh import load_part
        from .sim.cmm_sim import NOMINAL_PART_POSE, TRUE_PART_POSE, CmmSimSettings
        from .sim.sim_process import SimProcess

        settings = settings or CmmSimSettings()
        nominal_pose = NOMINAL_PART_POSE.copy()
        name = "sample part"
        if part_path is not None or part_pose is not None:
            from .sim.placement import check_placement, travel_of
            from .sim.sample_part import sample_part

            mesh = load_part(part_path) if part_path is not None else sample_part()[0]
            if part_path is not None:
                name = Path(part_path).name
            if part_pose is not None:
                true_pose = nominal_pose = np.asarray(part_pose, dtype=np.float64).reshape(4, 4).copy()
            else:
                shift = np.eye(4)
                shift[:3, 3] = -mesh.bounds[0]
                nominal_pose, true_pose = nominal_pose @ shift, TRUE_PART_POSE @ shift
            check_placement(mesh, true_pose, sphere_centre=settings.sphere_centre,
                            sphere_diameter=settings.sphere_diameter, travel=travel_of(self.config),
                            name=name if part_path is None else f"the part {name}")
            settings = replace(settings, part_mesh=mesh if part_path is not None else None, part_pose=true_pose)
        if port == "sim":  # in a process of its own, never under this process's interpreter lock
            self.sim = self._served = SimProcess(self.config, settings)
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

    def serving_ippdme(self, status: Any) -> None:
        """An I++ DME server now serves this station: the page shows its ``status`` (connected client, current
        command, measured points)."""
        self.ippdme = status

    @property
    def simulated(self) -> bool:
        return self.sim is not None

    def place_sim_part(self, pose: Any) -> None:
        """On the simulator: the operator puts the next part on the table at ``pose`` (4x4 part -> machine; the
        station's belief does not change: align the part). Refused with a PlacementError when it would collide with
        the reference sphere or leave the table."""
        from .sim.placement import check_placement, travel_of

        if self.sim is None:
            raise StationError("there is no simulator: put the part on the table by hand")
        pose = np.asarray(pose, dtype=np.float64).reshape(4, 4)
        settings = self.sim.settings
        part = self.measurement.part
        check_placement(self.sim.part_mesh, pose, sphere_centre=settings.sphere_centre,
                        sphere_diameter=settings.sphere_diameter, travel=travel_of(self.config),
                        name="the part" if part is None else f"the part {part.name}")
        self.sim.place_part(pose)

    def _register_part_verbs(self) -> None:
        """``load_part`` and ``place_sim_part`` in the command API (the control holder's, as the measurement verbs)."""
        from .control.api import REQUIRED

        def load(client: Any, path: str, pose: Any = None) -> Any:
            self.controller.check_access(client, "measure")
            return self.load_part(path, None if pose is None else pose_param(pose))

        def place(client: Any, pose: Any) -> list:
            self.controller.check_access(client, "measure")
            pose = pose_param(pose)
            self.place_sim_part(pose)
            return pose.tolist()

        cmds = self.controller.commands
        cmds.register("load_part", load, {"path": REQUIRED, "pose": None},
                      "load a part file (STEP, IGES with exact surfaces; STL, OBJ, PLY, 3MF, GLB) as the nominal CAD at "
                      "pose (\"X,Y,Z[,RZ]\" mm and degrees, or a 4x4 part -> machine; none: its lowest corner at the "
                      "nominal set-up); on the simulator the part is put on the table there; the control holder only")
        cmds.register("place_sim_part", place, {"pose": REQUIRED},
                      "on the simulator: the next part is put on the table at pose (\"X,Y,Z[,RZ]\" or a 4x4), where "
                      "the station does not know it until it is aligned; refused next to the reference sphere or off "
                      "the table; the control holder only; returns the pose (4x4)")

    def load_part(self, path: str | Path, pose: Any = None) -> Part:
        """Load the part file ``path`` (STEP, IGES or a mesh) as the station's nominal CAD at ``pose`` (4x4 part ->
        machine; None: its lowest corner at the nominal set-up); on the simulator the same part is put on the table
        there (refused with a PlacementError when it would collide with the reference sphere or leave the table)."""
        from .metrology.mesh import load_part
        from .sim.cmm_sim import NOMINAL_PART_POSE

        mesh = load_part(path)
        if pose is None:
            shift = np.eye(4)
            shift[:3, 3] = -mesh.bounds[0]
            pose = NOMINAL_PART_POSE @ shift
        pose = np.asarray(pose, dtype=np.float64).reshape(4, 4)
        if self.sim is not None:
            from .sim.placement import check_placement, travel_of

            settings = self.sim.settings
            check_placement(mesh, pose, sphere_centre=settings.sphere_centre, sphere_diameter=settings.sphere_diameter,
                            travel=travel_of(self.config), name=f"the part {Path(path).name}")
            self.sim.place_part(pose, mesh)
        return self.measurement.load_part(path, pose, mesh=mesh)

    def place_sim_artifacts(self, spheres: list) -> None:
        """On the simulator: the operator sets up artifacts [(centre, diameter)]; under the simulator's lock, so
        its servo ticks never see the world half changed."""
        if self.sim is None:
            raise StationError("there is no simulator: place the artifact by hand")
        self.sim.place_artifacts(spheres)  # under the simulator's lock, wherever it runs

    def mount_sim_stylus(self, tip_diameter: float) -> None:
        """On the simulator: the stylus of the probe selected (``tip_diameter`` mm) is the one that touches the
        part; nothing on a real machine (its operator changes the stylus)."""
        mount = getattr(self.sim, "mount_stylus", None)
        if mount is not None:
            mount(tip_diameter)

    # --- life cycle -----------------------------------------------------------

    def connect(self) -> "Station":
        """Start the modules in the caller's thread, without the machine loop (a script: commands then run in the
        caller's thread); :meth:`start` does this first."""
        self.controller.connect()
        return self

    def start(self, session_name: str | None = None, *, home: bool = False) -> "Station":
        """Connect the modules, run the machine loop, open a session; ``home`` runs the homing cycle too."""
        self.connect()
        self.controller.start()
        self.measurement.new_session(session_name)
        if home:
            self.controller.home(None)
        return self

    def close(self) -> None:
        self.controller.close()
        if self._served is not None:
            self._served.close()
        if self._sim_world_url is not None:
            from .sim.url import release

            release(self._sim_world_url)
        self.measurement.close()

    def __enter__(self) -> "Station":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

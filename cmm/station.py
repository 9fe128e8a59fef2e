"""The station: the composition root. It builds the machine, the control core, the measurement model and the
calibration service, and wires them together.

Front ends command the machine and change the measurement with the command API's verbs
(``station.controller.commands.invoke(client, verb, ...)``, :mod:`cmm.api`), so the access policy and the
state model are checked in one place. Each package registers its own verbs and queries where it lives
(:mod:`cmm.measurement.verbs` and :mod:`cmm.measurement.queries`: fit, construct, nominal, datum, GD&T, align,
auto-measure, programs, the session journal; :mod:`cmm.calibration.verbs` and :mod:`cmm.calibration.queries`:
qualify, save, accept gains, select probe, the probe list and records; :mod:`cmm.session.verbs`: the recorded
sessions and the trends); the station calls them on what it built. Front ends read the measurement model
(:mod:`cmm.measurement`) through the API's queries. The control core's hit recorder is the model's ``add_hit`` (a hit is journalled on the dispatcher
thread before its probe completes), its events go to the model's journal and listeners, and the model probes
through the control core.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from .calibration.service import CalibrationHost, CalibrationService
from .calibration.queries import register_calibration_queries
from .calibration.verbs import register_calibration_verbs
from .control import Controller
from .machine.config import ConfigError, MachineConfig, load
from .machine.config import load as load_config  # front ends read the machine configuration through the station
from .machine.motion import Machine
from .machine.probing import Prober
from .measurement.model import MeasurementError, MeasurementModel, Part
from .measurement.workspace import PartWorkspace
from .measurement.queries import register_queries
from .measurement.verbs import register_measurement_verbs
from .metrology.mesh import load_part
from .nmc.trace import ByteTrace
from .session.report import write_part_report
from .session.verbs import register_session_verbs
from .sim.bench import BenchError, default_pose, open_bench, pose_param
from .sim.placement import PlacementError, part_pose_of  # noqa: F401 - --part-pose of the front ends

StationError = MeasurementError  # the station's refusals and the model's are one kind of operator sentence
__all__ = ["ConfigError", "Station", "StationError", "load_config"]


class Station:
    """Build the machine, the control core, the measurement model and the calibration service; wire them.

    ``trends`` (:class:`cmm.session.trends.Trends`, opened by the caller, who closes it): every program run is
    recorded there as a part of its series.

    ``port`` None or "sim" starts the simulated CMM in a process of its own (cmm/sim/sim_process.py), served in
    real time over TCP on loopback; a ``sim://?cmm=1`` URL opens it in-process instead, on the virtual clock by
    default (tests) or ``&clock=realtime``. Either way the simulated world (the part on the table, the reference
    sphere, the home switches) comes from behind the port (:func:`cmm.sim.bench.open_bench`): ``self.bench`` is
    its bench (None on a real machine), ``self.sim`` the simulated CMM behind it (for tests and benchmarks).
    """

    def __init__(self, config: MachineConfig | None = None, *, port: str | None = None, baud: int | None = None,
                 part_path: str | Path | None = None, session_dir: str | Path = "sessions",
                 sim_settings: Any = None, calibration_dir: str | Path | None = None, trends: Any = None,
                 part_pose: Any = None) -> None:
        self.config = config or load()
        if baud is not None:
            self.config = self.config.with_link(baud=baud)
        self.trace = ByteTrace()
        self.lock = threading.RLock()
        port = port or self.config.link.port
        try:
            self.bench = open_bench(port, self.config, sim_settings, part_path, part_pose)
        except BenchError as exc:
            raise StationError(str(exc)) from None
        bench_part = None if self.bench is None else self.bench.part
        self.port = port if self.bench is None else self.bench.url
        self.machine = Machine(self.config, self.port, trace=self.trace)
        self.prober = Prober(self.machine)
        self.controller = Controller(self.machine, self.prober)
        self.measurement = MeasurementModel(
            self.machine, self.prober, lambda point, approach, clearance_z, client, hop_z=None: self.controller.probe(
                client, point, approach, frame="machine", clearance_z=clearance_z, hop_z=hop_z),
            part=None if bench_part is None else Part(bench_part.name, bench_part.mesh, bench_part.nominal_pose,
                                                      bench_part.nominal_features),
            session_dir=session_dir, lock=self.lock,
            start_fields=lambda: {"port": str(self.port), "calibration": self.calibration.status})
        self.measurement.trends = trends  # cmm.session.trends.Trends: each program run is recorded there as a part
        self.measurement.reporter = write_part_report  # a routine's report step: the part's report beside its journal
        self.ippdme: Any = None  # the I++ DME server's status (cmm.ippdme.status.IppStatus) once one serves this station
        self.controller.on_hit(self.measurement.add_hit)
        # routines, records and results, for every front end; the probe it selects is the model's probe in use
        host = CalibrationHost(self.controller.commands, self.config, self.lock, self.controller.wait_event, self.bench)
        self.calibration = CalibrationService(host, calibration_dir, use_probe=self.measurement.use_probe,
                                              tell=self.measurement.log)
        self.controller.jogs.probe_speed = lambda: self.calibration.qualified_probing_speed  # armed jogs: the qualified speed
        self.controller.set_workspace(PartWorkspace(self.measurement, reference=self.calibration.reference_sphere))
        register_measurement_verbs(self.controller, self.measurement, self.calibration)
        register_calibration_verbs(self.controller.commands, self.controller.check_access, self.calibration)
        register_calibration_queries(self.controller.commands, self.calibration)
        register_session_verbs(self.controller.commands, self.controller.check_access, self.measurement)
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
        if part_path is not None and self.bench is None:
            self.measurement.load_part(part_path, None if part_pose is None else np.asarray(part_pose, float))

    def serving_ippdme(self, status: Any) -> None:
        """An I++ DME server now serves this station: the page shows its ``status`` (connected client, current
        command, measured points)."""
        self.ippdme = status

    @property
    def sim(self) -> Any:
        """The simulated CMM behind the bench (None on a real machine): for tests and benchmarks."""
        return None if self.bench is None else self.bench.cmm

    @property
    def simulated(self) -> bool:
        return self.bench is not None

    def _sim_bench(self, what: str) -> Any:
        if self.bench is None:
            raise StationError(f"there is no simulator: {what} by hand")
        return self.bench

    def place_sim_part(self, pose: Any) -> None:
        """On the simulator: the operator puts the next part on the table at ``pose`` (4x4 part -> machine; the
        station's belief does not change: align the part). Refused with a PlacementError when it would collide with
        the reference sphere or leave the table."""
        part = self.measurement.part
        self._sim_bench("put the part on the table").place_part(
            pose, name="the part" if part is None else f"the part {part.name}")

    def _register_part_verbs(self) -> None:
        """``load_part`` and ``place_sim_part`` in the command API (the control holder's, as the measurement verbs)."""
        def load(client: Any, path: str, pose: Any = None) -> Any:
            self.controller.check_access(client, "measure")
            return self.load_part(path, None if pose is None else pose_param(pose))

        def place(client: Any, pose: Any) -> list:
            self.controller.check_access(client, "measure")
            pose = pose_param(pose)
            self.place_sim_part(pose)
            return pose.tolist()

        cmds = self.controller.commands
        cmds.register("simulator", lambda client: None if self.bench is None else {
                          "part_pose": self.bench.settings.part_pose}, {},
                      "None on a real machine; on the simulator: where the part truly lies (part_pose, 4x4 part -> "
                      "machine), which the station does not know until it aligns the part", query=True)
        cmds.register("load_part", load, {"path": cmds.REQUIRED, "pose": None},
                      "load a part file (STEP, IGES with exact surfaces; STL, OBJ, PLY, 3MF, GLB) as the nominal CAD at "
                      "pose (\"X,Y,Z[,RZ]\" mm and degrees, or a 4x4 part -> machine; none: its lowest corner at the "
                      "nominal set-up); on the simulator the part is put on the table there; the control holder only")
        cmds.register("place_sim_part", place, {"pose": cmds.REQUIRED},
                      "on the simulator: the next part is put on the table at pose (\"X,Y,Z[,RZ]\" or a 4x4), where "
                      "the station does not know it until it is aligned; refused next to the reference sphere or off "
                      "the table; the control holder only; returns the pose (4x4)")

    def load_part(self, path: str | Path, pose: Any = None) -> Part:
        """Load the part file ``path`` (STEP, IGES or a mesh) as the station's nominal CAD at ``pose`` (4x4 part ->
        machine; None: its lowest corner at the nominal set-up); on the simulator the same part is put on the table
        there (refused with a PlacementError when it would collide with the reference sphere or leave the table)."""
        mesh = load_part(path)
        pose = default_pose(mesh) if pose is None else np.asarray(pose, dtype=np.float64).reshape(4, 4)
        if self.bench is not None:
            self.bench.place_part(pose, mesh, name=f"the part {Path(path).name}")
        return self.measurement.load_part(path, pose, mesh=mesh)

    def place_sim_artifacts(self, spheres: list) -> None:
        """On the simulator: the operator sets up artifacts [(centre, diameter)]; under the simulator's lock, so
        its servo ticks never see the world half changed."""
        self._sim_bench("place the artifact").place_artifacts(spheres)

    def mount_sim_stylus(self, tip_diameter: float) -> None:
        """On the simulator: the stylus of the probe selected (``tip_diameter`` mm) is the one that touches the
        part; nothing on a real machine (its operator changes the stylus)."""
        if self.bench is not None:
            self.bench.mount_stylus(tip_diameter)

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
        if self.bench is not None:
            self.bench.close()
        self.measurement.close()

    def __enter__(self) -> "Station":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

"""The simulated CMM: a 3-axis bridge machine on three simulated PIC-SERVO modules.

The part sits on the table at a pose the operator does not know exactly; a
25 mm reference sphere stands beside it for calibration. Every servo tick the
axis carriage positions (plant, not encoder) give the real tip position, and
the probe's switch drives the configured LIMIT input of all three modules.
The host learns all of this only through the NMC bytes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..machine.config import MachineConfig, load
from ..metrology.transform import make_pose, rotation_about_axis
from .network import SimNetwork
from .probe_world import GeometryErrors, MeshObstacle, PlaneObstacle, ProbeModel, ProbeWorld, SphereObstacle

REFERENCE_SPHERE_DIAMETER = 25.0


def pose_matrix(xyz: tuple[float, float, float], rz_deg: float = 0.0, rx_deg: float = 0.0,
                ry_deg: float = 0.0) -> np.ndarray:
    """A 4x4 part -> machine transform: rotations about X, Y then Z, then a translation."""
    rot = np.eye(3)
    for axis, deg in ((2, rz_deg), (1, ry_deg), (0, rx_deg)):
        rot = rot @ rotation_about_axis(np.eye(3)[axis], np.radians(deg))
    return make_pose(rot, xyz)


# Where the station believes the part is (the nominal set-up) ...
NOMINAL_PART_POSE = pose_matrix((190.0, 150.0, 0.0))
# ... and where it really is: off by a few tenths of a millimetre and half a degree.
TRUE_PART_POSE = pose_matrix((190.35, 149.8, 0.0), rz_deg=0.5)
REFERENCE_SPHERE_CENTRE = (400.0, 300.0, 100.0)


@dataclass
class CmmSimSettings:
    part_mesh: object | None = None  # trimesh.Trimesh in part coordinates; None = the sample part
    part_pose: np.ndarray = field(default_factory=lambda: TRUE_PART_POSE.copy())
    sphere_centre: tuple[float, float, float] = REFERENCE_SPHERE_CENTRE
    sphere_diameter: float = REFERENCE_SPHERE_DIAMETER
    probe: ProbeModel = field(default_factory=ProbeModel)
    errors: GeometryErrors = field(default_factory=GeometryErrors)
    seed: int = 1
    # extra calibration artifacts: (centre, diameter) spheres, e.g. the two balls of a ball bar
    artifacts: list = field(default_factory=list)


class SimulatedCMM:
    """Three simulated modules plus the machine world that drives their probe inputs."""

    def __init__(self, config: MachineConfig | None = None, settings: CmmSimSettings | None = None, *,
                 wire_time: bool = False, realtime: bool = False, n_modules: int = 3,
                 firmware: str | None = None, version: int | None = None) -> None:
        """``n_modules`` > 3 puts idle modules on the chain after the axes; ``firmware``
        defaults to the configuration's (its SET_BAUD table and status items)."""
        self.config = config or load()
        self.settings = settings or CmmSimSettings()
        mesh = self.settings.part_mesh
        if mesh is None:
            from .sample_part import sample_part

            mesh, self.nominal_features = sample_part()
        else:
            self.nominal_features = {}
        self.part_mesh = mesh
        self._part = MeshObstacle(mesh, self.settings.part_pose)
        self._part.box_reach = max(1.0, self.settings.probe.tip_radius + 0.5)
        obstacles = [
            PlaneObstacle(0.0),
            self._part,
            SphereObstacle(np.array(self.settings.sphere_centre), self.settings.sphere_diameter / 2),
        ]
        self._artifacts = [SphereObstacle(np.array(c, dtype=np.float64), d / 2) for c, d in self.settings.artifacts]
        obstacles += self._artifacts
        self.world = ProbeWorld(obstacles, self.settings.probe, self.settings.errors, seed=self.settings.seed)
        if n_modules < 3:
            raise ValueError(f"the simulated CMM needs 3 modules (one per axis), not {n_modules}")
        self.network = SimNetwork(n_modules, version=version, wire_time=wire_time, realtime=realtime,
                                  firmware=firmware or self.config.link.firmware)
        # modules[0] is furthest from the host and takes address 1 first: order the axes by address
        order = sorted(range(3), key=lambda i: self.config.axes[i].address)
        self._axis_module = [order.index(i) for i in range(3)]
        # (plant, home, counts per mm along the axis): axis_readings runs twice a servo tick (probe, switches)
        self._encoders = [(self.network.plants[m], a.home, a.counts_per_mm * a.direction)
                          for a, m in zip(self.config.axes, self._axis_module)]
        self._input = self.config.probe.input
        self._active_high = self.config.probe.active_level == "high"
        self._level: bool | None = None
        self.network.add_tick_hook(self._tick, reads_axes_only=True)
        self.triggers = 0
        self.last_trigger_wall = 0.0
        self._tick(self.network, 0)

    def axis_readings(self) -> tuple[float, float, float]:
        """Machine coordinates the ideal encoders would read now (continuous, mm)."""
        (px, hx, kx), (py, hy, ky), (pz, hz, kz) = self._encoders  # as AxisConfig.to_mm, inlined
        return hx + px.x / kx, hy + py.x / ky, hz + pz.x / kz

    def tip_position(self) -> np.ndarray:
        """The true tip centre, machine mm (geometry errors included)."""
        return self.world.tip(np.array(self.axis_readings()))

    def _tick(self, network: SimNetwork, tick: int) -> None:
        (px, hx, kx), (py, hy, ky), (pz, hz, kz) = self._encoders  # axis_readings inlined (every servo tick)
        triggered = self.world.update(hx + px.x / kx, hy + py.x / ky, hz + pz.x / kz)
        level = triggered if self._active_high else not triggered
        if level != self._level:
            if triggered:
                self.triggers += 1
                self.last_trigger_wall = time.perf_counter()  # for latency benchmarks
            self._level = level
            for i in range(3):
                network.set_inputs(i, **{self._input: level})

    def place_artifacts(self, spheres: list) -> None:
        """The operator sets up an artifact: replace the extra spheres by ``spheres`` [(centre, diameter)]."""
        with self.network.lock:  # not between two servo ticks' probe checks of the host's poll thread
            for ob in self._artifacts:
                self.world.obstacles.remove(ob)
            self._artifacts = [SphereObstacle(np.array(c, dtype=np.float64), d / 2) for c, d in spheres]
            self.world.obstacles.extend(self._artifacts)
            self.world._safe_from = None  # the conservative-advancement cache knew nothing of them

    def mount_stylus(self, tip_diameter: float) -> None:
        """The operator mounts a stylus with a ``tip_diameter`` mm ball (the probe list's probe selected): the tip
        that touches the part from now on; its pre-travel and noise stay the probe body's."""
        from dataclasses import replace

        d = float(tip_diameter)
        if not 0.1 <= d <= 30.0:
            raise ValueError(f"a stylus tip of {d:g} mm cannot be mounted (0.1 to 30 mm)")
        with self.network.lock:  # not between two servo ticks' probe checks
            self.world.probe = replace(self.world.probe, tip_radius=d / 2.0)
            for ob in self.world.obstacles:  # their cheap box bound stays beyond any contact of this tip
                if isinstance(ob, MeshObstacle):
                    ob.box_reach = max(1.0, d / 2.0 + 0.5)
            self.settings.probe = self.world.probe
            self.world._safe_from = None  # the conservative-advancement cache assumed the old radius

    def place_part(self, pose: np.ndarray, mesh: object | None = None) -> None:
        """The operator puts the next part on the table at ``pose`` (part -> machine); ``mesh``: another part
        (a trimesh in part coordinates, a CAD part's with its exact surfaces) instead of the present one."""
        part = MeshObstacle(self.part_mesh if mesh is None else mesh, pose)
        part.box_reach = self._part.box_reach
        with self.network.lock:
            if mesh is not None:
                self.part_mesh, self.nominal_features = mesh, {}
                self.settings.part_mesh = mesh
            self.world.obstacles[self.world.obstacles.index(self._part)] = part
            self._part = part
            self.settings.part_pose = np.asarray(pose, dtype=np.float64).copy()
            self.world._safe_from = None

    def transport(self):
        """An in-process byte transport to this machine's NMC network (virtual clock)."""
        return self.network.transport()

"""The simulated world behind a ``sim`` port, as the station's composition root gets it: the bench.

Like a pyserial URL handler, the port names what is opened: ``open_bench(port, config)`` returns None for a real
machine's port, and for ``sim`` (the simulated CMM in a process of its own, served over TCP on loopback in real
time) or a ``sim://...?cmm=1`` URL (in process, on the world the URL names in :mod:`cmm.sim.url`'s registry) a
:class:`SimBench`: the port the driver opens, the part lying on the table (its name, mesh, where the station
believes it lies, its nominal features), the reference sphere, the home switches the configuration's homing cycle
looks for, and what the simulated operator does at the machine (put a part on the table, set up artifacts, mount
a stylus). The station never builds the world itself; it wires the bench's part into its measurement model and
hands the bench to what needs it (the calibration service places its ball bar through :class:`SimBench`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..metrology.mesh import load_part
from .cmm_sim import NOMINAL_PART_POSE, TRUE_PART_POSE, CmmSimSettings
from .home_switches import for_homing
from .placement import PlacementError, check_placement, parse_pose, travel_of
from .sample_part import sample_part
from .sim_process import SimProcess
from .url import open_world, parse, release


class BenchError(ValueError):
    """A port the station cannot use as its simulated machine, in an operator's words."""


@dataclass
class BenchPart:
    """The part on the simulated table as the station believes it lies (the simulator adds a set-up error)."""

    name: str
    mesh: Any
    nominal_pose: np.ndarray
    nominal_features: dict = field(default_factory=dict)


def is_sim_port(port: Any) -> bool:
    return port == "sim" or (isinstance(port, str) and port.startswith("sim://"))


def pose_param(pose: Any) -> np.ndarray:
    """A part pose as front ends send it: "X,Y,Z[,RZ]" (mm, degrees), [X, Y, Z(, RZ)] or a 4x4 matrix."""
    if isinstance(pose, str):
        return parse_pose(pose)
    arr = np.asarray(pose, dtype=np.float64)
    if arr.shape in ((3,), (4,)):
        return parse_pose(",".join(repr(float(v)) for v in arr))
    if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
        raise PlacementError(f"a part pose is X,Y,Z[,RZ] or a 4x4 matrix, not an array of shape {arr.shape}")
    return arr


def default_pose(mesh: Any) -> np.ndarray:
    """Where a part is set up without a pose: its lowest corner at the nominal set-up position."""
    shift = np.eye(4)
    shift[:3, 3] = -mesh.bounds[0]
    return NOMINAL_PART_POSE @ shift


class SimBench:
    """The simulated CMM behind the station's port and what its operator does at it."""

    def __init__(self, cmm: Any, url: str, config: Any, part: BenchPart, *, served: Any = None,
                 world_url: str | None = None) -> None:
        self.cmm = cmm  # cmm.sim.cmm_sim.SimulatedCMM, or the SimProcess serving one
        self.url = url  # the port the driver opens
        self.config = config
        self.part = part
        self._served = served  # a SimProcess this bench started: closed with it
        self._world_url = world_url  # a world made for this bench: released with it (a named one is its owner's)

    @property
    def settings(self) -> Any:
        return self.cmm.settings

    @property
    def sphere_centre(self) -> tuple[float, float, float]:
        return tuple(float(c) for c in self.settings.sphere_centre)

    def check(self, mesh: Any, pose: np.ndarray, name: str) -> None:
        """Refuse (PlacementError) a part at ``pose`` that collides with the reference sphere or leaves the table."""
        s = self.settings
        check_placement(mesh, pose, sphere_centre=s.sphere_centre, sphere_diameter=s.sphere_diameter,
                        travel=travel_of(self.config), name=name)

    def place_part(self, pose: Any, mesh: Any = None, name: str = "the part") -> None:
        """The operator puts a part (``mesh``; None: the one on the table) on the table at ``pose`` (4x4 part ->
        machine); refused with a PlacementError next to the reference sphere or off the table."""
        pose = np.asarray(pose, dtype=np.float64).reshape(4, 4)
        self.check(self.cmm.part_mesh if mesh is None else mesh, pose, name)
        if mesh is None:
            self.cmm.place_part(pose)
        else:
            self.cmm.place_part(pose, mesh)

    def place_artifacts(self, spheres: list) -> None:
        """The operator sets up artifacts [(centre, diameter)], under the simulator's lock wherever it runs."""
        self.cmm.place_artifacts(spheres)

    def mount_stylus(self, tip_diameter: float) -> None:
        """The stylus of the probe selected (``tip_diameter`` mm) is the one that touches the part."""
        mount = getattr(self.cmm, "mount_stylus", None)
        if mount is not None:
            mount(tip_diameter)

    def close(self) -> None:
        if self._served is not None:
            self._served.close()
        if self._world_url is not None:
            release(self._world_url)


def open_bench(port: Any, config: Any, settings: Any = None, part_path: str | Path | None = None,
               part_pose: Any = None) -> SimBench | None:
    """The bench behind ``port`` (None: not a simulator). A user's part (``part_path``) is put on its table:
    without ``part_pose`` where the station believes it is (its lowest corner at the nominal set-up position) up
    to the simulator's deliberate set-up error; with it (4x4 part -> machine, ``--part-pose``) exactly there.
    A part that would collide with the reference sphere or leave the table raises a PlacementError."""
    if not is_sim_port(port):
        return None
    settings = settings or CmmSimSettings()
    nominal_pose = NOMINAL_PART_POSE.copy()
    name = "sample part"
    if part_path is not None or part_pose is not None:
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
                        sphere_diameter=settings.sphere_diameter, travel=travel_of(config),
                        name=name if part_path is None else f"the part {name}")
        settings = replace(settings, part_mesh=mesh if part_path is not None else None, part_pose=true_pose)
    if port == "sim":  # in a process of its own, never under this process's interpreter lock
        served = SimProcess(config, settings)
        return SimBench(served, served.url, config, _part(served, name, nominal_pose), served=served)
    if not parse(port).cmm:
        raise BenchError(f"the station needs the simulated CMM: add cmm=1 to {port!r}")
    world = open_world(port, config=config, settings=settings)
    sim = world.cmm
    if not getattr(sim, "home_switches", None):  # the switches the configuration's homing cycle looks for
        sim.home_switches = for_homing(sim, config.homing)
    return SimBench(sim, world.url, config, _part(sim, name, nominal_pose),
                    world_url=None if parse(port).name else world.url)


def _part(sim: Any, name: str, nominal_pose: np.ndarray) -> BenchPart:
    return BenchPart(name, sim.part_mesh, nominal_pose, dict(sim.nominal_features))


__all__ = ["BenchError", "BenchPart", "SimBench", "default_pose", "is_sim_port", "open_bench", "pose_param"]

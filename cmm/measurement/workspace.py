"""The measurement model's part as the control core's motion rails see it (:class:`cmm.control.rails.Workspace`):
where the part lies, the clearance plane over it, how far points are from its surface, and the reference sphere
the tip must keep clear of."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..metrology.mesh import signed_deviation


class PartWorkspace:
    def __init__(self, measurement: Any, reference: Callable[[], Any] | None = None) -> None:
        self.measurement = measurement
        self.reference = reference  # () -> ((x, y, z), diameter) of the reference sphere, or None

    def part_pose(self) -> np.ndarray | None:
        part = self.measurement.part
        return None if part is None else np.asarray(part.pose, float)

    def clearance_z(self) -> float | None:
        return None if self.measurement.part is None else self.measurement.clearance_z()

    def surface_distance(self, points: np.ndarray) -> np.ndarray:
        part = self.measurement.part
        return signed_deviation(part.mesh, points, part.pose).deviations

    def keep_out(self) -> list[tuple[np.ndarray, float]]:
        """Spheres on their stands (centre, radius; machine mm) that the tip's routes go around: the reference
        sphere when its place is known."""
        found = None if self.reference is None else self.reference()
        if found is None:
            return []
        centre, diameter = found
        return [(np.asarray(centre, float), float(diameter) / 2.0)]

"""The measurement model's part as the control core's motion rails see it (:class:`cmm.control.rails.Workspace`):
where the part lies, the clearance plane over it, and how far points are from its surface."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..metrology.mesh import signed_deviation


class PartWorkspace:
    def __init__(self, measurement: Any) -> None:
        self.measurement = measurement

    def part_pose(self) -> np.ndarray | None:
        part = self.measurement.part
        return None if part is None else np.asarray(part.pose, float)

    def clearance_z(self) -> float | None:
        return None if self.measurement.part is None else self.measurement.clearance_z()

    def surface_distance(self, points: np.ndarray) -> np.ndarray:
        part = self.measurement.part
        return signed_deviation(part.mesh, points, part.pose).deviations

"""First-order machine geometry correction: per-axis scale and three squareness angles.

The tip really moves by M @ r for axis readings r (machine origin fixed),
where M has the scales (1 + s) on its diagonal and the squareness angles
above it: a Y move also shifts X by a_xy, a Z move shifts X by a_xz and Y by
a_yz. The calibration routine estimates M; the machine reports M @ r as the
position and commands M^-1 @ target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def geometry_matrix(scale_ppm: tuple[float, float, float], squareness_urad: tuple[float, float, float]) -> np.ndarray:
    sx, sy, sz = (1 + s * 1e-6 for s in scale_ppm)
    axy, axz, ayz = (a * 1e-6 for a in squareness_urad)
    return np.array([[sx, axy * sy, axz * sz], [0.0, sy, ayz * sz], [0.0, 0.0, sz]])


@dataclass(frozen=True)
class GeometryCorrection:
    scale_ppm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    squareness_urad: tuple[float, float, float] = (0.0, 0.0, 0.0)  # xy, xz, yz

    @property
    def matrix(self) -> np.ndarray:
        return geometry_matrix(self.scale_ppm, self.squareness_urad)

    @property
    def is_identity(self) -> bool:
        return not any(self.scale_ppm) and not any(self.squareness_urad)

    def apply(self, readings: np.ndarray) -> np.ndarray:
        """Axis readings (mm) -> corrected machine coordinates."""
        r = np.asarray(readings, dtype=np.float64)
        return r if self.is_identity else self.matrix @ r

    def invert(self, position: np.ndarray) -> np.ndarray:
        """Corrected machine coordinates -> the axis readings that reach them."""
        p = np.asarray(position, dtype=np.float64)
        return p if self.is_identity else np.linalg.solve(self.matrix, p)

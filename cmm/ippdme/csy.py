"""I++ DME coordinate systems (spec 6.3.3): MachineCsy and the chain above it.

A transformation (X0, Y0, Z0, Theta, Psi, Phi) maps machine coordinates to
the system's coordinates as p' = R p + (X0, Y0, Z0), where (X0, Y0, Z0) is
the machine origin in that system and R = Rz(Phi) Rx(Theta) Rz(Psi) with the
spec's coordinate-rotation matrices (Euler angles, degrees, Theta in 0..180).
The chain is machine -> MoveableMachineCsy -> MultipleArmCsy -> PartCsy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import IppError

SELECTABLE = ("MachineCsy", "MoveableMachineCsy", "MultipleArmCsy", "PartCsy")
TRANSFORMS = ("PartCsy", "JogDisplayCsy", "JogMoveCsy", "SensorCsy", "MoveableMachineCsy", "MultipleArmCsy")
CHAIN = ("MoveableMachineCsy", "MultipleArmCsy", "PartCsy")  # applied in this order


def _rz(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


@dataclass
class Transformation:
    values: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def rotation(self) -> np.ndarray:
        _, _, _, theta, psi, phi = self.values
        return _rz(phi) @ _rx(theta) @ _rz(psi)

    @property
    def origin(self) -> np.ndarray:
        return np.array(self.values[:3], dtype=float)

    def forward(self, p: np.ndarray) -> np.ndarray:
        return self.rotation @ p + self.origin

    def inverse(self, p: np.ndarray) -> np.ndarray:
        return self.rotation.T @ (p - self.origin)


@dataclass
class CoordinateSystems:
    current: str = "MachineCsy"
    transforms: dict[str, Transformation] = field(default_factory=lambda: {n: Transformation() for n in TRANSFORMS})

    def select(self, name: str, method: str = "SetCoordSystem") -> None:
        if name not in SELECTABLE:
            raise IppError(509, method, f"{name} is not one of {', '.join(SELECTABLE)}")
        self.current = name

    def set(self, name: str, values: list[float], method: str = "SetCsyTransformation") -> None:
        if name not in TRANSFORMS:
            raise IppError(509, method, f"{name} is not one of {', '.join(TRANSFORMS)}")
        if len(values) != 6 or not all(math.isfinite(v) for v in values):
            raise IppError(502, method, "expected X0, Y0, Z0, Theta, Psi, Phi")
        x0, y0, z0, theta, psi, phi = values
        if not 0.0 <= theta <= 180.0:
            raise IppError(1007, method, f"Theta {theta:g} is outside 0..180 degrees")
        self.transforms[name] = Transformation((x0, y0, z0, theta, psi % 360.0, phi % 360.0))

    def get(self, name: str, method: str = "GetCsyTransformation") -> Transformation:
        if name not in TRANSFORMS:
            raise IppError(509, method, f"{name} is not one of {', '.join(TRANSFORMS)}")
        return self.transforms[name]

    def _chain(self) -> list[Transformation]:
        if self.current == "MachineCsy":
            return []
        return [self.transforms[n] for n in CHAIN[:CHAIN.index(self.current) + 1]]

    def from_machine(self, p) -> np.ndarray:
        p = np.array(p, dtype=float)  # a copy: callers change it
        for t in self._chain():
            p = t.forward(p)
        return p

    def to_machine(self, p) -> np.ndarray:
        p = np.array(p, dtype=float)  # a copy: callers change it
        for t in reversed(self._chain()):
            p = t.inverse(p)
        return p

    def vector_from_machine(self, v) -> np.ndarray:
        v = np.array(v, dtype=float)
        for t in self._chain():
            v = t.rotation @ v
        return v

    def vector_to_machine(self, v) -> np.ndarray:
        v = np.array(v, dtype=float)
        for t in reversed(self._chain()):
            v = t.rotation.T @ v
        return v

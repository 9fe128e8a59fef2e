"""Machine geometry: per-axis scale and the three squareness angles from a ball bar.

The bar (two balls at a certified centre distance L) is set up along each
axis and along both diagonals of each face (XY, XZ, YZ). Each ball's centre
is measured (locate, then a small pattern of averaged hits; a sphere fit to
the latched tip centres, pre-travel model applied). With raw axis readings
d = r2 - r1 between the centres and the machine matrix M of
``cmm.machine.geometry`` (scales on the diagonal, squareness above it), the
true length is |M d| = L; the six parameters are fitted by least squares
over the nine set-ups. To first order a face's squareness is
(L_plus - L_minus) / L. The result is a :class:`GeometryCorrection` that
the machine applies (``machine.correction``); verify by measuring again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from scipy.optimize import least_squares

from ..machine.geometry import GeometryCorrection, geometry_matrix
from ..machine.motion import Machine
from ..machine.probing import ProbeSettings
from .probe import Progress, SphereProber, direction, report, unit, _fit_sphere
from .records import BallBarCertificate, CalibrationError, MachineRecord, now

BALL_PATTERN = np.array([[0.0, 0.0, 1.0]] + [direction(50.0, a) for a in (0, 90, 180, 270)]
                        + [direction(95.0, a) for a in (45, 135, 225, 315)])


@dataclass(frozen=True)
class Setup:
    """One placement of a bar: its name, the certificate used and the nominal ball centres (machine mm)."""

    name: str  # "X", "Y", "Z", "XY+", "XY-", "XZ+", ...
    artifact: str  # key into the certificates
    ball1: tuple[float, float, float]
    ball2: tuple[float, float, float]
    lane: tuple[float, float, float]  # horizontal side from which the balls are entered (clear of the bar)


def default_setups(long_bar: str = "ball_bar_300", short_bar: str = "ball_bar_200",
                   lengths: dict[str, float] | None = None) -> list[Setup]:
    """Nine set-ups in the default 500 x 400 x 300 mm volume, clear of the sample part and the reference sphere."""
    lengths = lengths or {long_bar: 300.0, short_bar: 200.0}
    L, S = lengths[long_bar], lengths[short_bar]
    h = L / math.sqrt(2) / 2

    def bar(name: str, key: str, mid: tuple[float, float, float], d: tuple[float, float, float],
            length: float, lane: tuple[float, float, float]) -> Setup:
        m, v = np.array(mid), unit(np.array(d, float)) * length / 2
        return Setup(name, key, tuple(m - v), tuple(m + v), lane)  # type: ignore[arg-type]

    return [
        bar("X", long_bar, (250.0, 60.0, 150.0), (1, 0, 0), L, (0, 1, 0)),
        bar("Y", long_bar, (60.0, 200.0, 150.0), (0, 1, 0), L, (1, 0, 0)),
        bar("Z", short_bar, (60.0, 60.0, 150.0), (0, 0, 1), S, (1, 0, 0)),
        bar("XY+", long_bar, (250.0, 200.0, 150.0), (1, 1, 0), L, (1, -1, 0)),
        bar("XY-", long_bar, (250.0, 200.0, 150.0), (1, -1, 0), L, (1, 1, 0)),
        bar("XZ+", long_bar, (250.0, 60.0, 60.0 + h), (1, 0, 1), L, (0, 1, 0)),
        bar("XZ-", long_bar, (250.0, 60.0, 60.0 + h), (1, 0, -1), L, (0, 1, 0)),
        bar("YZ+", long_bar, (60.0, 200.0, 60.0 + h), (0, 1, 1), L, (1, 0, 0)),
        bar("YZ-", long_bar, (60.0, 200.0, 60.0 + h), (0, 1, -1), L, (1, 0, 0)),
    ]


@dataclass
class BarMeasurement:
    setup: str
    certified: float  # mm
    raw_delta: np.ndarray  # axis readings between the ball centres (mm, no correction)
    measured: float  # |corrected delta| with the correction in force during the measurement

    @property
    def error_um(self) -> float:
        return (self.measured - self.certified) * 1000


@dataclass
class GeometryResult:
    correction: GeometryCorrection
    measurements: list[BarMeasurement]
    residuals_um: dict[str, float]  # fitted model vs certified length
    uncertainty_scale_ppm: float
    uncertainty_squareness_urad: float
    verification: list[BarMeasurement] = field(default_factory=list)

    def record(self, artifact: str, machine: str = "") -> MachineRecord:
        return MachineRecord(
            date=now(), artifact=artifact, scale_ppm=tuple(round(x, 3) for x in self.correction.scale_ppm),  # type: ignore[arg-type]
            squareness_urad=tuple(round(x, 3) for x in self.correction.squareness_urad),  # type: ignore[arg-type]
            uncertainty_scale_ppm=round(self.uncertainty_scale_ppm, 3),
            uncertainty_squareness_urad=round(self.uncertainty_squareness_urad, 3),
            length_errors_before_um={m.setup: round(m.error_um, 3) for m in self.measurements},
            length_errors_after_um={m.setup: round(m.error_um, 3) for m in self.verification},
            machine=machine)


def _xyz(p: Any) -> str:
    return "X={:.1f} Y={:.1f} Z={:.1f}".format(*p)


def fit_geometry(measurements: list[BarMeasurement]) -> tuple[GeometryCorrection, dict[str, float], float, float]:
    """Least-squares scale (ppm) and squareness (urad) from raw bar vectors and certified lengths."""
    if len(measurements) < 6:
        raise CalibrationError(f"only {len(measurements)} bar set-ups were measured; scale and squareness need "
                               "at least 6 (3 axes and one diagonal per face)")
    d = np.array([m.raw_delta for m in measurements])
    L = np.array([m.certified for m in measurements])

    def resid(p: np.ndarray) -> np.ndarray:
        mat = geometry_matrix(tuple(p[:3]), tuple(p[3:]))
        return (np.linalg.norm(d @ mat.T, axis=1) - L) * 1000  # um

    sol = least_squares(resid, np.zeros(6), x_scale=np.full(6, 10.0))
    res = resid(sol.x)
    dof = max(1, len(L) - 6)
    s = float(np.sqrt(res @ res / dof)) if len(L) > 6 else 0.5
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * s * s
        sd = np.sqrt(np.diag(cov))
    except np.linalg.LinAlgError:
        raise CalibrationError("the bar set-ups do not determine all six parameters: each axis and one "
                               "diagonal per face are needed") from None
    corr = GeometryCorrection(tuple(float(x) for x in sol.x[:3]), tuple(float(x) for x in sol.x[3:]))  # type: ignore[arg-type]
    return corr, {m.setup: float(r) for m, r in zip(measurements, res)}, 2 * float(sd[:3].max()), 2 * float(sd[3:].max())


def measure_setups(machine: Machine, settings: ProbeSettings, certificates: dict[str, BallBarCertificate],
                   setups: list[Setup], place: Callable[[Setup], None] | None, *, repeats: int = 2,
                   progress: Progress = None, seed: int = 2) -> list[BarMeasurement]:
    """Measure each set-up: ``place(setup)`` asks the operator (or the simulator) to put the bar there."""
    sp = SphereProber(machine, seed=seed)
    out = []
    for i, s in enumerate(setups):
        say = report(progress, i / len(setups), (i + 1) / len(setups))
        cert = certificates.get(s.artifact)
        if cert is None:
            raise CalibrationError(f"set-up {s.name} needs the certificate '{s.artifact}', which is not loaded")
        if place is not None:
            say(0.0, f"set-up {s.name}: place {cert.name} with its balls at {_xyz(s.ball1)} and {_xyz(s.ball2)}")
            place(s)
        radius = cert.ball_diameter / 2
        lane = np.array(s.lane, float)
        top = max(s.ball1[2], s.ball2[2]) + sp.safe_radius(radius) + 10.0
        sp.safe_z = min(machine.config.axis("z").max - 5.0, max(top, machine.position[2]))
        centres = []
        for j, nominal in enumerate((s.ball1, s.ball2)):
            say(0.5 * j, f"set-up {s.name}: ball {j + 1}")
            if j == 1:  # along the bar on the lane side, clear of both balls
                machine.move_to(np.asarray(nominal) + sp.safe_radius(radius) * unit(lane)).wait()
            located = sp.locate(nominal, radius, lane, enter=j == 0)
            t, u, skipped = sp.measure(located, radius, BALL_PATTERN, repeats=repeats)
            if len(t) < 6:
                raise CalibrationError(f"set-up {s.name}, ball {j + 1}: only {len(t)} valid points ({'; '.join(skipped)})")
            c = t - settings.pretravel(u)[:, None] * u
            centres.append(np.asarray(_fit_sphere(c, f"ball {j + 1} of set-up {s.name}").center, float))
            sp._around(located, radius, located + sp.safe_radius(radius) * unit(lane))
        raw = machine.correction.invert(centres[1]) - machine.correction.invert(centres[0])
        out.append(BarMeasurement(s.name, cert.length, raw, float(np.linalg.norm(centres[1] - centres[0]))))
        say(1.0, f"set-up {s.name}: {out[-1].measured:.4f} mm ({out[-1].error_um:+.2f} um)")
    return out


def calibrate_geometry(machine: Machine, settings: ProbeSettings, certificates: dict[str, BallBarCertificate],
                       setups: list[Setup] | None = None, place: Callable[[Setup], None] | None = None, *,
                       repeats: int = 2, verify: bool = True, progress: Progress = None) -> GeometryResult:
    """Measure, fit the correction, apply it to ``machine`` for the verification, and verify.

    On any failure the machine's previous correction is restored. The caller
    decides whether to keep the new correction (it stays applied on success).
    """
    setups = setups or default_setups(lengths={k: c.length for k, c in certificates.items()})
    previous = machine.correction
    try:
        meas = measure_setups(machine, settings, certificates, setups, place, repeats=repeats,
                              progress=report(progress, 0.0, 0.5 if verify else 0.95))
        corr, res, us, ua = fit_geometry(meas)
        result = GeometryResult(corr, meas, res, us, ua)
        machine.correction = corr
        if verify:
            result.verification = measure_setups(machine, settings, certificates, setups, place, repeats=repeats,
                                                 progress=report(progress, 0.5, 0.98), seed=3)
    except BaseException:
        machine.correction = previous
        raise
    if progress is not None:
        progress(1.0, "scale {} ppm, squareness {} urad".format(
            ", ".join(f"{x:+.1f}" for x in corr.scale_ppm), ", ".join(f"{x:+.1f}" for x in corr.squareness_urad)))
    return result

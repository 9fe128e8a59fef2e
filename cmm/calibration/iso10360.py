"""ISO 10360-5 style probing test: 25 points on the reference sphere.

Pattern: 1 at the pole, 4 at 22.5 deg from it, 8 at 45, 4 at 67.5, 8 at the
equator, each ring rotated relative to the previous one. The same hits are
evaluated with several probe settings (uncalibrated, r_eff only, r_eff +
directional pre-travel):
  P_Form.Sph.1x25 = Rmax - Rmin of the compensated points about their
                    unconstrained least-squares sphere
  P_Size.Sph.1x25 = fitted diameter - calibrated diameter
Points are compensated with the normal of the sphere fitted to the
pre-travel-corrected tip centres (better than the approach direction).

The standard takes single hits (``repeats=1``). With 2 um counts a single
hit carries about 0.6 um of quantisation, which alone gives a 25-point form
of 2..3 um; ``repeats > 1`` averages dithered hits per point to show the
systematic (compensable) part, reported separately.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..machine.motion import Machine
from ..machine.probing import ProbeSettings
from ..metrology.compensation import PretravelModel
from .probe import Progress, SphereProber, direction, report, unit, _fit_sphere
from .records import CalibrationError, SphereCertificate

RINGS = ((22.5, 4, 0.0), (45.0, 8, 22.5), (67.5, 4, 45.0), (90.0, 8, 0.0))  # polar deg, count, azimuth offset deg


def iso25_pattern() -> np.ndarray:
    """Outward normals of the 25-point pattern."""
    dirs = [np.array([0.0, 0.0, 1.0])]
    for polar, n, off in RINGS:
        dirs += [direction(polar, off + 360.0 * k / n) for k in range(n)]
    return np.array(dirs)


@dataclass
class ProbingFigures:
    form_um: float  # P_Form.Sph.1x25
    size_um: float  # P_Size.Sph.1x25
    diameter: float  # fitted, mm
    residuals_um: np.ndarray = field(repr=False)


def evaluate(centres: np.ndarray, approach: np.ndarray, settings: ProbeSettings, diameter: float) -> ProbingFigures:
    """P_Form and P_Size of latched tip centres compensated with ``settings``."""
    t = np.asarray(centres, float)
    u = unit(np.asarray(approach, float))
    c = t - settings.pretravel(u)[:, None] * u
    fit_c = _fit_sphere(c, "compensated tip centres")
    n = unit(np.asarray(fit_c.center) - c)  # into the material (probing from outside)
    pts = c + settings.tip_radius * n
    fit = _fit_sphere(pts, "compensated points")
    res = np.linalg.norm(pts - np.asarray(fit.center), axis=1) - fit.radius
    return ProbingFigures(float(np.ptp(res) * 1000), float((2 * fit.radius - diameter) * 1000), float(2 * fit.radius),
                          res * 1000)


@dataclass
class Iso10360Result:
    figures: dict[str, ProbingFigures]  # "uncalibrated", "radius only", "calibrated"
    centres: np.ndarray  # (25, 3) latched tip centres
    approach: np.ndarray
    repeats: int
    skipped: list[str]

    @property
    def form_um(self) -> float:
        return self.figures["calibrated"].form_um

    @property
    def size_um(self) -> float:
        return self.figures["calibrated"].size_um

    def table(self) -> str:
        lines = [f"ISO 10360-5 style test, 25 points x {self.repeats} hit(s):",
                 f"  {'settings':<14} {'P_Form.Sph.1x25':>16} {'P_Size.Sph.1x25':>16}"]
        for k, f in self.figures.items():
            lines.append(f"  {k:<14} {f.form_um:>13.2f} um {f.size_um:>+13.2f} um")
        return "\n".join(lines)


def run_iso10360_5(machine: Machine, certificate: SphereCertificate, settings: ProbeSettings, *,
                   approx_centre: Any = None, repeats: int = 1, progress: Progress = None,
                   seed: int = 1) -> Iso10360Result:
    """Measure the 25 points (locating the sphere first) and evaluate them."""
    centre = approx_centre if approx_centre is not None else certificate.approx_centre
    if centre is None:
        raise CalibrationError("the approximate centre of the test sphere is unknown: give [setup] centre in its "
                               "certificate or --centre X,Y,Z")
    say = report(progress, 0.0, 1.0)
    say(0.0, "locating the test sphere")
    sp = SphereProber(machine, seed=seed)
    radius = certificate.diameter / 2
    located = sp.locate(centre, radius)
    t, u, skipped = sp.measure(located, radius, iso25_pattern(), repeats=repeats, progress=report(say, 0.1, 0.95))
    sp.leave(located, radius, np.array([1.0, 0.0, 0.0]))
    if len(t) < 25:
        raise CalibrationError(f"only {len(t)} of the 25 points were measured ({'; '.join(skipped)}): the test is void")
    cfg = machine.config.probe
    variants = {
        "uncalibrated": ProbeSettings(cfg.tip_radius, PretravelModel.constant(cfg.pretravel)),
        "radius only": ProbeSettings(settings.tip_radius, PretravelModel()),
        "calibrated": settings,
    }
    figures = {k: evaluate(t, u, s, certificate.diameter) for k, s in variants.items()}
    say(1.0, f"P_Form {figures['calibrated'].form_um:.2f} um, P_Size {figures['calibrated'].size_um:+.2f} um")
    return Iso10360Result(figures, t, u, repeats, skipped)

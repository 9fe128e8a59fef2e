"""Probe qualification on the certified reference sphere.

Automatic: one hit near the top of the sphere from the approximate centre
(certificate [setup] centre or the operator's), four equator hits, a sphere
fit -> the real centre; then a denser pattern (default 3 latitudes x 24
points + the pole) in position mode with safe moves around the sphere.
Guided manual: :func:`qualify_from_hits` takes the operator's hits.

Pause and faults: between points the run asks ``between()`` (the service's pause: it holds the machine there
until the operator resumes); after a pause the probe lifts to the safe height before it goes on. A fault or
E-STOP (the machine's motion inhibited) stops the run with :class:`QualificationInterrupted`, whose
:class:`QualificationCheckpoint` keeps the located centre and the points measured; ``qualify_probe(...,
resume=checkpoint)`` after Reset lifts clear and measures the remaining points only.

Convention (pre-travel and radius are not separable on one sphere):
a sphere fitted to the latched tip centres T_i has radius D/2 + r_eff.
The residuals of T_i against that sphere, by approach direction, are the
directional part of the pre-travel; it is fitted with
:class:`PretravelModel` on the terms QUALIFICATION_TERMS and kept with zero
mean over the qualification pattern. r_eff (nominal radius minus the mean
pre-travel) holds the rest. The station compensates with
``ProbeSettings(tip_radius=r_eff, pretravel=model)``.

Counts are 2 um and the latch happens on a servo tick, so a single hit is
quantised (about 0.6 um sigma along the normal). Repeated hits are
dithered by a few um so that they sample different count and tick phases,
and averaged (``repeats``).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterator

import numpy as np
from scipy.optimize import least_squares

from ..machine.motion import Machine
from ..machine.probing import Hit, ProbeSettings, Prober, SurfaceNotFound
from ..machine.status import MotionError
from ..metrology import fit_criteria
from ..metrology.compensation import PretravelModel, pretravel_basis
from ..metrology.features import FitError
from .records import CalibrationError, ProbeRecord, SphereCertificate, now

Progress = Callable[[float, str], None] | None
QUALIFICATION_TERMS = ("const", "z2", "s2_cos3", "s2_sin3")
MIN_POINTS = 9
SHORT_APPROACH = 0.3  # mm, once the sphere centre is known to a few um


def report(progress: Progress, start: float, end: float) -> Callable[[float, str], None]:
    """A progress function for a sub-step mapped to [start, end] of the caller's range."""
    def fn(f: float, msg: str) -> None:
        if progress is not None:
            progress(start + (end - start) * min(max(f, 0.0), 1.0), msg)
    return fn


def unit(v: Any) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def direction(polar_deg: float, azimuth_deg: float) -> np.ndarray:
    """Outward normal at a polar angle from the +Z pole and an azimuth."""
    t, a = math.radians(polar_deg), math.radians(azimuth_deg)
    return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])


def qualification_pattern(polar_deg: tuple[float, ...] = (30.0, 60.0, 90.0), per_ring: int = 24,
                          pole: bool = True) -> np.ndarray:
    """Outward normals: the pole, then rings at the given polar angles (each rotated by half a step)."""
    dirs = [np.array([0.0, 0.0, 1.0])] if pole else []
    for i, p in enumerate(polar_deg):
        off = (180.0 / per_ring) * (i % 2)
        dirs += [direction(p, off + 360.0 * k / per_ring) for k in range(per_ring)]
    return np.array(dirs)


@contextmanager
def short_approach(machine: Machine, approach: float = SHORT_APPROACH) -> Iterator[None]:
    """Shorter approach, search and retract while the artifact position is known to a few um."""
    old = machine.config
    p = old.probe
    machine.config = replace(old, probe=replace(p, approach_distance=min(approach, p.approach_distance),
                                                retract_distance=min(approach, p.retract_distance),
                                                search_distance=min(2 * approach, p.search_distance)))
    try:
        yield
    finally:
        machine.config = old


def _segment_clearance(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    ab = b - a
    t = 0.0 if not ab.any() else float(np.clip(np.dot(c - a, ab) / np.dot(ab, ab), 0.0, 1.0))
    return float(np.linalg.norm(a + t * ab - c))


def _slerp(a: np.ndarray, b: np.ndarray, max_step_deg: float) -> list[np.ndarray]:
    """Unit directions from a to b (excluded a, included b) along the great circle, steps <= max_step."""
    ang = math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0)))
    if ang < 1e-9:
        return [b]
    if math.pi - ang < 1e-3:  # antipodal: go over the top
        mid = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        return _slerp(a, unit(mid - np.dot(mid, a) * a), max_step_deg) + _slerp(
            unit(mid - np.dot(mid, a) * a), b, max_step_deg)
    n = max(1, math.ceil(math.degrees(ang) / max_step_deg))
    s = math.sin(ang)
    return [(math.sin((1 - k / n) * ang) * a + math.sin(k / n * ang) * b) / s for k in range(1, n + 1)]


class SphereProber:
    """Hits on a sphere (reference sphere or a ball of a ball bar) with safe moves around it.

    Uses its own :class:`Prober` with raw settings (nominal radius, no
    pre-travel): calibration works on the latched tip centres.
    """

    def __init__(self, machine: Machine, *, tip_radius: float | None = None, safe_z: float | None = None,
                 seed: int = 0) -> None:
        self.machine = machine
        r = machine.config.probe.tip_radius if tip_radius is None else tip_radius
        self.prober = Prober(machine, ProbeSettings(r, PretravelModel()))
        self.tip_radius = r
        z = machine.config.axis("z")
        self.safe_z = z.max - 5.0 if safe_z is None else safe_z
        self.rng = np.random.default_rng(seed)
        self.hits = 0

    def safe_radius(self, radius: float) -> float:
        return radius + self.tip_radius + self.machine.config.probe.approach_distance + 1.0

    def enter(self, centre: np.ndarray, radius: float, lane: np.ndarray) -> None:
        """From anywhere: up to the safe height, across, down beside the sphere on the lane side."""
        m = self.machine
        c = np.asarray(centre, float)
        side = c + self.safe_radius(radius) * unit(lane)
        here = m.position
        z = max(self.safe_z, here[2])
        m.move_path([[here[0], here[1], z], [side[0], side[1], z], side]).wait()

    def lift_clear(self, centre: Any, radius: float, margin: float = 5.0) -> bool:
        """From wherever a stopped run left the probe (beside or below the sphere): out sideways until the line up
        is clear of the sphere (its approximate centre known to ``margin`` mm), then up to the safe height.
        True when it moved."""
        m = self.machine
        c = np.asarray(centre, float)
        here = np.asarray(m.position, float)
        if here[2] >= self.safe_z - 0.01:
            return False
        keep = self.safe_radius(radius) + margin
        flat = here[:2] - c[:2]
        d = float(np.linalg.norm(flat))
        path = []
        if d < keep and here[2] < c[2] + keep:  # straight up would pass through the sphere: step out first
            out = flat / d if d > 1e-6 else np.array([1.0, 0.0])
            side = c[:2] + keep * out
            path.append([side[0], side[1], here[2]])
            here = np.array([side[0], side[1], here[2]])
        path.append([here[0], here[1], self.safe_z])
        m.move_path(path).wait()
        return True

    def leave(self, centre: np.ndarray, radius: float, lane: np.ndarray) -> None:
        """Around the sphere back to the lane side, then up to the safe height."""
        c = np.asarray(centre, float)
        rs = self.safe_radius(radius)
        self._around(c, radius, c + rs * unit(lane))
        here = self.machine.position
        self.machine.move_to([here[0], here[1], max(self.safe_z, here[2])]).wait()

    def _around(self, c: np.ndarray, radius: float, target: np.ndarray) -> None:
        m = self.machine
        here = m.position
        keep = radius + self.tip_radius + 0.2
        if _segment_clearance(here, target, c) >= keep:
            path = [target]
        else:
            rs = self.safe_radius(radius)
            a, b = unit(here - c), unit(target - c)
            path = [c + rs * a] + [c + rs * d for d in _slerp(a, b, 30.0)] + [target]
        m.move_path(path).wait()

    def hit(self, centre: np.ndarray, radius: float, normal: np.ndarray, dither: float = 0.0) -> Hit:
        """One programmed hit at the surface point with outward ``normal`` (approach = -normal)."""
        c = np.asarray(centre, float)
        n = unit(normal)
        u = -n
        nominal = c + radius * n
        if dither > 0:
            nominal = nominal + self.rng.uniform(-dither, dither, 3)
        pre = nominal - (self.tip_radius + self.machine.config.probe.approach_distance) * u
        self._around(c, radius, pre)
        hit = self.prober.probe(nominal, u).wait()
        self.hits += 1
        return hit

    def locate(self, centre_guess: Any, radius: float, lane: np.ndarray | None = None, *,
               enter: bool = True) -> np.ndarray:
        """The sphere's centre (of the tip-centre sphere) from a hit near the top and four at the equator."""
        c = np.asarray(centre_guess, float)
        lane = np.array([1.0, 0.0, 0.0]) if lane is None else lane
        try:
            if enter:
                self.enter(c, radius, lane)
            top = self.hit(c, radius, [0, 0, 1])
            # the top hit fixes the height; the equator hits the centre in X and Y
            c = np.array([c[0], c[1], top.machine[2] - radius - self.tip_radius])
            pts = [top.machine] + [self.hit(c, radius, direction(90.0, a)).machine for a in (0, 90, 180, 270)]
        except SurfaceNotFound as exc:
            raise CalibrationError(
                "the sphere was not found near X={:.2f} Y={:.2f} Z={:.2f} mm: check that it stands there and the "
                "approximate centre in its certificate [setup] or --centre ({})".format(*c, exc)) from None
        fit = fit_criteria.fit("sphere", np.array(pts))
        return np.asarray(fit.center, float)

    def measure(self, centre: np.ndarray, radius: float, normals: np.ndarray, *, repeats: int = 1,
                dither: float = 0.004, progress: Progress = None, checkpoint: "QualificationCheckpoint | None" = None,
                between: Callable[[], bool] | None = None) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """Latched tip centres (mean of ``repeats`` dithered hits) per normal; approach directions; skipped.

        A point whose hits fail (surface not found, contact) is skipped and reported, not fatal; a fault or E-STOP
        (motion inhibited) raises :class:`QualificationInterrupted` with ``checkpoint`` (the points so far),
        from which a later call goes on. ``between()`` is asked before each point; True: the run was paused, so
        the probe lifts to the safe height and comes back.
        """
        cp = checkpoint if checkpoint is not None else QualificationCheckpoint(np.asarray(centre, float))
        with short_approach(self.machine):
            for i in range(cp.next, len(normals)):
                n = normals[i]
                if between is not None and between():
                    if progress is not None:
                        progress(i / len(normals), "lifting to the clearance height after the pause")
                    self.lift_clear(centre, radius, margin=1.0)  # the centre is known: a small margin
                if progress is not None:
                    progress(i / len(normals), f"point {i + 1} of {len(normals)}")
                hits = []
                for k in range(repeats):
                    try:
                        hits.append(self.hit(centre, radius, n, dither if (repeats > 1) else 0.0).machine)
                    except MotionError as exc:
                        if getattr(self.machine, "inhibit", None):  # fault or E-STOP: stop, resumable after Reset
                            raise QualificationInterrupted(
                                f"stopped at point {i + 1} of {len(normals)}: {exc}", cp) from exc
                        cp.skipped.append(f"point {i + 1} ({exc})")
                        self.machine.reset()
                        break
                if len(hits) == repeats:
                    cp.points.append(np.mean(hits, axis=0))
                    cp.approaches.append(-unit(n))
                cp.next = i + 1
        if progress is not None:
            progress(1.0, f"{len(cp.points)} points measured")
        return (np.array(cp.points).reshape(-1, 3), np.array(cp.approaches).reshape(-1, 3), list(cp.skipped))


@dataclass
class QualificationCheckpoint:
    """How far a qualification got: the located sphere centre and the points measured (kept across a fault)."""

    centre: np.ndarray
    points: list = field(default_factory=list)  # mean latched tip centres
    approaches: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    next: int = 0  # index of the next point of the pattern
    key: tuple = ()  # (probe, sphere serial, diameter, pattern options): what a resume goes on with


class QualificationInterrupted(CalibrationError):
    """A fault or E-STOP stopped the qualification; ``checkpoint`` lets it go on after Reset."""

    def __init__(self, message: str, checkpoint: QualificationCheckpoint) -> None:
        super().__init__(message)
        self.checkpoint = checkpoint


# ----------------------------------------------------------------- analysis


@dataclass
class ProbeQualification:
    """What the qualification found; ``record`` is what gets saved."""

    record: ProbeRecord
    settings: ProbeSettings  # apply to the station's prober
    centre: np.ndarray  # fitted sphere centre (machine mm)
    radius_fit: float  # radius of the tip-centre sphere after the directional model, = D/2 + r_eff
    approach: np.ndarray  # (n, 3) approach directions
    centres: np.ndarray  # (n, 3) latched tip centres (averaged over repeats)
    residuals_before: np.ndarray  # mm, against the LS sphere, constant pre-travel
    residuals_after: np.ndarray  # mm, after the directional model
    skipped: list[str]
    probe: str = ""  # the probe (stylus) of the probe list it qualified

    def by_ring(self) -> list[dict[str, float]]:
        """Residual figures per polar angle of the pattern (um): for the benchmark and the wizard."""
        polar = np.degrees(np.arccos(np.clip(-self.approach[:, 2], -1, 1)))
        rows = []
        for p in sorted(set(np.round(polar, 1))):
            sel = np.abs(polar - p) < 0.05
            b, a = self.residuals_before[sel] * 1000, self.residuals_after[sel] * 1000
            rows.append({"polar_deg": float(p), "n": int(sel.sum()), "range_before_um": float(np.ptp(b)),
                         "range_after_um": float(np.ptp(a)), "rms_after_um": float(np.sqrt(np.mean(a * a)))})
        return rows


def _fit_sphere(points: np.ndarray, what: str):
    try:
        return fit_criteria.fit("sphere", points)
    except FitError as exc:
        raise CalibrationError(f"cannot fit a sphere to the {what}: {exc}") from None


def _usable_terms(approach: np.ndarray) -> tuple[str, ...]:
    """QUALIFICATION_TERMS, minus those the pattern cannot determine (e.g. one latitude only)."""
    terms = list(QUALIFICATION_TERMS)
    while len(terms) > 1:
        a = pretravel_basis(approach, tuple(terms))
        if np.linalg.matrix_rank(a, tol=1e-6 * max(1.0, np.abs(a).max())) == len(terms) and len(approach) >= len(terms) + 4:
            break
        terms.pop(1)  # drop z2 first (a single latitude), then the lobes
    return tuple(terms)


def analyse_qualification(centres: np.ndarray, approach: np.ndarray, certificate: SphereCertificate, *,
                          nominal_tip_radius: float, probing_speed: float = 0.0,
                          master_centre: Any = None, repeats: int = 1, machine: str = "",
                          skipped: list[str] | None = None) -> ProbeQualification:
    """Effective radius, centre and directional pre-travel from latched tip centres on the reference sphere."""
    t = np.asarray(centres, float).reshape(-1, 3)
    u = unit(np.asarray(approach, float).reshape(-1, 3))
    if len(t) < MIN_POINTS:
        raise CalibrationError(f"only {len(t)} valid points on the reference sphere; qualification needs at least "
                               f"{MIN_POINTS} (check for obstructions and the approximate centre)")
    half = certificate.diameter / 2
    fit0 = _fit_sphere(t, "latched tip centres")
    c0 = np.asarray(fit0.center, float)
    if not (0.0 < fit0.radius - half < 5.0 * nominal_tip_radius):
        raise CalibrationError(f"the fitted tip-centre sphere has radius {fit0.radius:.4f} mm, which does not fit a "
                               f"D {certificate.diameter} mm sphere and a {nominal_tip_radius} mm tip: wrong artifact?")
    e0 = np.linalg.norm(t - c0, axis=1) - fit0.radius
    # deeper latch = smaller radius = more pre-travel: the measured directional pre-travel is -e0
    terms = _usable_terms(u)
    # joint least squares of sphere and model: |T - c| = R - f(u), f without its constant (which R holds)
    rest = tuple(k for k in terms if k != "const")
    basis = pretravel_basis(u, rest) if rest else np.zeros((len(u), 0))

    def resid(p: np.ndarray) -> np.ndarray:
        return (np.linalg.norm(t - p[:3], axis=1) - p[3] + basis @ p[4:]) * 1000.0

    sol = least_squares(resid, np.concatenate([c0, [fit0.radius], np.zeros(len(rest))]), method="lm")
    f = basis @ sol.x[4:]
    const = -float(np.mean(f))  # zero mean over the pattern: the constant goes to r_eff
    model = PretravelModel({"const": const, **{k: float(v) for k, v in zip(rest, sol.x[4:])}})
    comp = t - model(u)[:, None] * u
    fit1 = _fit_sphere(comp, "compensated tip centres")
    e1 = np.linalg.norm(comp - np.asarray(fit1.center, float), axis=1) - fit1.radius
    c1 = np.asarray(fit1.center, float)
    r_eff = fit1.radius - half
    # uncertainty (k = 2) of r_eff: fit scatter over sqrt(n), the certificate, one count of scale in quadrature
    sigma = float(np.std(e1, ddof=min(len(e1) - 1, 4 + len(terms))))
    u_r = 2 * math.sqrt((sigma / math.sqrt(len(t))) ** 2 + (certificate.uncertainty / 4) ** 2)
    # standard uncertainties of the directional coefficients (the joint fit's covariance, residuals in um)
    res1 = sol.fun
    dof1 = max(1, len(res1) - len(sol.x))
    try:
        cov = np.linalg.inv(sol.jac.T @ sol.jac) * float(res1 @ res1) / dof1
        coef_u = {k: float(math.sqrt(max(cov[4 + i, 4 + i], 0.0)) * 1000.0) for i, k in enumerate(rest)}
    except np.linalg.LinAlgError:
        coef_u = {}
    # each term's mean over the pattern went into r_eff: an error of a coefficient moves a hit by (basis - mean)
    basis_mean = {k: float(v) for k, v in zip(rest, basis.mean(axis=0))} if rest else {}
    offset = (0.0, 0.0, 0.0) if master_centre is None else tuple(float(x) for x in c1 - np.asarray(master_centre))
    record = ProbeRecord(
        date=now(), artifact=certificate.describe(), tip_radius=float(r_eff),
        pretravel={k: float(v) for k, v in model.coefficients.items()},
        nominal_tip_radius=float(nominal_tip_radius), sphere_centre=tuple(float(x) for x in c1),  # type: ignore[arg-type]
        tip_offset=offset, probing_speed=float(probing_speed), n_points=int(len(t)),  # type: ignore[arg-type]
        form_before_um=float(np.ptp(e0) * 1000), form_after_um=float(np.ptp(e1) * 1000),
        uncertainty_um=float(u_r * 1000), machine=machine, pretravel_u_um=coef_u, pretravel_mean=basis_mean,
        hit_sigma_um=float(sigma * math.sqrt(max(1, repeats)) * 1000),
        note=f"{len(t)} points x {repeats} hits; pre-travel terms {', '.join(terms)} (zero mean)")
    return ProbeQualification(record, ProbeSettings(float(r_eff), model), c1, float(fit1.radius), u, t, e0, e1,
                              list(skipped or []))


def qualify_probe(machine: Machine, certificate: SphereCertificate, *, approx_centre: Any = None,
                  polar_deg: tuple[float, ...] = (35.0, 80.0, 120.0), per_ring: int = 24, repeats: int = 2,
                  master_centre: Any = None, progress: Progress = None, seed: int = 0,
                  tip_radius: float | None = None, resume: QualificationCheckpoint | None = None,
                  between: Callable[[], bool] | None = None, key: tuple = ()) -> ProbeQualification:
    """Automatic qualification: lift clear of the sphere to the safe height (a stopped run may have left the probe
    beside or under it), locate the sphere, measure the pattern, analyse. ``tip_radius``: the stylus's nominal
    radius (default: the configured one). ``resume``: the checkpoint of a run a fault stopped (located centre and
    points kept; only the rest is measured). ``between()``: asked before each point (True: it was paused).
    Nothing is saved or applied; a fault raises :class:`QualificationInterrupted`."""
    centre = approx_centre if approx_centre is not None else certificate.approx_centre
    if centre is None and resume is None:
        raise CalibrationError("the approximate centre of the reference sphere is unknown: give [setup] centre in its "
                               "certificate or --centre X,Y,Z")
    say = report(progress, 0.0, 1.0)
    sp = SphereProber(machine, seed=seed, tip_radius=tip_radius)
    radius = certificate.diameter / 2
    say(0.0, "lifting to the clearance height")
    if resume is not None:
        located = np.asarray(resume.centre, float)
        sp.lift_clear(located, radius, margin=1.0)
        say(0.01, f"resuming at point {resume.next + 1}: {len(resume.points)} points kept")
    else:
        sp.lift_clear(centre, radius)
        say(0.01, "locating the reference sphere (one hit near its top, four at the equator)")
        try:
            located = sp.locate(centre, radius)
        except MotionError as exc:
            if getattr(machine, "inhibit", None):
                raise CalibrationError(f"stopped while locating the sphere: {exc}") from exc
            raise
    cp = resume if resume is not None else QualificationCheckpoint(located, key=key)
    normals = qualification_pattern(polar_deg, per_ring)
    t, u, skipped = sp.measure(located, radius, normals, repeats=repeats,
                               progress=report(say, 0.05, 0.95), checkpoint=cp, between=between)
    sp.leave(located, radius, np.array([1.0, 0.0, 0.0]))
    say(0.97, "fitting the sphere and the directional pre-travel")
    result = analyse_qualification(t, u, certificate, nominal_tip_radius=sp.tip_radius,
                                   probing_speed=machine.config.speeds.probing, master_centre=master_centre,
                                   repeats=repeats, machine=machine.config.source, skipped=skipped)
    say(1.0, f"r_eff {result.record.tip_radius:.4f} mm, form {result.record.form_before_um:.2f} -> "
             f"{result.record.form_after_um:.2f} um")
    return result


def qualify_from_hits(hits: list[Hit], certificate: SphereCertificate, *, nominal_tip_radius: float,
                      master_centre: Any = None) -> ProbeQualification:
    """Guided manual qualification: the operator's hits on the reference sphere (any pattern, >= 9 points)."""
    if not hits:
        raise CalibrationError("no hits were taken on the reference sphere")
    t = np.array([h.machine for h in hits])
    u = np.array([h.approach for h in hits])
    result = analyse_qualification(t, u, certificate, nominal_tip_radius=nominal_tip_radius,
                                   probing_speed=float(np.mean([h.speed for h in hits])), master_centre=master_centre)
    result.record.note = f"guided manual: {result.record.note}"
    return result

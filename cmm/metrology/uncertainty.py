"""Task-specific measurement uncertainty of a fitted feature (GUM, ISO 15530-4 ideas): a budget per
characteristic, the expanded uncertainty U (about 95 % coverage) shown with each reported value.

Every term is a systematic or random pattern of errors of the hits, propagated through the least-squares fit
itself: the hits are moved by the pattern (along their surface normals, or by the machine's error field) and the
feature is fitted again; the change of each reported value is that term's sensitivity. The fit's own geometry
(a 5-hit cap, a short arc, a cone's apex far from its hits) therefore amplifies each source as it really does,
which the fit's scatter alone (its covariance) does not show for systematic errors.

Terms (standard uncertainties; ``Sources`` holds their inputs):

- probe, qualification: the effective tip radius is known to ``u_tip`` (the qualification's uncertainty): every
  hit moved along its normal by the same amount.
- probe, lobing: residual direction-dependent pre-travel ``lobing`` (mm, amplitude of a 3-lobed cos 3 phi
  pattern about Z) at an unknown phase: the RMS over the phase (two patterns in quadrature), and half the
  difference of vertical and horizontal pre-travel left after an isotropic qualification ``z_xy`` (horizontal
  hits +z_xy, vertical ones -z_xy: the pattern 1 - 2 n_z^2).
- probe, direction (replaces the two above when the qualification fitted a directional model, which the
  compensation applies): each coefficient's standard uncertainty ``pretravel_u``, a hit moved along its normal by
  (the term's basis at its direction - the term's mean over the qualification pattern, which r_eff holds).
- machine: per-axis scale and the three squareness errors, each with the standard uncertainty of a rectangular
  distribution of half-width 1 / K (um per mm) from the length-measuring MPE ``A + L / K`` (ISO 10360-2), or
  from the geometry calibration's residuals when one is given (``scale_u``, ``squareness_u``); the hits moved by
  that error field about ``reference`` (the part's origin: locations carry it, sizes do not).
- thermal: the part at ``temperature`` C against 20 C with an allowance ``temperature_allowance`` (rectangular
  half-width, K), its expansion coefficient ``cte`` known to ``cte_u``: a uniform expansion about ``reference``,
  uncorrected (u of the expansion ``L * sqrt((cte * dT)^2 + (cte_u * dT)^2 + (cte * allowance / sqrt 3)^2)``).
- scatter: the probing repeatability ``repeatability`` (one sigma, per hit, independent).
- sampling: the part's form the hits see beyond the repeatability (the fit's residual sigma), independent per
  hit, pooled with ``form_prior`` (the form expected of the feature, worth PRIOR_DOF degrees of freedom): a few
  residuals do not show the form reliably.
- the form value (max - min residual): its two extreme hits' residuals after the refit, U from the range of the
  residuals' errors, see ``_form_ends`` and ``_form_range_quantile``.

``cmm.metrology.uncertainty_inputs`` fills ``Sources`` from the station's calibration records, configuration and
session, each term's ``origin`` saying where its input came from.

Coverage factor (GUM G.4): every term but the sampling is taken as exactly known (infinite degrees of freedom);
the sampling term's form estimate has the residuals' degrees of freedom plus PRIOR_DOF. The effective degrees of
freedom of each value (Welch-Satterthwaite) give k = Student's t at 95.45 % (``coverage_factor``): exactly 2
when the sampling term is negligible, 2.1-2.3 for a few hits whose form the residuals barely show (U = k u_c
with k = 2 there covered only ~94.5-95 % on the simulator's error model, the errors' RMS matching u_c).

The sensitivities of the random terms use the hits one at a time (exact for the linearised fit). Values: size
(``diameter``, a cone's ``half_angle_deg``), location (``x``, ``y``, ``z``: a centre, an apex, the axis point
at the hits' centroid, a plane's offset along its normal as ``offset``) in mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

K_COVERAGE = 2.0  # the coverage factor at infinite degrees of freedom (the normal distribution's 95.45 %)
COVERAGE = math.erf(K_COVERAGE / math.sqrt(2.0))  # 0.9545: the probability k = 2 gives a normal error
PRIOR_DOF = 8  # degrees of freedom the form prior is worth against the residuals' own
SOURCES_DOC = ("probe qualification", "probe lobing", "probe Z/XY", "machine scale", "machine squareness",
               "thermal", "scatter", "sampling")


@dataclass(frozen=True)
class Sources:
    """Inputs of the budget (mm, K, 1/K); defaults: the station's probe and the configured MPE."""

    u_tip: float = 0.0004  # standard uncertainty of the qualified effective tip radius
    lobing: float = 0.0015  # residual 3-lobed pre-travel amplitude
    z_xy: float = 0.001  # residual vertical vs horizontal pre-travel difference
    repeatability: float = 0.00025  # one sigma per hit
    mpe_a_um: float = 2.2  # MPE_E = A + L / K um (ISO 10360-2)
    mpe_k: float = 300.0
    scale_u: float | None = None  # per-axis scale, relative (None: from the MPE)
    squareness_u: float | None = None  # rad (None: from the MPE)
    temperature: float = 20.0  # part temperature, C
    temperature_allowance: float = 1.0  # K, rectangular half-width around it
    cte: float = 11.5e-6  # 1/K (steel; aluminium 23e-6)
    cte_u: float = 1.0e-6
    form_prior: float = 0.001  # mm, one sigma of form expected when the residuals cannot show it
    reference: tuple[float, float, float] | None = None  # the part's origin (machine); None: the hits' centroid
    # the qualification's directional pre-travel model: standard uncertainty of each coefficient (mm) and each
    # basis term's mean over the qualification pattern; when given it replaces ``lobing`` and ``z_xy`` (the
    # compensation corrects those; what is left is how well the coefficients are known)
    pretravel_u: dict[str, float] | None = None
    pretravel_mean: dict[str, float] | None = None
    scale_temperature: float = 20.0  # the machine's scales, C (their expansion is not corrected either)
    scale_cte: float = 0.0  # 1/K; 0: scales taken as compensated (or of zero expansion)
    origin: dict[str, str] | None = None  # budget term -> where its input came from (shown with the term)

    @classmethod
    def from_config(cls, config: Any = None, **overrides: Any) -> "Sources":
        """From a station configuration's ``uncertainty`` table (any field above), then ``overrides``."""
        table = {}
        if config is not None:
            raw = config.get("uncertainty", {}) if isinstance(config, dict) else getattr(config, "uncertainty", {})
            table = dict(raw or {})
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in {**table, **overrides}.items() if k in known})

    def machine_scale_u(self) -> float:
        return self.scale_u if self.scale_u is not None else 1e-3 / self.mpe_k / math.sqrt(3.0)

    def machine_squareness_u(self) -> float:
        return self.squareness_u if self.squareness_u is not None else 1e-3 / self.mpe_k / math.sqrt(3.0)

    def thermal_u(self) -> float:
        """Relative standard uncertainty of the uncorrected expansion of the part against the scales."""
        dt = self.temperature - 20.0
        ds = self.scale_temperature - 20.0
        return math.sqrt((self.cte * dt - self.scale_cte * ds) ** 2 + (self.cte_u * dt) ** 2
                         + (self.cte * self.temperature_allowance / math.sqrt(3.0)) ** 2)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields (``from_dict`` reads them back)."""
        out: dict[str, Any] = {}
        for k in self.__dataclass_fields__:
            v = getattr(self, k)
            out[k] = list(v) if isinstance(v, tuple) else (dict(v) if isinstance(v, dict) else v)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None, **overrides: Any) -> "Sources":
        """The inputs a budget recorded (``as_dict``); unknown keys are ignored."""
        known = set(cls.__dataclass_fields__)
        d = {k: v for k, v in {**(data or {}), **overrides}.items() if k in known}
        if d.get("reference") is not None:
            d["reference"] = tuple(float(v) for v in d["reference"])
        return cls(**d)

    def origin_of(self, term: str) -> str:
        return (self.origin or {}).get(term, "default")


@dataclass
class Term:
    source: str
    note: str
    u: dict[str, float]  # value name -> standard uncertainty contribution
    origin: str = "default"  # where the input came from: a calibration record, the configuration, a default
    dof: float = math.inf  # degrees of freedom of its standard uncertainty (GUM G.3; inf: taken as known)


def coverage_factor(nu_eff: float) -> float:
    """k for a coverage of 95.45 % at ``nu_eff`` effective degrees of freedom (Student's t; 2 at infinity)."""
    if not math.isfinite(nu_eff) or nu_eff > 1e6:
        return K_COVERAGE
    from scipy.stats import t as student_t

    return float(student_t.ppf(0.5 + COVERAGE / 2.0, max(nu_eff, 1.0)))


@dataclass
class Budget:
    kind: str
    values: dict[str, float]
    terms: list[Term] = field(default_factory=list)
    reference: tuple[float, ...] | None = None  # the point the machine's and thermal errors were taken about
    sources: "Sources | None" = None  # the inputs (kept with the budget: re-evaluation uses the same)
    k_given: dict[str, float] = field(default_factory=dict)  # k of values whose error is not normal (the form)

    def combined(self) -> dict[str, float]:
        return {k: math.sqrt(sum(t.u.get(k, 0.0) ** 2 for t in self.terms)) for k in self.values}

    def effective_dof(self) -> dict[str, float]:
        """Welch-Satterthwaite: u_c^4 / sum(u_i^4 / nu_i) per value (inf when every term is taken as known)."""
        out = {}
        for k, uc in self.combined().items():
            den = sum(t.u.get(k, 0.0) ** 4 / t.dof for t in self.terms if math.isfinite(t.dof) and t.dof > 0)
            out[k] = uc ** 4 / den if den > 0 and uc > 0 else math.inf
        return out

    def coverage_factors(self) -> dict[str, float]:
        """k per value: Student's t at 95.45 % for its effective degrees of freedom (2 when they are many)."""
        return {k: self.k_given.get(k, coverage_factor(nu)) for k, nu in self.effective_dof().items()}

    def expanded(self) -> dict[str, float]:
        """U = k u_c per value (k from ``coverage_factors``)."""
        ks = self.coverage_factors()
        return {k: ks[k] * v for k, v in self.combined().items()}

    def summary(self) -> dict[str, Any]:
        """JSON-ready: values, U, k and the effective degrees of freedom per value (null: infinite), and the terms
        (standard uncertainties, mm / deg)."""
        nu = self.effective_dof()
        return {"k": self.coverage_factors(), "U": self.expanded(), "u_c": self.combined(),
                "nu_eff": {k: (None if not math.isfinite(v) else float(v)) for k, v in nu.items()},
                "terms": [{"source": t.source, "note": t.note, "u": t.u, "from": t.origin,
                           **({} if not math.isfinite(t.dof) else {"dof": t.dof})} for t in self.terms],
                "reference": None if self.reference is None else [float(v) for v in self.reference],
                **({} if self.sources is None else {"inputs": self.sources.as_dict()})}

    def text(self) -> str:
        """The budget as lines for the feature's detail."""
        names = list(self.values)
        rows = [f"{'source':22s}" + "".join(f"{n:>12s}" for n in names) + "  from"]
        for t in self.terms:
            rows.append(f"{t.source:22s}" + "".join(f"{t.u.get(n, 0.0) * 1000:10.2f}um" for n in names)
                        + f"  {t.origin}")
        rows.append(f"{'k (95 %)':22s}" + "".join(f"{v:12.2f}" for v in self.coverage_factors().values()))
        rows.append(f"{'U = k u_c':22s}" + "".join(f"{v * 1000:10.2f}um" for v in self.expanded().values()))
        return "\n".join(rows)


# ---------------------------------------------------------------- the reported values of a fit


def values_of(kind: str, fit: Any, centroid: np.ndarray) -> dict[str, float]:
    """The reported values of a fitted feature (see the module doc)."""
    if kind in ("circle", "sphere"):
        c = np.asarray(fit.center, float)
        return {"diameter": 2.0 * float(fit.radius), "x": c[0], "y": c[1], "z": c[2]}
    if kind == "cylinder":
        u = np.asarray(fit.direction, float)
        p = np.asarray(fit.point, float)
        foot = p + ((centroid - p) @ u) * u
        return {"diameter": 2.0 * float(fit.radius), "x": foot[0], "y": foot[1], "z": foot[2]}
    if kind == "cone":
        a = np.asarray(fit.apex, float)
        return {"half_angle_deg": math.degrees(float(fit.half_angle)), "x": a[0], "y": a[1], "z": a[2]}
    if kind == "plane":
        n = np.asarray(fit.normal, float)
        return {"offset": float((np.asarray(fit.point, float) - centroid) @ n)}
    if kind in ("point", "line"):
        p = np.asarray(fit.point, float)
        return {"x": p[0], "y": p[1], "z": p[2]}
    raise ValueError(f"no uncertainty budget for a {kind}")


def _refit(kind: str, points: np.ndarray, start: Any) -> Any:
    from .fit_ls import LS_FITS

    if kind in ("cylinder", "cone"):
        g = {"direction": start.direction}
        if kind == "cone":
            g.update(apex=start.apex, half_angle=start.half_angle)
        else:
            g.update(point=start.point, radius=start.radius)
        return LS_FITS[kind](points, nominal=g)
    if kind in ("circle", "sphere"):
        return LS_FITS[kind](points, nominal={"center": start.center, "radius": start.radius})
    return LS_FITS[kind](points)


class _Axial:
    """A cylinder or cone as parameters (axis point 3, two tilts, radius or half angle) for linearised
    sensitivities: its multi-start least-squares fit takes a second, too slow to repeat per term."""

    def __init__(self, kind: str, fit: Any) -> None:
        from .geom_basics import frame_with_axis

        self.kind = kind
        self.u0 = np.asarray(fit.direction, float)
        self.frame = frame_with_axis(self.u0)
        if kind == "cylinder":  # the axis point moves across the axis only (along it, it is no parameter)
            self.origin = np.asarray(fit.point, float)
            self.p0 = np.r_[0.0, 0.0, 0.0, 0.0, float(fit.radius)]
        else:
            self.p0 = np.r_[np.asarray(fit.apex, float), 0.0, 0.0, float(fit.half_angle)]

    def geometry(self, p: np.ndarray) -> dict[str, Any]:
        if self.kind == "cylinder":
            u = self.u0 + p[2] * self.frame[:, 0] + p[3] * self.frame[:, 1]
            point = self.origin + p[0] * self.frame[:, 0] + p[1] * self.frame[:, 1]
            return {"point": point, "direction": u / np.linalg.norm(u), "radius": p[4]}
        u = self.u0 + p[3] * self.frame[:, 0] + p[4] * self.frame[:, 1]
        return {"apex": p[:3], "direction": u / np.linalg.norm(u), "half_angle": p[5]}

    def as_fit(self, p: np.ndarray) -> Any:
        from types import SimpleNamespace

        g = self.geometry(p)
        return SimpleNamespace(**g)


def _linear_sensitivity(kind: str, fit: Any, x: np.ndarray, centroid: np.ndarray):
    """f(moved) -> change of each value for point displacements ``moved`` (linearised least squares)."""
    from .feature_distance import surface_distance

    model = _Axial(kind, fit)
    p0 = model.p0
    h = 1e-6
    d0 = surface_distance(kind, model.geometry(p0), x)
    jac = np.zeros((len(x), len(p0)))
    v0 = values_of(kind, model.as_fit(p0), centroid)
    vj = np.zeros((len(v0), len(p0)))
    for k in range(len(p0)):
        e = np.zeros(len(p0))
        e[k] = h
        jac[:, k] = (surface_distance(kind, model.geometry(p0 + e), x) - d0) / h
        vk = values_of(kind, model.as_fit(p0 + e), centroid)
        vj[:, k] = [(vk[n] - v0[n]) / h for n in v0]
    pinv = np.linalg.pinv(jac, rcond=1e-10)
    normals = _normals(kind, model.geometry(p0), x)
    names = list(v0)

    def change(moved: np.ndarray) -> tuple[dict[str, float], np.ndarray]:
        """(change of each value, change of each hit's residual) for the point displacements ``moved``."""
        dd = np.einsum("ij,ij->i", normals, moved)  # the distances grow by the displacement along the normal
        dp = -pinv @ dd
        dv = vj @ dp
        return {n: float(dv[i]) for i, n in enumerate(names)}, dd + jac @ dp

    return change


def _normals(kind: str, geometry: dict[str, Any], points: np.ndarray) -> np.ndarray:
    """Outward unit normals of the feature's surface at the points (the gradient of the signed distance)."""
    from .feature_distance import surface_distance

    h = 1e-5
    grad = np.zeros_like(points)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        grad[:, k] = (surface_distance(kind, geometry, points + e) - surface_distance(kind, geometry, points - e)) / (2 * h)
    return grad / np.linalg.norm(grad, axis=1)[:, None]


def _geometry(kind: str, fit: Any) -> dict[str, Any]:
    s = fit.summary()
    if kind == "cone":
        s["half_angle"] = float(fit.half_angle)
    return s


def budget(kind: str, points: Any, fit: Any = None, sources: Sources | None = None) -> Budget:
    """The uncertainty budget of feature ``kind`` fitted (least squares) to ``points`` (compensated hits, mm)."""
    from .fit_ls import LS_FITS

    src = sources or Sources()
    x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    fit = fit if fit is not None else LS_FITS[kind](x)
    centroid = x.mean(axis=0)
    base = values_of(kind, fit, centroid)
    if kind == "point":
        n = np.asarray(getattr(fit, "normal", [0, 0, 1.0]), float).reshape(1, 3)
    else:
        n = _normals(kind, _geometry(kind, fit), x)
    ref = centroid if src.reference is None else np.asarray(src.reference, float)

    linear = _linear_sensitivity(kind, fit, x, centroid) if kind in ("cylinder", "cone") else None

    resid = np.asarray(getattr(fit, "residuals", np.zeros(0)), float)
    # the form value (max - min residual) moves with the residuals of its two extreme hits, after the refit
    ends = _form_ends(kind, resid, len(x))
    last = [np.zeros(len(x))]  # the residuals' change per unit of the last pattern (the form's Monte Carlo)
    form_sys: list[np.ndarray] = []  # each systematic pattern's residual change at its standard uncertainty

    def delta(moved: np.ndarray, scale: float) -> dict[str, float]:
        """Change of each value per unit of the pattern ``moved`` (point displacements for ``scale``), with the
        form's (``form``) when the feature has one."""
        if linear is not None:
            dv, dr = linear(moved)
            out = {k: v / scale for k, v in dv.items()}
        else:
            try:
                refit = _refit(kind, x + moved, fit)
                v = values_of(kind, refit, centroid)
            except Exception:  # noqa: BLE001 - a pattern the fit cannot take adds nothing it could say
                last[0] = np.zeros(len(x))
                return {k: 0.0 for k in base} | ({"form": 0.0} if ends else {})
            out = {k: (v[k] - base[k]) / scale for k in base}
            if ends:
                r = np.asarray(refit.residuals, float)
                if kind == "plane" and float(np.dot(refit.normal, fit.normal)) < 0:  # its residuals' sign flips too
                    r = -r
                dr = r - resid
        if ends:
            out["form"] = float(dr[ends[0]] - dr[ends[1]]) / scale
            last[0] = dr / scale
        return out

    def systematic(pattern: np.ndarray, u: float, scale: float = 1e-3) -> dict[str, float]:
        """A bias along the normals (per unit ``pattern``) of standard uncertainty ``u``."""
        d = delta(scale * pattern[:, None] * n, scale)
        form_sys.append(last[0] * u)
        return {k: abs(v) * u for k, v in d.items()}

    names = list(base) + (["form"] if ends else [])

    def quad(*parts: dict[str, float]) -> dict[str, float]:
        return {k: math.sqrt(sum(p.get(k, 0.0) ** 2 for p in parts)) for k in names}

    terms: list[Term] = []
    ones = np.ones(len(x))
    terms.append(Term("probe qualification", f"effective tip radius known to {src.u_tip * 1000:.2f} um",
                      systematic(ones, src.u_tip), src.origin_of("probe qualification")))
    if src.pretravel_u:
        # the directional model the station compensates with: each coefficient known to u_k; its error moves a
        # hit along the approach by (basis_k - its mean over the qualification pattern, which r_eff holds)
        from .compensation import pretravel_basis

        keys = tuple(k for k in src.pretravel_u if k != "const")
        if keys:
            basis = pretravel_basis(-n, keys)
            mean = src.pretravel_mean or {}
            parts = [systematic(basis[:, i] - mean.get(k, 0.0), src.pretravel_u[k]) for i, k in enumerate(keys)]
            terms.append(Term("probe direction", "pre-travel model (" + ", ".join(
                f"{k} +-{src.pretravel_u[k] * 1000:.2f}" for k in keys) + " um)", quad(*parts),
                src.origin_of("probe direction")))
    else:
        phi = np.arctan2(-n[:, 1], -n[:, 0])
        horizontal = n[:, 0] ** 2 + n[:, 1] ** 2
        lob = quad(systematic(horizontal * np.cos(3 * phi), src.lobing / math.sqrt(2.0)),
                   systematic(horizontal * np.sin(3 * phi), src.lobing / math.sqrt(2.0)))
        terms.append(Term("probe lobing", f"3-lobed residual pre-travel {src.lobing * 1000:.2f} um, phase unknown",
                          lob, src.origin_of("probe lobing")))
        # an isotropic qualification leaves horizontal hits +z_xy and vertical ones -z_xy (or the other way round)
        terms.append(Term("probe Z/XY", f"vertical vs horizontal pre-travel residual +-{src.z_xy * 1000:.2f} um",
                          systematic(horizontal - n[:, 2] ** 2, src.z_xy), src.origin_of("probe Z/XY")))
    rel = x - ref
    su, qu = src.machine_scale_u(), src.machine_squareness_u()
    scale_parts = []
    for k in range(3):
        m = np.zeros_like(x)
        m[:, k] = rel[:, k]
        d = delta(1e-4 * m, 1e-4)
        form_sys.append(last[0] * su)
        scale_parts.append({kk: abs(v) * su for kk, v in d.items()})
    terms.append(Term("machine scale", f"per axis, u = {su * 1e6:.2f} um/m", quad(*scale_parts),
                      src.origin_of("machine scale")))
    sq_parts = []
    for a, b in ((0, 1), (0, 2), (1, 2)):
        m = np.zeros_like(x)
        m[:, a] = rel[:, b]
        d = delta(1e-4 * m, 1e-4)
        form_sys.append(last[0] * qu)
        sq_parts.append({kk: abs(v) * qu for kk, v in d.items()})
    terms.append(Term("machine squareness", f"xy, xz, yz, u = {qu * 1e6:.2f} urad", quad(*sq_parts),
                      src.origin_of("machine squareness")))
    d = delta(1e-4 * rel, 1e-4)
    tu = src.thermal_u()
    form_sys.append(last[0] * tu)
    terms.append(Term("thermal", f"part at {src.temperature:g} C +- {src.temperature_allowance:g} K, CTE "
                                 f"{src.cte * 1e6:g} +- {src.cte_u * 1e6:g} um/m/K", {k: abs(v) * tu for k, v in d.items()},
                      src.origin_of("thermal")))
    # random terms: the hits one at a time
    sens = {k: 0.0 for k in names}
    hat = np.zeros((len(x), len(x)))  # row i: the residuals' change per unit error of hit i (I - the hat matrix)
    for i in range(len(x)):
        e = np.zeros(len(x))
        e[i] = 1.0
        di = delta(1e-3 * e[:, None] * n, 1e-3)
        hat[i] = last[0]
        for k in names:
            sens[k] += di[k] ** 2
    g = {k: math.sqrt(v) for k, v in sens.items()}
    terms.append(Term("scatter", f"repeatability {src.repeatability * 1000:.2f} um per hit",
                      {k: v * src.repeatability for k, v in g.items()}, src.origin_of("scatter")))
    form, seen, nu = sampling_form(kind, resid, src, len(x))
    dof = nu
    note = f"form seen by {len(x)} hits {seen * 1000:.2f} um, pooled with the prior: {form * 1000:.2f} um"
    if dof < 3:
        note = f"{len(x)} hits ({nu} residual degrees of freedom): form assumed {form * 1000:.2f} um"
    # its degrees of freedom (the residuals' and the prior's) set k through the value's effective ones
    # the form value's measurand is the part's form under the hits: the sampling adds nothing to its error
    terms.append(Term("sampling", note, {k: v * form for k, v in g.items() if k != "form"},
                      f"the hits' residuals and {src.origin_of('sampling')} prior", dof=float(nu + PRIOR_DOF)))
    k_given = {}
    if ends:
        base["form"] = float(getattr(fit, "form", resid[ends[0]] - resid[ends[1]]))
        for t in terms:
            t.u.setdefault("form", 0.0)
        uc = math.sqrt(sum(t.u["form"] ** 2 for t in terms))
        if uc > 0:
            k_given["form"] = _form_range_quantile(np.array(form_sys), hat, src.repeatability) / uc
    if kind == "cone":  # the half angle in degrees
        for t in terms:
            if "half_angle_deg" in t.u:
                t.u["half_angle_deg"] = float(t.u["half_angle_deg"])
    return Budget(kind, {k: float(v) for k, v in base.items()}, terms, src.reference, src, k_given)


def sampling_form(kind: str, resid: np.ndarray, src: Sources, n_hits: int) -> tuple[float, float, int]:
    """(the form sigma the sampling term uses, the form the residuals show beyond the scatter, their degrees of
    freedom): the residuals' form pooled with the prior (worth PRIOR_DOF degrees of freedom): a few residuals
    estimate it poorly (3 of them give a sigma anywhere from 0.2 to 1.8 times the truth)."""
    n_params = {"plane": 3, "line": 4, "circle": 6, "sphere": 4, "cylinder": 5, "cone": 6, "point": 3}.get(kind, 3)
    dof = n_hits - n_params
    sigma = float(np.sqrt(resid @ resid / dof)) if dof > 0 and resid.size else 0.0
    seen = math.sqrt(max(0.0, sigma ** 2 - src.repeatability ** 2)) if dof > 0 else 0.0
    nu = max(dof, 0)
    return math.sqrt((nu * seen ** 2 + PRIOR_DOF * src.form_prior ** 2) / (nu + PRIOR_DOF)), seen, nu


FORM_KINDS = ("plane", "circle", "sphere", "cylinder", "cone")


def _form_ends(kind: str, resid: np.ndarray, n_hits: int) -> tuple[int, int] | None:
    """The hits furthest out and furthest in (the form value is the difference of their residuals), or None for a
    feature without a form value.

    Every pattern of errors moves the form by the change of those two residuals after the refit: what the fit
    absorbs (a uniform offset, the tip radius, the machine's and the part's affine errors on a plane) cancels,
    and each hit's scatter counts through the residuals' projection (R = I - the fit's hat matrix: var(r_a - r_b)
    = sigma^2 (R_aa + R_bb - 2 R_ab)), not as two independent hits: with few residual degrees of freedom the
    extreme residuals are strongly correlated and the fit takes up most of each hit's error."""
    if kind not in FORM_KINDS or resid.size != n_hits or resid.size < 2:
        return None
    return int(np.argmax(resid)), int(np.argmin(resid))


FORM_DRAWS = 4000  # Monte Carlo draws of the residuals' errors for the form's U (fixed seed: a budget is repeatable)


def _form_range_quantile(systematic: np.ndarray, hat: np.ndarray, repeatability: float) -> float:
    """The 95.45 % quantile of the range (max - min) of the residuals' errors over the budget's terms (GUM
    Supplement 1: each systematic pattern a normal coefficient at its standard uncertainty, each hit's scatter
    through the fit): |measured form - true form| <= range(residual errors), whichever hits are the extremes.
    Where the form is much larger than the errors, the two extreme hits stay the extremes and the error is the
    change of their two residuals (the terms' linear ``form`` contributions); where the form is small against the
    errors (a nearly perfect part) other hits take over and the range of the errors is what bounds it."""
    rng = np.random.default_rng(0)
    dr = rng.standard_normal((FORM_DRAWS, len(hat))) @ hat * repeatability
    if systematic.size:
        dr += rng.standard_normal((FORM_DRAWS, len(systematic))) @ systematic
    return float(np.quantile(np.ptp(dr, axis=1), COVERAGE))


def expanded(kind: str, points: Any, fit: Any = None, sources: Sources | None = None) -> dict[str, float]:
    """U (k from ``Budget.coverage_factors``) of each reported value of the feature (mm; a cone's half angle in
    degrees)."""
    return budget(kind, points, fit, sources).expanded()


def with_reference(sources: Sources, reference: Any) -> Sources:
    return replace(sources, reference=None if reference is None else tuple(float(v) for v in reference))


def characteristic_u(name: str, expanded_u: dict[str, float] | None) -> float | None:
    """U of a reported characteristic (cmm.metrology.characteristics names) from a feature's budget's U per value
    (the same propagation of its u_c gives the characteristic's u_c); None where the budget has no term for it
    (constructed values)."""
    if not expanded_u:
        return None
    if name == "diameter":
        return expanded_u.get("diameter")
    if name == "half angle":
        return expanded_u.get("half_angle_deg")
    if name in ("flatness", "straightness", "roundness", "cylindricity", "sphericity", "cone form"):
        return expanded_u.get("form")
    if name.startswith("location"):
        return expanded_u.get("offset")
    if name.startswith("position"):  # the diameter 2 |deviation|: conservatively all three coordinates
        xyz = [expanded_u.get(k) for k in ("x", "y", "z")]
        return None if any(v is None for v in xyz) else 2.0 * math.sqrt(sum(v * v for v in xyz))  # type: ignore[operator]
    return None


def characteristic_k(name: str, summary: dict | None) -> float | None:
    """The coverage factor of a characteristic's U (``characteristic_u``) from a budget summary: its U over the
    same propagation of the u_c (a position combines three values, each with its own k)."""
    U = characteristic_u(name, (summary or {}).get("U"))
    u = characteristic_u(name, (summary or {}).get("u_c"))
    if U is None or not u:
        return None
    return U / u


def feature_budget(kind: str, method: str, points: Any, fit: Any, sources: Sources | None = None) -> dict | None:
    """The budget of a station feature as its record keeps it (``{"U": .., "u_c": .., "terms": ..}``), or None
    when none is defined (criteria other than least squares, kinds without one, too few hits)."""
    if method != "ls" or kind not in ("plane", "circle", "sphere", "cylinder", "cone", "point"):
        return None
    try:
        return budget(kind, points, fit, sources).summary()
    except Exception:  # noqa: BLE001 - the budget is help; the feature stands without one
        return None


def plan_note(kind: str, points: Any, nominal: Any = None, tolerance: dict[str, float] | None = None,
              sources: Sources | None = None) -> str:
    """A sentence for a hit plan whose expected U (about 95 %; the budget of its exact nominal points, the form prior
    for the sampling) is more than a quarter of the feature's tolerance zone (2 x the +- tolerance), else ""."""
    from .characteristics import DEFAULT_TOLERANCE
    from .fit_ls import LS_FITS

    tol = {**DEFAULT_TOLERANCE, **(tolerance or {})}
    x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    try:
        fit = LS_FITS[kind](x, nominal=nominal) if nominal is not None and kind in ("cylinder", "cone") else \
            LS_FITS[kind](x)
        b = budget(kind, x, fit, sources)
        expected, ks = b.expanded(), b.coverage_factors()
    except Exception:  # noqa: BLE001 - no expectation: nothing to say
        return ""
    name, key, zone = ("diameter", "diameter", 2 * tol["size"]) if "diameter" in expected else (
        ("location", "offset", 2 * tol["location"]) if "offset" in expected else ("", "", 0.0))
    value = expected.get(key)
    if value is None or value <= zone / 4:
        return ""
    return (f"the expected uncertainty of the {name} with these {len(x)} hits is U = {value * 1000:.1f} um "
            f"(k={ks[key]:.2f}), "
            f"more than a quarter of its {zone:.3f} mm tolerance zone: take more hits, or accept a U that large")

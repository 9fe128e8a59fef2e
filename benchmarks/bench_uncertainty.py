"""Coverage of the uncertainty budget (cmm.metrology.uncertainty) on the simulator's error model.

    python3 benchmarks/bench_uncertainty.py [--trials 200] [--seed 1] [--local-fits] [--gdt]

Each sample-part feature (the simulator's true geometry at its true pose) is measured ``--trials`` times with
the station's default hit plans (plane 4 hits, cylinders and cone 2 rings of 4, the sphere cap the pole and 4 at
45 deg). Each hit carries the simulator's error sources (cmm.sim.probe_world): the probe's pre-travel (4 um
horizontal with a 1.5 um 3-lobed pattern at a random phase per trial, 2 um vertical) left after an isotropic
qualification (its mean, known to u_tip), the trigger noise (0.25 um), the machine's per-axis scale and
squareness errors (drawn within the MPE's 1/K per trial), and the part's expansion at a temperature within the
allowance. The budget is computed from the measured hits alone; the error is the fitted value minus the true
one. Printed per feature and value: coverage (|error| <= U), the worst |error| / U, and U / the observed spread
(the standard deviation of the errors) and U / the RMS error (their spread about the truth, which U is
compared to: a value that cannot go negative, read near a true value of 0, has a folded error whose standard
deviation is 0.60 sigma while its 95 % point is 1.96 sigma): targets >= 95 %, < 2, <= 3. A count of 200
trials scatters by about +-1.4 % around the true coverage (binomial), U / spread by about +-5 %:
``--local-fits`` (cylinders and cones fitted by local least squares from the true geometry, the same minimum as
the station's multi-start fit on errors of a few um, about 50 times faster) makes 2000 trials a feature a five-minute run. ``--gdt``: geometric
tolerances against datums instead (``run_gdt``: the boss's position to A|B and perpendicularity to A, the
features and their datums measured in one set-up a trial), with their U (cmm.metrology.uncertainty_gdt).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cmm.calibration.probe import analyse_qualification, qualification_pattern  # noqa: E402
from cmm.calibration.records import SphereCertificate  # noqa: E402
from cmm.metrology.fit_ls import LS_FITS  # noqa: E402
from cmm.metrology.uncertainty_inputs import probe_sources  # noqa: E402
from cmm.metrology.uncertainty import Sources, budget, values_of  # noqa: E402
from cmm.sim.cmm_sim import TRUE_PART_POSE  # noqa: E402
from cmm.sim.probe_world import ProbeModel  # noqa: E402

PROBE = ProbeModel()
U_TIP = 0.0004


def _ring(c, axis, r, z, n, turn=0.0, half_angle=None):
    axis = np.asarray(axis, float)
    e1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False) + turn
    return np.array([c + z * axis + r * (math.cos(a) * e1 + math.sin(a) * e2) for a in t])


def plans() -> dict[str, tuple[str, np.ndarray]]:
    """Exact surface points of the default hit plans, part coordinates."""
    out = {}
    out["top_plane"] = ("plane", np.array([[10, 10, 40], [110, 8, 40], [112, 72, 40], [8, 70, 40.0]]))
    bore = np.r_[_ring(np.array([30, 40, 0.0]), [0, 0, 1], 15, 8, 4), _ring(np.array([30, 40, 0.0]), [0, 0, 1], 15,
                                                                            32, 4, math.pi / 4)]
    out["bore"] = ("cylinder", bore)
    boss = np.r_[_ring(np.array([70, 22, 40.0]), [0, 0, 1], 10, 3, 4), _ring(np.array([70, 22, 40.0]), [0, 0, 1], 10,
                                                                             12, 4, math.pi / 4)]
    out["boss"] = ("cylinder", boss)
    c = np.array([70, 58, 39.0])
    ring = _ring(c, [0, 0, 1], 10 * math.cos(math.pi / 4), 10 * math.sin(math.pi / 4), 4, math.pi / 4)
    out["dome"] = ("sphere", np.r_[[c + [0, 0, 10]], ring])
    apex, half = np.array([100, 40, 64.0]), math.atan(0.5)
    cone = []
    for depth, turn in ((14.4, 0.0), (21.6, math.pi / 4)):  # a fifth and four fifths of Z 52 .. 40
        z = 64.0 - depth
        cone.append(_ring(np.array([100, 40, z]), [0, 0, 1], depth * math.tan(half), 0.0, 4, turn))
    out["cone"] = ("cone", np.vstack(cone))
    return out


_NORMALS: dict[tuple, np.ndarray] = {}
SPHERE = SphereCertificate("reference sphere", 25.0, uncertainty=0.0003)
SPHERE_CENTRE = np.array([400.0, 300.0, 100.0])


def _pretravel(n: np.ndarray, phase: float) -> np.ndarray:
    """The simulated probe's pre-travel for outward normals ``n`` (cmm.sim.probe_world.ProbeModel, lobes at
    ``phase``)."""
    phi = np.arctan2(-n[:, 1], -n[:, 0])
    s2 = n[:, 0] ** 2 + n[:, 1] ** 2
    return s2 * (PROBE.pretravel_xy + PROBE.pretravel_lobe * np.cos(3 * phi + phase)) + (1 - s2) * PROBE.pretravel_z


def qualify(rng: np.random.Generator, phase: float, g: np.ndarray, repeats: int = 2):
    """The station's probe qualification (cmm.calibration.probe.analyse_qualification) of the simulated probe on
    the 25 mm reference sphere: the default pattern (3 rings of 24 and the pole), ``repeats`` hits averaged per
    point, the machine's geometry ``g`` about the sphere. Returns the probe record."""
    n = qualification_pattern((35.0, 80.0, 120.0), 24)
    depth = np.mean([_pretravel(n, phase) + rng.normal(0, PROBE.noise_sigma, len(n)) for _ in range(repeats)], axis=0)
    t = SPHERE_CENTRE + ((SPHERE.diameter / 2 + PROBE.tip_radius - depth)[:, None] * n) @ g.T
    return analyse_qualification(t, -n, SPHERE, nominal_tip_radius=PROBE.tip_radius, repeats=repeats).record


def measure(kind: str, true_pts: np.ndarray, rng: np.random.Generator, pose: np.ndarray, form: float = 0.0,
            isotropic: bool = False):
    """Machine hits of exact surface points with the simulator's error sources; (hits, truth, sources).

    The probe (its lobes at a random phase) is qualified first as the station does, and the hits compensated
    with its record's directional model (``isotropic``: with its mean pre-travel only, the budget's nominal probe
    figures); ``form``: the part's form under each hit (one sigma, mm)."""
    key = (kind, true_pts.tobytes())
    if key not in _NORMALS:
        fit = LS_FITS[kind](true_pts) if kind != "cone" else LS_FITS[kind](true_pts, nominal={
            "apex": [100, 40, 64.0], "direction": [0, 0, -1.0], "half_angle": math.atan(0.5)})
        from cmm.metrology.uncertainty import _geometry, _normals

        _NORMALS[key] = _normals(kind, _geometry(kind, fit), true_pts)
    n = _NORMALS[key]
    phase = rng.uniform(0, 2 * np.pi)
    mpe_k = Sources().mpe_k
    h = 1e-3 / mpe_k
    g = np.eye(3) + np.diag(rng.uniform(-h, h, 3))
    g[0, 1], g[0, 2], g[1, 2] = rng.uniform(-h, h, 3)
    delta = _pretravel(n, phase) + rng.normal(0, PROBE.noise_sigma, len(n))
    if isotropic:  # the mean pre-travel over the sphere, known to U_TIP
        model = 0.5 * (PROBE.pretravel_xy + PROBE.pretravel_z) + rng.normal(0, U_TIP)
        src = Sources(u_tip=U_TIP, lobing=PROBE.pretravel_lobe, z_xy=abs(PROBE.pretravel_xy - PROBE.pretravel_z) / 2,
                      repeatability=PROBE.noise_sigma, reference=tuple(pose[:3, 3]))
    else:
        record = qualify(rng, phase, g)
        # compensation: M = T - model(u) u + r_eff n, T = P + (r - delta) n, u = -n
        model = record.model(-n) + (PROBE.tip_radius - record.tip_radius)
        src = probe_sources(record, reference=tuple(pose[:3, 3]))
    surface = true_pts + rng.normal(0, form, len(n))[:, None] * n if form > 0 else true_pts
    local = surface - (delta - model)[:, None] * n
    # machine geometry (scale, squareness within the MPE's 1/K) and the part's expansion about its origin
    t = 20.0 + rng.uniform(-src.temperature_allowance, src.temperature_allowance)
    cte = src.cte + rng.normal(0, src.cte_u)
    machine = pose[:3, :3] @ local.T
    machine = machine.T + pose[:3, 3]
    rel = machine - pose[:3, 3]
    hits = pose[:3, 3] + rel @ g.T + rel * cte * (t - 20.0)
    truth = pose[:3, :3] @ true_pts.T
    measure.surface = (pose[:3, :3] @ surface.T).T + pose[:3, 3]  # the part's surface under the hits (its form)
    return hits, truth.T + pose[:3, 3], src


def _normals_of(kind: str, true_pts: np.ndarray) -> np.ndarray:
    key = (kind, true_pts.tobytes())
    if key not in _NORMALS:
        fit = LS_FITS[kind](true_pts)
        from cmm.metrology.uncertainty import _geometry, _normals

        _NORMALS[key] = _normals(kind, _geometry(kind, fit), true_pts)
    return _NORMALS[key]


def measure_set(items: dict[str, tuple[str, np.ndarray]], rng: np.random.Generator, pose: np.ndarray,
                form: float = 0.0):
    """Several features measured in one set-up: one probe (lobes at one phase, one qualification), one machine
    geometry and one part temperature for all of them, each hit its own noise and form. Returns
    {name: (hits, truth, surface)} and the sources."""
    phase = rng.uniform(0, 2 * np.pi)
    h = 1e-3 / Sources().mpe_k
    g = np.eye(3) + np.diag(rng.uniform(-h, h, 3))
    g[0, 1], g[0, 2], g[1, 2] = rng.uniform(-h, h, 3)
    record = qualify(rng, phase, g)
    src = probe_sources(record, reference=tuple(pose[:3, 3]))
    t = 20.0 + rng.uniform(-src.temperature_allowance, src.temperature_allowance)
    cte = src.cte + rng.normal(0, src.cte_u)
    out = {}
    for name, (kind, pts) in items.items():
        n = _normals_of(kind, pts)
        delta = _pretravel(n, phase) + rng.normal(0, PROBE.noise_sigma, len(n))
        model = record.model(-n) + (PROBE.tip_radius - record.tip_radius)
        surface = pts + rng.normal(0, form, len(n))[:, None] * n if form > 0 else pts
        local = surface - (delta - model)[:, None] * n
        rel = (pose[:3, :3] @ local.T).T
        hits = pose[:3, 3] + rel @ g.T + rel * cte * (t - 20.0)
        out[name] = (hits, (pose[:3, :3] @ pts.T).T + pose[:3, 3], (pose[:3, :3] @ surface.T).T + pose[:3, 3])
    return out, src


def run_gdt(trials: int, seed: int, form: float = 0.0, verbose: bool = True) -> dict[str, dict[str, float]]:
    """Geometric tolerances of the sample part against datums, with their U (cmm.metrology.uncertainty_gdt):
    datum A the top plane, B the bore; the boss's position to A|B (its nominal 5 um off the true axis, so the
    true value is 10 um) and its perpendicularity to A (true value 0). The features, datums included, are
    measured in one set-up per trial (measure_set); the true value is the same evaluation on the true geometry
    and the part's surface under the hits."""
    from cmm.metrology.gdt_eval import MeasuredFeature, evaluate

    rng = np.random.default_rng(seed)
    pose = TRUE_PART_POSE
    p = plans()
    items = {k: p[k] for k in ("top_plane", "bore", "boss")}
    ids = {"top_plane": 1, "bore": 2, "boss": 3}
    true_fits = {}
    nominal = {}
    for name, (kind, pts) in items.items():
        truth = (pose[:3, :3] @ pts.T).T + pose[:3, 3]
        true_fits[name] = LS_FITS[kind](truth)
        nominal[name] = {"kind": kind, **true_fits[name].geometry()}
        if kind == "cylinder":
            nominal[name]["bore"] = name == "bore"
    nominal["boss"]["point"] = (np.asarray(nominal["boss"]["point"]) + pose[:3, :3] @ [0.005, 0, 0]).tolist()
    datums = {"A": {"label": "A", "feature": 1}, "B": {"label": "B", "feature": 2}}
    defs = [{"id": 1, "name": "position", "characteristic": "position", "feature": 3, "tolerance": 0.05,
             "datums": ["A", "B"]},
            {"id": 2, "name": "perpendicularity", "characteristic": "perpendicularity", "feature": 3,
             "tolerance": 0.05, "datums": ["A"]}]
    errs: dict[str, list[float]] = {}
    us: dict[str, list[float]] = {}
    for _ in range(trials):
        measured, src = measure_set(items, rng, pose, form)
        feats, truths = {}, {}
        for name, (kind, _pts) in items.items():
            hits, _truth, surface = measured[name]
            fit = local_fit(kind, true_fits[name], hits) if kind == "cylinder" else LS_FITS[kind](hits)
            geo = {k: (np.asarray(v).tolist()) for k, v in (fit.summary() if kind == "cylinder" else
                                                               fit.geometry()).items()}
            b = budget(kind, hits, fit, src).summary()
            feats[ids[name]] = MeasuredFeature(name, kind, geo, nominal[name], hits, budget=b)
            tg = true_fits[name].geometry()
            truths[ids[name]] = MeasuredFeature(name, kind, tg, nominal[name], surface)
        for (d, c), (_, ct) in zip(evaluate(defs, datums, feats), evaluate(defs, datums, truths)):
            errs.setdefault(d["name"], []).append(float(c.actual) - float(ct.actual))
            us.setdefault(d["name"], []).append(float(c.uncertainty))
    out = {}
    for k in errs:
        e, u = np.abs(np.array(errs[k])), np.array(us[k])
        rms = float(np.sqrt(np.mean(np.square(errs[k])))) or 1e-12
        out[k] = {"coverage": float(np.mean(e <= u)), "worst": float(np.max(e / u)),
                  "U_over_spread": float(np.mean(u) / (float(np.std(errs[k])) or 1e-12)),
                  "U_over_rms": float(np.mean(u) / rms), "U": float(np.mean(u)), "err_max": float(e.max()),
                  "bias": float(np.mean(errs[k])), "rms": rms}
        if verbose:
            r = out[k]
            print(f"boss       {k:17s} U {r['U'] * 1000:8.3f} um  max|err| {r['err_max'] * 1000:8.3f}  coverage "
                  f"{r['coverage'] * 100:5.1f} %  worst |err|/U {r['worst']:5.2f}  U/spread {r['U_over_spread']:5.2f}  "
                  f"U/rms {r['U_over_rms']:5.2f}  (mean err {r['bias'] * 1000:+.3f} um, rms {rms * 1000:.3f} um)",
                  flush=True)
    return out


def local_fit(kind: str, true_fit, hits: np.ndarray):
    """A cylinder or cone fitted by least squares from the true geometry (no multi-start search)."""
    from types import SimpleNamespace

    from scipy.optimize import least_squares

    from cmm.metrology.feature_distance import surface_distance
    from cmm.metrology.uncertainty import _Axial

    model = _Axial(kind, true_fit)
    sol = least_squares(lambda p: surface_distance(kind, model.geometry(p), hits), model.p0, method="lm",
                        xtol=1e-14, ftol=1e-14)
    g = model.geometry(sol.x)
    fit = SimpleNamespace(**g, residuals=sol.fun, form=float(np.ptp(sol.fun)))
    fit.summary = lambda: dict(g)
    return fit


def run(trials: int, seed: int, verbose: bool = True, features: tuple[str, ...] | None = None, form: float = 0.0,
        isotropic: bool = False, local_fits: bool = False,
        form_prior: float | None = None) -> dict[str, dict[str, dict[str, float]]]:
    rng = np.random.default_rng(seed)
    pose = TRUE_PART_POSE
    out: dict[str, dict[str, dict[str, float]]] = {}
    for name, (kind, pts) in plans().items():
        if features is not None and name not in features:
            continue
        errs: dict[str, list[float]] = {}
        us: dict[str, list[float]] = {}
        true_fit = None
        for _ in range(trials):
            hits, truth, src = measure(kind, pts, rng, pose, form, isotropic)
            if form_prior is not None:  # the form the shop tells the budget to expect (its process, its drawing)
                src = dataclasses.replace(src, form_prior=form_prior)
            nominal = None
            if kind == "cone":
                ax = pose[:3, :3] @ [0, 0, -1.0]
                nominal = {"apex": (pose[:3, :3] @ [100, 40, 64.0]) + pose[:3, 3], "direction": ax,
                           "half_angle": math.atan(0.5)}
            if true_fit is None:  # the true geometry (exact points: the fit is the truth), once per feature
                true_fit = LS_FITS[kind](truth) if nominal is None else LS_FITS[kind](truth, nominal=nominal)
            if local_fits and kind in ("cylinder", "cone"):
                fit = local_fit(kind, true_fit, hits)
            else:
                fit = LS_FITS[kind](hits) if nominal is None else LS_FITS[kind](hits, nominal=nominal)
            centroid = hits.mean(axis=0)
            b = budget(kind, hits, fit, src)
            true_values = values_of(kind, true_fit, centroid)
            if "form" in b.values:  # the true form: the part's surface under the hits, fitted the same way
                surf = measure.surface
                if local_fits and kind in ("cylinder", "cone"):
                    sf = local_fit(kind, true_fit, surf)
                else:
                    sf = LS_FITS[kind](surf) if nominal is None else LS_FITS[kind](surf, nominal=nominal)
                true_values["form"] = float(sf.form)
            U = b.expanded()
            for k, v in b.values.items():
                errs.setdefault(k, []).append(v - true_values[k])
                us.setdefault(k, []).append(U[k])
        out[name] = {}
        for k in errs:
            e, u = np.abs(np.array(errs[k])), np.array(us[k])
            spread = float(np.std(errs[k])) or 1e-12
            rms = float(np.sqrt(np.mean(np.square(errs[k])))) or 1e-12
            out[name][k] = {"coverage": float(np.mean(e <= u)), "worst": float(np.max(e / np.maximum(u, 1e-15))),
                            "U_over_spread": float(np.mean(u) / spread), "U_over_rms": float(np.mean(u) / rms),
                            "U": float(np.mean(u)), "err_max": float(e.max())}
            if verbose:
                r = out[name][k]
                unit = "deg" if k.endswith("_deg") else "um"
                f = 1.0 if unit == "deg" else 1000.0
                print(f"{name:10s} {k:15s} U {r['U'] * f:8.3f} {unit}  max|err| {r['err_max'] * f:8.3f}  coverage "
                      f"{r['coverage'] * 100:5.1f} %  worst |err|/U {r['worst']:5.2f}  U/spread {r['U_over_spread']:5.2f}  "
                      f"U/rms {r['U_over_rms']:5.2f}",
                      flush=True)
    return out


def table(res: dict[str, dict[str, dict[str, float]]]) -> str:
    """README-ready markdown: per feature and value, U, the largest error, coverage, worst |err|/U, U / spread,
    U / RMS error (the errors' spread about the truth: a value near zero that cannot go negative, a zone or
    twice a distance, has a folded error whose std is small against any 95 % U)."""
    rows = ["| feature | value | U | max abs error | coverage | worst abs err / U | U / spread | U / RMS error |",
            "|---|---|---|---|---|---|---|---|"]
    for name, values in res.items():
        for k, r in values.items():
            if r["err_max"] <= 1e-6:  # an axis point's coordinate along its own axis: never in error
                continue
            unit, f = ("deg", 1.0) if k.endswith("_deg") else ("um", 1000.0)
            rows.append(f"| {name} | {k} | {r['U'] * f:.3g} {unit} | {r['err_max'] * f:.3g} {unit} | "
                        f"{r['coverage'] * 100:.1f} % | {r['worst']:.2f} | {r['U_over_spread']:.2f} | {r['U_over_rms']:.2f} |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--form", type=float, default=1.0,
                        help="the part's form under each hit, um (one sigma; the budget's prior is 1 um); 0: perfect")
    parser.add_argument("--form-prior", type=float, default=None,
                        help="the form the budget is told to expect, um (one sigma; default: the budget's 1 um)")
    parser.add_argument("--isotropic", action="store_true",
                        help="compensate with the mean pre-travel only (no directional qualification)")
    parser.add_argument("--local-fits", action="store_true",
                        help="fit cylinders and cones by local least squares from the true geometry (fast)")
    parser.add_argument("--gdt", action="store_true",
                        help="geometric tolerances against datums instead (the boss's position to A|B, perpendicularity to A)")
    args = parser.parse_args()
    if args.gdt:
        run_gdt(args.trials, args.seed, form=args.form / 1000)
        return
    res = run(args.trials, args.seed, form=args.form / 1000, isotropic=args.isotropic, local_fits=args.local_fits,
              form_prior=None if args.form_prior is None else args.form_prior / 1000)
    cov = [r["coverage"] for f in res.values() for r in f.values()]
    worst = max(r["worst"] for f in res.values() for r in f.values())
    real = [r for f in res.values() for r in f.values() if r["err_max"] > 1e-6]  # values the errors move at all
    ratio = max(r["U_over_spread"] for r in real)
    print(f"\nall values: coverage min {min(cov) * 100:.1f} %, mean {np.mean(cov) * 100:.1f} %; worst |err|/U "
          f"{worst:.2f}; U / spread {min(r['U_over_spread'] for r in real):.2f} .. {ratio:.2f}\n")
    print(table(res))


if __name__ == "__main__":
    main()

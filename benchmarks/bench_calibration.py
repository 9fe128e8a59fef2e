"""Calibration on the simulator with injected errors: before/after figures.

Injected: the simulator's 3-lobed pre-travel (4 um XY, 1.5 um lobe, 2 um Z,
0.25 um trigger noise, 2 um counts), X scale +50 ppm, XY squareness 30 urad.
Prints probe qualification (r_eff, model, residual by direction), the
ISO 10360-5 figures (single hits and averaged), and the ball-bar geometry
(scale, squareness, length errors before/after). Run:
    python benchmarks/bench_calibration.py [--quick]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from cmm.calibration.geometry import calibrate_geometry
from cmm.calibration.iso10360 import run_iso10360_5
from cmm.calibration.probe import qualify_probe
from cmm.calibration.records import BallBarCertificate, SphereCertificate
from cmm.machine.config import load
from cmm.machine.motion import Machine
from cmm.sim.cmm_sim import CmmSimSettings, SimulatedCMM
from cmm.sim.probe_world import GeometryErrors


def main() -> None:
    quick = "--quick" in sys.argv
    config = load()
    sim = SimulatedCMM(config, CmmSimSettings(errors=GeometryErrors((50.0, 0.0, 0.0), (30.0, 0.0, 0.0))))
    m = Machine(config, sim.transport())
    m.connect()
    sphere = SphereCertificate("reference sphere", 25.0, 0.0002, 0.0001, approx_centre=(400.3, 299.7, 100.2))
    p = sim.settings.probe
    print(f"simulated probe: pre-travel XY {p.pretravel_xy * 1000:.1f} um, lobe {p.pretravel_lobe * 1000:.1f} um (3-lobed), "
          f"Z {p.pretravel_z * 1000:.1f} um, noise {p.noise_sigma * 1000:.2f} um; counts 2 um")

    t0 = time.perf_counter()
    q = qualify_probe(m, sphere, repeats=2)
    r = q.record
    print(f"\nprobe qualification ({r.n_points} points x 2 hits, {time.perf_counter() - t0:.1f} s wall):")
    print(f"  r_eff {r.tip_radius:.5f} mm (nominal {r.nominal_tip_radius}), U(k=2) {r.uncertainty_um:.2f} um")
    print(f"  model: {q.settings.pretravel.describe()}  (true lobe {p.pretravel_lobe * 1000:+.2f}, "
          f"true z2 {(p.pretravel_z - p.pretravel_xy) * 1000:+.2f})")
    print(f"  tip-centre sphere form {r.form_before_um:.2f} -> {r.form_after_um:.2f} um")
    print("  residual by direction (um):  polar   n   range before   range after   rms after")
    for row in q.by_ring():
        print("                             {polar_deg:5.1f} {n:3d} {range_before_um:12.2f} {range_after_um:13.2f} "
              "{rms_after_um:11.2f}".format(**row))

    for repeats in ((1,) if quick else (1, 16)):
        t0 = time.perf_counter()
        iso = run_iso10360_5(m, sphere, q.settings, repeats=repeats)
        print(f"\n{iso.table()}   ({time.perf_counter() - t0:.1f} s wall)")

    certs = {"ball_bar_300": BallBarCertificate("ball bar 300", 300.0, 25.0, 0.0005),
             "ball_bar_200": BallBarCertificate("ball bar 200", 200.0, 25.0, 0.0004)}
    rng = np.random.default_rng(11)

    def place(s):
        off = rng.uniform(-0.3, 0.3, 3)
        sim.place_artifacts([(np.add(s.ball1, off), 25.0), (np.add(s.ball2, off), 25.0)])

    t0 = time.perf_counter()
    g = calibrate_geometry(m, q.settings, certs, place=place, repeats=2, verify=not quick)
    c = g.correction
    print(f"\nmachine geometry (9 ball-bar set-ups, {time.perf_counter() - t0:.1f} s wall incl. verification):")
    print("  scale ppm       X {:+7.2f} (true +50)  Y {:+7.2f} (0)  Z {:+7.2f} (0)   U(k=2) {:.2f}".format(
        *c.scale_ppm, g.uncertainty_scale_ppm))
    print("  squareness urad XY {:+6.2f} (true 30)  XZ {:+6.2f} (0)  YZ {:+6.2f} (0)   U(k=2) {:.2f}".format(
        *c.squareness_urad, g.uncertainty_squareness_urad))
    after = {x.setup: x.error_um for x in g.verification}
    print("  length error um: set-up  before   after")
    for x in g.measurements:
        a = after.get(x.setup)
        print(f"                   {x.setup:<6} {x.error_um:+7.2f} {'' if a is None else f'{a:+7.2f}'}")
    m.close()


if __name__ == "__main__":
    main()

"""`cmm calibrate probe|iso10360-5|geometry|servo`: run a routine, print results, write its record.

By default the routine runs on the in-process simulator (virtual clock, fast).
Records are written only when the routine succeeds, atomically; on failure the
message says why and the previous calibration stays in force.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

ROUTINES = ("probe", "iso10360-5", "geometry", "servo")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("routine", choices=ROUTINES, help="what to calibrate")
    p.add_argument("--serial", metavar="URL", help="pyserial URL of the NMC network (default: in-process simulator)")
    p.add_argument("--config", metavar="FILE", help="machine configuration TOML (default: the shipped one)")
    p.add_argument("--records", metavar="DIR", default="calibration", help="calibration records folder (default: calibration)")
    p.add_argument("--artifacts", metavar="DIR", help="artifact certificates folder (default: RECORDS/artifacts)")
    p.add_argument("--centre", metavar="X,Y,Z", help="approximate reference sphere centre (overrides its certificate)")
    p.add_argument("--repeats", type=int, default=None, help="hits averaged per point (dithered)")
    p.add_argument("--accept", action="store_true", help="servo: apply the proposed gains without asking")
    p.add_argument("--inject-errors", action="store_true",
                   help="simulator: X scale +50 ppm and XY squareness 30 urad (the probe is 3-lobed anyway)")
    p.add_argument("--no-verify", action="store_true", help="geometry: skip the verification pass")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


class _Rig:
    """The machine (simulator in-process or a serial URL) with the current calibration applied."""

    def __init__(self, args: Any) -> None:
        from ..machine.config import load
        from ..machine.motion import Machine
        from ..machine.probing import Prober
        from .records import apply_calibration, load_station_calibration

        self.config = load(args.config)
        self.sim = None
        if args.serial:
            port: Any = args.serial
        else:
            from ..sim.cmm_sim import CmmSimSettings, SimulatedCMM
            from ..sim.probe_world import GeometryErrors

            settings = CmmSimSettings()
            if args.inject_errors:
                settings.errors = GeometryErrors((50.0, 0.0, 0.0), (30.0, 0.0, 0.0))
            self.sim = SimulatedCMM(self.config, settings)
            port = self.sim.transport()
        self.machine = Machine(self.config, port)
        self.machine.connect()
        self.prober = Prober(self.machine)
        self.loaded = load_station_calibration(args.records)
        for problem in self.loaded.problems:
            print(f"warning: {problem} (not applied)", file=sys.stderr)
        for line in apply_calibration(self.loaded, self.machine, self.prober):
            print(f"in force: {line}")

    def close(self) -> None:
        self.machine.close()


def _progress(args: Any):
    if args.quiet:
        return None
    last = [""]

    def fn(f: float, msg: str) -> None:
        if msg != last[0]:
            print(f"[{f * 100:5.1f}%] {msg}", flush=True)
            last[0] = msg
    return fn


def _centre(args: Any):
    if not args.centre:
        return None
    try:
        v = [float(x) for x in args.centre.split(",")]
        assert len(v) == 3
        return v
    except (ValueError, AssertionError):
        raise SystemExit(f"--centre needs X,Y,Z in mm, got {args.centre!r}") from None


def _ask(question: str) -> bool:
    if not sys.stdin.isatty():
        return False
    return input(f"{question} [y/N] ").strip().lower() in ("y", "yes")


def run(args: Any) -> int:
    from .records import CalibrationError

    artifacts = Path(args.artifacts) if args.artifacts else Path(args.records) / "artifacts"
    try:
        rig = _Rig(args)
    except Exception as exc:  # noqa: BLE001 - an operator's message, not a traceback
        print(f"error: cannot start the machine: {exc}", file=sys.stderr)
        return 1
    try:
        return _ROUTINES[args.routine](args, rig, artifacts)
    except CalibrationError as exc:
        print(f"calibration stopped: {exc}\nThe previous calibration stays in force.", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001
        from ..machine.status import MotionError

        if isinstance(exc, MotionError):
            print(f"calibration stopped: {exc}\nThe previous calibration stays in force.", file=sys.stderr)
            return 1
        raise
    finally:
        rig.close()


def _run_probe(args: Any, rig: _Rig, artifacts: Path) -> int:
    from .probe import qualify_probe
    from .records import PROBE_RECORD, load_sphere_certificate, save_record

    cert = load_sphere_certificate(artifacts / "reference-sphere.toml")
    master = rig.loaded.probe.sphere_centre if rig.loaded.probe is not None else None
    q = qualify_probe(rig.machine, cert, approx_centre=_centre(args), repeats=args.repeats or 2,
                      master_centre=master, progress=_progress(args))
    r = q.record
    print(f"reference sphere {cert.describe()}: centre X={q.centre[0]:.4f} Y={q.centre[1]:.4f} Z={q.centre[2]:.4f}")
    print(f"effective tip radius r_eff = {r.tip_radius:.5f} mm (nominal {r.nominal_tip_radius}), U(k=2) {r.uncertainty_um:.2f} um")
    print(f"tip offset to master: {', '.join(f'{x * 1000:+.2f}' for x in r.tip_offset)} um")
    print(f"directional pre-travel (zero mean): {q.settings.pretravel.describe()}")
    print(f"tip-centre sphere form: {r.form_before_um:.2f} um -> {r.form_after_um:.2f} um with the model ({r.n_points} points)")
    for row in q.by_ring():
        print("  polar {polar_deg:5.1f} deg: {n:2d} points, range {range_before_um:5.2f} -> {range_after_um:5.2f} um".format(**row))
    path = save_record(r, Path(args.records) / PROBE_RECORD)
    print(f"wrote {path}")
    return 0


def _run_iso(args: Any, rig: _Rig, artifacts: Path) -> int:
    from .iso10360 import run_iso10360_5
    from .records import load_sphere_certificate

    cert = load_sphere_certificate(artifacts / "reference-sphere.toml")
    if rig.loaded.probe is None:
        print("note: no probe record in force: run `cmm calibrate probe` first; testing the nominal settings")
    result = run_iso10360_5(rig.machine, cert, rig.prober.settings, approx_centre=_centre(args),
                            repeats=args.repeats or 1, progress=_progress(args))
    print(result.table())
    return 0


def _run_geometry(args: Any, rig: _Rig, artifacts: Path) -> int:
    import numpy as np

    from .geometry import calibrate_geometry, default_setups
    from .records import MACHINE_RECORD, BallBarCertificate, load_certificate, save_record

    certs = {}
    for f in sorted(artifacts.glob("*.toml")):
        c = load_certificate(f)
        if isinstance(c, BallBarCertificate):
            certs[f.stem.replace("-", "_")] = c
    if not {"ball_bar_300", "ball_bar_200"} <= set(certs):
        from .records import CalibrationError

        raise CalibrationError(f"the geometry routine needs ball-bar-300.toml and ball-bar-200.toml in {artifacts}")
    setups = default_setups(lengths={k: c.length for k, c in certs.items() if k in ("ball_bar_300", "ball_bar_200")})
    if rig.sim is not None:
        rng = np.random.default_rng(7)

        def place(s):  # the simulated operator puts the bar within 0.3 mm of the set-up
            d = certs[s.artifact].ball_diameter
            off = rng.uniform(-0.3, 0.3, 3)
            rig.sim.place_artifacts([(np.add(s.ball1, off), d), (np.add(s.ball2, off), d)])
    else:
        if not sys.stdin.isatty():
            from .records import CalibrationError

            raise CalibrationError("the geometry routine on a real machine needs an operator to place the bar")

        def place(s):
            input(f"Place {certs[s.artifact].describe()} for set-up {s.name}: balls at "
                  "X={:.1f} Y={:.1f} Z={:.1f} and X={:.1f} Y={:.1f} Z={:.1f}; ".format(*s.ball1, *s.ball2) +
                  "press Enter when it is clamped ")
    result = calibrate_geometry(rig.machine, rig.prober.settings, certs, setups, place, repeats=args.repeats or 2,
                                verify=not args.no_verify, progress=_progress(args))
    c = result.correction
    print("scale (ppm): X {:+.2f} Y {:+.2f} Z {:+.2f}   U(k=2) {:.2f}".format(*c.scale_ppm, result.uncertainty_scale_ppm))
    print("squareness (urad): XY {:+.2f} XZ {:+.2f} YZ {:+.2f}   U(k=2) {:.2f}".format(
        *c.squareness_urad, result.uncertainty_squareness_urad))
    print(f"{'set-up':<6} {'before um':>10} {'after um':>10}")
    after = {m.setup: m.error_um for m in result.verification}
    for m in result.measurements:
        a = after.get(m.setup)
        print(f"{m.setup:<6} {m.error_um:>+10.2f} {'' if a is None else f'{a:+10.2f}':>10}")
    artifact = ", ".join(sorted({certs[s.artifact].describe() for s in setups}))
    path = save_record(result.record(artifact, rig.config.source), Path(args.records) / MACHINE_RECORD)
    print(f"wrote {path}")
    return 0


def _run_servo(args: Any, rig: _Rig, artifacts: Path) -> int:
    from .records import SERVO_RECORD, save_record
    from .servo import apply_gains, svg_plot, tune_servos

    result = tune_servos(rig.machine, progress=_progress(args))
    print(result.table())
    out = Path(args.records)
    for a in result.proposed:
        p = svg_plot([t for t in result.trials if t.axis == a], out / f"servo-{a}.svg", f"{a.upper()} step responses")
        print(f"plot: {p}")
    accepted = args.accept or _ask("apply the proposed gains now?")
    save_record(result.record(accepted, rig.config.source), out / ("servo.toml" if accepted else "servo-proposal.toml"))
    if accepted:
        apply_gains(rig.machine, result.proposed)
        print(f"applied and recorded in {out / SERVO_RECORD}; copy them into the machine configuration [gains] to keep them")
    else:
        print("not applied (no --accept); proposal written to servo-proposal.toml")
    return 0


_ROUTINES = {"probe": _run_probe, "iso10360-5": _run_iso, "geometry": _run_geometry, "servo": _run_servo}

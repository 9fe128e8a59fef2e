"""`cmm calibrate probe|iso10360-5|geometry|servo`: run a routine, print results, write its record.

A front end of the command API like the station's Calibration tab: it builds a
station (no UI, no session) on the machine, homes it, applies the records in
force, and runs the routine through the station's calibration service
(``controller.run_job``); records are saved and gains applied through the
service too (``controller.configure``). By default the machine is the
in-process simulator (virtual clock, fast); the control core then runs without
threads (the routine's waits drive the machine loop). Records are written only
when the routine succeeds, atomically; on failure the message says why and the
previous calibration stays in force.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

ROUTINES = ("probe", "iso10360-5", "geometry", "servo")
SIM_URL = "sim://?cmm=1"  # the simulated CMM in-process on the virtual clock, released with the station


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("routine", choices=ROUTINES, help="what to calibrate")
    p.add_argument("--serial", metavar="URL", help="pyserial URL of the NMC network (default: in-process simulator)")
    p.add_argument("--config", metavar="FILE", help="machine configuration TOML (default: the shipped one)")
    from ..sim.placement import add_part_arguments

    add_part_arguments(p)
    p.add_argument("--records", metavar="DIR", default="calibration", help="calibration records folder (default: calibration)")
    p.add_argument("--artifacts", metavar="DIR", help="artifact certificates folder (default: RECORDS/artifacts)")
    p.add_argument("--centre", metavar="X,Y,Z", help="approximate reference sphere centre (overrides its certificate)")
    p.add_argument("--probe", metavar="NAME", help="probe: qualify the stylus of this name in the probe list (added "
                   "with --tip-diameter when the list has none of that name; the simulator mounts it)")
    p.add_argument("--tip-diameter", metavar="D", type=float,
                   help="probe: the nominal tip diameter (mm) of the stylus --probe names")
    p.add_argument("--repeats", type=int, default=None, help="hits averaged per point (dithered)")
    p.add_argument("--accept", action="store_true", help="servo: apply the proposed gains without asking")
    p.add_argument("--inject-errors", action="store_true",
                   help="simulator: X scale +50 ppm and XY squareness 30 urad (the probe is 3-lobed anyway)")
    p.add_argument("--no-verify", action="store_true", help="geometry: skip the verification pass")
    p.add_argument("--no-home", dest="home", action="store_false",
                   help="do not run the homing cycle: refuse unless the machine is homed already "
                        "(a machine configured with [homing] method = \"none\")")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


class RigError(Exception):
    """The machine could not be made ready to measure (the message says why and what to do)."""


class _Rig:
    """The station (simulator in-process or a serial URL): connected, homed, the current calibration applied."""

    def __init__(self, args: Any) -> None:
        from ..station import Station, load_config

        config = load_config(args.config)
        settings = None
        if not args.serial:
            from ..sim.cmm_sim import CmmSimSettings
            from ..sim.probe_world import GeometryErrors

            settings = CmmSimSettings()
            if args.inject_errors:
                settings.errors = GeometryErrors((50.0, 0.0, 0.0), (30.0, 0.0, 0.0))
        from ..sim.placement import part_pose_of

        self.station = Station(config, port=args.serial or SIM_URL, sim_settings=settings,
                               part_path=getattr(args, "part", None), part_pose=part_pose_of(args))
        try:
            self.station.connect()  # the modules started in this thread (no machine loop: a script)
            self.commands = self.station.controller.commands  # every command below goes through the command API
            if not self.commands.invoke(None, "state").homed:
                self._home(args)
            self.station.calibration.load(args.records)
        except BaseException:
            self.station.close()
            raise
        self.service = self.station.calibration
        if args.artifacts:
            self.service.artifacts_dir = Path(args.artifacts)
        status = self.station.calibration.status
        for problem in status["problems"]:
            print(f"warning: {problem} (not applied)", file=sys.stderr)
        for line in self.station.calibration.log:
            if not line.startswith("refused: "):
                print(f"in force: {line}")

    def _home(self, args: Any) -> None:
        """The homing cycle before measuring, announced; or a refusal that says how to get one."""
        if not args.home:
            raise RigError("the machine is not homed and --no-home was given: run without --no-home to home it "
                           "first (the machine moves to its home switches)")
        if not self.station.simulated:  # the operator is told before the machine moves to its switches
            print("homing cycle: the machine moves to its home switches", flush=True)
        try:
            self.commands.invoke(None, "home")
        except Exception as exc:  # noqa: BLE001 - said to the operator with what to check
            hint = ("the routines measure only on a homed machine; on a machine without home switches set "
                    "[homing] method = \"none\" in the configuration given with --config")
            if args.serial and args.serial.startswith(("socket://", "rfc2217://")):
                hint += "; `cmm sim` serves the CMM with its home switches only with --cmm"
            raise RigError(f"homing failed: {exc} ({hint})") from exc
        if not self.station.simulated:
            print("homed", flush=True)

    def qualify(self, routine: str, progress: Any, **options: Any) -> Any:
        """Run a calibration routine through the command API's ``qualify`` verb (its result; nothing applied)."""
        return self.commands.invoke(None, "qualify", routine=routine, progress=progress, options=options)

    @property
    def probe_in_force(self) -> bool:
        return self.station.calibration.status["probe"] is not None

    def close(self) -> None:
        self.station.close()


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
    from ..calibration.service import calibration_errors
    from ..control import ControlError

    from ..metrology.mesh import MeshError
    from ..sim.placement import PlacementError

    try:
        rig = _Rig(args)
    except (RigError, MeshError, PlacementError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - an operator's message, not a traceback
        print(f"error: cannot start the machine: {exc}", file=sys.stderr)
        return 1
    try:
        return _ROUTINES[args.routine](args, rig)
    except (*calibration_errors(), ControlError) as exc:  # ControlError: refused, or the link failed (fault)
        print(f"calibration stopped: {exc}\nThe previous calibration stays in force.", file=sys.stderr)
        return 1
    finally:
        rig.close()


def _mount_probe(args: Any, rig: _Rig) -> None:
    """--probe NAME [--tip-diameter D]: the stylus NAME (added to the probe list when new) becomes the probe in
    use, so the qualification that follows is its own."""
    from ..calibration.records import CalibrationError

    if args.probe is None:
        if args.tip_diameter is not None:
            raise CalibrationError("--tip-diameter needs --probe NAME: the stylus it is the diameter of")
        return
    svc = rig.service
    probes, _ = svc.probe_list()
    have = next((p for p in probes if p.name == args.probe), None)
    if have is None:
        if args.tip_diameter is None:
            raise CalibrationError(f"the probe list has no probe {args.probe}: give its tip with --tip-diameter D "
                                   f"(the list has {', '.join(p.name for p in probes)})")
        have = svc.add_probe(args.probe, args.tip_diameter)
        print(f"probe {have.name} added to the probe list: {have.tip_diameter:g} mm tip")
    elif args.tip_diameter is not None and abs(have.tip_diameter - args.tip_diameter) > 1e-6:
        raise CalibrationError(f"the probe {have.name} of the list has a {have.tip_diameter:g} mm tip, not "
                               f"{args.tip_diameter:g} mm: give another name to a stylus with another tip")
    print(rig.commands.invoke(None, "select_probe", name=have.name))


def _run_probe(args: Any, rig: _Rig) -> int:
    svc = rig.service
    _mount_probe(args, rig)
    cert = svc.certificates("probe")
    q = rig.qualify("probe", _progress(args), repeats=args.repeats or 2, approx_centre=_centre(args))
    r = q.record
    print(f"reference sphere {cert.describe()}: centre X={q.centre[0]:.4f} Y={q.centre[1]:.4f} Z={q.centre[2]:.4f}")
    print(f"effective tip radius r_eff = {r.tip_radius:.5f} mm (nominal {r.nominal_tip_radius}), U(k=2) {r.uncertainty_um:.2f} um")
    print(f"tip offset to master: {', '.join(f'{x * 1000:+.2f}' for x in r.tip_offset)} um")
    print(f"directional pre-travel (zero mean): {q.settings.pretravel.describe()}")
    print(f"tip-centre sphere form: {r.form_before_um:.2f} um -> {r.form_after_um:.2f} um with the model ({r.n_points} points)")
    for row in q.by_ring():
        print("  polar {polar_deg:5.1f} deg: {n:2d} points, range {range_before_um:5.2f} -> {range_after_um:5.2f} um".format(**row))
    path, _ = rig.commands.invoke(None, "save_calibration", routine="probe", result=q)
    print(f"wrote {path}")
    return 0


def _run_iso(args: Any, rig: _Rig) -> int:
    if not rig.probe_in_force:
        print("note: no probe record in force: run `cmm calibrate probe` first; testing the nominal settings")
    result = rig.qualify("iso", _progress(args), repeats=args.repeats or 1, approx_centre=_centre(args))
    print(result.table())
    return 0


def _run_geometry(args: Any, rig: _Rig) -> int:
    from ..calibration.records import CalibrationError

    svc = rig.service
    options: dict[str, Any] = {}
    if not rig.station.simulated:  # on the simulator the service's simulated operator places the bar
        certs = svc.certificates("geometry")  # for the prompt (a missing one is said before the tty check)
        if not sys.stdin.isatty():
            raise CalibrationError("the geometry routine on a real machine needs an operator to place the bar")

        def place(s: Any) -> None:  # in the machine loop, between set-ups (the machine stands still)
            input(f"Place {certs[s.artifact].describe()} for set-up {s.name}: balls at "
                  "X={:.1f} Y={:.1f} Z={:.1f} and X={:.1f} Y={:.1f} Z={:.1f}; ".format(*s.ball1, *s.ball2) +
                  "press Enter when it is clamped ")
        options["place"] = place
    result = rig.qualify("geometry", _progress(args), repeats=args.repeats or 2, verify=not args.no_verify, **options)
    c = result.correction
    print("scale (ppm): X {:+.2f} Y {:+.2f} Z {:+.2f}   U(k=2) {:.2f}".format(*c.scale_ppm, result.uncertainty_scale_ppm))
    print("squareness (urad): XY {:+.2f} XZ {:+.2f} YZ {:+.2f}   U(k=2) {:.2f}".format(
        *c.squareness_urad, result.uncertainty_squareness_urad))
    print(f"{'set-up':<6} {'before um':>10} {'after um':>10}")
    after = {m.setup: m.error_um for m in result.verification}
    for m in result.measurements:
        a = after.get(m.setup)
        print(f"{m.setup:<6} {m.error_um:>+10.2f} {'' if a is None else f'{a:+10.2f}':>10}")
    path, _ = rig.commands.invoke(None, "save_calibration", routine="geometry", result=result)
    print(f"wrote {path}")
    return 0


def _run_servo(args: Any, rig: _Rig) -> int:
    from ..calibration.records import SERVO_RECORD
    from ..calibration.servo import svg_plot

    svc = rig.service
    result = rig.qualify("servo", _progress(args))
    print(result.table())
    out = svc.records_dir
    for a in result.proposed:
        p = svg_plot([t for t in result.trials if t.axis == a], out / f"servo-{a}.svg", f"{a.upper()} step responses")
        print(f"plot: {p}")
    if args.accept or _ask("apply the proposed gains now?"):
        rig.commands.invoke(None, "accept_gains", result=result)  # sent to the modules, then recorded
        print(f"applied and recorded in {out / SERVO_RECORD}; copy them into the machine configuration [gains] to keep them")
    else:
        rig.commands.invoke(None, "save_calibration", routine="servo", result=result, accepted=False)
        print("not applied (no --accept); proposal written to servo-proposal.toml")
    return 0


_ROUTINES = {"probe": _run_probe, "iso10360-5": _run_iso, "geometry": _run_geometry, "servo": _run_servo}

"""`cmm run PROGRAM.dmi`: run a DMIS part program on the station; `--check` only checks it.

The whole program is checked first (syntax, supported statements, blocks): any problem stops it before the machine
moves, with the line it is on. Then the station (by default the simulated CMM in-process, on the virtual clock) is
connected and homed, the calibration records in force are applied, a session is opened, and the program runs as
one job of the control core. It writes the DMIS output (``FA(..)`` actuals, ``TA(..)`` tolerances with
INTOL / OUTOL) to the program's output devices or ``--output``, and the station's own HTML report of the session.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

SIM_URL = "sim://?cmm=1"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("program", help="DMIS program (.dmi or .dms)")
    p.add_argument("--check", action="store_true", help="only check the whole program (syntax, supported statements)")
    p.add_argument("-o", "--output", metavar="FILE",
                   help="DMIS output file when the program opens no output device (default: PROGRAM_out.dms here)")
    p.add_argument("--report", metavar="FILE", help="the station's HTML report (default: PROGRAM_report.html here)")
    p.add_argument("--serial", metavar="URL", help="pyserial URL of the NMC network (default: in-process simulator)")
    p.add_argument("--part", metavar="FILE", default=None,
                   help="the part: STEP/IGES (exact surfaces) or a mesh (STL, OBJ, PLY, 3MF, GLB); on the simulator "
                        "it is also the part on the table")
    p.add_argument("--part-pose", metavar="X,Y,Z[,RZ]", default=None,
                   help="where the part's CAD origin sits in machine coordinates (mm), turned RZ degrees about Z")
    p.add_argument("--config", metavar="FILE", help="machine configuration TOML (default: the shipped one)")
    p.add_argument("--records", metavar="DIR", default="calibration", help="calibration records (default: calibration)")
    p.add_argument("--sessions", metavar="DIR|URL", default="sessions", help="session store (default: ./sessions)")
    p.add_argument("--no-home", dest="home", action="store_false",
                   help="do not run the homing cycle (a machine configured with [homing] method = \"none\")")
    p.add_argument("--qif", metavar="FILE", nargs="?", const=True,
                   help="also write the run's QIF 3 Results (default: PROGRAM.qif beside the DMIS output)")
    from ..session.notify import add_arguments as notify_arguments

    notify_arguments(p)
    p.add_argument("--trends", metavar="DIR", help="also record the run as a part of the program's series in this "
                   "trends folder (its tolerance results; see cmm trends)")
    p.add_argument("--trends-db", metavar="URL", help="with --trends: the shared trends database (default: CMM_TRENDS_DB)")
    p.add_argument("--station", metavar="NAME",
                   help="this station's name in the trends (--trends) and the notifications (default: the host name)")


def run(args: Any) -> int:
    from ..dmis.check import check
    from ..dmis.executor import DmisError
    from ..dmis.runner import load_text

    path = Path(args.program)
    if path.suffix.lower() not in (".dmi", ".dms"):
        print(f"cmm run: {path} is not a DMIS program (.dmi or .dms)", file=sys.stderr)
        return 2
    try:
        text = load_text(path)
    except DmisError as exc:
        print(f"cmm run: {exc}", file=sys.stderr)
        return 1
    stmts, problems = check(text)
    for problem in problems:
        print(f"{path}: {problem}", file=sys.stderr)
    if problems:
        return 1
    from ..dmis.check import warnings

    for warning in warnings(text, stmts):
        print(f"{path}: warning: {warning}")
    if args.check:
        print(f"{path}: {len(stmts)} statements, all supported")
        return 0
    return _run(args, path, text)


def _run(args: Any, path: Path, text: str) -> int:
    from ..session.export import resolve_part_mesh
    from ..session.report import write_report
    from ..journal.store import open_session
    from ..station import Station, load_config
    from ..session.notify import NotifyError, from_args
    from ..dmis.executor import DmisError
    from ..dmis.runner import register_verbs

    trends = None
    if getattr(args, "trends", None):
        from ..session.trends import open_trends

        trends = open_trends(args.trends, station=args.station, database=args.trends_db, sessions=args.sessions,
                             background=False)
    from ..metrology.mesh import MeshError
    from ..station import PlacementError, part_pose_of

    try:
        station = Station(load_config(args.config), port=args.serial or SIM_URL, session_dir=args.sessions,
                          trends=trends, part_path=getattr(args, "part", None), part_pose=part_pose_of(args))
    except (MeshError, PlacementError) as exc:
        if trends is not None:
            trends.close()
        print(f"cmm run: {exc}", file=sys.stderr)
        return 2
    except BaseException:
        if trends is not None:
            trends.close()
        raise
    notifier = None
    try:
        report = Path(args.report) if args.report else Path(f"{path.stem}_report.html")
        if not getattr(args, "report_url", None):
            args.report_url = report.resolve().as_uri()  # the report this command writes
        notifier = from_args(args, args.sessions)
        if notifier is not None:
            notifier.attach(station.measurement)
        station.connect()  # the modules started in this thread (no machine loop: a script)
        commands = station.controller.commands  # every command below goes through the command API
        if Path(args.records).is_dir():
            station.calibration.load(args.records)
        else:  # the run still measures, but its sizes carry the probe's pre-travel: say so before the results
            print(f"no calibration records in {args.records}: the probe is not qualified (its nominal tip radius, "
                  "no pre-travel model); name the records with --records DIR")
        if _refuse_sensors(commands, path, text):  # before anything moves, homing included
            return 1
        if not commands.invoke(None, "state").homed:
            if not args.home:
                print("cmm run: the machine is not homed and --no-home was given", file=sys.stderr)
                return 1
            commands.invoke(None, "home")
        session = str(commands.invoke(None, "new_part"))  # this run is a part of its own
        try:
            register_verbs(commands)
            result = commands.invoke(None, "run_dmis", text=text, name=path.name, manual_hits=terminal_hits(commands),
                                    query=terminal_query)
        except DmisError as exc:
            print(f"{path}: {exc}", file=sys.stderr)
            print(f"the hits taken so far are in the session {Path(session).stem}", file=sys.stderr)
            if exc.result is not None:
                _write_outputs(args, path, exc.result, "the output up to that line")
            return 1
    except NotifyError as exc:
        print(f"cmm run: {exc}", file=sys.stderr)
        return 2
    finally:
        station.close()
        if notifier is not None:
            notifier.close()
            for why in notifier.errors:
                print(f"cmm run: {why}", file=sys.stderr)
        if station.measurement.trends is not None:
            print(f"trends: {station.measurement.trends.status_text().replace('**', '')}")
            station.measurement.trends.close()
    _write_outputs(args, path, result)
    for line in result.log:
        print(line)
    failed = [e for e in result.evaluations if not e.intol]
    print(f"{len(result.actuals)} features, {result.hits} hits, {len(result.evaluations)} tolerances, "
          f"{len(failed)} out of tolerance" + (": " + ", ".join(f"T({e.tolerance.label})" for e in failed) if failed else ""))
    name = Path(session).stem
    s = open_session(name, args.sessions)
    report = Path(args.report) if args.report else Path(f"{path.stem}_report.html")
    mesh = resolve_part_mesh(s)
    write_report(s, report, mesh=mesh)
    print(f"wrote {report} (session {name})")
    if getattr(args, "qif", None):
        from ..session.qif import write_qif

        out_default = Path(args.output) if args.output else Path(f"{path.stem}_out.dms")
        qif = out_default.parent / f"{path.stem}.qif" if args.qif is True else Path(args.qif)
        write_qif(s, qif, mesh=mesh, program_name=path.name, report=str(report), dmis=result.evaluations)
        print(f"wrote {qif} (QIF 3 Results)")
    return 0


def terminal_query(prompt: str, answer: bool) -> str:
    """TEXT/MAN and TEXT/QUERY on the command line: asked at the terminal (refused in words without one)."""
    from ..dmis.executor import DmisError

    if not sys.stdin or not sys.stdin.isatty():
        raise DmisError(f"{prompt.split(':')[0]}: the program asks the operator and the input is not a terminal; "
                        "run it at a terminal or from the page's Routine tab")
    return input(f"{prompt} " + ("(type the answer, Enter): " if answer else "(Enter to go on): ")).strip()


def _refuse_sensors(commands: Any, path: Path, text: str) -> bool:
    """Whether a SNSLCT names a stylus the station has not qualified (said with the command that qualifies it)."""
    from ..dmis.check import check
    from ..dmis.rules import sensor_problems
    from ..dmis.runner import StationTarget

    target = StationTarget(commands)
    problems = sensor_problems(check(text)[0], target.probes(), target.nominal_tip_diameter)
    for problem in problems:
        print(f"{path}: {problem}", file=sys.stderr)
    return bool(problems)


def terminal_hits(commands: Any) -> Any:
    """Manual mode (MODE/MAN) on the command line, which has no jog: each hit is asked for at the terminal and,
    once the operator confirms it, taken by the machine at the program's point (Enter) or where the operator
    types it (X, Y, Z machine coordinates, e.g. read off the part's real place), approaching as the program says."""
    from ..dmis.executor import DmisError
    from ..dmis.runner import StationTarget

    target = StationTarget(commands)  # the hits' session ids, read through the command API

    def take(prompt: str, n: int, guides: list) -> list[int]:
        line = prompt.split(":")[0]
        if not sys.stdin or not sys.stdin.isatty():
            raise DmisError(f"{line}: manual mode needs an operator at the terminal (the input is not one); or run "
                            "the program from the page's Routine tab and take the hits with the pendant")
        if len(guides) < n:
            raise DmisError(f"{line}: on the command line every manual hit needs its PTMEAS point to guide it")
        print(prompt, flush=True)
        ids = []
        for k, (point, approach) in enumerate(guides[:n], 1):
            where = ", ".join(f"{x:.3f}" for x in point)
            while True:
                answer = input(f"  hit {k} of {n} at machine {where}: Enter takes it there, or type X, Y, Z "
                               "(q stops): ").strip()
                if answer.lower() in ("q", "quit", "stop"):
                    raise DmisError(f"{line}: stopped by the operator")
                try:
                    at = point if not answer else [float(x) for x in answer.replace(",", " ").split()]
                    if len(at) != 3:
                        raise ValueError
                    break
                except ValueError:
                    print("  three numbers please: X, Y, Z (or Enter, or q)", flush=True)
            hit = commands.invoke(None, "probe", target=at, approach=approach, frame="machine").wait(120)
            ids.append(target.hit_id(hit))
        return ids

    return take


def _write_outputs(args: Any, path: Path, result: Any, what: str = "") -> None:
    """The DMIS output files: the program's STOR devices (beside ``-o``), else ``-o``."""
    out_default = Path(args.output) if args.output else Path(f"{path.stem}_out.dms")
    from ..dmis.rules import device_file

    for device, content in result.outputs.items():
        # a program's device is written in the run's output folder under its last name, never elsewhere
        target = out_default if device is None else out_default.parent / (device_file(device) or "device.dms")
        target.write_text(content, encoding="utf-8")
        print(f"wrote {target}" + (f" ({what})" if what else ""))

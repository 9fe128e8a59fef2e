"""`cmm report SESSION -o report.html`: the inspection report of a recorded session.

SESSION is a name in the store (``--store DIR|URL``, default ./sessions) or
the path of a ``.jsonl`` journal. The part mesh is found from the recorded
path, ``--part`` or the simulator's sample part, and used only if its sha256
matches the recorded one. ``--program`` takes tolerances from a program. ``--trend SERIES`` adds the
control charts of the series' characteristics (:mod:`cmm.cli.trends`).
"""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="session name in the store, or a .jsonl journal file")
    parser.add_argument("-o", "--output", default="report.html", help="HTML file to write (default report.html)")
    parser.add_argument("--store", default=None, help="session directory or postgresql:// URL (default ./sessions)")
    parser.add_argument("--part", metavar="MESH", help="part mesh file (must match the recorded sha256)")
    parser.add_argument("--program", metavar="PROGRAM.toml", help="take the feature tolerances from this program")
    parser.add_argument("--tolerance", type=float, help="default tolerance in mm (size, location, form; default 0.02)")
    parser.add_argument("--title", help="report title")
    parser.add_argument("--map-tolerance", type=float, metavar="MM",
                        help="colour map: out of tolerance (red / blue) beyond +-MM (default: the form tolerance)")
    parser.add_argument("--warning", type=float, default=50.0, metavar="PERCENT",
                        help="colour map: warning (amber / cyan) beyond this %% of the map tolerance (default 50)")
    parser.add_argument("--max-deviation", type=float, metavar="MM",
                        help="colour map: hits deviating more are grey and not used (default 25 x the map tolerance)")
    parser.add_argument("--reach", type=float, default=15.0, metavar="MM",
                        help="colour map: surface farther than MM from every hit stays grey (default 15)")
    parser.add_argument("--csv", metavar="FILE", help="also write the feature table (one row per characteristic) as CSV")
    parser.add_argument("--trend", metavar="SERIES",
                        help="include the control charts of every characteristic of this series (cmm trends)")
    parser.add_argument("--trends", metavar="DIR", default="trends", help="with --trend: the local trends journal")
    parser.add_argument("--trends-db", metavar="URL", default=None,
                        help="with --trend: the shared trends database (default: CMM_TRENDS_DB)")


def run(args: argparse.Namespace) -> int:
    from ..journal.writer import JournalError
    from ..program.toml_program import ProgramError
    from ..journal.store import StoreError
    from ..session.trends import TrendError

    from ..metrology.colour_scale import ColourScale
    from ..metrology.characteristics import DEFAULT_TOLERANCE

    try:  # the colour map's bands (the 3D view's defaults unless given)
        scale = ColourScale(args.map_tolerance or args.tolerance or DEFAULT_TOLERANCE["form"], args.max_deviation,
                            args.warning / 100.0, args.reach)
    except ValueError as exc:
        print(f"cmm report: {exc}", file=sys.stderr)
        return 2
    try:
        from ..session.export import resolve_part_mesh
        from ..program.toml_program import load as load_program
        from ..session.report import write_features_csv, write_report
        from ..journal.store import open_session

        session = open_session(args.session, args.store)
        mesh = resolve_part_mesh(session, args.part)
        program = load_program(args.program) if args.program else None
        charts = None
        if getattr(args, "trend", None):
            from ..session.trends_chart import charts_for, open_trends

            trends = open_trends(args.trends, args.trends_db)
            try:
                charts = charts_for(trends, args.trend)
            finally:
                trends.close()
        write_report(session, args.output, mesh=mesh, program=program, title=args.title,
                     default_tolerance=args.tolerance, colour_scale=scale, trends=charts)
        if getattr(args, "csv", None):
            write_features_csv(session, args.csv, program=program, default_tolerance=args.tolerance, mesh=mesh)
    except (StoreError, JournalError, ProgramError, TrendError, OSError) as exc:
        print(f"cmm report: {exc}", file=sys.stderr)
        return 1
    if session.part is not None and mesh is None:
        print(f"warning: part {session.part.name!r} not found (or its sha256 differs): the report shows hits only",
              file=sys.stderr)
    for w in session.warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(f"wrote {args.output}: {len(session.features)} features, {len(session.hits)} hits")
    return 0

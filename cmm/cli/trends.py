"""`cmm trends`: the parts of a series across stations, per characteristic: chart statistics, CSV, upload.

    cmm trends list                                   # series, their characteristics and stations
    cmm trends show bracket                           # every characteristic's chart statistics
    cmm trends show bracket "bore / diameter" --subgroup 5 --station cmm-2
    cmm trends export bracket "bore / diameter" -o bore.csv
    cmm trends sync                                   # upload the parts waiting in the local journal

``--trends DIR`` is the station's local trends journal (default ./trends); ``--db URL`` (or CMM_TRENDS_DB)
the shared PostgreSQL database; without it only the local journal's parts are shown.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from ..session.trends_chart import charts_for, open_trends


def add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trends", metavar="DIR", default="trends", help="the local trends journal (default ./trends)")
    parser.add_argument("--db", metavar="URL", default=None,
                        help="the shared trends database, postgresql://... (default: CMM_TRENDS_DB)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser)
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.add_parser("list", help="series, characteristics and stations")
    p = sub.add_parser("show", help="chart statistics, Cp/Cpk and out-of-tolerance parts")
    p.add_argument("series")
    p.add_argument("characteristic", nargs="?", help="one characteristic (default: every one of the series)")
    p.add_argument("--subgroup", type=int, default=1, help="1: individuals (I-MR) chart; 2 to 25: X-bar-R")
    p.add_argument("--station", default=None, help="only this station's parts")
    p = sub.add_parser("export", help="one characteristic's parts as CSV")
    p.add_argument("series")
    p.add_argument("characteristic")
    p.add_argument("-o", "--output", required=True, metavar="FILE.csv")
    p.add_argument("--station", default=None, help="only this station's parts")
    sub.add_parser("sync", help="upload the parts waiting in the local journal to the shared database")


def run(args: argparse.Namespace) -> int:
    from ..session.trends import TrendError
    from ..session.trends_chart import history_csv, summary

    if not getattr(args, "action", None):
        print("cmm trends: choose list, show, export or sync (cmm trends --help)", file=sys.stderr)
        return 2
    try:
        trends = open_trends(args.trends, args.db)
    except (TrendError, OSError) as exc:
        print(f"cmm trends: {exc}", file=sys.stderr)
        return 1
    try:
        if args.action == "list":
            for s in trends.series():
                print(f"{s}  (stations: {', '.join(trends.stations(s))})")
                for name, unit in trends.characteristics(s):
                    print(f"    {name} [{unit}]")
        elif args.action == "show":
            for tc in charts_for(trends, args.series, args.characteristic, subgroup=args.subgroup,
                                 station=args.station):
                print(f"{tc.history.series}: {tc.history.characteristic}")
                for k, v in summary(tc):
                    print(f"    {k}: {v}")
        elif args.action == "export":
            (tc,) = charts_for(trends, args.series, args.characteristic, station=args.station)
            with open(args.output, "w", encoding="utf-8") as fh:
                fh.write(history_csv(tc.history))
            print(f"wrote {args.output}: {len(tc.history)} parts")
        elif args.action == "sync":
            if not trends.database_url:
                print("cmm trends sync: give the shared database with --db URL (or CMM_TRENDS_DB)", file=sys.stderr)
                return 2
            sent = trends.sync(force=True)
            print(f"uploaded {sent} parts; {trends.pending()} waiting")
            if trends.pending():
                print(f"cmm trends sync: {trends.state.error}", file=sys.stderr)
                return 1
        if trends.database_url and trends.source == "local":
            print(f"note: the shared database is unreachable ({trends.state.error}); these are this folder's parts",
                  file=sys.stderr)
    except (TrendError, OSError) as exc:
        print(f"cmm trends: {exc}", file=sys.stderr)
        return 1
    finally:
        trends.close()
    return 0

"""`cmm sessions`: list, show, rename, delete and export recorded sessions.

    cmm sessions [--store DIR|URL] list
    cmm sessions show NAME
    cmm sessions rename OLD NEW
    cmm sessions delete NAME [--yes]
    cmm sessions export NAME [--csv FILE] [--json FILE] [--part MESH]
    cmm sessions reevaluate NAME NEW [--tip-radius MM] [--method ls|minzone|mic|mcc]
    cmm sessions teach NAME -o PROGRAM.toml [--clearance MM]

``--store`` is a directory of JSON Lines journals (default ./sessions, or
$CMM_SESSION_STORE) or a postgresql:// URL. A session being recorded cannot
be renamed or deleted.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from . import action


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--store", default=None, help="session directory or postgresql:// URL (default ./sessions)")
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("list", help="list the sessions")
    action(sub, "show", "summary, features and warnings of a session", "name")
    action(sub, "rename", "rename a session", "old", "new")
    p = action(sub, "delete", "delete a session", "name")
    p.add_argument("--yes", action="store_true", help="do not ask for confirmation")
    p = action(sub, "export", "export hits as CSV, the whole session as JSON and/or its results as QIF 3", "name")
    p.add_argument("--csv", metavar="FILE")
    p.add_argument("--json", metavar="FILE")
    p.add_argument("--qif", metavar="FILE", nargs="?", const=True,
                   help="QIF 3 Results document (default NAME.qif here)")
    p.add_argument("--program", metavar="PROGRAM.toml", help="with --qif: take the feature tolerances from a program")
    p.add_argument("--part", metavar="MESH", help="part mesh for deviations (else the recorded one if found)")
    p = action(sub, "reevaluate",
               "recompute points and features (a DMIS run's tolerances too: its program run again) from the raw "
               "counts into a new session", "name", "new")
    p.add_argument("--tip-radius", type=float, help="tip radius in mm (default: the recorded one)")
    p.add_argument("--method", choices=("ls", "minzone", "mic", "mcc"), help="refit every feature with this criterion")
    p = action(sub, "teach", "write a measurement program (TOML) from a session", "name")
    p.add_argument("-o", "--output", required=True, metavar="PROGRAM.toml")
    p.add_argument("--clearance", type=float, default=10.0, help="mm above the part for moves between hits")


def _when(t: float | None) -> str:
    return "" if t is None else time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))


def _print_dmis(old: Any, new: Any) -> None:
    """A DMIS run's tolerances the report has no row for, recorded and re-evaluated, one line each; those left out
    in one sentence."""
    from ..session.qif_dmis import DMIS_ONLY, left_out, session_evaluations

    before = {(e.tolerance.label, tuple(e.features)): e for e in session_evaluations(old)}
    for e in session_evaluations(new):
        if e.tolerance.word in DMIS_ONLY:
            b = before.get((e.tolerance.label, tuple(e.features)))
            was = "—" if b is None else f"{b.value:.5f}"
            print(f"{'-'.join(e.features)}: T({e.tolerance.label}) TOL/{e.tolerance.word}: {was} -> {e.value:.5f} "
                  f"{'INTOL' if e.intol else 'OUTOL'}")
    if gone := left_out(new):
        print(f"warning: {gone}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    from ..journal.writer import JournalError
    from ..program.toml_program import ProgramError
    from ..journal.store import StoreError

    try:
        return _run(args)
    except (StoreError, JournalError, ProgramError, OSError) as exc:
        print(f"cmm sessions: {exc}", file=sys.stderr)
        return 1


def _run(args: argparse.Namespace) -> int:
    from ..journal.store import load_session, open_store

    store = open_store(args.store)
    if args.action == "list":
        infos = store.list()
        if not infos:
            print(f"no sessions in {store.location}")
            return 0
        width = max(len(i.name) for i in infos)
        for i in infos:
            flag = "  (recording)" if i.open_for_writing else ""
            print(f"{i.name:<{width}}  {i.events:7d} events  {_when(i.modified)}{flag}")
        return 0
    if args.action == "show":
        s = load_session(store, args.name)
        summary = s.summary()
        for k in ("name", "events", "hits", "deleted_hits", "features", "alignments", "notes", "errors", "part",
                  "part_sha256"):
            print(f"{k:>13}: {summary[k]}")
        print(f"{'started':>13}: {_when(summary['started'])}")
        print(f"{'ended':>13}: {_when(summary['ended'])}")
        if s.derived_from:
            print(f"{'derived from':>13}: {s.derived_from.get('session')}")
        for f in s.features.values():
            g = f.fit
            size = f"  D {2 * g['radius']:.4f}" if "radius" in g else ""
            print(f"  feature {f.id} {f.name!r}: {f.kind}/{f.method}, {len(f.hit_ids)} hits{size}  form {g.get('form', 0):.4f}")
        for w in s.warnings:
            print(f"warning: {w}", file=sys.stderr)
        return 0
    if args.action == "rename":
        store.rename(args.old, args.new)
        print(f"renamed {args.old!r} to {args.new!r}")
        return 0
    if args.action == "delete":
        if not store.exists(args.name):
            print(f"cmm sessions: there is no session {args.name!r} in {store.location}", file=sys.stderr)
            return 1
        if not args.yes:
            if not sys.stdin.isatty():
                print("cmm sessions: refusing to delete without confirmation: add --yes", file=sys.stderr)
                return 1
            if input(f"delete session {args.name!r}? [y/N] ").strip().lower() not in ("y", "yes"):
                print("not deleted")
                return 1
        store.delete(args.name)
        print(f"deleted {args.name!r}")
        return 0
    if args.action == "export":
        from ..session.export import resolve_part_mesh, write_csv, write_json

        if not args.csv and not args.json and not args.qif:
            print("cmm sessions: export needs --csv FILE, --json FILE and/or --qif [FILE]", file=sys.stderr)
            return 2
        s = load_session(store, args.name)
        mesh = resolve_part_mesh(s, args.part)
        if s.part is not None and mesh is None:
            print(f"warning: part {s.part.name!r} not found (or its sha256 differs): no deviations", file=sys.stderr)
        if args.csv:
            write_csv(s, args.csv, mesh)
            print(f"wrote {len(s.hits) + len(s.state.deleted_hits)} hits to {args.csv}")
        if args.json:
            write_json(s, args.json, mesh)
            print(f"wrote {len(s.events)} events to {args.json}")
        if args.qif:
            from ..program.toml_program import load as load_program
            from ..session.qif import write_qif

            target = f"{args.name}.qif" if args.qif is True else args.qif
            program = load_program(args.program) if args.program else None
            write_qif(s, target, mesh=mesh, program=program)
            print(f"wrote the QIF 3 results of {args.name!r} to {target}")
            from ..session.qif_dmis import left_out

            if gone := left_out(s):  # the document says it too (a NotedEvent)
                print(f"warning: {gone}", file=sys.stderr)
        for w in s.warnings:
            print(f"warning: {w}", file=sys.stderr)
        return 0
    if args.action == "reevaluate":
        from dataclasses import replace

        from ..dmis.replay import reevaluate_event
        from ..session.reevaluate import reevaluate
        from ..journal.store import write_session

        s = load_session(store, args.name)
        settings = s.probe_settings()
        if args.tip_radius is not None:
            settings = replace(settings, tip_radius=args.tip_radius)
        new = reevaluate(s, settings, method=args.method, name=args.new, tolerances=reevaluate_event)
        write_session(store, args.new, new.events)
        print(f"wrote {args.new!r}: {len(new.hits)} hits, {len(new.features)} features re-evaluated from raw counts")
        _print_dmis(s, new)
        if new.state.gdt:  # the geometric tolerances, recorded and re-evaluated, one line each
            from ..session.export import resolve_part_mesh
            from ..session.gdt_session import session_gdt

            mesh = resolve_part_mesh(s)
            before = {d.get("id"): c for d, c in session_gdt(s, mesh)}
            for d, c in session_gdt(new, mesh):
                b = before.get(d.get("id"))
                was = "—" if b is None or b.actual is None else f"{b.actual:.4f}"
                now = "not evaluated" if c.actual is None else f"{c.actual:.4f}"
                print(f"{c.feature}: {c.name}{' | ' + c.datums if c.datums else ''}: {was} -> {now} "
                      f"(allowed {c.upper:.4f}) {c.verdict}")
        for _, m in new.state.errors[len(s.state.errors):]:
            print(f"warning: {m}", file=sys.stderr)
        return 0
    if args.action == "teach":
        from ..session.export import resolve_part_mesh
        from ..program.toml_program import save, teach

        s = load_session(store, args.name)
        prog = teach(s, clearance=args.clearance, part_mesh=resolve_part_mesh(s))
        save(prog, args.output)
        print(f"wrote {args.output}: {len(prog.features)} features, {len(prog.hits)} hits")
        return 0
    return 2  # pragma: no cover


def main(argv: list[str] | None = None) -> Any:  # pragma: no cover - convenience
    parser = argparse.ArgumentParser(prog="cmm sessions")
    add_arguments(parser)
    return run(parser.parse_args(argv))

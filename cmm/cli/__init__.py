"""The `cmm` command line: one sub-command per capability.

Every sub-command is a module of this package (a front end like the page: it
translates options into the capability's calls); each exposes
``add_arguments(parser)`` and ``run(args) -> int`` and keeps heavy imports
inside ``run`` so `cmm --help` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("cmm.cli.sim", "serve the simulated PIC-SERVO network (TCP or pseudo-terminal)"),
    "fit": ("cmm.cli.fit", "fit a feature to points from a text file"),
    "deviation": ("cmm.cli.deviation", "signed deviation of points to a part mesh"),
    "serve": ("cmm.cli.serve", "start the browser station"),
    "calibrate": ("cmm.cli.calibrate", "calibrate the probe, test it (ISO 10360-5), machine geometry, servo tuning"),
    "sessions": ("cmm.cli.sessions", "list, show, rename, delete, export and re-evaluate recorded sessions"),
    "report": ("cmm.cli.report", "HTML inspection report of a recorded session"),
    "trends": ("cmm.cli.trends", "a series of parts across stations: control charts, Cp/Cpk, CSV, upload"),
    "run": ("cmm.cli.run", "run a DMIS part program (.dmi, .dms) on the station; --check only checks it"),
    "dmis-export": ("cmm.cli.dmis_export", "write a taught program (TOML) as a DMIS program"),
    "users": ("cmm.cli.users", "the station's users and roles: add, list, remove, passwd, role, token, revoke"),
    "ippdme-client": ("cmm.ippdme.client", "send I++ DME commands (or a NIST .prg file) to an I++ DME server"),
}


def action(sub: argparse._SubParsersAction, name: str, help_text: str, *positionals: str) -> argparse.ArgumentParser:
    """A sub-command's action (``cmm sessions rename OLD NEW``) with its positional arguments, in one line."""
    p = sub.add_parser(name, help=help_text)
    for positional in positionals:
        p.add_argument(positional)
    return p


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser; ``only``: the command given, whose module alone is imported (the others are
    listed without their options, so `cmm fit --help` does not load the station, numpy or scipy)."""
    parser = argparse.ArgumentParser(prog="cmm", description="CMM measurement station")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=help_text, description=help_text)
            continue
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:  # a capability not built yet must not break the others
            if exc.name and exc.name.startswith("cmm"):
                continue
            raise
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else argv
    first = next((w for w in words if not w.startswith("-")), None)
    parser = build_parser(first if first in COMMANDS else None)
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""`cmm fit KIND FILE [--method ls|minzone|mic|mcc] [--json]`

FILE holds one point per line, ``x y z`` separated by commas and/or
whitespace; one header line is allowed before the first point, or a first
line with the number of points (NIST data set format); blank lines and ``#``
comments are skipped; ``-`` reads standard input.  The output (table or
``--json``) carries the standard uncertainties (``uncertainty``, mm / rad)
and ``warnings`` (poorly determined fits, ambiguous or unproven optima); ``--gdt`` adds geometric
tolerances against ``--datum`` features (see :mod:`cmm.cli.gdt`) as ``gdt``.  Exit status: 0
success, 1 the fit or a tolerance was refused (too few / degenerate points, method not
available for the kind, a datum that constrains nothing, a profile without a mesh), 2 a file is missing
or malformed.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

KINDS = ("line", "plane", "circle", "sphere", "cylinder", "cone")
METHODS = ("ls", "minzone", "mic", "mcc")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("kind", choices=KINDS, help="feature to fit")
    parser.add_argument("file", help="text file with one 'x y z' point per line ('-' for stdin)")
    parser.add_argument("--method", choices=METHODS, default="ls",
                        help="ls: least squares (default); minzone: minimum zone; "
                             "mic: maximum inscribed; mcc: minimum circumscribed")
    parser.add_argument("--json", action="store_true", help="print the result as JSON (full float precision)")
    from .gdt_args import add_arguments as add_gdt

    add_gdt(parser)


def _format(value: Any) -> str:
    if isinstance(value, dict):
        return "  ".join(f"{k}={v:.3g}" for k, v in value.items()) or "-"
    if isinstance(value, list):
        return "  ".join(f"{v:.9f}" for v in value) or "-"
    if isinstance(value, float):
        return f"{value:.9f}"
    return str(value)


def format_table(summary: dict[str, Any]) -> str:
    width = max(len(k) for k in summary)
    rows = []
    for k, v in summary.items():
        if k == "gdt":  # one line per geometric tolerance: value, allowed, verdict, datums
            rows.extend(f"{(k if i == 0 else '').ljust(width)}  {t['characteristic']}: {t['value']:.6f} "
                        f"(allowed {t['allowed']:.6f}{', ' + t['material'] if t['material'] else ''}"
                        f"{', UZ%+.6f' % t['offset'] if t.get('offset') else ''}"
                        f"{' | ' + t['drf'] if t['drf'] else ''}) {'pass' if t['ok'] else 'FAIL'}"
                        for i, t in enumerate(v))
            continue
        if k == "proof":  # the domain a criterion's optimum was searched and proven in
            from ..metrology.features import proof_text

            rows.append(f"{k.ljust(width)}  {proof_text(v)}")
            continue
        if isinstance(v, list) and v and isinstance(v[0], str):  # warnings: one per line
            rows.extend(f"{(k if i == 0 else '').ljust(width)}  ! {w}" for i, w in enumerate(v))
        else:
            rows.append(f"{k.ljust(width)}  {_format(v) if v is not None else '-'}")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from cmm.metrology.features import FitError
    from cmm.metrology.pointfile import PointFileError, read_points_array

    # only what the command needs: a least-squares fit without tolerances loads neither scipy nor trimesh
    errors: tuple[type[Exception], ...] = (FitError,)
    if args.gdt:
        from cmm.metrology.datums import DatumError
        from cmm.metrology.mesh import MeshError

        errors += (DatumError, MeshError)
    try:
        points = read_points_array(args.file)
        if args.method == "ls":
            from cmm.metrology.fit_ls import LS_FITS

            result = LS_FITS[args.kind](points)
        else:
            from cmm.metrology.fit_criteria import fit

            result = fit(args.kind, points, args.method)
        summary = result.summary()
        tolerances = []
        if args.gdt:
            from cmm.cli.gdt import evaluate as evaluate_gdt

            tolerances = evaluate_gdt(args, args.kind, summary, np.asarray(points, float))
    except PointFileError as exc:
        print(f"cmm fit: {exc}", file=sys.stderr)
        return 2
    except errors as exc:
        print(f"cmm fit: {exc}", file=sys.stderr)
        return 1
    if tolerances:
        summary["gdt"] = tolerances
    if args.json:
        print(json.dumps(summary))  # json writes floats with repr: full precision
    else:
        print(format_table(summary))
    return 0

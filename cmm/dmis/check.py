"""The check of a whole DMIS program before anything moves: every statement supported, blocks closed, labels
defined before they are used, the probe one the station has.

:func:`check` returns the problems as "line N: ..." sentences (empty: the program can run); the first one stops
``cmm run`` and ``cmm run --check`` lists them all. Unsupported statements read "line N: SCNMOD is not
supported" (or "MEAS/TORUS", naming the minor word where only some are supported).
"""

from __future__ import annotations

from .features import KINDS, NUMBERS, SIZED
from .lexer import DmisSyntaxError, statements
from .parser import Expr, Label, Statement, Text, Word, parse_statement
from .tolerances import ALL as TOLERANCES

# major word -> the minor words supported (None: any parameters)
SUPPORTED: dict[str, set[str] | None] = {
    "DMISMN": None, "DMISMD": None, "FILNAM": None, "ENDFIL": None, "DISPLY": None, "PRCOMP": None, "TEXT": None,
    "MODE": {"PROG", "AUTO", "MAN"}, "UNITS": {"MM", "INCH", "CM", "METER", "FEET"},
    "DATSET": None, "TRANS": None, "ROTAT": None, "RECALL": None,
    "SNSDEF": {"PROBE"}, "SNSLCT": None, "SNSET": {"APPRCH", "SEARCH", "RETRCT", "DEPTH"},
    "FEDRAT": {"POSVEL", "MESVEL"}, "GOTO": None,
    "FEAT": set(KINDS), "MEAS": set(KINDS), "PTMEAS": {"CART", "POL"}, "ENDMES": None,
    "CONST": {"POINT", "LINE", "PLANE", "CIRCLE"}, "DATDEF": None, "TOL": set(TOLERANCES),
    "DEVICE": {"STOR", "TERM", "PRINT"}, "OPEN": None, "CLOSE": None, "OUTPUT": None,
    "DECL": None, "ASSIGN": None, "IF": None, "ELSE": None, "ENDIF": None, "DO": None, "ENDDO": None,
    "MACRO": None, "ENDMAC": None, "CALL": None,
}
LABELLED = {"FEAT": "F", "TOL": "T", "SNSDEF": "S", "DEVICE": "DID", "MACRO": "M"}
CONST_METHODS = {"INTOF", "MIDPT", "MIDLI", "MIDPL", "PROJCT", "BF"}
OPEN_BLOCKS = {"MEAS": "ENDMES", "IF": "ENDIF", "DO": "ENDDO", "MACRO": "ENDMAC"}
CLOSE_BLOCKS = {v: k for k, v in OPEN_BLOCKS.items()}


# words that are not values (anything else may be a variable holding one)
NOT_VALUES = {"CART", "POL", "INCR", "INNER", "OUTER", "BND", "UNBND", *KINDS}
IN_MEAS = {"PTMEAS", "GOTO", "DO", "ENDDO", "IF", "ELSE", "ENDIF", "ASSIGN", "CALL", "TEXT"}


def numbers(params: list) -> int:
    """How many parameters are values: numbers, expressions, variables."""
    return sum(isinstance(p, Expr) or (isinstance(p, Word) and p.text not in NOT_VALUES) for p in params)


def _feat_problem(s: Statement) -> str | None:
    words = [p.text for p in s.params if isinstance(p, Word)]
    kind = s.minor
    if kind in SIZED and not ({"INNER", "OUTER"} & set(words)):
        return f"FEAT/{kind} needs INNER or OUTER"
    if "CART" not in words and "POL" not in words:
        return f"FEAT/{kind} needs CART or POL and its coordinates"
    n = numbers(s.params)
    lo, hi = NUMBERS[kind]  # type: ignore[index]
    if kind == "LINE" and n not in (6, 9):  # UNBND x, y, z, i, j, k / BND two end points; then pi, pj, pk
        ends = "x1, y1, z1, x2, y2, z2" if "BND" in words else "x, y, z, i, j, k"
        return (f"FEAT/LINE takes 9 numbers after {'POL' if 'POL' in words else 'CART'} ({ends}, and pi, pj, pk: "
                f"the normal of the plane the line lies in), it has {n}")
    if not lo <= n <= hi:
        want = str(lo) if lo == hi else f"{lo} to {hi}"
        return f"FEAT/{kind} takes {want} numbers after {'POL' if 'POL' in words else 'CART'}, it has {n}"
    return None


def statement_problem(s: Statement) -> str | None:
    """What is wrong with one statement on its own, or None."""
    if s.major not in SUPPORTED:
        return f"{s.major} is not supported"
    minors = SUPPORTED[s.major]
    if minors is not None and s.minor not in minors:
        what = f"{s.major}/{s.minor}" if s.minor else s.major
        return f"{what} is not supported" if s.minor else f"{s.major} needs one of {', '.join(sorted(minors))}"
    m = s.major
    labels = [p for p in s.params if isinstance(p, Label)]
    if m in LABELLED and s.label is None:
        return f"{m} defines a label: write it as {LABELLED[m]}(name) = {m}/..."
    if m == "FEAT":
        return _feat_problem(s)
    if m == "MEAS":
        if not labels or labels[0].type != "F":
            return f"MEAS/{s.minor} needs the feature it measures: MEAS/{s.minor}, F(name), number of points"
    if m == "PTMEAS":
        n = numbers(s.params)
        if n not in (3, 6):
            return f"PTMEAS/{s.minor} takes 3 coordinates and optionally a 3-number vector, it has {n} numbers"
    if m == "GOTO":
        words = [p.text for p in s.params if isinstance(p, Word)]
        n = numbers(s.params)
        if "INCR" in words and n != 4:
            return f"GOTO/INCR takes a distance and a direction (4 numbers), it has {n}"
        if "INCR" not in words and n != 3:
            return f"GOTO takes X, Y, Z, it has {n} numbers"
    if m == "SNSDEF":
        values = [p.constant() for p in s.params if isinstance(p, Expr)]
        words = {p.text for p in s.params if isinstance(p, Word)}
        if "CART" in words and len(values) >= 7 and all(v is not None for v in values[3:6]):
            i, j, k = values[3:6]
            norm = (i * i + j * j + k * k) ** 0.5  # type: ignore[operator]
            if norm < 1e-9 or -k / norm < 0.9999:  # type: ignore[operator]
                return (f"{s.label} points along ({i:g}, {j:g}, {k:g}): the station has one fixed probe pointing "
                        "down (0, 0, -1)")
    if m == "SNSLCT" and (not labels or labels[0].type != "S"):
        return "SNSLCT needs the sensor: SNSLCT/S(name)"
    if m == "RECALL" and (not labels or labels[0].type not in ("D", "DA")):
        return "RECALL needs a datum system: RECALL/D(name)"
    if m == "CONST":
        words = {p.text for p in s.params if isinstance(p, Word)}
        if not (words & CONST_METHODS):
            return f"CONST/{s.minor} needs one of {', '.join(sorted(CONST_METHODS))} (other constructions are not supported)"
    if m == "DATDEF" and (len(labels) != 2 or labels[1].type != "DAT"):
        return "DATDEF names a feature and a datum: DATDEF/FA(name), DAT(A)"
    if m in ("OPEN", "CLOSE") and (not labels or labels[0].type != "DID"):
        return f"{m} needs a device: {m}/DID(name)..."
    if m == "DEVICE" and s.minor == "STOR" and not any(isinstance(p, Text) for p in s.params):
        return "DEVICE/STOR needs a file name in quotes"
    if m == "CALL" and (not labels or labels[0].type != "M"):
        return "CALL needs a macro: CALL/M(name)"
    if m == "DO":
        if len(s.params) < 3 or not isinstance(s.params[0], Word):
            return "DO needs a variable, a start and an end: DO/I, 1, 10"
    if m == "IF" and len(s.params) != 1:
        return "IF takes one condition: IF/(X .GT. 1)"
    return None


def check_statements(stmts: list[Statement]) -> list[str]:
    problems: list[str] = []
    stack: list[Statement] = []
    defined: set[str] = set()
    in_meas = False
    for s in stmts:
        p = statement_problem(s)
        if p is not None:
            problems.append(f"line {s.line}: {p}")
        if s.label is not None:
            defined.add(str(s.label))
        if s.major in OPEN_BLOCKS:
            stack.append(s)
            if s.major == "MEAS":
                if in_meas:
                    problems.append(f"line {s.line}: MEAS inside MEAS: close the first with ENDMES")
                in_meas = True
                for lab in (q for q in s.params if isinstance(q, Label)):
                    if str(lab) not in defined:
                        problems.append(f"line {s.line}: {lab} is measured before it is defined (F({lab.name}) = FEAT/...)")
        elif s.major in CLOSE_BLOCKS:
            if not stack or stack[-1].major != CLOSE_BLOCKS[s.major]:
                problems.append(f"line {s.line}: {s.major} without {CLOSE_BLOCKS[s.major]}")
            else:
                stack.pop()
            if s.major == "ENDMES":
                in_meas = False
        elif s.major == "ELSE" and (not stack or stack[-1].major != "IF"):
            problems.append(f"line {s.line}: ELSE without IF")
        if in_meas and s.major not in IN_MEAS | {"MEAS", "ENDMES"}:
            problems.append(f"line {s.line}: {s.major} inside MEAS: only PTMEAS, GOTO, loops, conditions, "
                            "assignments and macro calls until ENDMES")
        elif s.major == "PTMEAS" and not in_meas:
            problems.append(f"line {s.line}: PTMEAS outside MEAS ... ENDMES")
    for s in stack:
        problems.append(f"line {s.line}: {s.major} is not closed with {OPEN_BLOCKS[s.major]}")
    return problems


def check(text: str) -> tuple[list[Statement], list[str]]:
    """(statements, problems) of a program's text. A statement that cannot be read is a syntax error; the others
    are still checked one by one (supported, well formed), so one pass lists every such problem, in line order.
    The blocks (MEAS, IF, DO) are checked only when every statement reads: a lost line would upset them."""
    try:
        raws = statements(text)
    except DmisSyntaxError as exc:
        return [], [str(exc)]
    stmts: list[Statement] = []
    found: list[tuple[int, str]] = []
    for raw in raws:
        try:
            stmts.append(parse_statement(raw))
        except DmisSyntaxError as exc:
            found.append((exc.line, str(exc)))
    if not found:
        return stmts, check_statements(stmts)
    for s in stmts:
        p = statement_problem(s)
        if p is not None:
            found.append((s.line, f"line {s.line}: {p}"))
    return [], [msg for _, msg in sorted(found, key=lambda f: f[0])]

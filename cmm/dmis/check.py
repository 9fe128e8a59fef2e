"""The check of a whole DMIS program before anything moves: every statement supported, blocks closed, labels
defined before they are used, the probe one the station has.

:func:`check` returns the problems as "line N: ..." sentences (empty: the program can run); the first one stops
``cmm run`` and ``cmm run --check`` lists them all. Unsupported statements read "line N: SCNMOD is not
supported" (or "MEAS/TORUS", naming the minor word where only some are supported).
"""

from __future__ import annotations

import math

from .features import KINDS, NUMBERS, SIZED, size_problem
from .lexer import DmisSyntaxError, statements
from .parser import Expr, Label, Statement, Text, Word, parse_statement
from .parser import evaluate
from .frames import DIRS
from .tolerances import kind_problem
from .rules import (SAVED, SUPPORTED, const_problem, datset_word_problem, material_problem, mount_matrix, mounted,
                    open_problem, probe_direction, probe_problem, rotat_problem)

LABELLED = {"FEAT": "F", "TOL": "T", "SNSDEF": "S", "DEVICE": "DID", "MACRO": "M"}
OPEN_BLOCKS = {"MEAS": "ENDMES", "IF": "ENDIF", "DO": "ENDDO", "MACRO": "ENDMAC"}
CLOSE_BLOCKS = {v: k for k, v in OPEN_BLOCKS.items()}


# words that are not values (anything else may be a variable holding one)
NOT_VALUES = {"CART", "POL", "INCR", "INNER", "OUTER", "BND", "UNBND", *KINDS}
IN_MEAS = {"PTMEAS", "GOTO", "DO", "ENDDO", "IF", "ELSE", "ENDIF", "ASSIGN", "CALL", "TEXT"}
LIMIT = 1e6  # a number larger than this (a kilometre in mm) is no coordinate, speed or tolerance of a CMM
NOT_FINITE = {"NAN", "INF", "INFINITY", "NANQ", "NANS"}
# the statements whose words after the minor word are values (a word there must be a declared variable)
VALUED = {"FEAT", "PTMEAS", "GOTO", "SNSDEF", "SNSET", "FEDRAT", "TOL", "SNSMNT"}
VALUE_WORDS = {"CART", "POL", "INCR", "INNER", "OUTER", "BND", "UNBND", "PROBE", "FIXED", "INDEX", "XVEC", "ZVEC",
               "MNTOFF", "MPM", "MMPS", "IPM", "IPS", "PCENT", "NOMINL", "MMC", "LMC", "RFS", "2D", "3D", "CIRCLR",
               "TOTAL", "XAXIS", "YAXIS", "ZAXIS", "PT2PT", "AVG", "MINIMUM", "MAXIMUM", "XDIR", "YDIR", "ZDIR",
               "UNDEF", "HEIGHT", "DIST", *KINDS}


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
    values = [p.constant() for p in s.params if isinstance(p, Expr)]
    if len(values) != n or any(v is None for v in values):
        return None  # a variable: its value is known only when the program runs (the run judges it then)
    if kind != "SPHERE" and not ("LINE" == kind and "BND" in words) and not any(values[3:6]):
        return f"FEAT/{kind}: its direction vector is zero"
    problem = size_problem(kind, values)  # type: ignore[arg-type]
    return None if problem is None else f"FEAT/{kind}: {problem}"


def _words(s: Statement) -> list[str]:
    return [p.text for p in s.params if isinstance(p, Word)]


def number_problem(s: Statement, variables: set[str] | None = None) -> str | None:
    """A number no run could use: not finite (``nan``, ``1e999``), absurdly large (``GOTO/1e308, 0, 0``), or a
    word where a value goes that no DECL, ASSIGN, DO or MACRO gives a value (``variables``; None: not judged)."""
    for p in s.params:
        if isinstance(p, Word) and p.text in NOT_FINITE:
            return f"{p.text.lower()} is not a finite number"
        if isinstance(p, Expr) and all(t.kind != "word" for t in p.tokens):
            try:
                v = evaluate(p, {}, s.line)
            except (DmisSyntaxError, OverflowError, ZeroDivisionError) as exc:
                return f"{''.join(t.text for t in p.tokens)} cannot be computed: {exc}"
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                shown = "".join(t.text for t in p.tokens)
                if not math.isfinite(v):
                    return f"{shown} is not a finite number"
                if abs(v) > LIMIT:
                    return f"{shown} is not a usable number (more than {LIMIT:g} in size)"
    if variables is not None and s.major in VALUED:
        for p in s.params[1 if s.name != s.major else 0:]:
            if isinstance(p, Word) and p.text not in VALUE_WORDS and p.text not in variables:
                return f"{p.text} is not a number (nor a variable given a value by DECL, ASSIGN or DO)"
    return None


def declared(stmts: list[Statement]) -> set[str]:
    """The names a program gives values: DECL'd, ASSIGNed, DO loop variables, MACRO arguments."""
    out: set[str] = set()
    for s in stmts:
        if s.major == "DECL":
            out |= {p.text for p in s.params if isinstance(p, Word)}
        elif s.major == "ASSIGN" and s.variable:
            out.add(s.variable)
        elif s.major == "DO" and s.params and isinstance(s.params[0], Word):
            out.add(s.params[0].text)
        elif s.major == "MACRO":
            out |= {p.text.upper() for p in s.params if isinstance(p, (Word, Text))}
    return out


def warnings(text: str, stmts: list[Statement]) -> list[str]:
    """What runs but is not as the standard writes it: another spelling of a major word, no ENDFIL at the end."""
    out = [f"line {s.line}: {s.spelled} is not DMIS: read as {s.major} (write {s.major}/...)"
           for s in stmts if s.spelled]
    out += [f"line {line}: RECALL/{key}: nothing named {key} is defined or saved before it in this program: the "
            "run takes it from the station's saved items (an earlier program's SAVE) and stops before any motion "
            "when it has none" for line, key in outside_recalls(stmts)]
    if stmts and not any(s.major == "ENDFIL" for s in stmts):
        last = len(text.splitlines())
        out.append(f"line {last}: the program does not end with ENDFIL: it is taken to end at its last line")
    return out


def statement_problem(s: Statement, angle_scale: float = math.pi / 180.0, mount: list | None = None) -> str | None:
    """What is wrong with one statement on its own, or None (``angle_scale``: radians per program angle unit,
    as the UNITS before it set it; ``mount``: the probe head's axes an SNSMNT before it set)."""
    if s.major not in SUPPORTED:
        return f"{s.major} is not supported"
    if (problem := number_problem(s)) is not None:
        return problem
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
        counts = [p.constant() for p in s.params if isinstance(p, Expr)]
        if counts and counts[-1] is not None and not (counts[-1] >= 1 and float(counts[-1]).is_integer()):
            return f"MEAS/{s.minor}, {labels[0]}: the number of points must be a whole number of at least 1, not {counts[-1]:g}"
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
    if m == "FEDRAT":
        values = [p.constant() for p in s.params if isinstance(p, Expr)]
        if len(values) != 1:
            return f"FEDRAT/{s.minor} takes a unit and one speed, it has {len(values)} numbers"
        if values[0] is not None and not values[0] > 0.0:
            return f"FEDRAT/{s.minor} takes a unit and a positive speed, not {values[0]:g}"
        if not {"MPM", "MMPS", "IPM", "IPS", "PCENT"} & set(_words(s)):
            return f"FEDRAT/{s.minor} needs a unit: MPM, MMPS, IPM, IPS or PCENT"
    if m == "SNSDEF":
        values = [p.constant() for p in s.params if isinstance(p, Expr)]
        # constants only: a variable (an expression or a word) is known only when it runs
        if all(v is not None for v in values) and set(_words(s)) <= {"PROBE", "FIXED", "INDEX", "CART", "POL"}:
            direction, problem = probe_direction(_words(s), values, angle_scale)  # type: ignore[arg-type]
            return problem or probe_problem(str(s.label), mounted(mount, direction))  # type: ignore[arg-type]
    if m == "SNSMNT":
        values = [p.constant() for p in s.params if isinstance(p, Expr)]
        if all(v is not None for v in values):
            return mount_matrix(values, _words(s))[1]  # type: ignore[arg-type]
    if m == "SAVE" and (len(s.params) != 1 or not labels or labels[0].type not in SAVED):
        return "SAVE takes one label: SAVE/DA(name) (a coordinate system), DAT(A), FA(name) or SA(name)"
    if m == "TEXT" and not any(isinstance(p, Text) for p in s.params):
        return f"TEXT/{s.minor} needs its text in quotes: TEXT/{s.minor}, 'text'"
    if m == "SNSLCT" and (not labels or labels[0].type != "S"):
        return "SNSLCT needs the sensor: SNSLCT/S(name)"
    if m == "RECALL" and (len(s.params) != 1 or not labels or labels[0].type not in SAVED):
        return "RECALL takes one label: RECALL/DA(name) (a coordinate system), DAT(A), FA(name) or SA(name)"
    if m == "CONST":
        named = bool(labels) and labels[0].type == "F"
        return const_problem(s.minor, named, _words(s)[1:], len(labels) - 1)  # type: ignore[arg-type]
    if m == "DATSET":
        for w in _words(s):
            if s.minor != "MCS" and (problem := datset_word_problem(w)) is not None:
                return problem
    if m == "ROTAT":
        p = s.params
        return rotat_problem(p[0].text if p and isinstance(p[0], Word) else None,
                             len(p) > 1 and isinstance(p[1], Label),
                             p[2].text if len(p) > 2 and isinstance(p[2], Word) else None, len(p))
    if m == "TOL" and (problem := material_problem(s.minor, _words(s))) is not None:  # type: ignore[arg-type]
        return problem
    if m == "DATDEF" and (len(labels) != 2 or labels[1].type != "DAT"):
        return "DATDEF names a feature and a datum: DATDEF/FA(name), DAT(A)"
    if m in ("OPEN", "CLOSE") and (not labels or labels[0].type != "DID"):
        return f"{m} needs a device: {m}/DID(name)..."
    if m == "OPEN":
        return open_problem(_words(s))
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


def mounts(stmts: list[Statement]) -> list[list | None]:
    """The probe head's axes (SNSMNT) in force at each statement: the machine's until an SNSMNT."""
    out, current = [], None
    for s in stmts:
        if s.major == "SNSMNT":
            values = [p.constant() for p in s.params if isinstance(p, Expr)]
            if all(v is not None for v in values):
                current = mount_matrix(values, _words(s))[0] or current  # type: ignore[arg-type]
        out.append(current)
    return out


def recall_problems(stmts: list[Statement], *, earlier: bool = False) -> dict[int, str]:
    """Statement index -> why its SAVE has nothing to save or its RECALL cannot find what it names in the program:
    nothing of that name was defined or saved before it (in program order). ``earlier``: the RECALLs of that kind
    instead, with the saved item's key (``DA(x)``): they take what an earlier program saved on the station (the
    run looks before any motion; see :func:`outside_recalls`)."""
    known: set[str] = set()
    out: dict[int, str] = {}
    recalls: dict[int, str] = {}
    for k, s in enumerate(stmts):
        labels = [p for p in s.params if isinstance(p, Label)]
        if s.label is not None:
            known.add(f"{'DA' if s.label.type == 'D' else s.label.type}({s.label.name})")
        if s.major == "DATDEF" and len(labels) == 2:
            known.add(str(labels[1]))
        if s.major in ("MEAS", "CONST") and labels:
            known.add(f"FA({labels[0].name})")
        if s.major == "SAVE" and labels:
            lab = labels[0]
            name = f"{'DA' if lab.type == 'D' else lab.type}({lab.name})"
            if name not in known:
                out[k] = f"SAVE/{lab}: nothing named {lab} is defined before it"
        if s.major == "RECALL" and labels:
            lab = labels[0]
            name = f"{'DA' if lab.type == 'D' else lab.type}({lab.name})"
            if name not in known:
                recalls[k] = name
    return recalls if earlier else out


def outside_recalls(stmts: list[Statement]) -> list[tuple[int, str]]:
    """(line, key) of each RECALL of an item this program neither defines nor saves before it: it must have been
    saved by an earlier program on the station (cmm.dmis.saved)."""
    return [(stmts[k].line, key) for k, key in recall_problems(stmts, earlier=True).items()]


def angle_scales(stmts: list[Statement]) -> list[float]:
    """Radians per program angle unit at each statement: degrees until a UNITS/.., ANGRAD."""
    out, scale = [], math.pi / 180.0
    for s in stmts:
        if s.major == "UNITS":
            words = _words(s)
            scale = 1.0 if "ANGRAD" in words else (math.pi / 180.0 if "ANGDEC" in words else scale)
        out.append(scale)
    return out


def _material(s: Statement) -> tuple[str, list[tuple[str, str]]]:
    """TOL/..: (the zone's material condition, the datums at MMC / LMC) as the run reads them."""
    zone, datums = "", []
    last = None
    for p in s.params[1:]:
        if isinstance(p, Word) and p.text in ("MMC", "LMC"):
            if isinstance(last, Label) and last.type == "DAT":
                datums.append((last.name, p.text))
            else:
                zone = p.text
        last = p
    return zone, datums


def size_problems(stmts: list[Statement]) -> dict[int, str]:
    """Statement index -> why its OUTPUT cannot evaluate a position at MMC / LMC: the feature (or a datum feature
    at MMC / LMC) has no size limits yet, from a TOL/DIAM or TOL/RAD output with it before, in program order.
    Inside a MACRO the order is the CALL's, so only its size outputs count there."""
    kinds: dict[str, str] = {}
    tols: dict[str, tuple[str, str, list[tuple[str, str]]]] = {}  # T label -> (word, zone material, datums at MMC / LMC)
    datum_features: dict[str, str] = {}
    sized: set[str] = set()
    out: dict[int, str] = {}
    in_macro = False
    for k, s in enumerate(stmts):
        labels = [p for p in s.params if isinstance(p, Label)]
        in_macro = (in_macro or s.major == "MACRO") and s.major != "ENDMAC"
        if s.major == "FEAT" and s.label is not None:
            kinds[s.label.name] = s.minor or ""
        elif s.major == "TOL" and s.label is not None:
            tols[s.label.name] = (s.minor or "", *_material(s))
        elif s.major == "DATDEF" and len(labels) == 2:
            datum_features[labels[1].name] = labels[0].name
        elif s.major == "OUTPUT":
            pending: list[str] = []
            after = False
            for lab in labels:
                if lab.type in ("FA", "F"):
                    pending, after = ([] if after else pending) + [lab.name], False
                elif lab.type in ("TA", "T") and lab.name in tols and pending:
                    after = True
                    word, zone, datums = tols[lab.name]
                    if word in ("DIAM", "RAD") and kinds.get(pending[0]) in SIZED:
                        sized.add(pending[0])
                    elif word == "POS" and not in_macro and k not in out:
                        f = pending[0]
                        if zone and f not in sized:
                            out[k] = (f"T({lab.name}) at {zone} needs FA({f})'s size limits: output its TOL/DIAM "
                                      f"first (OUTPUT/FA({f}), TA(..))")
                        for d, mod in datums:
                            g = datum_features.get(d)
                            if g is not None and g not in sized and k not in out:
                                out[k] = (f"DAT({d}) at {mod} needs FA({g})'s size limits: output its "
                                          f"TOL/DIAM first (OUTPUT/FA({g}), TA(..))")
    return out


def reference_problems(stmts: list[Statement]) -> dict[int, str]:
    """Statement index -> a name it uses that the program never gives anything: a device CLOSEd that no DEVICE
    defines, a datum (TOL, DATSET) that no DATDEF defines nor RECALL brings, a feature OUTPUT as measured (FA)
    that no MEAS or CONST makes nor RECALL brings, a sensor selected (SNSLCT) that no SNSDEF defines nor RECALL
    brings. The whole program is looked at (not only the lines before): a
    MACRO may be called after the lines it uses are run, so the order is the run's to judge."""
    devices, datums, features, sensors = set(), set(), set(), set()
    for s in stmts:
        labels = [p for p in s.params if isinstance(p, Label)]
        if s.label is not None and s.label.type == "FA":  # FA(name) = FEAT/..: an actual written as a statement
            features.add(s.label.name)
        if s.major == "DEVICE" and s.label is not None:
            devices.add(s.label.name)
        elif s.major == "SNSDEF" and s.label is not None:
            sensors.add(s.label.name)
        elif s.major == "DATDEF" and len(labels) == 2:
            datums.add(labels[1].name)
        elif s.major in ("MEAS", "CONST") and labels:
            features.add(labels[0].name)
        elif s.major == "RECALL" and labels:
            {"DAT": datums, "SA": sensors}.get(labels[0].type, features).add(labels[0].name)
    out: dict[int, str] = {}
    for k, s in enumerate(stmts):
        labels = [p for p in s.params if isinstance(p, Label)]
        if s.major == "CLOSE" and labels and labels[0].type == "DID" and labels[0].name not in devices:
            out[k] = f"CLOSE/{labels[0]}: no DEVICE defines DID({labels[0].name}) (DID(name) = DEVICE/STOR, 'file')"
        elif s.major in ("TOL", "DATSET"):
            missing = [lab for lab in labels if lab.type == "DAT" and lab.name not in datums]
            if missing:
                what = f"{s.major}/{s.minor}" if s.minor else s.major
                out[k] = (f"{what}: {missing[0]} is defined by no DATDEF in the program "
                          f"(DATDEF/FA(name), {missing[0]})")
        elif s.major == "SNSLCT" and labels and labels[0].type == "S" and labels[0].name not in sensors:
            out[k] = (f"SNSLCT/{labels[0]}: no SNSDEF in the program defines {labels[0]} "
                      f"({labels[0]} = SNSDEF/PROBE, ..., tip diameter)")
        elif s.major == "OUTPUT":
            missing = [lab for lab in labels if lab.type == "FA" and lab.name not in features]
            if missing:
                out[k] = (f"OUTPUT/{missing[0]}: no MEAS or CONST in the program makes {missing[0]} (output the "
                          f"nominal as F({missing[0].name}))")
    return out


UNDIRECTED = ("point", "sphere")  # a datum of these kinds has a location but no direction


def kind_problems(stmts: list[Statement]) -> dict[int, str]:
    """Statement index -> a tolerance output on a feature of a kind it does not apply to (TOL/FLAT of a point,
    TOL/DIAM of a plane), or a DATSET direction word (ZDIR ...) on a datum with no direction (a point, a sphere):
    the kinds come from the program's FEAT and CONST statements, and the words are the run's own refusals."""
    kinds: dict[str, str] = {}
    tols: dict[str, str] = {}
    datums: dict[str, str] = {}
    for s in stmts:
        labels = [p for p in s.params if isinstance(p, Label)]
        if s.major == "FEAT" and s.label is not None and s.minor in KINDS:
            kinds[s.label.name] = KINDS[s.minor]
        elif s.major == "CONST" and labels and labels[0].type == "F" and s.minor in KINDS:
            kinds[labels[0].name] = KINDS[s.minor]
        elif s.major == "TOL" and s.label is not None and s.minor:
            tols[s.label.name] = s.minor
        elif s.major == "DATDEF" and len(labels) == 2 and labels[1].type == "DAT":
            datums[labels[1].name] = labels[0].name
    out: dict[int, str] = {}
    for k, s in enumerate(stmts):
        labels = [p for p in s.params if isinstance(p, Label)]
        if s.major == "OUTPUT":
            features = [lab.name for lab in labels if lab.type in ("FA", "F")]
            for lab in (lab for lab in labels if lab.type == "TA" and lab.name in tols):
                word = tols[lab.name]
                if len(features) == 1 and features[0] in kinds:
                    problem = kind_problem(word, kinds[features[0]], features[0])
                    if problem is not None:
                        out[k] = f"T({lab.name}): {problem}"
                        break
        elif s.major == "DATSET":
            current = None
            for p in s.params:
                if isinstance(p, Label):
                    current = (str(p), datums.get(p.name) if p.type == "DAT" else p.name)
                elif isinstance(p, Word) and p.text in DIRS and current is not None:
                    kind = kinds.get(current[1] or "")
                    if kind in UNDIRECTED:
                        out[k] = (f"DATSET: {current[0]} (FA({current[1]}), a {kind}) has no direction for "
                                  f"{p.text}: use a plane, line, axis or circle")
                        break
    return out


def check_statements(stmts: list[Statement]) -> list[str]:
    problems: list[str] = []
    stack: list[Statement] = []
    defined: set[str] = set()
    in_meas = False
    sizes = size_problems(stmts)
    recalls = recall_problems(stmts)
    references = reference_problems(stmts)
    kinds = kind_problems(stmts)
    variables = declared(stmts)
    for k, (s, scale, mount) in enumerate(zip(stmts, angle_scales(stmts), mounts(stmts))):
        p = (statement_problem(s, scale, mount) or number_problem(s, variables) or sizes.get(k) or recalls.get(k)
             or references.get(k) or kinds.get(k))
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
    for s, scale, mount in zip(stmts, angle_scales(stmts), mounts(stmts)):
        p = statement_problem(s, scale, mount)
        if p is not None:
            found.append((s.line, f"line {s.line}: {p}"))
    return [], [msg for _, msg in sorted(found, key=lambda f: f[0])]

"""What each supported DMIS statement accepts: one table read by the check before any motion
(:mod:`cmm.dmis.check`) and by the run (:mod:`cmm.dmis.executor`), so a statement the run would refuse is
refused, with its line, before anything moves.

Each ``*_problem`` function returns what is wrong in words (None: accepted)."""

from __future__ import annotations

import math
from typing import Sequence

from .features import KINDS
from .frames import AXES, DIRS, ORIGINS
from .parser import Expr, Label, Statement, Word
from .tolerances import ALL as TOLERANCES

# major word -> the minor words supported (None: any parameters)
SUPPORTED: dict[str, set[str] | None] = {
    "DMISMN": None, "DMISMD": None, "FILNAM": None, "ENDFIL": None, "DISPLY": None, "PRCOMP": None,
    "MODE": {"PROG", "AUTO", "MAN"}, "UNITS": {"MM", "INCH", "CM", "METER", "FEET"},
    "TEXT": {"OPER", "OUTFIL", "QUERY", "MAN"},
    "DATSET": None, "TRANS": None, "ROTAT": None, "RECALL": None, "SAVE": None, "WKPLAN": {"XYPLAN", "YZPLAN", "ZXPLAN"},
    "SNSDEF": {"PROBE"}, "SNSLCT": None, "SNSMNT": None, "SNSET": {"APPRCH", "SEARCH", "RETRCT", "DEPTH"},
    "FEDRAT": {"POSVEL", "MESVEL"}, "GOTO": None,
    "FEAT": set(KINDS), "MEAS": set(KINDS), "PTMEAS": {"CART", "POL"}, "ENDMES": None,
    "CONST": {"POINT", "LINE", "PLANE", "CIRCLE"}, "DATDEF": None, "TOL": set(TOLERANCES),
    "DEVICE": {"STOR", "TERM", "PRINT"}, "OPEN": None, "CLOSE": None, "OUTPUT": None,
    "DECL": None, "ASSIGN": None, "IF": None, "ELSE": None, "ENDIF": None, "DO": None, "ENDDO": None,
    "MACRO": None, "ENDMAC": None, "CALL": None,
}

# CONST/<kind>: the construction methods each kind is built with (cmm.dmis.construct)
CONST_METHODS: dict[str, tuple[str, ...]] = {
    "POINT": ("INTOF", "MIDPT", "PROJCT"),
    "LINE": ("BF", "INTOF", "MIDLI", "PROJCT"),
    "PLANE": ("BF", "MIDPL"),
    "CIRCLE": ("BF", "INTOF", "PROJCT"),
}
ALL_CONST_METHODS = {m for ms in CONST_METHODS.values() for m in ms}
BF_OPERANDS = {"LINE": 2, "PLANE": 3, "CIRCLE": 3}  # the fewest features a best fit goes through

LENGTH_UNITS = {"MM": 1.0, "CM": 10.0, "METER": 1000.0, "INCH": 25.4, "FEET": 304.8}  # mm per program unit
DATSET_WORDS = {*DIRS, *ORIGINS}
MATERIAL = ("MMC", "LMC", "RFS")
DOWN_COS = 0.9999  # a probe points down when its direction is within 0.8 degrees of (0, 0, -1)


def _one_of(words: Sequence[str]) -> str:
    return ", ".join(words[:-1]) + " or " + words[-1] if len(words) > 1 else words[0]


def const_problem(kind: str, named: bool, words: Sequence[str], operands: int) -> str | None:
    """CONST/<kind>, F(name), <method>, FA(..), ...: ``named`` when F(name) is its first label; ``words`` its words
    after the kind, ``operands`` the features after F(name)."""
    methods = CONST_METHODS[kind]
    if not named:
        return (f"CONST/{kind} names the feature it constructs among its parameters: "
                f"CONST/{kind}, F(name), {methods[0]}, FA(..), ...")
    for w in words:
        if w not in methods:
            return f"CONST/{kind}, .., {w} is not supported: CONST/{kind} takes {_one_of(methods)}"
    used = [w for w in words if w in methods]
    if len(used) != 1:
        return (f"CONST/{kind} needs one of {_one_of(methods)}" if not used else
                f"CONST/{kind} takes one construction method, it has {', '.join(used)}")
    method = used[0]
    if method == "BF":
        if operands < BF_OPERANDS[kind]:
            return f"CONST/{kind}, .., BF takes {BF_OPERANDS[kind]} or more features, it has {operands}"
    elif operands != 2:
        return f"CONST/{kind}, .., {method} takes two features, it has {operands}"
    return None


def datset_word_problem(word: str) -> str | None:
    if word in DATSET_WORDS:
        return None
    return f"DATSET/.., {word} is not supported: use XDIR, YDIR, ZDIR (XMINUS ...), XORIG, YORIG, ZORIG"


ROTAT_FORMS = ("ROTAT takes an axis and an angle (ROTAT/ZAXIS, 30) or an axis, a feature and the direction that "
               "turns onto it (ROTAT/ZAXIS, FA(HOLE2), XDIR)")


def rotat_problem(axis: str | None, feature: bool, direction: str | None, count: int) -> str | None:
    """ROTAT/<axis>, angle or ROTAT/<axis>, FA(..), <direction>: ``feature`` when the second parameter is a
    feature label, ``direction`` the third parameter's word, ``count`` the parameters."""
    if count < 2 or axis not in AXES:
        return ROTAT_FORMS
    if not feature:
        return None if count == 2 else ROTAT_FORMS
    if count != 3 or direction not in DIRS:
        return ROTAT_FORMS
    if DIRS[direction][0] == AXES[axis]:
        return f"ROTAT/{axis} cannot turn {direction} onto a feature: it is the rotation axis"
    return None


def probe_direction(words: Sequence[str], values: Sequence[float], angle_scale: float
                    ) -> tuple[tuple[float, float, float] | None, str | None]:
    """(direction, problem) of SNSDEF/PROBE, .., CART, x, y, z, i, j, k, diameter or .., POL, a, b, diameter
    (angles in the program's unit: ``angle_scale`` radians each)."""
    if "CART" in words:
        if len(values) < 7:
            return None, "SNSDEF/PROBE, .., CART takes the tip offset X, Y, Z, the direction I, J, K and the tip diameter"
        i, j, k = values[3:6]
        return (float(i), float(j), float(k)), None
    if "POL" in words:
        if len(values) < 3:
            return None, "SNSDEF/PROBE, .., POL takes the angles A, B .. and the tip diameter"
        a, b = values[0] * angle_scale, values[1] * angle_scale
        return (math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), -math.cos(a)), None
    return None, "SNSDEF/PROBE needs CART or POL"


def probe_problem(label: str, direction: tuple[float, float, float]) -> str | None:
    """The station's probes point down: a sensor along any other direction is refused."""
    n = math.sqrt(sum(x * x for x in direction))
    if n > 1e-9 and -direction[2] / n >= DOWN_COS:
        return None
    shown = ", ".join(f"{round(x, 6) + 0.0:g}" for x in direction)
    return f"{label} points along ({shown}): the station has one fixed probe pointing down (0, 0, -1)"


def open_problem(words: Sequence[str]) -> str | None:
    """OPEN/DID(..), DIRECT | FDATA [, DMIS], OUTPUT [, APPEND | OVERWR]: a file of the run's output folder that
    receives the program's DMIS output while it is open."""
    if "INPUT" in words:
        return "OPEN for INPUT is not supported: the station reads no data files in a program"
    if "OUTPUT" not in words:
        return "OPEN/DID(..) takes OUTPUT: OPEN/DID(name), FDATA, DMIS, OUTPUT, OVERWR (or DIRECT, OUTPUT)"
    if "FDATA" in words and any(w not in OPEN_WORDS for w in words):
        other = next(w for w in words if w not in OPEN_WORDS)
        return f"OPEN/DID(..), FDATA, {other} is not supported: the station writes FDATA in the DMIS format only"
    if not {"DIRECT", "FDATA"} & set(words):
        return "OPEN/DID(..) needs DIRECT or FDATA: OPEN/DID(name), FDATA, DMIS, OUTPUT, OVERWR"
    for w in words:
        if w not in OPEN_WORDS:
            return f"OPEN/DID(..), {w} is not supported: OPEN takes DIRECT or FDATA, DMIS, OUTPUT, APPEND or OVERWR"
    return None


OPEN_WORDS = {"DIRECT", "FDATA", "DMIS", "OUTPUT", "APPEND", "OVERWR"}


def device_file(path: str) -> str | None:
    """The file a DEVICE/STOR names, as it is written: its last name only (``C:\\QC\\part.dms``, ``/tmp/x.dms``,
    ``../x.dms`` are all ``part.dms`` / ``x.dms`` of the run's output folder: a program never writes outside
    it); None when nothing usable is left."""
    name = str(path).replace("\\", "/").rstrip("/").rsplit("/", 1)[-1].strip()
    if ":" in name:  # C:part.dms
        name = name.rsplit(":", 1)[-1]
    if name in ("", ".", "..") or any(ord(c) < 32 for c in name):
        return None
    return name


def mount_matrix(values: Sequence[float], words: Sequence[str]) -> tuple[list[list[float]] | None, str | None]:
    """(3x3 rotation, problem) of SNSMNT/XVEC, i, j, k, ZVEC, i, j, k, MNTOFF, x, y, z: the columns are the
    probe head's X, Y, Z axes in machine axes (the sensors SNSDEF defines after it are given in the head's)."""
    form = "SNSMNT takes XVEC, i, j, k, ZVEC, i, j, k, MNTOFF, x, y, z"
    if list(words) != ["XVEC", "ZVEC", "MNTOFF"] or len(values) != 9:
        return None, form
    x, z = [float(v) for v in values[0:3]], [float(v) for v in values[3:6]]
    nx, nz = math.sqrt(sum(v * v for v in x)), math.sqrt(sum(v * v for v in z))
    if nx < 1e-9 or nz < 1e-9:
        return None, "SNSMNT: XVEC and ZVEC must not be zero"
    x, z = [v / nx for v in x], [v / nz for v in z]
    if abs(sum(a * b for a, b in zip(x, z))) > 1e-3:
        return None, "SNSMNT: XVEC and ZVEC must be perpendicular"
    y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]]
    return [[x[i], y[i], z[i]] for i in range(3)], None


def mounted(matrix: Sequence[Sequence[float]] | None, direction: Sequence[float]) -> tuple[float, float, float]:
    """A sensor direction given in the probe head's axes, in machine axes."""
    if matrix is None:
        return (float(direction[0]), float(direction[1]), float(direction[2]))
    return tuple(sum(matrix[i][k] * float(direction[k]) for k in range(3)) for i in range(3))  # type: ignore[return-value]


SAVED = ("D", "DA", "DAT", "FA", "SA")  # what SAVE / RECALL keep: coordinate systems, datums, actuals, sensors


def material_problem(word: str, words: Sequence[str]) -> str | None:
    """TOL/<word>: MMC and LMC apply to TOL/POS only."""
    for w in words:
        if w in ("MMC", "LMC") and word != "POS":
            return f"TOL/{word}, {w}: a material condition applies to TOL/POS only"
    return None


TIP_MATCH = 0.005  # mm: a probe-list tip within this of the SNSDEF's diameter is that sensor


def qualify_command(label: str, diameter: float) -> str:
    """The command that qualifies the stylus S(label) of an SNSDEF tip ``diameter`` mm."""
    return f"cmm calibrate probe --probe {label} --tip-diameter {_mm(diameter)}"


def _fits(p: dict, diameter: float) -> bool:
    return any(abs(float(d) - diameter) <= TIP_MATCH for d in (p["tip_diameter"], *p.get("qualified_diameters", ())))


def match_probe(label: str, diameter: float, probes: Sequence[dict]) -> tuple[str | None, str | None]:
    """(probe name, problem) for SNSLCT/S(label) of an SNSDEF tip ``diameter`` (mm) among the station's probe list
    (rows with ``name``, ``tip_diameter``, ``qualified``, ``selected`` and optionally ``qualified_diameters``).
    The probe named like the sensor when the list has one (its tip must be the sensor's and it must be qualified),
    else the qualified probe with that tip (the one in use first). A stylus not qualified is refused with the
    command that qualifies it."""
    how = f"qualify it with `{qualify_command(label, diameter)}` (or in the Calibration tab's probe list)"
    named = [p for p in probes if str(p["name"]).upper() == label.upper()]
    if named:
        p = named[0]
        if not _fits(p, diameter):
            return None, (f"SNSLCT/S({label}): the probe {p['name']} of the probe list has a {_mm(p['tip_diameter'])} "
                          f"mm tip, the program's S({label}) a {_mm(diameter)} mm tip")
        if not p.get("qualified"):
            return None, f"SNSLCT/S({label}): the probe {p['name']} ({_mm(diameter)} mm) is not qualified: {how}"
        return str(p["name"]), None
    fits = [p for p in probes if p.get("qualified") and _fits(p, diameter)]
    fits.sort(key=lambda p: not p.get("selected"))
    if fits:
        return str(fits[0]["name"]), None
    listed = [f"{p['name']} ({_mm(p['tip_diameter'])} mm)" for p in probes if p.get("qualified")]
    return None, (f"SNSLCT/S({label}): no qualified probe has a {_mm(diameter)} mm tip: {how}; qualified probes: "
                  f"{', '.join(listed) or 'none'}")


def station_tip_problem(label: str, diameter: float, tip_diameter: float) -> str | None:
    """A station without a probe list (no calibration records) measures with its one configured probe: a sensor
    with another tip is refused with the command that qualifies it."""
    if abs(diameter - tip_diameter) <= TIP_MATCH:
        return None
    return (f"SNSLCT/S({label}): the station's probe has a {_mm(tip_diameter)} mm tip, the program's S({label}) a "
            f"{_mm(diameter)} mm tip: qualify it with `{qualify_command(label, diameter)}` and run with its "
            "--records folder")


def sensor_problems(stmts: Sequence[Statement], probes: Sequence[dict] | None,
                    tip_diameter: float | None = None) -> list[str]:
    """"line N: ..." for every SNSLCT whose sensor is not a qualified probe of the station's list (without a list:
    whose tip is not the station's probe's, ``tip_diameter``), read before the run (a sensor whose diameter is a
    variable is judged when it runs)."""
    if probes is None and tip_diameter is None:
        return []
    scale, diameters, out = 1.0, {}, []
    for s in stmts:
        words = [p.text for p in s.params if isinstance(p, Word)]
        if s.major == "UNITS" and words and words[0] in LENGTH_UNITS:
            scale = LENGTH_UNITS[words[0]]
        elif s.major == "SNSDEF" and s.label is not None:
            last = s.params[-1] if s.params else None
            value = last.constant() if isinstance(last, Expr) else None
            diameters[s.label.name] = None if value is None else float(value) * scale
        elif s.major == "SNSLCT":
            label = next((p for p in s.params if isinstance(p, Label)), None)
            if label is not None and diameters.get(label.name) is not None:
                d = float(diameters[label.name])  # type: ignore[arg-type]
                problem = (match_probe(label.name, d, probes)[1] if probes is not None
                           else station_tip_problem(label.name, d, float(tip_diameter)))  # type: ignore[arg-type]
                if problem:
                    out.append(f"line {s.line}: {problem}")
    return out


def _mm(x: float) -> str:
    """2.0, 2.54, 0.125: a length as written on a drawing."""
    s = f"{float(x):.4f}".rstrip("0")
    return s + "0" if s.endswith(".") else s

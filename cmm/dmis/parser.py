"""DMIS statements parsed into a label, a major word and parameters, and the expressions inside them.

``F(BORE) = FEAT/CIRCLE, INNER, CART, 30, 40, 30, 0, 0, 1, 30`` becomes
``Statement(line, label=Label("F", "BORE"), major="FEAT", params=[Word CIRCLE, Word INNER, Word CART, Expr 30, ...])``.
Parameters are words (minor words or variable names), quoted text, labels (``FA(BORE)``, ``DAT(A)``) or
expressions (numbers, variables, ``+ - * / ^``, ``.EQ.`` ..., ``SIN(..)``), evaluated when the statement runs so
variables and loops work. ``X = ASSIGN/ expr`` assigns a variable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Union

from .lexer import DmisSyntaxError, RawStatement, Token, statements, tokens

# label types: F nominal feature, FA actual, D datum (coordinate system), DA, S sensor, SA, T tolerance, TA actual,
# DAT datum, DID device, M macro, and a few more a program may define
LABEL_TYPES = {"F", "FA", "D", "DA", "S", "SA", "T", "TA", "DAT", "DATDEF", "DID", "M", "CR", "DR", "DS", "DV", "FS",
               "G", "GSA", "MA", "PS", "PV", "RT", "SS", "SW", "TL", "V", "VL", "VW", "CZ", "CZSL", "OP", "Q",
               "QIS", "SX", "SENS", "DME", "KC", "KCA", "LI", "PC", "PL", "PR", "SAV"}
FUNCTIONS = {"SIN": math.sin, "COS": math.cos, "TAN": math.tan, "ASIN": math.asin, "ACOS": math.acos,
             "ATAN": math.atan, "SQRT": math.sqrt, "ABS": abs, "EXP": math.exp, "LN": math.log, "LOG": math.log10,
             "INT": lambda x: float(int(x)), "NINT": lambda x: float(round(x))}


@dataclass(frozen=True)
class Label:
    type: str
    name: str

    def __str__(self) -> str:
        return f"{self.type}({self.name})"


@dataclass(frozen=True)
class Word:
    text: str


@dataclass(frozen=True)
class Text:
    text: str


@dataclass(frozen=True)
class Expr:
    tokens: tuple[Token, ...]

    def constant(self) -> float | None:
        """The value when the expression is one number, else None (it depends on variables)."""
        if len(self.tokens) == 1 and self.tokens[0].kind == "num":
            return float(self.tokens[0].value)  # type: ignore[arg-type]
        if len(self.tokens) == 2 and self.tokens[0].text in "+-" and self.tokens[1].kind == "num":
            v = float(self.tokens[1].value)  # type: ignore[arg-type]
            return -v if self.tokens[0].text == "-" else v
        return None


Param = Union[Word, Text, Label, Expr]


@dataclass
class Statement:
    line: int
    major: str  # FEAT, MEAS, PTMEAS, ... or ASSIGN for "X = ASSIGN/.."
    params: list[Param] = field(default_factory=list)
    label: Label | None = None  # F(..) = ...
    variable: str | None = None  # X = ASSIGN/ ...
    text: str = ""
    spelled: str = ""  # the major word as written when it was another spelling of it (ROTATE for ROTAT)

    @property
    def minor(self) -> str | None:
        """The first parameter when it is a word (MEAS/CIRCLE, TOL/DIAM, SNSET/APPRCH)."""
        return self.params[0].text if self.params and isinstance(self.params[0], Word) else None

    @property
    def name(self) -> str:
        """How the operator names the statement: FEAT/CIRCLE, MEAS/CIRCLE, GOTO, ENDMES."""
        m = self.minor
        return f"{self.major}/{m}" if m and self.major in MINOR_NAMED else self.major


# vendors' spellings of DMIS major words, read as the standard's with a warning naming it
SPELLINGS = {"ROTATE": "ROTAT"}

# statements whose first word names what they do (their support is checked per minor word)
MINOR_NAMED = {"FEAT", "MEAS", "TOL", "CONST", "SNSDEF", "SNSET", "FEDRAT", "MODE", "DEVICE", "PTMEAS", "DECL", "OPEN",
               "UNITS", "DATSET", "SNSDEF", "TEXT", "WKPLAN"}


def _label(toks: list[Token], k: int, line: int) -> tuple[Label, int] | None:
    """A label ``TYPE(name)`` starting at token k: (label, index after it)."""
    if k + 1 < len(toks) and toks[k].kind == "word" and toks[k].text in LABEL_TYPES and toks[k + 1].text == "(":
        j = k + 2
        parts = []
        while j < len(toks) and toks[j].text != ")":
            if toks[j].kind not in ("word", "num") and toks[j].text not in ("-",):
                raise DmisSyntaxError(line, f"a label name may hold letters, digits and '_', not {toks[j].text!r}")
            parts.append(toks[j].text)
            j += 1
        if j >= len(toks):
            raise DmisSyntaxError(line, f"the label {toks[k].text}( is not closed with ')'")
        if not parts:
            raise DmisSyntaxError(line, f"the label {toks[k].text}() has no name")
        return Label(toks[k].text, "".join(parts)), j + 1
    return None


def _split(toks: list[Token], line: int) -> list[list[Token]]:
    """Parameters split at the commas outside parentheses."""
    out: list[list[Token]] = [[]]
    depth = 0
    for t in toks:
        if t.text == "(":
            depth += 1
        elif t.text == ")":
            depth -= 1
            if depth < 0:
                raise DmisSyntaxError(line, "a ')' has no '(' before it")
        if t.text == "," and depth == 0:
            out.append([])
        else:
            out[-1].append(t)
    if depth:
        raise DmisSyntaxError(line, "a '(' is not closed with ')'")
    return out


def _param(toks: list[Token], line: int) -> Param:
    if not toks:
        raise DmisSyntaxError(line, "an empty parameter (two commas in a row, or a comma at the end)")
    if len(toks) == 1 and toks[0].kind == "word":
        return Word(toks[0].text)
    if len(toks) == 1 and toks[0].kind == "str":
        return Text(str(toks[0].value))
    lab = _label(toks, 0, line)
    if lab is not None and lab[1] == len(toks):
        return lab[0]
    expr = Expr(tuple(toks))
    evaluate(expr, None, line)  # syntax only: variables are not looked up
    return expr


def parse_statement(raw: RawStatement) -> Statement:
    toks = tokens(raw)
    line = raw.line
    label = None
    variable = None
    k = 0
    lab = _label(toks, 0, line)
    if lab is not None and lab[1] < len(toks) and toks[lab[1]].text == "=":
        label, k = lab[0], lab[1] + 1
    elif len(toks) >= 2 and toks[0].kind == "word" and toks[1].text == "=":
        variable, k = toks[0].text, 2
    if k >= len(toks) or toks[k].kind != "word":
        raise DmisSyntaxError(line, f"a statement starts with a word such as FEAT or GOTO: {raw.text!r}")
    major = toks[k].text
    spelled = ""
    if major in SPELLINGS:  # a vendor's spelling of a DMIS major word: read as the standard's (the check warns)
        spelled, major = major, SPELLINGS[major]
    rest = toks[k + 1:]
    params: list[Param] = []
    if rest:
        if rest[0].text != "/":
            raise DmisSyntaxError(line, f"{major} must be followed by '/' before its parameters: {raw.text!r}")
        if len(rest) > 1:
            params = [_param(p, line) for p in _split(rest[1:], line)]
    if variable is not None and major != "ASSIGN":
        raise DmisSyntaxError(line, f"a variable is given a value with {variable} = ASSIGN/ ...; got {raw.text!r}")
    return Statement(line, major, params, label, variable, raw.text, spelled)


def parse(text: str) -> list[Statement]:
    """Every statement of a DMIS program (syntax errors raise :class:`DmisSyntaxError` naming the line)."""
    return [parse_statement(r) for r in statements(text)]


# --------------------------------------------------------------------------------------------- expressions

_COMPARE = {".EQ.": lambda a, b: a == b, ".NE.": lambda a, b: a != b, ".LT.": lambda a, b: a < b,
            ".LE.": lambda a, b: a <= b, ".GT.": lambda a, b: a > b, ".GE.": lambda a, b: a >= b}


def evaluate(expr: Expr, variables: dict[str, Any] | None, line: int) -> Any:
    """The value of an expression; ``variables`` None checks the syntax only (names evaluate to 1)."""
    toks = list(expr.tokens)
    pos = 0

    def peek() -> str | None:
        return toks[pos].text if pos < len(toks) else None

    def take() -> Token:
        nonlocal pos
        if pos >= len(toks):
            raise DmisSyntaxError(line, "an expression ends too early")
        pos += 1
        return toks[pos - 1]

    def primary() -> Any:
        t = take()
        if t.kind == "num":
            return float(t.value)  # type: ignore[arg-type]
        if t.kind == "str":
            return t.value
        if t.text == "(":
            v = orexpr()
            if take().text != ")":
                raise DmisSyntaxError(line, "a '(' is not closed with ')'")
            return v
        if t.kind == "word":
            if peek() == "(" and t.text in FUNCTIONS:
                take()
                v = orexpr()
                if take().text != ")":
                    raise DmisSyntaxError(line, f"{t.text}( is not closed with ')'")
                if variables is None:
                    return 1.0
                try:
                    return float(FUNCTIONS[t.text](v))
                except (ValueError, TypeError) as exc:
                    raise DmisSyntaxError(line, f"{t.text}({v}) cannot be computed: {exc}") from None
            if t.text in (".TRUE.", "TRUE"):
                return True
            if variables is None:
                return 1.0
            if t.text not in variables:
                raise DmisSyntaxError(line, f"the variable {t.text} has no value (declare it with DECL/ and ASSIGN it)")
            return variables[t.text]
        raise DmisSyntaxError(line, f"unexpected {t.text!r} in an expression")

    def unary() -> Any:
        if peek() in ("-", "+"):
            sign = take().text
            v = unary()
            return -v if sign == "-" else v
        if peek() == ".NOT.":
            take()
            return not unary()
        v = primary()
        if peek() in ("^",) or (peek() == "*" and pos + 1 < len(toks) and toks[pos + 1].text == "*"):
            take()
            if peek() == "*":
                take()
            return v ** unary()
        return v

    def mul() -> Any:
        v = unary()
        while peek() in ("*", "/"):
            op = take().text
            w = unary()
            if op == "/" and variables is not None and w == 0:
                raise DmisSyntaxError(line, "division by zero")
            v = v * w if op == "*" else (v / w if variables is not None else v)
        return v

    def add() -> Any:
        v = mul()
        while peek() in ("+", "-"):
            op = take().text
            w = mul()
            v = v + w if op == "+" else v - w
        return v

    def compare() -> Any:
        v = add()
        while peek() in _COMPARE:
            op = take().text
            v = _COMPARE[op](v, add())
        return v

    def andexpr() -> Any:
        v = compare()
        while peek() == ".AND.":
            take()
            w = compare()
            v = bool(v) and bool(w)
        return v

    def orexpr() -> Any:
        v = andexpr()
        while peek() == ".OR.":
            take()
            w = andexpr()
            v = bool(v) or bool(w)
        return v

    value = orexpr()
    if pos != len(toks):
        raise DmisSyntaxError(line, f"unexpected {toks[pos].text!r} in an expression")
    return value

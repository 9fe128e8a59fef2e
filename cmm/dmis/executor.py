"""Run checked DMIS statements on a measuring target: motion, probing, fits, alignments, tolerances, output.

The target (:class:`cmm.dmis.runner.StationTarget` on the station) moves in straight lines (``GOTO``), takes
programmed hits with the program's approach, search and retract distances and speeds (``PTMEAS`` inside
``MEAS .. ENDMES``, with ``SNSET`` and ``FEDRAT``), and its measurement model fits the features, so every hit
and feature is journalled like any other session's. Coordinates are read in the units and the coordinate system
in force (``UNITS``, ``DATSET``, ``TRANS``, ``ROTAT``, ``RECALL``) and output the same way.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..metrology.numbers_text import num
from ..measurement.program import record_trend
from ..session.trends import tolerance_values
from .features import KINDS, Actual, Nominal, actual_line, bounded_line, nominal_from, nominal_line
from .frames import AXES, DIRS, ORIGINS, FrameError, apply, apply_vector, datum_frame, inverse, rotation, translation
from .lexer import DmisSyntaxError
from .parser import Expr, Label, Param, Statement, Text, Word, evaluate
from .rules import (LENGTH_UNITS, const_problem, datset_word_problem, match_probe, material_problem,
                    mounted, probe_direction, probe_problem, rotat_problem, station_tip_problem)
from .vendor import VendorStatements
from .tolerances import Evaluation, planar_position, Tolerance, ToleranceError, evaluate as evaluate_tolerance, model_tolerance, output_line

SPEED_UNITS = {"MPM": 1000.0 / 60.0, "MMPS": 1.0, "IPM": 25.4 / 60.0, "IPS": 25.4}


class DmisError(RuntimeError):
    """A DMIS program stopped: "line N: what happened". ``result``: what the run had done by then (its actuals
    and the output up to that line, ending in a ``$$`` comment that says why), or None when nothing ran."""

    result: "RunResult | None" = None


class Target(Protocol):
    model: Any  # the measurement model, read: hits and features (fits go through ``fit``, notes through ``note``)

    def position(self) -> np.ndarray: ...
    def move(self, target: np.ndarray, speed: float | None) -> None: ...
    def probe(self, point: np.ndarray, approach: np.ndarray, *, speed: float | None, approach_distance: float,
              search_distance: float, retract_distance: float, rapid_speed: float | None) -> int: ...
    def manual_hits(self, prompt: str, n: int, guides: list[tuple[np.ndarray, np.ndarray]]) -> list[int]: ...
    def align(self, measured: np.ndarray, nominal: np.ndarray, points: np.ndarray, name: str) -> str: ...
    def fit(self, kind: str, hit_ids: list[int], name: str, nominal: Any) -> Any: ...
    def note(self, text: str) -> None: ...
    def set_tolerance(self, feature_id: int, tolerance: dict[str, float]) -> None: ...
    def set_nominal(self, feature_id: int, nominal: Any) -> None: ...
    def define_datum(self, label: str, feature_id: int) -> None: ...
    def define_position(self, feature_id: int, tolerance: float, datums: list[str], *, material: str, name: str,
                        datum_modifiers: dict[str, str] | None) -> None: ...
    def probes(self) -> list[dict[str, Any]] | None: ...
    def select_probe(self, name: str) -> str: ...
    def tell(self, text: str) -> None: ...
    def hold(self, done: Any) -> None: ...
    def ask(self, prompt: str, *, answer: bool) -> str: ...
    @property
    def tip_radius(self) -> float: ...
    @property
    def nominal_tip_diameter(self) -> float: ...
    @property
    def probing_speed(self) -> float: ...
    @property
    def positioning_speed(self) -> float: ...
    @property
    def probe_distances(self) -> tuple[float, float, float]: ...


@dataclass
class RunResult:
    actuals: dict[str, Actual] = field(default_factory=dict)
    evaluations: list[Evaluation] = field(default_factory=list)
    outputs: dict[str | None, str] = field(default_factory=dict)  # device file (None: the default output) -> text
    log: list[str] = field(default_factory=list)
    hits: int = 0
    frames: dict[str, np.ndarray] = field(default_factory=dict)  # D(label) -> program -> machine, as defined


def _text(p: Param) -> str:
    if isinstance(p, Word):
        return p.text
    if isinstance(p, Text):
        return f"'{p.text}'"
    if isinstance(p, Label):
        return str(p)
    toks = p.tokens
    return "".join(t.text if t.kind != "str" else f"'{t.value}'" for t in toks)


def statement_text(s: Statement) -> str:
    head = f"{s.label} = " if s.label else (f"{s.variable} = " if s.variable else "")
    return head + s.major + ("/" + ", ".join(_text(p) for p in s.params) if s.params else "")


def blocks(stmts: list[Statement]) -> dict[int, int]:
    """Statement index -> where its block goes on: MEAS <-> ENDMES, DO <-> ENDDO, MACRO -> ENDMAC, IF -> ELSE (or
    ENDIF), ELSE -> ENDIF. The check has matched them already."""
    pairs: dict[int, int] = {}
    stack: list[int] = []
    for k, s in enumerate(stmts):
        if s.major in ("MEAS", "IF", "DO", "MACRO"):
            stack.append(k)
        elif s.major == "ELSE":
            pairs[stack[-1]] = k
            stack[-1] = k
        elif s.major in ("ENDMES", "ENDIF", "ENDDO", "ENDMAC"):
            start = stack.pop()
            pairs[start] = k
            pairs[k] = start
    return pairs


class Executor(VendorStatements):
    """One run of a program on a target."""

    def __init__(self, stmts: list[Statement], target: Target, *, name: str = "program") -> None:
        self.stmts = stmts
        self.target = target
        self.model = target.model
        self.name = name
        self.frame = np.eye(4)
        # the same coordinate systems built from the datums' nominals instead of their actuals: nominals defined
        # in any of them land in one design frame, where position tolerances compare them with their datums
        self.design_frame = np.eye(4)
        self.design_frames: dict[str, np.ndarray] = {}
        # where the program's alignments found the part against where its nominals put it (see _move_nominals)
        self.placement = np.eye(4)
        self.scale = 1.0
        self.angle_scale = math.pi / 180.0
        self.frames: dict[str, np.ndarray] = {}
        self.nominals: dict[str, Nominal] = {}
        self.tolerances: dict[str, Tolerance] = {}
        self.datums: dict[str, Actual] = {}
        self.sizes: dict[str, tuple[float, float]] = {}  # FA label -> (low, high) diameters from its TOL/DIAM
        self.sensors: dict[str, dict[str, Any]] = {}
        self.sensor: str | None = None
        approach, search, retract = target.probe_distances
        self.snset = {"APPRCH": approach, "SEARCH": search, "RETRCT": retract, "DEPTH": 0.0}
        self.posvel: float | None = None
        self.mesvel: float | None = None
        self.variables: dict[str, Any] = {}
        self.macros: dict[str, int] = {}
        self.devices: dict[str, str | None] = {}
        self.open_devices: list[str] = []
        self.output: list[str] = []
        self.result = RunResult()
        self._meas: tuple[Statement, list[int]] | None = None
        # MODE/MAN and MODE/PROG, MAN: the operator takes the hits by hand (PTMEAS points guide them, GOTO is
        # theirs to make); MODE/AUTO: the machine does
        self.manual = False
        self._guides: list[tuple[np.ndarray, np.ndarray, str]] = []
        self._vendor_init()
        self.on_progress: Any = None  # (fraction, "line N: STATEMENT") as the run goes on
        self.cancelled = threading.Event()  # the operator's Cancel: the run ends before the next statement
        self.paused = threading.Event()  # the operator's Pause: the run holds before the next statement

    # --- helpers ---------------------------------------------------------------------------

    def fail(self, s: Statement, message: str) -> DmisError:
        return DmisError(f"line {s.line}: {message}")

    def num(self, s: Statement, p: Param) -> float:
        if isinstance(p, Expr):
            try:
                v = evaluate(p, self.variables, s.line)
            except DmisSyntaxError as exc:
                raise DmisError(str(exc)) from None
        elif isinstance(p, Word) and p.text in self.variables:
            v = self.variables[p.text]
        else:
            raise self.fail(s, f"{_text(p)} is not a number")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(s, f"{_text(p)} is not a finite number")
        return float(v)

    def numbers(self, s: Statement, params: list[Param] | None = None) -> list[float]:
        return [self.num(s, p) for p in (s.params if params is None else params)
                if isinstance(p, Expr) or (isinstance(p, Word) and p.text in self.variables)]

    def words(self, s: Statement) -> list[str]:
        return [p.text for p in s.params if isinstance(p, Word) and p.text not in self.variables]

    def labels(self, s: Statement) -> list[Label]:
        return [p for p in s.params if isinstance(p, Label)]

    def actual(self, s: Statement, label: Label) -> Actual:
        if label.type not in ("FA", "F"):
            raise self.fail(s, f"{label} is not a feature")
        a = self.result.actuals.get(label.name)
        if a is None:
            raise self.fail(s, f"FA({label.name}) has not been measured or constructed yet")
        return a

    def log(self, text: str) -> None:
        self.result.log.append(text)

    # --- run -----------------------------------------------------------------------------

    def run(self) -> RunResult:
        self.target.note(f"DMIS program {self.name!r} started")
        try:
            self._run()
        except DmisError as exc:  # the output so far is kept, saying where and why it stopped
            self.emit(f"$$ the program stopped: {exc}")
            self._finish()
            exc.result = self.result
            try:
                self.target.note(f"DMIS program {self.name!r} stopped: {exc}")
            except Exception:  # noqa: BLE001 - a journal refused (control taken over): the stop itself is told
                pass
            raise
        self._finish()
        self.target.note(f"DMIS program {self.name!r} finished ({len(self.result.actuals)} features, "
                        f"{sum(not e.intol for e in self.result.evaluations)} out of tolerance)")
        if self.result.evaluations:  # the run is a part of the program's series (when the model records trends)
            record_trend(self.model, self.name, values=tolerance_values(self.result.evaluations))
        return self.result

    def _run(self) -> None:
        pairs = blocks(self.stmts)
        calls: list[int] = []
        pc = 0
        told = -1
        while pc < len(self.stmts):
            s = self.stmts[pc]
            nxt = pc + 1
            m = s.major
            self._between(s)  # the operator's Pause holds here, Cancel ends the run here (never mid-hit)
            if self.on_progress is not None and int(100 * pc / len(self.stmts)) != told:
                told = int(100 * pc / len(self.stmts))
                self.on_progress(pc / len(self.stmts), f"line {s.line}: {s.name}")
            try:
                if m == "IF":
                    cond = evaluate(s.params[0], self.variables, s.line)  # type: ignore[arg-type]
                    if not cond:
                        nxt = pairs[pc] + 1
                elif m == "ELSE":
                    nxt = pairs[pc] + 1
                elif m == "DO":
                    var = s.params[0].text  # type: ignore[union-attr]
                    start, end, *step = [self.num(s, p) for p in s.params[1:]]
                    self.variables[var] = start
                    inc = step[0] if step else 1.0
                    if inc == 0:
                        raise self.fail(s, "a DO loop's increment cannot be 0")
                    if (inc > 0 and start > end) or (inc < 0 and start < end):
                        nxt = pairs[pc] + 1
                elif m == "ENDDO":
                    do = self.stmts[pairs[pc]]
                    var = do.params[0].text  # type: ignore[union-attr]
                    _, end, *step = [self.num(do, p) for p in do.params[1:]]
                    inc = step[0] if step else 1.0
                    self.variables[var] += inc
                    if (inc > 0 and self.variables[var] <= end + 1e-9) or (inc < 0 and self.variables[var] >= end - 1e-9):
                        nxt = pairs[pc] + 1
                elif m == "MACRO":
                    self.macros[s.label.name] = pc  # type: ignore[union-attr]
                    nxt = pairs[pc] + 1
                elif m == "ENDMAC":
                    if not calls:
                        raise self.fail(s, "ENDMAC reached without a CALL")
                    nxt = calls.pop()
                elif m == "CALL":
                    name = self.labels(s)[0].name
                    if name not in self.macros:
                        raise self.fail(s, f"M({name}) is not defined before this CALL")
                    macro = self.stmts[self.macros[name]]
                    formals = [p.text for p in macro.params if isinstance(p, (Text, Word))]
                    actuals = [p for p in s.params[1:]]
                    if len(formals) != len(actuals):
                        raise self.fail(s, f"M({name}) takes {len(formals)} arguments, the CALL gives {len(actuals)}")
                    for f, a in zip(formals, actuals):
                        self.variables[f.upper()] = a.text if isinstance(a, Text) else self.num(s, a)
                    calls.append(pc + 1)
                    nxt = self.macros[name] + 1
                else:
                    self.execute(s)
            except DmisError:
                raise
            except DmisSyntaxError as exc:
                raise DmisError(str(exc)) from None
            except (ToleranceError, FrameError) as exc:
                raise self.fail(s, str(exc)) from None
            except Exception as exc:  # noqa: BLE001 - motion, probing and fit errors are operator sentences
                raise self.fail(s, f"{s.name}: {exc}") from None
            pc = nxt

    def _between(self, s: Statement) -> None:
        """Between two statements: hold while the operator has paused the run; end it when they cancelled."""
        if self.paused.is_set() and not self.cancelled.is_set():
            self.log(f"line {s.line}: paused by the operator")
            self.target.hold(lambda: not self.paused.is_set() or self.cancelled.is_set())
        if self.cancelled.is_set():
            raise self.fail(s, "the program was cancelled by the operator before this statement")

    def execute(self, s: Statement) -> None:
        handler = getattr(self, "do_" + s.major.lower(), None)
        if handler is None:  # the check lets through only what has a handler or is a no-op
            if s.major == "ENDIF":
                return  # the end of the branch taken
            if s.major in ("DMISMN", "DMISMD", "DISPLY", "PRCOMP", "ENDFIL"):
                return  # the program's name, display and mode settings: the station has one way of each
            raise self.fail(s, f"{s.major} is not supported")
        handler(s)

    # --- program and output ------------------------------------------------------------------

    def do_mode(self, s: Statement) -> None:
        manual = "AUTO" not in self.words(s)
        if manual != self.manual:
            self.log(f"line {s.line}: {'manual mode: the operator takes the hits' if manual else 'automatic mode'}")
        self.manual = manual

    def do_filnam(self, s: Statement) -> None:
        self.emit(statement_text(s))

    def do_units(self, s: Statement) -> None:
        w = self.words(s)
        self.scale = LENGTH_UNITS[w[0]]
        if "ANGRAD" in w:
            self.angle_scale = 1.0
        elif "ANGDEC" in w:
            self.angle_scale = math.pi / 180.0
        self.emit(statement_text(s))

    def do_decl(self, s: Statement) -> None:
        w = [p.text for p in s.params if isinstance(p, Word)]
        kinds = {"COMMON", "GLOBAL", "LOCAL", "BOOL", "CHAR", "INTGR", "LONG", "REAL", "DOUBLE", "VECTOR"}
        text = "CHAR" in w
        for name in w:
            if name not in kinds:
                self.variables.setdefault(name, "" if text else 0.0)

    def do_assign(self, s: Statement) -> None:
        if len(s.params) != 1:
            raise self.fail(s, "ASSIGN takes one expression")
        p = s.params[0]
        value = p.text if isinstance(p, Text) else (
            self.variables.get(p.text, p.text) if isinstance(p, Word) else evaluate(p, self.variables, s.line))  # type: ignore[arg-type]
        if isinstance(value, float) and not math.isfinite(value):
            raise self.fail(s, f"{s.variable or 'the variable'} = {_text(p)} is {num(value)}: give a finite number")
        self.variables[s.variable] = value

    def do_output(self, s: Statement) -> None:
        self.emit(statement_text(s))
        pending: list[Actual] = []
        after_tolerance = False  # FA(a), TA(x), TA(y), FA(b), TA(z): x and y apply to a, z to b
        for lab in self.labels(s):
            if lab.type in ("FA", "F") and after_tolerance:
                pending, after_tolerance = [], False
            if lab.type == "FA":
                a = self.actual(s, lab)
                pending.append(a)
                self.emit(actual_line(a, self.frame, self.scale, self.angle_scale))
                u_line = self._uncertainty_line(a)
                if u_line:
                    self.emit(u_line)
            elif lab.type == "F":
                nom = self.nominals.get(lab.name)
                if nom is None:
                    raise self.fail(s, f"F({lab.name}) is not defined")
                pending.append(self.result.actuals.get(lab.name) or Actual(lab.name, nom.kind, {}, nom))
                self.emit(nominal_line(lab.name, nom, self.frame, self.scale, self.angle_scale))
            elif lab.type in ("TA", "T"):
                tol = self.tolerances.get(lab.name)
                if tol is None:
                    raise self.fail(s, f"T({lab.name}) is not defined (T({lab.name}) = TOL/...)")
                if not pending:
                    raise self.fail(s, f"TA({lab.name}) needs the feature it applies to before it: "
                                       f"OUTPUT/FA(name), TA({lab.name})")
                ev = evaluate_tolerance(tol, pending, self.datums, self.frame, self.sizes)
                self.result.evaluations.append(ev)
                self.emit(output_line(ev))
                if ev.note:
                    self.emit(f"$$ T({tol.label}): {ev.note}; allowed {tol.upper + ev.bonus:.5f}")
                nom = pending[0].nominal
                if tol.word in ("DIAM", "RAD") and nom is not None and nom.diameter is not None:
                    k = 2.0 if tol.word == "RAD" else 1.0  # the size limits as diameters, for MMC / LMC
                    self.sizes[pending[0].label] = (nom.diameter + k * tol.lower, nom.diameter + k * tol.upper)
                self._to_model(ev, pending)
                after_tolerance = True
            else:
                raise self.fail(s, f"OUTPUT of {lab} is not supported: output FA(..), F(..) and TA(..)")

    def _uncertainty_line(self, a: Actual) -> str:
        """A comment with the feature's expanded uncertainty (k = 2, cmm.metrology.uncertainty), or ""."""
        f = self.model.features.get(a.feature_id) if a.feature_id is not None else None
        expanded = ((getattr(f, "budget", None) or {}).get("U")) if f is not None else None
        if not expanded:
            return ""
        parts = [f"{k} {v / (1.0 if k.endswith('_deg') else self.scale):.5f}" for k, v in expanded.items()]
        return f"$$ FA({a.label}): U (k=2) " + ", ".join(parts)

    def _to_model(self, ev: Evaluation, features: list[Actual]) -> None:
        """The station's report carries the DMIS tolerance too (where the model has the same characteristic):
        sizes and form as the feature's tolerance, a position with datums or at MMC / LMC as the station's
        GD&T (its datums defined on the same features), so the report gives the same value and bonus."""
        keys = model_tolerance(ev.tolerance)
        fid = features[0].feature_id
        if keys and fid is not None and fid in self.model.features:
            self.target.set_tolerance(fid, keys)
        tol = ev.tolerance
        if tol.word == "POS" and (tol.datums or tol.material) and fid is not None and fid in self.model.features:
            why = planar_position(tol, features[0].kind) or self._position_to_model(tol, fid)
            if why:
                self.log(f"T({tol.label}) is not in the station's GD&T: {why}")
                self.target.note(f"DMIS T({tol.label}) is not in the station's GD&T: {why}")
        self.target.note(f"{output_line(ev)} ({', '.join('FA(' + f + ')' for f in ev.features)})")

    def _position_to_model(self, tol: Tolerance, fid: int) -> str:
        """Define TOL/POS in the station's GD&T: its datums on the DATDEF features (at RFS; the frame says how
        it references each: MMB / LMB for a DAT(..) at MMC / LMC), then the position. Why not, in words ("" when
        it is)."""
        names = list(tol.datums[:3])
        for name in names:
            d = self.datums.get(name)
            if d is None or d.feature_id is None or d.feature_id not in self.model.features:
                return f"DAT({name}) is not a measured feature of the station"
            have = self.model.datums.get(name)
            if have is None or int(have["feature"]) != d.feature_id or have.get("targets"):
                try:
                    self.target.define_datum(name, d.feature_id)
                except Exception as exc:  # noqa: BLE001 - a datum the station's GD&T cannot take, in words
                    return str(exc)
        modifiers = {n: {"MMC": "MMB", "LMC": "LMB"}.get(tol.datum_material.get(n, ""), "") for n in names}
        try:
            self.target.define_position(fid, tol.upper, names, material=tol.material, name=f"T({tol.label})",
                                        datum_modifiers=modifiers or None)
        except Exception as exc:  # noqa: BLE001 - the station's GD&T refuses it, in words
            return str(exc)
        return ""

    # --- coordinate systems -----------------------------------------------------------------------

    def _set_frame(self, s: Statement, frame: np.ndarray, design: np.ndarray) -> None:
        self.frame, self.design_frame = frame, design
        if s.label is not None:
            self.frames[s.label.name] = frame.copy()
            self.design_frames[s.label.name] = design.copy()
            self.result.frames[s.label.name] = frame.copy()
        self.emit(statement_text(s))

    def _align_part(self, s: Statement, features: list[Actual]) -> None:
        """The alignment the statement made moves the station's part (its pose: the rails, the 3-D view and the
        report follow): the part lies ``frame @ inverse(design_frame)`` from where the program's nominals put it.
        Checked on the part with the hits of the features it used; when that fails the part stays and the run's
        log and the journal say why."""
        hits = [a.hit_points for a in features if a.hit_points is not None and len(a.hit_points)]
        if not hits:  # constructed features only: the hits of everything measured so far
            hits = [a.hit_points for a in self.result.actuals.values()
                    if a.hit_points is not None and len(a.hit_points)]
        if not hits:
            return self._not_aligned(s, "no measured hits to check it on the part")
        name = f"D({s.label.name})" if s.label is not None else f"line {s.line}"
        try:
            said = self.target.align(self.frame, self.design_frame, np.vstack(hits), name)
        except Exception as exc:  # noqa: BLE001 - not this part at its set-up: said, and the part stays
            return self._not_aligned(s, str(exc), said=True)
        self.log(f"line {s.line}: {said}")
        self._move_nominals(self.frame @ inverse(self.design_frame))

    def _move_nominals(self, placement: np.ndarray) -> None:
        """The part lies ``placement`` (machine, 4x4) away from where the program's nominals put it (the align
        verb moved the station's part by as much): every FEAT nominal defined so far moves with it, from where
        the previous alignment had put it, and the station's features measured so far take the same nominals.
        So a position without datums judges a feature against one nominal in the DMIS output and in the
        station's report, measured before the alignment or after it, on the first part or the tenth. The design
        nominals (for positions with datums) stay where the program's nominals put the part."""
        move = placement @ inverse(self.placement)
        self.placement = placement
        for nom in self.nominals.values():
            nom.point = apply(move, nom.point)
            if nom.vector is not None:
                nom.vector = apply_vector(move, nom.vector)
        for a in self.result.actuals.values():
            nominal = None if a.nominal is None else a.nominal.to_model()
            if nominal is not None and a.feature_id is not None and a.feature_id in self.model.features:
                self.target.set_nominal(a.feature_id, nominal)

    def _not_aligned(self, s: Statement, why: str, *, said: bool = False) -> None:
        text = why if said else f"{statement_text(s)} does not move the station's part: {why}"
        self.log(f"line {s.line}: {text}")
        self.target.note(f"DMIS line {s.line}: {text}")

    def do_datset(self, s: Statement) -> None:
        if self.words(s) == ["MCS"]:
            return self._set_frame(s, np.eye(4), np.eye(4))
        entries, design = [], []
        current: Actual | None = None
        name = ""
        used: list[Actual] = []
        for p in s.params:
            if isinstance(p, Label):
                if p.type == "DAT":
                    if p.name not in self.datums:
                        raise self.fail(s, f"DAT({p.name}) is not defined (DATDEF/FA(name), DAT({p.name}))")
                    current, name = self.datums[p.name], str(p)
                else:
                    current, name = self.actual(s, p), str(p)
                used.append(current)
            elif isinstance(p, Word):
                if current is None:
                    raise self.fail(s, f"{p.text} must follow a datum: DATSET/DAT(A), ZDIR, ZORIG, ...")
                problem = datset_word_problem(p.text)
                if problem:
                    raise self.fail(s, problem)
                entries.append((name, p.text, current.axis_point(), current.direction()))
                nom = None if current.nominal is None else (current.nominal.design or current.nominal)
                design.append(None if nom is None else (name, p.text, nom.point, nom.vector))
            else:
                raise self.fail(s, f"DATSET takes datums and words, not {_text(p)}")
        frame = datum_frame(entries, self.frame)
        if all(d is not None for d in design):
            design_frame = datum_frame(design, self.design_frame)  # type: ignore[arg-type]
        else:  # a datum without a nominal: the design frame follows the measured one
            design_frame = frame.copy()
        self._set_frame(s, frame, design_frame)
        if all(d is not None for d in design):
            self._align_part(s, used)
        else:
            self._not_aligned(s, "a datum has no nominal (FEAT), so where the part lies cannot be told")

    def do_trans(self, s: Statement) -> None:
        origin = np.zeros(3)
        design_origin = np.zeros(3)
        params = list(s.params)
        k = 0
        inv = inverse(self.frame)
        design_inv = inverse(self.design_frame)
        used: list[Actual] = []
        nominal_less = False
        while k < len(params):
            w = params[k]
            if not isinstance(w, Word) or w.text not in ORIGINS or k + 1 >= len(params):
                raise self.fail(s, "TRANS takes XORIG, YORIG, ZORIG each followed by a value or a feature FA(..)")
            v = params[k + 1]
            axis = ORIGINS[w.text]
            if isinstance(v, Label):  # the origin on a measured feature; in the design frame on its nominal
                a = self.actual(s, v)
                origin[axis] = apply(inv, a.axis_point())[axis]
                nom = None if a.nominal is None else (a.nominal.design or a.nominal)
                design_origin[axis] = (origin[axis] if nom is None
                                       else apply(design_inv, nom.point)[axis])
                used.append(a)
                nominal_less |= nom is None
            else:
                origin[axis] = design_origin[axis] = self.num(s, v) * self.scale
            k += 2
        self._set_frame(s, self.frame @ translation(origin), self.design_frame @ translation(design_origin))
        if used and not nominal_less:
            self._align_part(s, used)
        elif used:
            self._not_aligned(s, "its feature has no nominal (FEAT), so where the part lies cannot be told")

    def do_rotat(self, s: Statement) -> None:
        """ROTAT/ZAXIS, angle: turn about an axis of the current system. ROTAT/ZAXIS, FA(x), XDIR: turn about
        the axis until XDIR (YDIR, XMINUS ...) points along the feature: its direction (a line, a plane's normal)
        or, for a feature whose direction is the rotation axis (a bore, a point), towards its location."""
        p = s.params
        problem = rotat_problem(p[0].text if p and isinstance(p[0], Word) else None,
                                len(p) > 1 and isinstance(p[1], Label),
                                p[2].text if len(p) > 2 and isinstance(p[2], Word) else None, len(p))
        if problem:
            raise self.fail(s, problem)
        axis = AXES[p[0].text]  # type: ignore[union-attr]
        if isinstance(p[1], Label):
            d_axis, sign = DIRS[p[2].text]  # type: ignore[union-attr]
            a = self.actual(s, p[1])
            angle = self._turn_onto(s, self.frame, axis, d_axis, sign, a.direction(), a.location(), p[1].name)
            nom = None if a.nominal is None else (a.nominal.design or a.nominal)
            design_angle = angle if nom is None else self._turn_onto(
                s, self.design_frame, axis, d_axis, sign, nom.vector, nom.point, p[1].name)
            self._set_frame(s, self.frame @ rotation(axis, angle), self.design_frame @ rotation(axis, design_angle))
            if nom is not None:
                self._align_part(s, [a])
            else:
                self._not_aligned(s, f"FA({p[1].name}) has no nominal (FEAT), so where the part lies cannot be told")
            return
        angle = self.num(s, p[1]) * self.angle_scale
        turn = rotation(axis, angle)
        self._set_frame(s, self.frame @ turn, self.design_frame @ turn)

    def _turn_onto(self, s: Statement, frame: np.ndarray, axis: int, d_axis: int, sign: float,
                   direction: np.ndarray | None, location: np.ndarray, name: str) -> float:
        """The angle about ``axis`` of ``frame`` that turns its ``d_axis`` (times ``sign``) onto a feature."""
        inv = inverse(frame)
        e = np.zeros(3)
        e[axis] = 1.0
        v = None
        if direction is not None:
            v = apply_vector(inv, direction)
            v = v - (v @ e) * e
        if v is None or np.linalg.norm(v) < 0.05:  # within 3 degrees of the axis: towards the feature's location
            v = apply(inv, location)
            v = v - (v @ e) * e
            if np.linalg.norm(v) < 1e-6:
                raise self.fail(s, f"FA({name}) lies on the rotation axis: it cannot set the direction")
        target = sign * v / np.linalg.norm(v)
        current = np.zeros(3)
        current[d_axis] = 1.0
        return math.atan2(float(np.cross(current, target) @ e), float(current @ target))

    # --- sensors and motion ---------------------------------------------------------------------

    def do_snsdef(self, s: Statement) -> None:
        v = self.numbers(s)
        direction, problem = probe_direction(self.words(s), v, self.angle_scale)
        problem = problem or probe_problem(str(s.label), mounted(self.mount, direction))  # type: ignore[arg-type]
        if problem:
            raise self.fail(s, problem)
        self.sensors[s.label.name] = {"diameter": v[-1] * self.scale}  # type: ignore[union-attr]

    def do_snslct(self, s: Statement) -> None:
        name = self.labels(s)[0].name
        if name not in self.sensors:
            raise self.fail(s, f"S({name}) is not defined (S({name}) = SNSDEF/PROBE, ...)")
        self.sensor = name
        want = self.sensors[name]["diameter"]
        probes = self.target.probes()
        if probes is not None:  # the station's probe list: the matching probe is the one in use from here on
            probe, problem = match_probe(name, want, probes)
            if problem:
                raise self.fail(s, problem)
            said = self.target.select_probe(probe)  # type: ignore[arg-type]
            if said:
                self.log(f"line {s.line}: S({name}): {said}")
            return
        problem = station_tip_problem(name, want, float(self.target.nominal_tip_diameter))
        if problem:  # no probe list: the station's one probe measures, when it is the sensor's tip
            raise self.fail(s, problem)

    def do_snset(self, s: Statement) -> None:
        v = self.numbers(s)
        if len(v) != 1:
            raise self.fail(s, f"SNSET/{s.minor} takes one value")
        if v[0] < 0:
            raise self.fail(s, f"SNSET/{s.minor} must not be negative")
        self.snset[s.minor] = v[0] * self.scale  # type: ignore[index]
        if s.minor == "DEPTH" and v[0] > 0:
            # DEPTH places the points a machine chooses itself below a feature's edge; here every automatic hit
            # is a PTMEAS with its own point, so the depth changes nothing: say so rather than ignore it silently
            self.log(f"line {s.line}: SNSET/DEPTH has no effect here: every PTMEAS gives its own point")

    def do_fedrat(self, s: Statement) -> None:
        w = self.words(s)
        v = self.numbers(s)
        if len(v) != 1 or not math.isfinite(v[0]) or v[0] <= 0:
            raise self.fail(s, f"FEDRAT/{s.minor} takes a unit and a positive speed"
                               + (f", not {num(v[0])}" if len(v) == 1 else ""))
        if "PCENT" in w:
            base = self.target.positioning_speed if s.minor == "POSVEL" else self.target.probing_speed
            speed = base * v[0] / 100.0
        else:
            unit = next((u for u in w if u in SPEED_UNITS), None)
            if unit is None:
                raise self.fail(s, f"FEDRAT/{s.minor} needs a unit: MPM, MMPS, IPM, IPS or PCENT")
            speed = v[0] * SPEED_UNITS[unit]
        if s.minor == "POSVEL":
            if not speed <= self.target.positioning_speed:
                self.log(f"line {s.line}: POSVEL {num(speed, 2)} mm/s is above the station's positioning speed "
                         f"{self.target.positioning_speed:.2f} mm/s; moves are made at {self.target.positioning_speed:.2f} mm/s")
            self.posvel = min(speed, self.target.positioning_speed)
        else:
            limit = self.target.probing_speed
            if speed > limit:
                self.log(f"line {s.line}: MESVEL {num(speed, 2)} mm/s is above the probe's qualified {limit:.2f} mm/s; "
                         f"hits are taken at {limit:.2f} mm/s")
            self.mesvel = min(speed, limit)

    def do_goto(self, s: Statement) -> None:
        if self.manual:  # the operator moves the probe in manual mode
            return
        w = self.words(s)
        v = self.numbers(s)
        if "INCR" in w:
            d = np.array(v[1:4], float)
            if np.linalg.norm(d) < 1e-12:
                raise self.fail(s, "GOTO/INCR needs a direction that is not zero")
            move = apply_vector(self.frame, d / np.linalg.norm(d)) * v[0] * self.scale
            target = self.target.position() + move
        else:
            target = apply(self.frame, np.array(v, float) * self.scale)
        self.target.move(target, self.posvel)

    # --- features -------------------------------------------------------------------------------

    def do_feat(self, s: Statement) -> None:
        w = self.words(s)
        v = self.numbers(s)
        word = s.minor
        inner = None if word not in ("CIRCLE", "CYLNDR", "CONE", "SPHERE") else "INNER" in w
        polar = "POL" in w
        if polar:  # POL: the location as radius, angle, height in the current system (the vector stays I, J, K)
            if len(v) < 3:
                raise self.fail(s, f"FEAT/{word}, POL takes the radius, angle and height of its location")
            r, a = v[0], v[1] * self.angle_scale
            v = [r * math.cos(a), r * math.sin(a), *v[2:]]
            if word == "LINE" and "BND" in w and len(v) >= 6:  # the second end point is polar too
                r, a = v[3], v[4] * self.angle_scale
                v = [*v[:3], r * math.cos(a), r * math.sin(a), *v[5:]]
        try:
            if word == "LINE" and "BND" in w:
                nom = bounded_line(v, self.frame, self.scale)
                nom.design = bounded_line(v, self.design_frame, self.scale)
            else:
                nom = nominal_from(word, inner, v, self.frame, self.scale, self.angle_scale)  # type: ignore[arg-type]
                nom.design = nominal_from(word, inner, v, self.design_frame, self.scale,  # type: ignore[arg-type]
                                          self.angle_scale)
        except ValueError as exc:
            raise self.fail(s, f"FEAT/{word}: {exc}") from None
        nom.polar = polar
        self.nominals[s.label.name] = nom  # type: ignore[union-attr]

    def do_meas(self, s: Statement) -> None:
        label = self.labels(s)[0]
        nom = self.nominals.get(label.name)
        if nom is None:
            raise self.fail(s, f"F({label.name}) is not defined")
        if KINDS[s.minor] != nom.kind:  # type: ignore[index]
            raise self.fail(s, f"MEAS/{s.minor} measures F({label.name}), which is a {nom.word}")
        self._meas = (s, [])
        self._guides = []

    def do_ptmeas(self, s: Statement) -> None:
        if self._meas is None:
            raise self.fail(s, "PTMEAS outside MEAS ... ENDMES")
        meas, ids = self._meas
        nom = self.nominals[self.labels(meas)[0].name]
        v = self.numbers(s)
        if s.minor == "POL":  # radius, angle, height in the current system's XY plane
            r, a, h = v[0], v[1] * self.angle_scale, v[2]
            local = np.array([r * math.cos(a), r * math.sin(a), h])
        else:
            local = np.array(v[:3], float)
        p = apply(self.frame, local * self.scale)
        if len(v) == 6:
            n = np.array(v[3:6], float)
            if np.linalg.norm(n) < 1e-12:
                raise self.fail(s, "the PTMEAS vector is zero")
            normal = apply_vector(self.frame, n / np.linalg.norm(n))
        else:
            normal = nom.surface_normal(p)
            if normal is None:
                raise self.fail(s, f"PTMEAS without a vector: give I, J, K for a point on a {nom.word}")
        if self.manual:  # a guide for the operator's hand: where to take the hit and from which side
            near = ", ".join(f"{x:.3f}" for x in local)  # as the program gives it
            self._guides.append((p, -normal, f"near {near}"))
            return
        hid = self.target.probe(p, -normal, speed=self.mesvel, approach_distance=self.snset["APPRCH"],
                                search_distance=self.snset["SEARCH"], retract_distance=self.snset["RETRCT"],
                                rapid_speed=self.posvel)
        ids.append(hid)
        self.result.hits += 1

    def do_endmes(self, s: Statement) -> None:
        meas, ids = self._meas  # type: ignore[misc]
        self._meas = None
        label = self.labels(meas)[0].name
        nom = self.nominals[label]
        expected = self.numbers(meas)
        if self.manual:
            guides, self._guides = self._guides, []
            n = int(expected[0]) if expected else len(guides)
            if n < 1:
                raise DmisError(f"line {meas.line}: MEAS/{meas.minor}, F({label}) in manual mode needs the number of "
                                "hits the operator takes")
            prompt = (f"line {meas.line}: take {n} hit{'s' if n > 1 else ''} by hand on F({label}) ({nom.word})"
                      + (": " + "; ".join(g[2] for g in guides) if guides else ""))
            ids.extend(self.target.manual_hits(prompt, n, [(g[0], g[1]) for g in guides]))
            if len(ids) < n:
                raise DmisError(f"line {meas.line}: F({label}) needs {n} hits by hand, {len(ids)} were taken")
            self.result.hits += len(ids)
            self.target.note(f"DMIS F({label}): {len(ids)} hits taken by hand (manual mode)")
        if expected and int(expected[0]) != len(ids):
            self.log(f"line {meas.line}: MEAS/{meas.minor}, F({label}) announced {int(expected[0])} points, "
                     f"{len(ids)} were measured")
        try:
            feature = self.target.fit(nom.kind, ids, label, nom.to_model())
        except Exception as exc:  # noqa: BLE001 - a fit refused in words
            raise DmisError(f"line {meas.line}: F({label}) could not be fitted: {exc}") from None
        g = {**feature.result.geometry(), "form": float(feature.result.form)}
        if feature.result.alternative is not None:
            self.log(f"line {meas.line}: FA({label}): another {nom.kind} fits the hits better; check it")
        self.result.actuals[label] = Actual(label, nom.kind, g, nom, feature.id,
                                            np.array([self.model.hits[h].point for h in ids], float))

    def do_const(self, s: Statement) -> None:
        from .construct import construct_actual

        labels = self.labels(s)
        words = [p.text for p in s.params[1:] if isinstance(p, Word)]
        problem = const_problem(s.minor, bool(labels) and labels[0].type == "F", words,  # type: ignore[arg-type]
                                len(labels) - 1)
        if problem:
            raise self.fail(s, problem)
        target = labels[0].name
        method = words[0]
        operands = [self.actual(s, lab) for lab in labels[1:]]
        kind, geometry = construct_actual(s.minor.lower(), method, operands)  # type: ignore[union-attr]
        self.result.actuals[target] = Actual(target, kind, geometry, self.nominals.get(target))
        self.target.note(f"DMIS CONST/{s.minor}, F({target}), {method} of "
                        + ", ".join(f"FA({a.label})" for a in operands))

    def do_datdef(self, s: Statement) -> None:
        feat, dat = self.labels(s)
        self.datums[dat.name] = self.actual(s, feat)
        self.target.note(f"DMIS datum {dat.name}: FA({feat.name})")

    def do_tol(self, s: Statement) -> None:
        word = s.minor
        w = [p for p in s.params[1:]]
        v = self.numbers(s, w)
        options = [p.text for p in w if isinstance(p, Word) and p.text not in self.variables]
        datums = [p.name for p in w if isinstance(p, Label) and p.type == "DAT"]
        if word == "POS" and "2D" in options:  # a point's 2D position is taken in the working plane (WKPLAN)
            options.append(self.work_plane)
        tol = Tolerance(s.label.name, word, datums=datums, options=options)  # type: ignore[union-attr, arg-type]
        # material conditions: MMC / LMC / RFS after the zone is the feature's, after a DAT(..) that datum's
        last: Param | None = None
        for p in w:
            if isinstance(p, Word) and p.text in ("MMC", "LMC", "RFS"):
                problem = material_problem(word, [p.text])  # type: ignore[arg-type]
                if problem:
                    raise self.fail(s, problem)
                if isinstance(last, Label) and last.type == "DAT":
                    if p.text != "RFS":
                        tol.datum_material[last.name] = p.text
                elif p.text != "RFS":
                    tol.material = p.text
            last = p
        if word in ("DIAM", "RAD"):
            if len(v) != 2:
                raise self.fail(s, f"TOL/{word} takes the lower and the upper tolerance")
            tol.lower, tol.upper = v
        elif word in ("DISTB", "ANGLB"):
            if len(v) != 3:
                raise self.fail(s, f"TOL/{word} takes NOMINL, the nominal, the lower and the upper tolerance")
            tol.nominal, tol.lower, tol.upper = v[0] * (self.scale if word == "DISTB" else 1.0), v[1], v[2]
        elif word == "ANGLR":
            if len(v) != 2:
                raise self.fail(s, "TOL/ANGLR takes the angle and the zone")
            tol.nominal, tol.upper = v[0], v[1]
        elif word in ("PROFS", "PROFL"):
            if len(v) == 1:
                tol.lower, tol.upper = -v[0] / 2.0, v[0] / 2.0
            elif len(v) == 2:
                tol.lower, tol.upper = v
            else:
                raise self.fail(s, f"TOL/{word} takes the zone, or the lower and the upper tolerance")
        else:
            if len(v) != 1:
                raise self.fail(s, f"TOL/{word} takes one zone value, it has {len(v)} numbers")
            tol.upper = v[0]
        degrees = self.angle_scale * 180.0 / math.pi  # program angle units -> degrees
        if word == "ANGLB":
            tol.nominal, tol.lower, tol.upper = v[0] * degrees, v[1] * degrees, v[2] * degrees
        elif word == "ANGLR":
            tol.nominal, tol.upper = v[0] * degrees, v[1] * self.scale
        else:
            tol.lower, tol.upper = tol.lower * self.scale, tol.upper * self.scale
        if tol.lower > tol.upper:
            raise self.fail(s, f"TOL/{word}: the lower tolerance {tol.lower:g} is above the upper {tol.upper:g}")
        self.tolerances[tol.label] = tol

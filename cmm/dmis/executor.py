"""Run checked DMIS statements on a measuring target: motion, probing, fits, alignments, tolerances, output.

The target (:class:`cmm.dmis.runner.StationTarget` on the station) moves in straight lines (``GOTO``), takes
programmed hits with the program's approach, search and retract distances and speeds (``PTMEAS`` inside
``MEAS .. ENDMES``, with ``SNSET`` and ``FEDRAT``), and its measurement model fits the features, so every hit
and feature is journalled like any other session's. Coordinates are read in the units and the coordinate system
in force (``UNITS``, ``DATSET``, ``TRANS``, ``ROTAT``, ``RECALL``) and output the same way.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..metrology.numbers_text import num
from ..session.qif_dmis import EVENT as TOLERANCES_EVENT, to_records
from ..session.trends import tolerance_values
from .alignments import AlignmentStatements
from .controls import RunControls
from .features import KINDS, Actual, Nominal, bounded_line, nominal_from
from .frames import FrameError, apply, apply_vector
from .lexer import DmisSyntaxError
from .parser import Expr, Label, Param, Statement, Text, Word, evaluate
from .reporting import OutputStatements
from .rules import LENGTH_UNITS, const_problem, match_probe, mounted, probe_direction, probe_problem, station_tip_problem
from .run_state import DmisError, RunResult, Target, _text, blocks, replay_data, statement_text
from .tolerances import Tolerance, ToleranceError
from .vendor import VendorStatements

SPEED_UNITS = {"MPM": 1000.0 / 60.0, "MMPS": 1.0, "IPM": 25.4 / 60.0, "IPS": 25.4}
__all__ = ["DmisError", "Executor", "RunResult", "SPEED_UNITS", "Target", "blocks", "statement_text"]


class Executor(RunControls, AlignmentStatements, OutputStatements, VendorStatements):
    """One run of a program on a target."""

    def __init__(self, stmts: list[Statement], target: Target, *, name: str = "program", text: str = "") -> None:
        self.stmts = stmts
        self.text = text  # the program's text, kept in the session so that its re-evaluation can replay it
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
        # the part programs' one runner (cmm.program.runner): its state, progress and the operator's controls.
        # Each statement reached is a step. Cancel ends the run before the next statement; Pause holds it there
        # (the machine loop serving STOP meanwhile); Skip step ends the measurement in progress after its current
        # hit (its feature is not fitted), or leaves out the next one (a MEAS block); moves are never skipped (the
        # program's GOTOs keep the probe clear of the part). DMIS says where it holds, not the runner.
        self._controls_init(len(stmts))
        self.skipped: dict[str, str] = {}  # the features skipped, by label
        self._meas_at = -1  # the statement index of the MEAS block in progress

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
        if a is None and label.name in self.skipped:
            raise self.fail(s, f"FA({label.name}) was skipped by the operator ({self.skipped[label.name]}): "
                               "this statement needs it")
        if a is None:
            raise self.fail(s, f"FA({label.name}) has not been measured or constructed yet")
        return a

    def log(self, text: str) -> None:
        self.result.log.append(text)

    # --- run -----------------------------------------------------------------------------

    def run(self) -> RunResult:
        self.target.note(f"DMIS program {self.name!r} started")
        self.runner.update(state="running")
        try:
            self._run()
        except DmisError as exc:  # the output so far is kept, saying where and why it stopped
            self.runner.update(state="cancelled" if self.runner.cancelled else "failed", message=str(exc))
            self.emit(f"$$ the program stopped: {exc}")
            self._finish()
            exc.result = self.result
            try:
                self.target.note(f"DMIS program {self.name!r} stopped: {exc}")
            except Exception:  # noqa: BLE001 - a journal refused (control taken over): the stop itself is told
                pass
            try:
                self.target.run_end(self.name, stopped=exc)  # told to the notifier; the stop itself stands
            except Exception:  # noqa: BLE001 - a notification never hides the run's error
                pass
            raise
        self._finish()
        self.runner.update(state="done", step=len(self.stmts))
        self.target.note(f"DMIS program {self.name!r} finished ({len(self.result.actuals)} features, "
                        f"{sum(not e.intol for e in self.result.evaluations)} out of tolerance)")
        if self.result.evaluations:  # the run is a part of the program's series (when the model records trends)
            replay = replay_data(self.text, self.result, self.skipped)
            recs = to_records(self.result.evaluations)  # for the session's QIF, with what its re-evaluation replays
            event = (TOLERANCES_EVENT, {"program": str(self.name), "evaluations": recs,
                                        **({"replay": replay} if replay else {})}) if recs else None
            self.target.run_end(self.name, values=tolerance_values(self.result.evaluations), event=event)
        else:  # no tolerances: the run's end is still told
            self.target.run_end(self.name)
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
            self.runner.update(step=pc)
            self._between(s)  # the operator's Pause holds here, Cancel ends the run here (never mid-hit)
            if self.runner.skip_asked:
                skip_to = self._skip(pc, s, pairs)
                if skip_to is not None:
                    pc = skip_to
                    continue
            if m == "MEAS":
                self._meas_at = pc
            if int(100 * pc / len(self.stmts)) != told:
                told = int(100 * pc / len(self.stmts))
                self.runner.tell(message=f"line {s.line}: {s.name}")
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
        self.result.hit_ids.append(int(hid))
        self.result.hits += 1
        self.runner.hit_taken(quiet=True)

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
            self.runner.hit_taken(len(ids), quiet=True)
            self.result.hit_ids.extend(int(h) for h in ids)
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
                                            _points(self.model.hits, ids))

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



def _points(hits: Any, ids: list[int]) -> np.ndarray:
    """The hits' points (``hits``: one read of the model's hits)."""
    return np.array([hits[h].point for h in ids], float)

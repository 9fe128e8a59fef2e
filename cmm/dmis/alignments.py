"""The coordinate systems of a DMIS run: DATSET, TRANS and ROTAT (chains of them), and the station's part moved
where the program's alignments found it (a mixin of :class:`cmm.dmis.executor.Executor`)."""

from __future__ import annotations

import math

import numpy as np

from .features import Actual
from .frames import AXES, DIRS, ORIGINS, apply, apply_vector, datum_frame, inverse, rotation, translation
from .parser import Label, Statement, Word
from .rules import datset_word_problem, rotat_problem
from .run_state import _text, statement_text


class AlignmentStatements:
    """Mixin of :class:`cmm.dmis.executor.Executor` (its state: frame, design frame, placement, nominals, datums)."""

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
            self.result.aligned.append(False)
            return self._not_aligned(s, str(exc), said=True)
        self.result.aligned.append(True)
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


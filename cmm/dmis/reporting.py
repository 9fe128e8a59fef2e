"""The output of a DMIS run: OUTPUT of actuals, nominals and tolerances (with their uncertainty), TOL definitions,
and the same tolerances in the station's report and GD&T (a mixin of :class:`cmm.dmis.executor.Executor`)."""

from __future__ import annotations

import math

from .features import Actual, actual_line, nominal_line
from .parser import Label, Param, Statement, Word
from .rules import material_problem
from .run_state import statement_text
from .tolerance_u import tolerance_u_line
from .tolerances import (Evaluation, Tolerance, evaluate as evaluate_tolerance, model_tolerance, output_line,
                         planar_position)


class OutputStatements:
    """Mixin of :class:`cmm.dmis.executor.Executor` (its state: actuals, nominals, tolerances, datums, frame)."""

    skipped: dict[str, str]  # FA label -> where the operator skipped it (see Executor.skip)

    def do_output(self, s: Statement) -> None:
        self.emit(statement_text(s))
        pending: list[Actual] = []
        after_tolerance = False  # FA(a), TA(x), TA(y), FA(b), TA(z): x and y apply to a, z to b
        gap = ""  # a feature of the group the operator skipped: its tolerances are not evaluated, said so
        for lab in self.labels(s):
            if lab.type in ("FA", "F") and after_tolerance:
                pending, after_tolerance, gap = [], False, ""
            if lab.type == "FA" and lab.name in self.skipped and lab.name not in self.result.actuals:
                gap = lab.name
                self.emit(f"$$ FA({lab.name}): skipped by the operator ({self.skipped[lab.name]}), not measured")
            elif lab.type == "FA":
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
                if gap:
                    self.emit(f"$$ TA({lab.name}): not evaluated: FA({gap}) was skipped by the operator")
                    after_tolerance = True
                    continue
                if not pending:
                    raise self.fail(s, f"TA({lab.name}) needs the feature it applies to before it: "
                                       f"OUTPUT/FA(name), TA({lab.name})")
                nominal_only = [a.label for a in pending if not a.geometry]
                if nominal_only and lab.type == "T":  # the nominal feature and the tolerance as defined: no value
                    self.emit(tol.text)
                    after_tolerance = True
                    continue
                if nominal_only:
                    raise self.fail(s, f"TA({lab.name}) is the tolerance evaluated on a measured feature, and "
                                       f"F({nominal_only[0]}) has not been measured: output TA({lab.name}) after "
                                       f"MEAS/.., F({nominal_only[0]}), or T({lab.name}) for its definition")
                ev = evaluate_tolerance(tol, pending, self.datums, self.frame, self.sizes)
                self.result.evaluations.append(ev)
                self.emit(output_line(ev))
                if ev.note:
                    self.emit(f"$$ T({tol.label}): {ev.note}; allowed {tol.upper + ev.bonus:.5f}")
                nom = pending[0].nominal
                if tol.word in ("DIAM", "RAD") and nom is not None and nom.diameter is not None:
                    k = 2.0 if tol.word == "RAD" else 1.0  # the size limits as diameters, for MMC / LMC
                    self.sizes[pending[0].label] = (nom.diameter + k * tol.lower, nom.diameter + k * tol.upper)
                self.emit(tolerance_u_line(ev, pending, self.datums, self.frame, self.sizes, self.model, self.scale))
                self._to_model(ev, pending)
                after_tolerance = True
            else:
                raise self.fail(s, f"OUTPUT of {lab} is not supported: output FA(..), F(..) and TA(..)")

    def _uncertainty_line(self, a: Actual) -> str:
        """A comment with the feature's expanded uncertainties (about 95 %, each with its coverage factor k:
        cmm.metrology.uncertainty), or ""."""
        f = self.model.features.get(a.feature_id) if a.feature_id is not None else None
        budget = (getattr(f, "budget", None) or {}) if f is not None else {}
        expanded = budget.get("U")
        if not expanded:
            return ""
        ks = budget.get("k")
        ks = ks if isinstance(ks, dict) else {}
        parts = [f"{k} {v / (1.0 if k.endswith('_deg') else self.scale):.5f} k={float(ks.get(k, 2.0)):.2f}"
                 for k, v in expanded.items()]
        return f"$$ FA({a.label}): U (95 %) " + ", ".join(parts)

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

    def do_tol(self, s: Statement) -> None:
        word = s.minor
        w = [p for p in s.params[1:]]
        v = self.numbers(s, w)
        options = [p.text for p in w if isinstance(p, Word) and p.text not in self.variables]
        datums = [p.name for p in w if isinstance(p, Label) and p.type == "DAT"]
        if word == "POS" and "2D" in options:  # a point's 2D position is taken in the working plane (WKPLAN)
            options.append(self.work_plane)
        tol = Tolerance(s.label.name, word, datums=datums, options=options,  # type: ignore[union-attr, arg-type]
                        text=statement_text(s))
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

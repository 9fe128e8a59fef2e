"""Datums and geometric tolerances (ISO 1101 / ASME Y14.5) of a measurement model.

:class:`Tolerancing` works for a :class:`~cmm.measurement.model.MeasurementModel`
(``model``): it checks a datum or a tolerance frame against the model's fitted
features, journals it through the model and evaluates the characteristics as
the report does (:func:`cmm.metrology.gdt_eval.evaluate`), keeping the last
evaluation while none of its inputs changed. The model's methods of the same
names delegate here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import MeasurementError



class Tolerancing:
    """The model's datums and geometric tolerances: define, delete, evaluate."""

    def __init__(self, model: Any) -> None:
        self.model = model
        self.next_id = 1  # the next geometric tolerance's id (ids go on counting across the parts of a series)
        self.cache: tuple[Any, list, list] | None = None  # (inputs, rows, the fits they reference)

    def measured_features(self) -> dict[int, Any]:
        """The fitted features as :class:`cmm.metrology.gdt_eval.MeasuredFeature` (geometry, nominal, points)."""
        m = self.model
        with m.lock:
            hits = {**m.deleted, **m.hits}
            return {fid: f.record().measured(hits) for fid, f in m.features.items()}

    def gdt_characteristics(self, definitions: list[dict[str, Any]] | None = None) -> list[tuple[dict, Any]]:
        """(definition, Characteristic) of every geometric tolerance (or of ``definitions``), evaluated as the
        report does (:func:`cmm.metrology.gdt_eval.evaluate`)."""
        m = self.model
        from ..metrology.gdt_eval import evaluate

        with m.lock:
            defs = list(m.gdt.values()) if definitions is None else definitions
            datums = dict(m.datums)
            part = m.part
            # the tree asks at every refresh (5 Hz per client): evaluate again only when an input changed
            key = (repr(defs), repr(datums), id(part), None if part is None else np.asarray(part.pose).tobytes(),
                   tuple((fid, id(f.result), id(f.nominal), tuple(f.hit_ids), repr(f.tolerance))
                         for fid, f in m.features.items()))
            if definitions is None and self.cache is not None and self.cache[0] == key:
                return list(self.cache[1])
        rows = evaluate(defs, datums, self.measured_features(), None if part is None else part.mesh,
                        None if part is None else np.asarray(part.pose, float))
        if definitions is None:
            with m.lock:  # the results and nominals stay referenced, so their ids in the key stay theirs
                self.cache = (key, rows, [(f.result, f.nominal) for f in m.features.values()])
        return rows

    def define_datum(self, label: str, feature_id: int, modifier: str = "", targets: Any = None) -> dict[str, Any]:
        """Make feature ``feature_id`` datum ``label`` (A, B, C ...), at RFS or MMB / LMB, or established by
        ``targets`` (hit ids of the feature: 3 on a primary plane, 2 on a secondary, 1 on a tertiary; a target
        area or line as ``{"area": [hit ids]}`` / ``{"line": [hit ids]}``, a line counting as two);
        journalled."""
        m = self.model
        from ..metrology.datums import DatumError, datum_from_feature
        from ..metrology.gdt_eval import check_datum

        try:
            d = check_datum({"label": label, "feature": feature_id, "modifier": modifier,
                             **({"targets": list(targets)} if targets else {})})
            with m.lock:
                f = m.features.get(d["feature"])
                if f is None:
                    raise MeasurementError(f"there is no fitted feature {feature_id} to be datum {d['label']}")
                datum_from_feature(d["label"], f.kind, f.result.summary(), feature=f.name)
                if d["modifier"] or d.get("targets"):
                    from ..metrology.gdt_eval import datum_of

                    datum_of(d["label"], {d["label"]: d}, self.measured_features(), False)
                m.record("datum", **d)
        except (DatumError, ValueError, TypeError) as exc:
            raise MeasurementError(str(exc)) from None
        m._notify("features", None)
        return d

    def define_gdt(self, characteristic: str, feature_id: int, tolerance: float, datums: Any = (), *,
                   material: str = "", angle: float | None = None, direction: str = "radial",
                   name: str | None = None, gdt_id: int | None = None, pattern: Any = None,
                   composite: dict[str, Any] | None = None,
                   datum_modifiers: dict[str, str] | None = None,
                   offset: float = 0.0) -> tuple[dict[str, Any], Any]:
        """Define (or with ``gdt_id`` replace) a geometric tolerance on feature ``feature_id`` against
        ``datums`` (labels in precedence order, e.g. "A|B|C" or ["A", "B"]); it is evaluated at once and
        refused in words when it cannot be (a datum not defined or constraining nothing, no nominal, no
        mesh for a profile). A composite position frame: ``pattern`` (the ids of the pattern's features) and
        ``composite`` ({"tolerance", "datums"}: the feature-relating tier). ``datum_modifiers``: how this frame
        references its datums ({"B": "MMB"}), over the datums' own modifiers. ``offset``: a profile's unequally
        disposed zone (mm, ISO 1101 UZ, + towards the outside of the material). Journalled; returns (definition,
        its first Characteristic)."""
        m = self.model
        from ..metrology.datums import DatumError
        from ..metrology.gdt_eval import check_definition, evaluate_one

        if isinstance(datums, str):
            datums = [x for x in datums.replace(",", "|").split("|") if x.strip()]
        raw = {"characteristic": characteristic, "feature": int(feature_id), "tolerance": tolerance,
               "datums": list(datums), "material": material, "angle": angle, "direction": direction}
        if composite is not None:
            low = dict(composite)
            if isinstance(low.get("datums"), str):
                low["datums"] = [x for x in low["datums"].replace(",", "|").split("|") if x.strip()]
            raw.update(pattern=list(pattern or []), composite=low)
        if datum_modifiers:
            raw["datum_modifiers"] = dict(datum_modifiers)
        if offset:
            raw["offset"] = offset
        try:
            d = check_definition(raw)
            with m.lock:
                part, datum_defs = m.part, dict(m.datums)
            evaluate_one(d, datum_defs, self.measured_features(), None if part is None else part.mesh,
                         None if part is None else np.asarray(part.pose, float))
        except (DatumError, ValueError) as exc:
            raise MeasurementError(str(exc)) from None
        with m.lock:
            gid = gdt_id if gdt_id is not None else self.next_id
            self.next_id = max(self.next_id, gid + 1)
            f = m.features.get(int(feature_id))
            d = {"id": gid, "name": name or f"{d['characteristic']} {f.name if f else feature_id}", **d}
            m.record("gdt", **d)
        m._notify("features", None)
        return d, self.gdt_characteristics([d])[0][1]

    def delete_gdt(self, gid: int) -> None:
        m = self.model
        with m.lock:
            if int(gid) not in m.gdt:
                raise MeasurementError(f"there is no geometric tolerance {gid}")
            m.record("gdt_deleted", id=int(gid))
        m._notify("features", None)

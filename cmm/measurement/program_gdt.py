"""A taught routine's datums and geometric tolerances defined on the run's model, on the features it measured
(the program file's tables are read and written by :mod:`cmm.program.gdt`)."""

from __future__ import annotations

from typing import Any

from ..program.gdt import map_targets
from .model import MeasurementError


def define(model: Any, datums: list[dict], gdts: list[dict], fids: dict[str, int],
           hits: dict[int, int]) -> list[str]:
    """Define the program's datums and geometric tolerances on ``model`` (a run's), on the features it measured
    (``fids``: name -> this run's feature id; ``hits``: program hit id -> this run's hit id). Returns what was
    not defined, in words (a feature skipped, a definition the model refused); the rest is defined."""
    left = []
    for d in datums:
        fid = fids.get(d["feature"])
        if fid is None:
            left.append(f"datum {d['label']} not defined: {d['feature']} was not measured")
            continue
        targets = map_targets(d.get("targets"), hits.get) if d.get("targets") else None
        if d.get("targets") and targets is None:
            left.append(f"datum {d['label']} not defined: a datum target hit was not taken")
            continue
        try:
            model.define_datum(d["label"], fid, d.get("modifier", ""), targets=targets)
        except MeasurementError as exc:
            left.append(f"datum {d['label']} not defined: {exc}")
    for d in gdts:
        fid = fids.get(d["feature"])
        pattern = [fids.get(p) for p in d.get("pattern") or []]
        if fid is None or any(p is None for p in pattern):
            left.append(f"{d.get('name')} not evaluated: a feature it tolerances was not measured")
            continue
        try:
            model.define_gdt(d["characteristic"], fid, float(d["tolerance"]), d.get("datums") or [],
                             material=d.get("material", ""), angle=d.get("angle"),
                             direction=d.get("direction", "radial"), name=d.get("name"),
                             pattern=pattern or None, composite=d.get("composite"),
                             datum_modifiers=d.get("datum_modifiers"), offset=float(d.get("offset") or 0.0))
        except MeasurementError as exc:
            left.append(f"{d.get('name')} not evaluated: {exc}")
    return left

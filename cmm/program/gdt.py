"""A taught program keeps the session's datums and geometric tolerances (the routine forgot them).

A session's ``datum`` and ``gdt`` definitions name features and hits by their ids in that session; a program
names them by FEATURE NAME and by the program's own hit ids, so a run on the next part defines the same datums
(with their modifiers and datum targets) and the same feature control frames (characteristic, tolerance, datum
reference frame A|B|C, material condition, datum modifiers, composite tiers, patterns, zone offsets, angles,
runout directions) on the features it measured there::

    [[datums]]
    label = "A"
    feature = "TOP"
    modifier = ""                # "", "MMB" or "LMB"
    targets = [1, 2, 3]          # optional: datum targets, the program's hit ids

    [[gdt]]
    name = "position bore"
    characteristic = "position"
    feature = "bore"
    tolerance = 0.05
    datums = ["A", "B", "C"]
    material = "MMC"

:func:`taught` builds both lists from a session, :func:`toml_lines` writes them, :func:`parse` reads them back,
and :func:`define` applies them to the model of a run.
"""

from __future__ import annotations

from typing import Any, Callable

from .toml_text import toml_value

SKIPPED = ("id", "feature", "pattern", "seq", "time", "kind", "feature_name")


def map_targets(targets: Any, ids: Callable[[int], int | None]) -> list[Any] | None:
    out: list[Any] = []
    for t in targets or []:
        if isinstance(t, dict):
            shape, hs = next(iter(t.items()))
            mapped = [ids(int(h)) for h in hs]
            if any(m is None for m in mapped):
                return None
            out.append({shape: mapped})
        else:
            m = ids(int(t))
            if m is None:
                return None
            out.append(m)
    return out


def taught(state: Any, renumber: dict[int, int], taught_names: set[str]) -> tuple[list[dict], list[dict], list[str]]:
    """(datums, geometric tolerances, what could not be taught in words) of a session's state, by feature name
    and program hit id (``renumber``: session hit id -> program hit id)."""
    names = {f.id: f.name for f in state.features.values()}
    left: list[str] = []
    datums = []
    for label, d in sorted(state.datums.items()):
        name = names.get(d.get("feature"))
        if name not in taught_names:
            left.append(f"datum {label}: its feature is not in the program")
            continue
        out = {"label": label, "feature": name, "modifier": str(d.get("modifier") or "")}
        if d.get("targets"):
            targets = map_targets(d["targets"], renumber.get)
            if targets is None:
                left.append(f"datum {label}: a datum target hit is not in the program")
                continue
            out["targets"] = targets
        datums.append(out)
    gdts = []
    for _gid, d in sorted(state.gdt.items()):
        name = names.get(d.get("feature"))
        pattern = [names.get(i) for i in d.get("pattern") or []]
        if name not in taught_names or any(p not in taught_names for p in pattern):
            left.append(f"{d.get('name', d.get('characteristic'))}: its feature is not in the program")
            continue
        out = {"name": d.get("name") or f"{d.get('characteristic')} {name}", "feature": name,
               **{k: v for k, v in d.items() if k not in SKIPPED and k != "name" and v is not None}}
        if pattern:
            out["pattern"] = pattern
        gdts.append(out)
    return datums, gdts, left


def toml_lines(datums: list[dict], gdts: list[dict]) -> list[str]:
    lines: list[str] = []
    for table, rows in (("datums", datums), ("gdt", gdts)):
        for row in rows:
            lines += ["", f"[[{table}]]"] + [f"{k} = {toml_value(v)}" for k, v in row.items() if v is not None]
    return lines


def parse(data: dict, source: str) -> tuple[list[dict], list[dict]]:
    """The ``[[datums]]`` and ``[[gdt]]`` tables of a program file, checked for what a run needs (ValueError in
    words: the program loader tells it as its ProgramError)."""

    datums, gdts = data.get("datums") or [], data.get("gdt") or []
    for k, d in enumerate(datums, 1):
        if not isinstance(d, dict) or not isinstance(d.get("label"), str) or not isinstance(d.get("feature"), str):
            raise ValueError(f"{source}: datum #{k} needs a label and a feature name")
    for k, d in enumerate(gdts, 1):
        if not isinstance(d, dict) or not isinstance(d.get("feature"), str) or not isinstance(
                d.get("characteristic"), str):
            raise ValueError(f"{source}: geometric tolerance #{k} needs a characteristic and a feature name")
        if not isinstance(d.get("tolerance"), (int, float)) or isinstance(d.get("tolerance"), bool):
            raise ValueError(f"{source}: geometric tolerance #{k} ({d['feature']}) needs a tolerance in mm")
    return [dict(d) for d in datums], [dict(d) for d in gdts]

"""What DMIS SAVE keeps beyond its run: the station's record of saved alignments, datums, actuals and sensors.

The standard's SAVE stores an item for a later RECALL, "possibly in a different input program": a fixture's
alignment saved by one program is recalled by the next. The station keeps them in ``dmis-saved.json`` in its
sessions folder (one entry per ``DA(x)``, ``DAT(x)``, ``FA(x)``, ``SA(x)``, the last SAVE of each winning), with
the program and the time that saved it. Coordinate systems keep their program -> machine matrices (a recalled
alignment holds while the part or fixture has not moved); datums and actuals keep their measured geometry and
nominal, not the session's feature (that belongs to the run that measured it).
"""

from __future__ import annotations

import dataclasses
import json
import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from .features import Actual, Nominal

FILE_NAME = "dmis-saved.json"
_LOCK = threading.Lock()


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _nominal_data(nom: Nominal | None) -> dict[str, Any] | None:
    if nom is None:
        return None
    data = {f.name: _plain(getattr(nom, f.name)) for f in dataclasses.fields(nom) if f.name != "design"}
    data["design"] = _nominal_data(nom.design)
    return data


def _nominal(data: dict[str, Any] | None) -> Nominal | None:
    if data is None:
        return None
    arrays = ("point", "vector", "plane")
    kw = {k: (None if v is None else np.asarray(v, float)) if k in arrays else v for k, v in data.items()
          if k != "design"}
    return Nominal(**kw, design=_nominal(data.get("design")))


def encode(key: str, value: Any) -> dict[str, Any]:
    """A saved item as JSON data: ``DA``: (frame, design frame); ``DAT`` / ``FA``: an Actual; ``SA``: a sensor."""
    kind = key.split("(", 1)[0]
    if kind == "DA":
        return {"frame": _plain(value[0]), "design": _plain(value[1])}
    if kind in ("DAT", "FA"):
        return {"label": value.label, "kind": value.kind, "geometry": _plain(value.geometry),
                "nominal": _nominal_data(value.nominal),
                "hit_points": None if value.hit_points is None else _plain(value.hit_points)}
    return {"sensor": _plain(value)}


def decode(key: str, data: dict[str, Any]) -> Any:
    kind = key.split("(", 1)[0]
    if kind == "DA":
        return np.asarray(data["frame"], float), np.asarray(data["design"], float)
    if kind in ("DAT", "FA"):
        geometry = {k: np.asarray(v, float) if isinstance(v, list) else v for k, v in data["geometry"].items()}
        hits = data.get("hit_points")
        return Actual(data["label"], data["kind"], geometry, _nominal(data.get("nominal")), None,
                      None if hits is None else np.asarray(hits, float).reshape(-1, 3))
    return dict(data["sensor"])


class SavedItems:
    """The station's saved DMIS items in ``folder`` (read afresh at each RECALL: another program may have saved)."""

    def __init__(self, folder: str | Path) -> None:
        self.path = Path(folder) / FILE_NAME

    def _read(self) -> dict[str, Any]:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as exc:
            raise OSError(f"the station's saved DMIS items ({self.path}) cannot be read: {exc}") from None
        return data if isinstance(data, dict) else {}

    def keep(self, key: str, value: Any, program: str) -> None:
        with _LOCK:
            items = self._read()
            items[key] = {"program": program, "saved": time.strftime("%Y-%m-%d %H:%M:%S"), "item": encode(key, value)}
            tmp = self.path.with_suffix(".tmp")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(items, indent=1), encoding="utf-8")
            os.replace(tmp, self.path)

    def recall(self, key: str) -> tuple[Any, str] | None:
        """The item saved as ``key`` and who saved it ("program 'x' at time"), or None."""
        entry = self._read().get(key)
        if entry is None:
            return None
        return decode(key, entry["item"]), f"program {entry.get('program', '?')!r} at {entry.get('saved', '?')}"

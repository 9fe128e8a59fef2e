"""Plain helpers of the measurement model: the report header's fields checked,
a session journal opened under its name, its ``start`` event's fields, and a construction from two features
computed (the measured result and, when both have nominals, the nominal one).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..journal.store import is_url, open_store
from ..journal.writer import Journal
from ..metrology.features import FitError
from .errors import INFO_FIELDS, MeasurementError


def clean_info(fields: dict[str, Any]) -> dict[str, Any]:
    """Report header fields checked: known names only, the temperature a plausible number of deg C, the rest text."""
    unknown = sorted(set(fields) - set(INFO_FIELDS))
    if unknown:
        raise MeasurementError(f"unknown report field(s) {', '.join(unknown)}; use {', '.join(INFO_FIELDS)}")
    clean: dict[str, Any] = {}
    for k, v in fields.items():
        if k == "temperature" and v not in (None, ""):
            try:
                t = float(v)
            except (TypeError, ValueError):
                raise MeasurementError(f"the temperature must be a number of degrees Celsius, got {v!r}") from None
            if not -50.0 <= t <= 100.0:
                raise MeasurementError(f"a temperature of {t} °C is not plausible for a measuring room")
            clean[k] = t
        else:
            clean[k] = "" if v is None else str(v).strip()
    return clean


def open_journal(session_dir: Path | str, name: str, stamp: str) -> tuple[Any, Path | str]:
    """A new session journal ``name`` in ``session_dir`` (a folder or a postgresql:// URL) -> (journal, path).
    A name that is the time ``stamp`` and already taken gets a suffix (two stations started in the same second)."""
    if is_url(session_dir):
        return open_store(session_dir).create(name, append=True), f"{name}"
    path = Path(session_dir) / f"{name}.jsonl"
    for n in range(2, 100):  # two stations started in the same second get their own sessions
        if name != stamp or not path.exists():
            break
        path = Path(session_dir) / f"{stamp}-{n}.jsonl"
    return Journal(path), path


def start_event(snapshot: dict[str, Any], part: Any, start: dict[str, Any]) -> dict[str, Any]:
    """The fields of a session's ``start`` event: the port, the machine ``snapshot`` (configuration and
    calibration), the owner's ``start`` fields and the part (name, pose, mesh checksum and path)."""
    start = dict(start)
    port = start.pop("port", "")
    return {"port": port, **snapshot, **start, "part": None if part is None else part.name,
            "part_pose": None if part is None else part.pose,
            "part_sha256": None if part is None else part.sha256,
            "part_path": None if part is None or part.mesh is None else part.mesh.metadata.get("path")}


def construct_pair(operation: str, fa: Any, fb: Any, workplane: Any, three_d: bool) -> tuple[Any, Any]:
    """(result, nominal) of ``operation`` on fitted features ``fa`` and ``fb`` (nominal None unless both have
    nominals and their construction succeeds); MeasurementError when the measured one cannot be made."""
    from ..metrology.construct import construct, nominal_geometry

    how = {"workplane": workplane, "three_d": three_d}
    try:
        result = construct(operation, (fa.kind, fa.result.geometry()), (fb.kind, fb.result.geometry()), **how)
    except (FitError, ValueError, KeyError) as exc:
        raise MeasurementError(str(exc)) from None
    from ..metrology.uncertainty_construct import distance_uncertainty

    try:
        result.uncertainty = distance_uncertainty(
            operation, (fa.kind, fa.result.geometry()), (fb.kind, fb.result.geometry()),
            (getattr(fa, "budget", None), getattr(fb, "budget", None)), **how)
    except (FitError, ValueError, KeyError, TypeError, np.linalg.LinAlgError) as exc:
        result.uncertainty = {"why": f"no uncertainty: it could not be propagated ({exc})"}
    nominal = None
    na = nominal_geometry(fa.kind, None if fa.nominal is None else fa.nominal.to_dict())
    nb = nominal_geometry(fb.kind, None if fb.nominal is None else fb.nominal.to_dict())
    if na is not None and nb is not None:
        try:
            nominal = construct(operation, na, nb, **how)
        except (FitError, ValueError, KeyError, np.linalg.LinAlgError):
            nominal = None
    return result, nominal

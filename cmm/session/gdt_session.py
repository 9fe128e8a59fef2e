"""A session's geometric tolerances (``datum`` / ``gdt`` events) evaluated on its features and hits.

The report (HTML and CSV), the JSON export and a re-evaluated session all read these rows, and the station's
feature tree the same :func:`cmm.metrology.gdt_eval.evaluate` on its live features: one code path.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..journal.session import Session
from ..metrology.characteristics import Characteristic
from ..metrology.gdt_eval import MeasuredFeature, evaluate


def measured_features(session: Session, tolerances: dict[int, dict[str, float]] | None = None) -> dict[int, MeasuredFeature]:
    """The session's fitted features with their hits' points (deleted hits too: a feature keeps its hits)."""
    st = session.state
    hits = {**st.deleted_hits, **st.hits}
    return {fid: f.measured(hits, {**(f.tolerance or {}), **((tolerances or {}).get(fid) or {})})
            for fid, f in st.features.items()}


def session_gdt(session: Session, mesh: Any = None,
                tolerances: dict[int, dict[str, float]] | None = None) -> list[tuple[dict, Characteristic]]:
    """(definition, Characteristic) per ``gdt`` definition of the session, in definition order; profiles
    against ``mesh`` at the session's current part pose."""
    st = session.state
    if not st.gdt:
        return []
    return evaluate(list(st.gdt.values()), st.datums, measured_features(session, tolerances), mesh,
                    None if st.part_pose is None else np.array(st.part_pose, float))

"""The frame a coordinate field shows or takes, in the words every field of the page uses.

Machine coordinates are the axes' own; part coordinates go through the part's pose: the alignment in force
(named: "3-2-1 TOP/FRONT/LEFT", "best_fit"), or the nominal set-up when no alignment was made. Both read a
snapshot of the model (the ``model`` query, :class:`cmm.measurement.queries.ModelSnapshot`).
"""

from __future__ import annotations

from typing import Any


def alignment_text(model: Any) -> str:
    """The alignment part coordinates go through now, as the operator knows it (``model``: a snapshot)."""
    if model.part is None:
        return "no part loaded"
    if not model.aligned:
        return "nominal set-up, no alignment made"
    return f"alignment {getattr(model, 'alignment_name', '') or 'made'}"


def frame_label(model: Any, frame: str) -> str:
    """'machine', or 'part (alignment 3-2-1 TOP/FRONT/LEFT)' / 'part (nominal set-up, no alignment made)'."""
    if str(frame).lower() != "part":
        return "machine"
    return f"part ({alignment_text(model)})"

"""The probe data the hits actually used: per hit, per tip, from the journal (not the session's start snapshot).

Each ``hit`` event carries ``probe_data`` (the tip radius, the pre-travel model and the date of the qualification
in force when the hit was taken: :meth:`cmm.measurement.model.MeasurementModel.probe_data`) beside its ``probe``
(the stylus name). A requalification during a session therefore shows in the report header as the qualification
its hits were taken with; a journal from before hits carried it falls back to the start snapshot.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class ProbeUse:
    probe: str  # the stylus name ("" before hits named it)
    tip_radius: float | None
    pretravel: str
    qualified: str  # the qualification's date ("" never qualified: the nominal radius)
    hits: list[int] = field(default_factory=list)

    def text(self) -> str:
        r = "radius not recorded" if self.tip_radius is None else f"r {self.tip_radius:.5f} mm"
        q = f"qualified {self.qualified[:16].replace('T', ' ')}" if self.qualified else "not qualified (nominal radius)"
        name = f"{self.probe}: " if self.probe else ""
        n = len(self.hits)
        return f"{name}{r}, {q}, pre-travel {self.pretravel or 'none'} ({n} hit{'s' if n != 1 else ''})"


def _start_data(start: dict) -> dict[str, Any]:
    cal = start.get("calibration") if isinstance(start.get("calibration"), dict) else {}
    coef = start.get("pretravel") or {}
    return {"tip_radius": start.get("tip_radius"),
            "pretravel": ", ".join(f"{k} {float(v) * 1000:+.2f} µm" for k, v in coef.items()
                                   if isinstance(v, (int, float))),
            "qualified": str(((cal or {}).get("probe") or {}).get("date") or "")}


def probe_uses(session: Any) -> list[ProbeUse]:
    """The active hits grouped by the probe data they were taken with, in the order first used."""
    active = set(session.state.hits)
    fallback = _start_data(session.start or {})
    groups: dict[tuple, ProbeUse] = {}
    for ev in session.events:
        if ev.get("kind") != "hit" or int(ev.get("id", -1)) not in active:
            continue
        d = ev.get("probe_data") if isinstance(ev.get("probe_data"), dict) else fallback
        r = d.get("tip_radius")
        q = d.get("qualified")
        q = fallback["qualified"] if q is None else q  # recorded without a calibration service: the start's word
        key = (str(ev.get("probe") or ""), None if r is None else round(float(r), 7), str(d.get("pretravel") or ""),
               str(q or ""))
        use = groups.get(key)
        if use is None:
            use = groups[key] = ProbeUse(key[0], key[1], key[2], key[3])
        use.hits.append(int(ev["id"]))
    return list(groups.values())


def hits_probe_text(session: Any) -> str:
    """One line per probe data set the hits used ("" without hits)."""
    return "; ".join(u.text() for u in probe_uses(session))

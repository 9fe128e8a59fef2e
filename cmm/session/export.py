"""Exports: CSV of hits (raw and compensated) and JSON of the whole session.

CSV columns: id, mode, deleted, counts_x/y/z (raw latched counts),
machine_x/y/z (tip centre, mm), approach_x/y/z, speed (mm/s), time (ISO 8601
UTC), point_x/y/z (compensated surface point, mm), deviation (signed
distance of the point to the part mesh at the pose in force when the hit was
taken, + = outside the material; empty when no part mesh is known).
"""

from __future__ import annotations

import csv
import io
import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from ..journal.session import Session, mesh_sha256
from .gdt_session import session_gdt

CSV_COLUMNS = ["id", "mode", "deleted", "counts_x", "counts_y", "counts_z", "machine_x", "machine_y", "machine_z",
               "approach_x", "approach_y", "approach_z", "speed", "time", "point_x", "point_y", "point_z", "deviation"]


def resolve_part_mesh(session: Session, part: Any = None, search: list[str | Path] | None = None) -> Any:
    """The part mesh of a session if it can be found and its content hash matches, else None.

    ``part``: a mesh or a mesh file to use (its hash must match the recorded one);
    otherwise the recorded ``path``, files named like the part in ``search``
    directories, and the simulator's sample part are tried.
    """
    ref = session.part
    if ref is None:
        return None
    from ..metrology.mesh import load_part
    from ..journal.session import file_sha256

    candidates: list[Any] = []
    if part is not None:
        candidates.append(part)
    if ref.path:
        candidates.append(Path(ref.path))
    for d in search or []:
        candidates.append(Path(d) / ref.name)
    for c in candidates:
        try:
            if isinstance(c, (str, Path)):
                if not Path(c).is_file():
                    continue
                mesh = load_part(c)
                mesh.metadata["sha256"] = file_sha256(c)
            else:
                mesh = c
        except Exception:  # noqa: BLE001 - an unreadable candidate is just not the part
            continue
        if ref.sha256 is None or mesh_sha256(mesh) == ref.sha256:
            return mesh
    if ref.name == "sample part":
        return sample_part_mesh(ref.sha256)
    return None


def sample_part_mesh(sha256: str | None) -> Any:
    """The simulator's sample part, made again (it has no file), if its hash is ``sha256`` (or none was recorded)."""
    from ..sim.sample_part import sample_part

    mesh, _ = sample_part()
    return mesh if sha256 is None or mesh_sha256(mesh) == sha256 else None


def hit_deviations(session: Session, mesh: Any) -> dict[int, float]:
    """Signed deviation per hit (active and deleted) at the pose in force when it was taken."""
    from ..metrology.mesh import signed_deviation

    st = session.state
    hits = {**st.deleted_hits, **st.hits}
    if mesh is None or not hits:
        return {}
    out: dict[int, float] = {}
    by_pose: dict[Any, list[int]] = {}
    for hid in hits:
        by_pose.setdefault(st.hit_pose.get(hid) or st.part_pose, []).append(hid)
    for pose, ids in by_pose.items():
        if pose is None:
            continue
        res = signed_deviation(mesh, np.array([hits[i].point for i in ids]), np.array(pose))
        out.update({i: float(d) for i, d in zip(ids, res.deviations)})
    return out


def _iso(t: float) -> str:
    return datetime.fromtimestamp(t, timezone.utc).isoformat(timespec="microseconds")


def hits_csv(session: Session, mesh: Any = None) -> str:
    st = session.state
    dev = hit_deviations(session, mesh) if mesh is not None else {}
    rows = sorted([(h, False) for h in st.hits.values()] + [(h, True) for h in st.deleted_hits.values()],
                  key=lambda r: r[0].id)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for h, deleted in rows:
        d = dev.get(h.id)
        w.writerow([h.id, h.mode, int(deleted), *h.counts, *(repr(float(x)) for x in h.machine),
                    *(repr(float(x)) for x in h.approach), repr(h.speed), _iso(h.time),
                    *(repr(float(x)) for x in h.point), "" if d is None else repr(d)])
    return buf.getvalue()


def session_json(session: Session, mesh: Any = None) -> dict:
    """The whole session: summary, configuration, every event, and the final hits/features/alignments."""
    st = session.state
    dev = hit_deviations(session, mesh) if mesh is not None else {}
    return {
        "format": "cmm-session-export/1",
        "session": session.summary(),
        "warnings": session.warnings,
        "start": session.start,
        "part": None if st.part is None else {"name": st.part.name, "sha256": st.part.sha256, "path": st.part.path,
                                              "pose": st.part_pose},
        "alignments": [{"seq": a.seq, "method": a.method, "pose": a.pose, **a.info} for a in st.alignments],
        "hits": [{**h.to_event(), "seq": h.seq, "deviation": dev.get(h.id)} for h in st.hits.values()],
        "deleted_hits": [h.id for h in st.deleted_hits.values()],
        "features": [{**f.to_event(), "seq": f.seq} for f in st.features.values()],
        "datums": st.datums,
        "gdt": [{**d, "feature_name": c.feature, "value": c.actual, "allowed": c.upper, "drf": c.datums,
                 "result": c.verdict, "note": c.note, "check": c.check} for d, c in session_gdt(session, mesh)],
        "notes": [{"seq": s, "text": t} for s, t in st.notes],
        "errors": [{"seq": s, "message": m} for s, m in st.errors],
        "events": session.events,
    }


def write_csv(session: Session, path: str | Path, mesh: Any = None) -> Path:
    p = Path(path)
    p.write_text(hits_csv(session, mesh), encoding="utf-8")
    return p


def write_json(session: Session, path: str | Path, mesh: Any = None) -> Path:
    p = Path(path)
    p.write_text(json.dumps(session_json(session, mesh), indent=1, allow_nan=False), encoding="utf-8")
    return p

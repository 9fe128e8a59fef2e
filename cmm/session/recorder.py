"""A headless session recorder: a Machine + Prober recorded into a session store.

The station records its own sessions; this is the same recording without a
UI, for scripts, tests and benchmarks: hits are written (fsync'ed /
committed) in the prober's listener, before ``probe(...).wait()`` returns
them, and features are fitted exactly as the station fits them. It offers
the small interface :func:`cmm.session.program.run_program` drives (``probe``,
``hits``, ``fit_feature``, ``set_alignment``, ``part``), like the Station.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..metrology.features import FitError, FitResult
from .model import machine_snapshot, mesh_sha256
from .reevaluate import feature_fields, fit_hit_records


class RecorderError(RuntimeError):
    pass


@dataclass
class PartInfo:
    name: str
    mesh: Any  # trimesh.Trimesh in part coordinates
    pose: np.ndarray  # part -> machine
    nominal_features: dict[str, Any] = field(default_factory=dict)
    sha256: str | None = None

    def __post_init__(self) -> None:
        if self.sha256 is None and self.mesh is not None:
            self.sha256 = mesh_sha256(self.mesh)


@dataclass
class RecordedFeature:
    id: int
    name: str
    kind: str
    method: str
    hit_ids: list[int]
    result: FitResult
    nominal: Any = None


class SessionRecorder:
    def __init__(self, writer: Any, machine: Any, prober: Any, part: PartInfo | None = None, *, port: str = "") -> None:
        self.writer = writer
        self.machine = machine
        self.prober = prober
        self.part = part
        self.hits: dict[int, Any] = {}
        self.features: dict[int, RecordedFeature] = {}
        self._lock = threading.RLock()
        self._next_hit = 1
        self._next_feature = 1
        snap = machine_snapshot(machine.config, machine.correction, prober.settings)
        writer.append("start", port=port, **snap, part=None if part is None else part.name,
                      part_pose=None if part is None else np.asarray(part.pose, float),
                      part_sha256=None if part is None else part.sha256,
                      part_path=None if part is None else (part.mesh.metadata.get("path") if part.mesh is not None else None))
        prober.listeners.append(self._on_hit)

    def _on_hit(self, hit: Any) -> None:
        with self._lock:
            hid = self._next_hit
            self.writer.append("hit", id=hid, counts=hit.counts, machine=hit.machine, approach=hit.approach,
                               speed=hit.speed, hit_time=hit.time, point=hit.point, mode=hit.mode, normal=hit.normal)
            self._next_hit += 1
            self.hits[hid] = hit  # acknowledged only after it is durable

    def probe(self, point: Any, approach: Any, clearance_z: float | None = None) -> Any:
        return self.prober.probe(point, approach, clearance_z=clearance_z)

    def hit_id(self, hit: Any) -> int:
        with self._lock:
            for hid in reversed(list(self.hits)):
                if self.hits[hid] is hit:
                    return hid
        raise RecorderError("the hit was not recorded")

    def fit_feature(self, kind: str, hit_ids: list[int], method: str = "ls", name: str | None = None,
                    nominal: Any = None, tolerance: dict | None = None) -> RecordedFeature:
        with self._lock:
            missing = [h for h in hit_ids if h not in self.hits]
            if missing:
                raise RecorderError(f"no hits with ids {missing}")
            hits = [self.hits[h] for h in hit_ids]
        try:
            result = fit_hit_records(kind, method, hits, self.prober.settings, nominal)
        except FitError as exc:
            self.error(str(exc), source="fit")
            raise
        with self._lock:
            fid = self._next_feature
            self._next_feature += 1
            feat = RecordedFeature(fid, name or f"{kind} {fid}", kind, method, list(hit_ids), result, nominal)
            self.features[fid] = feat
            extra = {} if tolerance is None else {"tolerance": tolerance}
            fields = feature_fields(result)
            fields["feature_kind"] = kind
            self.writer.append("feature", id=fid, name=feat.name, hit_ids=list(hit_ids), **fields,
                               nominal=None if nominal is None else nominal.to_dict(), **extra)
        return feat

    def set_alignment(self, pose: Any, method: str = "manual", **info: Any) -> None:
        pose = np.asarray(pose, dtype=np.float64).reshape(4, 4)
        if self.part is not None:
            self.part.pose = pose
        self.writer.append("alignment", pose=pose, method=method, **info)

    def note(self, text: str) -> None:
        self.writer.append("note", text=text)

    def error(self, message: str, source: str = "recorder") -> None:
        self.writer.append("error", message=message, source=source)

    def record(self, kind: str, **data: Any) -> None:
        self.writer.append(kind, **data)

    def close(self) -> None:
        if self._on_hit in self.prober.listeners:
            self.prober.listeners.remove(self._on_hit)
        self.writer.close()

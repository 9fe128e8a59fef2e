"""Teach and repeat: a recorded session's hits become a measurement program.

``teach(session)`` expresses every hit used by a feature in PART coordinates
(through the session's last alignment, or the recorded part pose) and
writes a readable, editable TOML file::

    format = "cmm-program/1"
    name = "bracket"
    clearance = 10.0              # mm above the highest hit, for the rapid moves between hits

    [part]
    name = "bracket.stl"
    sha256 = "9f2c..."            # sha256 of the mesh file (or of the mesh's vertices+faces)

    [[features]]
    name = "boss"
    kind = "cylinder"             # point line plane circle sphere cylinder cone
    method = "ls"                 # ls minzone mic mcc (as available for the kind)
    hits = [1, 2, 3, 4, 5, 6]     # ids of [[hits]] below
    tolerance = { size = 0.02, form = 0.02, location = 0.02 }
    nominal = { kind = "cylinder", point = [70.0, 22.0, 40.0], direction = [0.0, 0.0, 1.0], radius = 10.0 }
    nominal_ref = "boss"          # optional: a nominal feature of the part that must exist

    [[hits]]
    id = 1
    point = [80.0, 22.0, 47.0]    # nominal surface point, part mm
    approach = [-1.0, 0.0, 0.0]   # unit direction into the surface, part coordinates
    clearance_z = 65.0            # part Z to climb to before moving to this hit

``check(program, part, pose, machine)`` refuses a program that does not fit
the loaded part (content hash, feature references, kinds, methods, point
counts, machine travel) with :class:`ProgramError` and a sentence naming the
mismatch; :func:`cmm.measurement.program.run_program` checks BEFORE anything
moves, then probes every hit and fits the features with their recorded kind
and method.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..journal.session import Session, mesh_sha256
from ..metrology import fit_criteria, fit_ls
from ..metrology.characteristics import DEFAULT_TOLERANCE
from ..metrology.pick import NominalFeature
from . import gdt as program_gdt
from .toml_text import toml_value

FORMAT = "cmm-program/1"
FORMAT_ROUTINE = "cmm-program/2"  # the same file with an ordered [[steps]] list (cmm.measurement.routine)
KINDS = ("point", "line", "plane", "circle", "sphere", "cylinder", "cone")


class ProgramError(ValueError):
    """A program that cannot run, in an operator's words."""


@dataclass
class ProgramHit:
    id: int
    point: tuple[float, float, float]  # part coordinates, nominal surface point
    approach: tuple[float, float, float]  # unit, into the surface, part coordinates
    clearance_z: float  # part Z


@dataclass
class ProgramFeature:
    name: str
    kind: str
    method: str
    hits: list[int]
    tolerance: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_TOLERANCE))
    nominal: dict[str, Any] | None = None  # NominalFeature.to_dict() in part coordinates
    nominal_ref: str | None = None


@dataclass
class Program:
    name: str
    part_name: str
    part_sha256: str
    features: list[ProgramFeature]
    hits: list[ProgramHit]
    clearance: float = 10.0
    taught_from: str | None = None
    steps: list[dict[str, Any]] = field(default_factory=list)  # the routine's ordered steps (format 2)
    datums: list[dict[str, Any]] = field(default_factory=list)  # datum definitions by feature name (program_gdt)
    gdt: list[dict[str, Any]] = field(default_factory=list)  # geometric tolerances by feature name (program_gdt)
    untaught: list[str] = field(default_factory=list)  # what teaching could not keep, in words (not written)

    def feature(self, name: str) -> ProgramFeature:
        for f in self.features:
            if f.name == name:
                return f
        raise KeyError(name)


def _pose_inv(pose: np.ndarray) -> np.ndarray:
    inv = np.eye(4)
    inv[:3, :3] = pose[:3, :3].T
    inv[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return inv


# ------------------------------------------------------------------------ teach


def teach(session: Session, *, name: str | None = None, clearance: float = 10.0, part_mesh: Any = None,
          part_nominals: dict[str, Any] | None = None, features: list[str] | None = None) -> Program:
    """A program from a session's features and the hits they use.

    ``features`` limits the program to those feature names (default: every
    feature of the session). ``part_mesh`` (part coordinates) sets the
    clearance height from its top; ``part_nominals`` adds ``nominal_ref``
    for features named like a nominal feature of the part.
    """
    st = session.state
    if st.part is None or st.part_pose is None:
        raise ProgramError(f"session {session.name!r} has no part: a program needs the part the hits refer to")
    if not st.part.sha256:
        raise ProgramError(f"session {session.name!r} does not record the part's content hash: re-record it")
    feats = [f for f in st.features.values() if features is None or f.name in features]
    if not feats:
        raise ProgramError(f"session {session.name!r} has no features to teach")
    inv = _pose_inv(st.pose_array)  # type: ignore[arg-type]
    all_hits = {**st.deleted_hits, **st.hits}
    used = sorted({h for f in feats for h in f.hit_ids})
    pts, dirs = {}, {}
    for hid in used:
        h = all_hits[hid]
        pts[hid] = inv[:3, :3] @ np.array(h.point) + inv[:3, 3]
        dirs[hid] = inv[:3, :3] @ np.array(h.approach)
    top = float(np.asarray(part_mesh.bounds)[1, 2]) if part_mesh is not None else max(float(p[2]) for p in pts.values())
    renumber = {hid: k + 1 for k, hid in enumerate(used)}
    hits = [ProgramHit(renumber[h], tuple(round(float(x), 6) + 0.0 for x in pts[h]),  # type: ignore[arg-type]
                       tuple(round(float(x), 9) + 0.0 for x in dirs[h] / np.linalg.norm(dirs[h])),  # type: ignore[arg-type]
                       round(top + clearance, 3)) for h in used]
    out = []
    for f in feats:
        nominal = None
        if f.nominal:
            nf = NominalFeature(f.nominal["kind"], {k: v for k, v in f.nominal.items() if k != "kind"})
            nominal = nf.transformed(inv).to_dict()
        ref = f.name if part_nominals and f.name in part_nominals else None
        # every kind of tolerance the feature had (position, angle, size limits ...) over the defaults: a
        # feature given only a position tolerance kept no location and the routine list showed it as 0
        out.append(ProgramFeature(f.name, f.kind, f.method, [renumber[h] for h in f.hit_ids],
                                  {**DEFAULT_TOLERANCE, **(f.tolerance or {})}, nominal, ref))
    datums, gdts, left = program_gdt.taught(st, renumber, {f.name for f in out})
    return Program(name or session.name, st.part.name, st.part.sha256, out, hits, clearance, session.name,
                   datums=datums, gdt=gdts, untaught=left)


# ------------------------------------------------------------------------ TOML


def _val(v: Any) -> str:
    try:
        return toml_value(v)
    except (TypeError, ValueError) as exc:
        raise ProgramError(f"cannot write this into a program: {exc}") from None


def to_toml(program: Program) -> str:
    lines = [
        "# CMM measurement program (teach & repeat). Edit freely.",
        "# Coordinates are PART coordinates in mm; approach directions are unit vectors into the surface.",
        "# Run it after aligning the next part: the program is refused if the part's sha256 differs.",
        f"format = {_val(FORMAT_ROUTINE if program.steps else FORMAT)}",
        f"name = {_val(program.name)}",
    ]
    if program.taught_from:
        lines.append(f"taught_from = {_val(program.taught_from)}")
    lines += [f"clearance = {_val(float(program.clearance))}", "", "[part]",
              f"name = {_val(program.part_name)}", f"sha256 = {_val(program.part_sha256)}"]
    for f in program.features:
        lines += ["", "[[features]]", f"name = {_val(f.name)}", f"kind = {_val(f.kind)}", f"method = {_val(f.method)}",
                  f"hits = {_val(list(f.hits))}", f"tolerance = {_val({k: float(v) for k, v in f.tolerance.items()})}"]
        if f.nominal:
            lines.append(f"nominal = {_val(f.nominal)}")
        if f.nominal_ref:
            lines.append(f"nominal_ref = {_val(f.nominal_ref)}")
    for h in program.hits:
        lines += ["", "[[hits]]", f"id = {h.id}", f"point = {_val([float(x) for x in h.point])}",
                  f"approach = {_val([float(x) for x in h.approach])}", f"clearance_z = {_val(float(h.clearance_z))}"]
    try:
        lines += program_gdt.toml_lines(program.datums, program.gdt)
    except (TypeError, ValueError) as exc:
        raise ProgramError(f"cannot write this into a program: {exc}") from None
    for step in program.steps:
        lines += ["", "[[steps]]"] + [f"{k} = {_val(v)}" for k, v in step.items() if v is not None]
    return "\n".join(lines) + "\n"


def _vec(value: Any, where: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3 or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                                    and math.isfinite(x) for x in value):
        raise ProgramError(f"{where} must be a list of three finite numbers, got {value!r}")
    return tuple(float(x) for x in value)  # type: ignore[return-value]


def from_toml(text: str, source: str = "<program>") -> Program:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProgramError(f"{source} is not valid TOML: {exc}") from None
    if data.get("format") not in (FORMAT, FORMAT_ROUTINE):
        raise ProgramError(f"{source}: format must be {FORMAT!r} or {FORMAT_ROUTINE!r}, got {data.get('format')!r}")
    part = data.get("part") or {}
    if not part.get("sha256"):
        raise ProgramError(f"{source}: [part] needs the sha256 of the part the program was taught on")
    hits = []
    for k, h in enumerate(data.get("hits") or [], 1):
        where = f"{source}: hit #{k}"
        if not isinstance(h.get("id"), int):
            raise ProgramError(f"{where} needs an integer id")
        u = np.array(_vec(h.get("approach"), f"{where} approach"))
        if np.linalg.norm(u) < 1e-9:
            raise ProgramError(f"{where}: the approach direction is zero")
        cz = h.get("clearance_z", None)
        if not isinstance(cz, (int, float)) or isinstance(cz, bool):
            raise ProgramError(f"{where} needs a clearance_z height (part Z, mm)")
        norm = float(np.linalg.norm(u))
        if abs(norm - 1.0) > 1e-6:  # an edited direction need not be unit
            u = u / norm
        hits.append(ProgramHit(h["id"], _vec(h.get("point"), f"{where} point"),
                               tuple(float(x) for x in u), float(cz)))  # type: ignore[arg-type]
    features = []
    for k, f in enumerate(data.get("features") or [], 1):
        where = f"{source}: feature #{k}"
        if not isinstance(f.get("name"), str) or not isinstance(f.get("kind"), str):
            raise ProgramError(f"{where} needs a name and a kind")
        ids = f.get("hits")
        if not isinstance(ids, list) or not all(isinstance(i, int) for i in ids):
            raise ProgramError(f"{where} ({f['name']}) needs hits = [ids of its [[hits]]]")
        tol = {**DEFAULT_TOLERANCE, **{k2: float(v) for k2, v in (f.get("tolerance") or {}).items()}}
        features.append(ProgramFeature(f["name"], f["kind"], str(f.get("method", "ls")), list(ids), tol,
                                       f.get("nominal"), f.get("nominal_ref")))
    steps = data.get("steps") or []
    if not isinstance(steps, list) or not all(isinstance(st, dict) and isinstance(st.get("kind"), str)
                                              for st in steps):
        raise ProgramError(f"{source}: every [[steps]] entry needs a kind")
    try:
        datums, gdts = program_gdt.parse(data, source)
    except ValueError as exc:
        raise ProgramError(str(exc)) from None
    return Program(str(data.get("name", "program")), str(part.get("name", "")), str(part["sha256"]), features, hits,
                   float(data.get("clearance", 10.0)), data.get("taught_from"), [dict(st) for st in steps],
                   datums=datums, gdt=gdts)


def save(program: Program, path: str | Path) -> Path:
    p = Path(path)
    p.write_text(to_toml(program), encoding="utf-8")
    return p


def load(path: str | Path) -> Program:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ProgramError(f"cannot read the program {p}: {exc.strerror or exc}") from None
    return from_toml(text, str(p))


# ------------------------------------------------------------------------ checks and run


def part_hash(part: Any) -> str:
    """The content hash of a loaded part (:class:`cmm.measurement.model.Part` or anything with a mesh)."""
    if getattr(part, "sha256", None):
        return str(part.sha256)
    return mesh_sha256(part.mesh)


def machine_targets(program: Program, pose: np.ndarray) -> list[tuple[ProgramHit, np.ndarray, np.ndarray, float]]:
    """(hit, machine point, machine approach, machine clearance Z) for every hit."""
    R, t = pose[:3, :3], pose[:3, 3]
    out = []
    for h in program.hits:
        p = R @ np.array(h.point) + t
        u = R @ np.array(h.approach)
        cz = float((R @ np.array([h.point[0], h.point[1], h.clearance_z]) + t)[2])
        out.append((h, p, u, max(cz, float(p[2]))))
    return out


def check(program: Program, part: Any, pose: Any = None, machine: Any = None, tip_radius: float | None = None) -> None:
    """Refuse (ProgramError) a program that does not fit the loaded part or machine. Moves nothing."""
    if part is None:
        raise ProgramError(f"program {program.name!r} needs the part {program.part_name!r} loaded; no part is loaded")
    have = part_hash(part)
    if have != program.part_sha256:
        raise ProgramError(
            f"program {program.name!r} was taught on part {program.part_name!r} (sha256 {program.part_sha256[:12]}...) "
            f"but the loaded part {getattr(part, 'name', '?')!r} has sha256 {have[:12]}...: "
            "load the part the program was taught on, or teach a new program")
    ids = [h.id for h in program.hits]
    if len(set(ids)) != len(ids):
        raise ProgramError(f"program {program.name!r} has duplicate hit ids")
    known = set(ids)
    names = [f.name for f in program.features]
    if len(set(names)) != len(names):
        raise ProgramError(f"program {program.name!r} has two features with the same name")
    nominals = getattr(part, "nominal_features", None) or {}
    for f in program.features:
        if f.kind not in KINDS:
            raise ProgramError(f"feature {f.name!r}: unknown kind {f.kind!r}; choose one of {', '.join(KINDS)}")
        if f.method not in fit_criteria.methods_for(f.kind):
            raise ProgramError(f"feature {f.name!r}: method {f.method!r} is not available for a {f.kind}; "
                               f"choose one of {', '.join(fit_criteria.methods_for(f.kind))}")
        missing = [i for i in f.hits if i not in known]
        if missing:
            raise ProgramError(f"feature {f.name!r} refers to hits {missing} that the program does not have")
        need = fit_ls.MIN_POINTS.get(f.kind, 1)
        if len(f.hits) < need:
            raise ProgramError(f"feature {f.name!r} ({f.kind}) needs at least {need} hits, the program has {len(f.hits)}")
        if f.nominal_ref is not None and f.nominal_ref not in nominals:
            raise ProgramError(f"feature {f.name!r} refers to the nominal feature {f.nominal_ref!r}, which the loaded "
                               f"part does not have (it has: {', '.join(nominals) or 'none'})")
        if f.nominal is not None:
            try:
                NominalFeature(f.nominal["kind"], {k: v for k, v in f.nominal.items() if k != "kind"})
            except (KeyError, ValueError, TypeError) as exc:
                raise ProgramError(f"feature {f.name!r}: its nominal is not valid ({exc})") from None
    if machine is not None and pose is not None:
        cfg = machine.config.probe
        r = cfg.tip_radius if tip_radius is None else tip_radius
        for h, p, u, cz in machine_targets(program, np.asarray(pose, float)):
            contact = p - r * u
            try:
                machine.check_target(contact - cfg.approach_distance * u)
                machine.check_target(contact + cfg.search_distance * u)
                machine.check_target([*(contact - cfg.approach_distance * u)[:2], cz])
            except Exception as exc:  # noqa: BLE001 - travel errors are operator sentences
                raise ProgramError(f"hit {h.id} cannot be reached on this set-up: {exc}") from None

"""Calibration certificates (inputs) and records (results) as TOML files.

Certificates describe artifacts (``kind = "sphere"`` or ``"ball_bar"``);
records hold what a routine found (``kind = "probe"``, ``"machine"``,
``"servo"``). Every file has an ``[artifact]`` or ``[record]`` table; values
are millimetres unless the key says otherwise (``_um``, ``_ppm``, ``_urad``).
Records are written atomically (temporary file + rename), so a failed or
interrupted routine never leaves a half-written record and the previous
calibration stays in force.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import tempfile
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..machine.geometry import GeometryCorrection
from ..metrology.compensation import ALL_PRETRAVEL_TERMS, PretravelModel
from ..metrology.numbers_text import finite
from ..program.toml_text import toml_key, toml_value

DEFAULT_DIR = Path("calibration")
PROBE_RECORD = "probe.toml"
MACHINE_RECORD = "machine.toml"
SERVO_RECORD = "servo.toml"
SPHERE_CERTIFICATE = "reference-sphere.toml"


class CalibrationError(RuntimeError):
    """A calibration that cannot go on, in an operator's words; the previous calibration stays in force."""


# ----------------------------------------------------------------- TOML in / out


def _read(path: str | Path, what: str) -> dict:
    p = Path(path)
    if not p.is_file():
        raise CalibrationError(f"{what} {p} is missing: create it (see calibration/README.md) or pass its path")
    try:
        return tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{what} {p} is not valid TOML: {exc}") from None


_value = toml_value


def dumps(data: dict, header: str = "") -> str:
    """A small TOML writer: nested dicts become tables; scalars, strings and (nested) lists."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]

    def table(prefix: str, d: dict) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        tables = {k: v for k, v in d.items() if isinstance(v, dict)}
        if prefix and (scalars or not tables):
            lines.append("")
            lines.append(f"[{prefix}]")
        for k, v in scalars.items():
            if v is not None:
                lines.append(f"{toml_key(k)} = {_value(v)}")
        for k, v in tables.items():
            table(f"{prefix}.{toml_key(k)}" if prefix else toml_key(k), v)

    table("", data)
    return "\n".join(lines).lstrip("\n") + "\n"


def write_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        tomllib.loads(text)  # never replace a record by something unreadable
        os.chmod(tmp, 0o644)  # mkstemp makes it private; records are for everyone to read
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


def now() -> str:
    return _dt.datetime.now().astimezone().isoformat(timespec="seconds")


# ----------------------------------------------------------------- validation helpers


def _num(src: str, table: dict, key: str, *, positive: bool = False, default: Any = ...) -> float:
    if key not in table:
        if default is not ...:
            return default
        raise CalibrationError(f"{src}: '{key}' is missing")
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise CalibrationError(f"{src}: '{key}' must be a number, got {v!r}")
    if positive and v <= 0:
        raise CalibrationError(f"{src}: '{key}' must be greater than 0, got {v!r}")
    return float(v)


def _vec(src: str, table: dict, key: str, n: int = 3, default: Any = ...) -> tuple[float, ...]:
    if key not in table:
        if default is not ...:
            return default
        raise CalibrationError(f"{src}: '{key}' is missing")
    v = table[key]
    if not isinstance(v, list) or len(v) != n or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v):
        raise CalibrationError(f"{src}: '{key}' must be a list of {n} numbers, got {v!r}")
    return tuple(float(x) for x in v)


def _table(src: str, data: dict, key: str) -> dict:
    t = data.get(key)
    if not isinstance(t, dict):
        raise CalibrationError(f"{src}: the [{key}] table is missing")
    return t


# ----------------------------------------------------------------- certificates


@dataclass(frozen=True)
class SphereCertificate:
    name: str
    diameter: float  # mm, certified
    form: float = 0.0  # mm, certified form deviation
    uncertainty: float = 0.0  # mm, expanded (k = 2) uncertainty of the diameter
    serial: str = ""
    certified: str = ""
    approx_centre: tuple[float, float, float] | None = None  # where it stands on the table (machine mm)
    source: str = ""

    def describe(self) -> str:
        return f"{self.name} {self.serial} D {self.diameter:.4f} mm".replace("  ", " ")


@dataclass(frozen=True)
class BallBarCertificate:
    name: str
    length: float  # mm, certified centre-to-centre distance
    ball_diameter: float  # mm (nominal; the centres are what matter)
    uncertainty: float = 0.0  # mm (k = 2)
    serial: str = ""
    certified: str = ""
    source: str = ""

    def describe(self) -> str:
        return f"{self.name} {self.serial} L {self.length:.4f} mm".replace("  ", " ")


def load_certificate(path: str | Path) -> SphereCertificate | BallBarCertificate:
    """Read and check an artifact certificate; CalibrationError names what is wrong."""
    src = str(path)
    data = _read(path, "artifact certificate")
    art = _table(src, data, "artifact")
    kind = art.get("kind")
    name = str(art.get("name", Path(path).stem))
    common = dict(name=name, serial=str(art.get("serial", "")), certified=str(art.get("certified", "")), source=src)
    if kind == "sphere":
        d = _num(src, art, "diameter", positive=True)
        form = _num(src, art, "form", default=0.0)
        if form < 0 or form > 0.01 * d:
            raise CalibrationError(f"{src}: 'form' {form} mm is not a plausible form deviation for a D {d} mm sphere")
        setup = data.get("setup", {})
        centre = _vec(src, setup, "centre", default=None) if isinstance(setup, dict) else None
        return SphereCertificate(diameter=d, form=form, uncertainty=_num(src, art, "uncertainty", default=0.0),
                                 approx_centre=centre, **common)
    if kind == "ball_bar":
        return BallBarCertificate(length=_num(src, art, "length", positive=True),
                                  ball_diameter=_num(src, art, "ball_diameter", positive=True),
                                  uncertainty=_num(src, art, "uncertainty", default=0.0), **common)
    raise CalibrationError(f"{src}: [artifact] kind must be \"sphere\" or \"ball_bar\", got {kind!r}")


def load_sphere_certificate(path: str | Path) -> SphereCertificate:
    cert = load_certificate(path)
    if not isinstance(cert, SphereCertificate):
        raise CalibrationError(f"{path}: expected a sphere certificate, found a {type(cert).__name__}")
    return cert


def load_ball_bar_certificate(path: str | Path) -> BallBarCertificate:
    cert = load_certificate(path)
    if not isinstance(cert, BallBarCertificate):
        raise CalibrationError(f"{path}: expected a ball bar certificate, found a {type(cert).__name__}")
    return cert


# ----------------------------------------------------------------- records


@dataclass
class ProbeRecord:
    """Probe qualification: effective radius + zero-mean directional pre-travel model.

    Convention: a sphere fitted to latched tip centres has radius D/2 + r_eff;
    the pre-travel constant and the stylus radius cannot be separated on one
    sphere, so ``tip_radius`` holds the effective radius (nominal radius minus
    the mean pre-travel) and ``pretravel`` only the directional part, with zero
    mean over the qualification pattern. Compensation: M = T - pretravel(u) u + tip_radius n.
    """

    date: str
    artifact: str
    tip_radius: float  # effective radius r_eff (mm)
    pretravel: dict[str, float]  # PretravelModel coefficients (mm), zero mean over the pattern
    nominal_tip_radius: float
    sphere_centre: tuple[float, float, float]
    tip_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sphere centre seen by this tip - master tip
    probing_speed: float = 0.0
    n_points: int = 0
    form_before_um: float = 0.0  # sphere form of the latched centres, constant pre-travel
    form_after_um: float = 0.0  # after the directional model
    uncertainty_um: float = 0.0  # expanded (k = 2) uncertainty of r_eff
    machine: str = ""
    note: str = ""
    # standard uncertainties (um) of the directional pre-travel coefficients the qualification fitted (e.g. z2,
    # s2_cos3, s2_sin3): what the compensation leaves by direction; and the scatter of one hit about the model
    pretravel_u_um: dict[str, float] = field(default_factory=dict)
    hit_sigma_um: float = 0.0
    pretravel_mean: dict[str, float] = field(default_factory=dict)  # each term's mean over the pattern (in r_eff)

    @property
    def model(self) -> PretravelModel:
        return PretravelModel(dict(self.pretravel))

    def to_dict(self) -> dict:
        return {
            "record": {"kind": "probe", "date": self.date, "artifact": self.artifact, "machine": self.machine,
                       "probing_speed": self.probing_speed, "note": self.note},
            "results": {"tip_radius": self.tip_radius, "nominal_tip_radius": self.nominal_tip_radius,
                        "sphere_centre": list(self.sphere_centre), "tip_offset": list(self.tip_offset),
                        "n_points": self.n_points, "form_before_um": self.form_before_um,
                        "form_after_um": self.form_after_um, "pretravel": dict(self.pretravel)},
            "uncertainty": {"tip_radius_um": self.uncertainty_um, "hit_sigma_um": self.hit_sigma_um,
                            "pretravel_um": dict(self.pretravel_u_um), "pretravel_mean": dict(self.pretravel_mean)},
        }


@dataclass
class MachineRecord:
    date: str
    artifact: str
    scale_ppm: tuple[float, float, float]
    squareness_urad: tuple[float, float, float]  # xy, xz, yz
    uncertainty_scale_ppm: float = 0.0
    uncertainty_squareness_urad: float = 0.0
    length_errors_before_um: dict[str, float] = field(default_factory=dict)
    length_errors_after_um: dict[str, float] = field(default_factory=dict)
    machine: str = ""
    note: str = ""

    @property
    def correction(self) -> GeometryCorrection:
        return GeometryCorrection(tuple(self.scale_ppm), tuple(self.squareness_urad))  # type: ignore[arg-type]

    def to_dict(self) -> dict:
        return {
            "record": {"kind": "machine", "date": self.date, "artifact": self.artifact, "machine": self.machine,
                       "note": self.note},
            "results": {"scale_ppm": list(self.scale_ppm), "squareness_urad": list(self.squareness_urad)},
            "uncertainty": {"scale_ppm": self.uncertainty_scale_ppm, "squareness_urad": self.uncertainty_squareness_urad},
            "verification": {"length_errors_before_um": dict(self.length_errors_before_um),
                             "length_errors_after_um": dict(self.length_errors_after_um)},
        }


@dataclass
class ServoRecord:
    date: str
    gains: dict[str, dict[str, int]]  # axis -> {kp, kd, ki, il}
    accepted: bool = False
    machine: str = ""
    note: str = ""

    def to_dict(self) -> dict:
        return {"record": {"kind": "servo", "date": self.date, "accepted": self.accepted, "machine": self.machine,
                           "note": self.note},
                "axes": {a: dict(g) for a, g in self.gains.items()}}


def save_record(record: ProbeRecord | MachineRecord | ServoRecord, path: str | Path) -> Path:
    kind = record.to_dict()["record"]["kind"]
    header = (f"{kind} calibration record written by `cmm calibrate` (units: mm unless the key says _um/_ppm/_urad).\n"
              "The station loads it at start; a new calibration replaces it atomically.")
    return write_atomic(path, dumps(record.to_dict(), header))


def _record_table(src: str, data: dict, kind: str) -> dict:
    rec = _table(src, data, "record")
    if rec.get("kind") != kind:
        raise CalibrationError(f"{src}: [record] kind must be \"{kind}\", got {rec.get('kind')!r}")
    return rec


def load_probe_record(path: str | Path) -> ProbeRecord:
    src = str(path)
    data = _read(path, "probe calibration record")
    rec = _record_table(src, data, "probe")
    res = _table(src, data, "results")
    pre = res.get("pretravel", {})
    if not isinstance(pre, dict):
        raise CalibrationError(f"{src}: [results.pretravel] must be a table of coefficients")
    unknown = set(pre) - set(ALL_PRETRAVEL_TERMS)
    if unknown:
        raise CalibrationError(f"{src}: unknown pre-travel terms {sorted(unknown)}; known: {', '.join(ALL_PRETRAVEL_TERMS)}")
    coef = {k: _num(src, pre, k) for k in pre}
    r = _num(src, res, "tip_radius", positive=True)
    unc = data.get("uncertainty", {})
    unc = unc if isinstance(unc, dict) else {}
    pre_u = unc.get("pretravel_um", {})
    pre_u = pre_u if isinstance(pre_u, dict) else {}
    pre_m = unc.get("pretravel_mean", {})
    pre_m = pre_m if isinstance(pre_m, dict) else {}
    return ProbeRecord(
        date=str(rec.get("date", "")), artifact=str(rec.get("artifact", "")), tip_radius=r, pretravel=coef,
        nominal_tip_radius=_num(src, res, "nominal_tip_radius", positive=True, default=r),
        sphere_centre=_vec(src, res, "sphere_centre", default=(0.0, 0.0, 0.0)),  # type: ignore[arg-type]
        tip_offset=_vec(src, res, "tip_offset", default=(0.0, 0.0, 0.0)),  # type: ignore[arg-type]
        probing_speed=_num(src, rec, "probing_speed", default=0.0), n_points=int(_num(src, res, "n_points", default=0)),
        form_before_um=_num(src, res, "form_before_um", default=0.0),
        form_after_um=_num(src, res, "form_after_um", default=0.0),
        uncertainty_um=_num(src, unc, "tip_radius_um", default=0.0),
        machine=str(rec.get("machine", "")), note=str(rec.get("note", "")),
        pretravel_u_um={k: _num(src, pre_u, k) for k in pre_u if k in ALL_PRETRAVEL_TERMS},
        hit_sigma_um=_num(src, unc, "hit_sigma_um", default=0.0),
        pretravel_mean={k: _num(src, pre_m, k) for k in pre_m if k in ALL_PRETRAVEL_TERMS})


def load_machine_record(path: str | Path) -> MachineRecord:
    src = str(path)
    data = _read(path, "machine calibration record")
    rec = _record_table(src, data, "machine")
    res = _table(src, data, "results")
    scale = _vec(src, res, "scale_ppm")
    sq = _vec(src, res, "squareness_urad")
    for k, v in (("scale_ppm", scale), ("squareness_urad", sq)):
        if any(abs(x) > 5000 for x in v):
            raise CalibrationError(f"{src}: '{k}' {list(v)} is implausibly large (above 5000): check the record")
    unc = data.get("uncertainty", {})
    ver = data.get("verification", {})
    return MachineRecord(date=str(rec.get("date", "")), artifact=str(rec.get("artifact", "")),
                         scale_ppm=scale, squareness_urad=sq,  # type: ignore[arg-type]
                         uncertainty_scale_ppm=_num(src, unc, "scale_ppm", default=0.0),
                         uncertainty_squareness_urad=_num(src, unc, "squareness_urad", default=0.0),
                         length_errors_before_um=dict(ver.get("length_errors_before_um", {})),
                         length_errors_after_um=dict(ver.get("length_errors_after_um", {})),
                         machine=str(rec.get("machine", "")), note=str(rec.get("note", "")))


def load_servo_record(path: str | Path) -> ServoRecord:
    src = str(path)
    data = _read(path, "servo tuning record")
    rec = _record_table(src, data, "servo")
    axes = _table(src, data, "axes")
    gains: dict[str, dict[str, int]] = {}
    for axis, g in axes.items():
        if axis not in ("x", "y", "z") or not isinstance(g, dict):
            raise CalibrationError(f"{src}: [axes.{axis}] is not an axis table (x, y or z)")
        gains[axis] = {k: int(_num(src, g, k)) for k in g}
    return ServoRecord(date=str(rec.get("date", "")), gains=gains, accepted=bool(rec.get("accepted", False)),
                       machine=str(rec.get("machine", "")), note=str(rec.get("note", "")))


@dataclass
class LoadedCalibration:
    """What the station applies at start (None where no record exists); ``problems`` lists refused files."""

    probe: ProbeRecord | None = None
    machine: MachineRecord | None = None
    problems: list[str] = field(default_factory=list)
    probing_test: dict | None = None  # the ISO 10360-5 test's calibrated figures (date, form_um, size_um)


def load_station_calibration(directory: str | Path = DEFAULT_DIR) -> LoadedCalibration:
    """Load calibration/probe.toml and calibration/machine.toml if present; a bad file is reported, not applied."""
    d = Path(directory)
    out = LoadedCalibration()
    for name, loader, attr in ((PROBE_RECORD, load_probe_record, "probe"), (MACHINE_RECORD, load_machine_record, "machine")):
        if (d / name).is_file():
            try:
                setattr(out, attr, loader(d / name))
            except CalibrationError as exc:
                out.problems.append(str(exc))
    out.probing_test = _probing_test(d / ISO_RECORD, out.probe)
    return out


ISO_RECORD = "iso10360-5.toml"


def _probing_test(path: Path, probe: ProbeRecord | None) -> dict | None:
    """The ISO 10360-5 test's calibrated figures when it was run with the qualification in force (dated no
    earlier than it), else None."""
    if not path.is_file():
        return None
    try:
        data = tomllib.loads(path.read_text())
        cal = data.get("results", {}).get("calibrated", {})
        date = str(data.get("record", {}).get("date", ""))
        fig = {"date": date, "form_um": float(cal["form_um"]), "size_um": float(cal["size_um"])}
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError, AttributeError):
        return None
    if not all(math.isfinite(v) for v in (fig["form_um"], fig["size_um"])):
        return None
    if probe is not None and date < probe.date:
        return None
    return fig


def apply_calibration(loaded: LoadedCalibration, machine: Any, prober: Any) -> list[str]:
    """Apply loaded records: machine.correction and prober.settings. Returns what was applied, for a log."""
    from ..machine.probing import ProbeSettings

    done = []
    if loaded.machine is not None:
        machine.correction = loaded.machine.correction
        machine.geometry_record = loaded.machine  # its uncertainties feed the measurement uncertainty budget
        done.append(f"machine geometry from {loaded.machine.date}: scale {loaded.machine.scale_ppm} ppm, "
                    f"squareness {loaded.machine.squareness_urad} urad")
    if loaded.probing_test is not None or loaded.probe is not None:  # a new qualification voids an older test
        machine.probing_test = loaded.probing_test
    if loaded.probe is not None:
        prober.settings = ProbeSettings(loaded.probe.tip_radius, loaded.probe.model, record=loaded.probe)
        done.append(f"probe from {loaded.probe.date}: r_eff {loaded.probe.tip_radius:.4f} mm, "
                    f"{loaded.probe.model.describe()}")
    return done


# ----------------------------------------------------------------- the probe list and the sphere certificate

PROBE_LIST = "probes.toml"
PROBE_QUALIFICATIONS = "probes"  # <records>/probes/<name>.toml: each probe's last qualification (a probe record)
PROBE_VALIDITY_DAYS = 30  # a qualification older than this is shown as expired
_PROBE_NAME = __import__("re").compile(r"^[A-Za-z0-9_-]{1,32}$")


@dataclass(frozen=True)
class ProbeDefinition:
    """A stylus on the probe head: what the operator declares before qualifying it."""

    name: str
    tip_diameter: float  # mm, nominal
    stylus: tuple[float, float, float] = (0.0, 0.0, -1.0)  # stylus vector, head to tip (machine axes)


def check_probe_name(name: str) -> str:
    name = str(name).strip()
    if not _PROBE_NAME.match(name):
        raise CalibrationError(f"the probe name {name!r} must be 1 to 32 letters, digits, '-' or '_' (e.g. T1, "
                               "D2-down)")
    return name


def check_probe_definition(name: str, tip_diameter: Any, stylus: Any = (0.0, 0.0, -1.0)) -> ProbeDefinition:
    """A probe definition from the operator's fields; CalibrationError says what is wrong."""
    name = check_probe_name(name)
    try:
        d = float(tip_diameter)
    except (TypeError, ValueError):
        raise CalibrationError(f"the tip diameter of {name} must be a number in mm, got {tip_diameter!r}") from None
    if not math.isfinite(d) or not 0.1 <= d <= 30.0:
        raise CalibrationError(f"the tip diameter of {name} must be between 0.1 and 30 mm, got {tip_diameter!r}")
    try:
        v = tuple(float(x) for x in stylus)
    except (TypeError, ValueError):
        v = ()
    if len(v) != 3 or not all(math.isfinite(x) for x in v) or not any(v):
        raise CalibrationError(f"the stylus vector of {name} must be three numbers, not all 0, got {stylus!r}")
    return ProbeDefinition(name, d, v)  # type: ignore[arg-type]


def load_probe_list(directory: str | Path) -> tuple[list[ProbeDefinition], str | None]:
    """(probes, selected name) from <directory>/probes.toml; ([], None) when there is no list yet."""
    path = Path(directory) / PROBE_LIST
    if not path.is_file():
        return [], None
    src = str(path)
    data = _read(path, "probe list")
    table = data.get("probes", {})
    if not isinstance(table, dict):
        raise CalibrationError(f"{src}: [probes] must hold one table per probe")
    out = []
    for name, t in table.items():
        if not isinstance(t, dict):
            raise CalibrationError(f"{src}: [probes.{name}] must be a table")
        try:
            out.append(check_probe_definition(name, t.get("tip_diameter"), t.get("stylus", (0.0, 0.0, -1.0))))
        except CalibrationError as exc:
            raise CalibrationError(f"{src}: {exc}") from None
    selected = data.get("selected")
    if selected is not None and selected not in {p.name for p in out}:
        raise CalibrationError(f"{src}: the selected probe {selected!r} is not in the list")
    return out, selected


def save_probe_list(directory: str | Path, probes: list[ProbeDefinition], selected: str | None) -> Path:
    data: dict[str, Any] = {"selected": selected,
                            "probes": {p.name: {"tip_diameter": p.tip_diameter, "stylus": list(p.stylus)}
                                       for p in probes}}
    return write_atomic(Path(directory) / PROBE_LIST, dumps(
        data, "The probe list of the station (styli on the head; mm). Written by the Calibration tab;\n"
              "each probe's qualification is in probes/<name>.toml, the selected one's also in probe.toml."))


def probe_expiry(date: str, days: int = PROBE_VALIDITY_DAYS) -> str:
    """The date a qualification done on ``date`` (ISO) expires ("" when the date is unreadable)."""
    try:
        return (_dt.datetime.fromisoformat(date) + _dt.timedelta(days=days)).date().isoformat()
    except (TypeError, ValueError):
        return ""


def write_sphere_certificate(path: str | Path, *, diameter: Any, serial: str, uncertainty: Any, form: Any = 0.0,
                             centre: Any = None, name: str = "reference sphere",
                             certified: str | None = None) -> SphereCertificate:
    """Write the reference sphere's certificate as the operator entered it (uncertainty and form in mm, the
    certificate's date YYYY-MM-DD, default today); checked before it replaces the old one, so a bad entry leaves
    the previous certificate."""
    def number(v: Any, what: str) -> float:
        try:
            return finite(v, f"the sphere's {what}")
        except ValueError as e:
            raise CalibrationError(str(e)) from None

    d = number(diameter, "diameter")
    if not 1.0 <= d <= 200.0:
        raise CalibrationError(f"the sphere's diameter must be between 1 and 200 mm, got {diameter!r}")
    u = number(uncertainty, "uncertainty")
    if not 0.0 <= u <= 0.01:
        raise CalibrationError(f"the sphere's uncertainty must be between 0 and 0.01 mm (10 um), got {uncertainty!r} "
                               "(enter it in mm: 0.0001 for 0.1 um)")
    f = number(form, "form deviation")
    if not 0.0 <= f <= 0.01 * d:
        raise CalibrationError(f"the sphere's form deviation {form!r} mm is not plausible for a D {d} mm sphere")
    serial = str(serial or "").strip()
    if not serial:
        raise CalibrationError("enter the sphere's serial number as on its certificate")
    day = _dt.date.today()
    if str(certified or "").strip():
        try:
            day = _dt.date.fromisoformat(str(certified).strip())
        except ValueError:
            raise CalibrationError(f"the certificate's date must be written YYYY-MM-DD, got {certified!r}") from None
        if day > _dt.date.today():
            raise CalibrationError(f"the certificate's date {day.isoformat()} is in the future")
    data: dict[str, Any] = {"artifact": {"kind": "sphere", "name": name, "serial": serial, "diameter": d, "form": f,
                                         "uncertainty": u, "certified": day.isoformat()}}
    if centre is not None:
        data["setup"] = {"centre": [number(c, "set-up centre") for c in centre]}
    p = write_atomic(path, dumps(data, "Certificate of the reference sphere, entered in the Calibration tab.\n"
                                       "Units: mm. uncertainty: expanded (k = 2) uncertainty of the diameter."))
    return load_sphere_certificate(p)

"""The inputs of the uncertainty budget (cmm.metrology.uncertainty.Sources) from the station's own data, each
term saying where its input came from.

- probe: the qualification record in force (``ProbeRecord``): the effective radius's uncertainty (k = 2 in the
  record), the standard uncertainties of the directional pre-travel coefficients the compensation applies, and the
  scatter of one hit about the model; an ISO 10360-5 probing test's size error P_Size (when one was run after
  the qualification) widens the radius term by a rectangular +-P_Size / 2. Without a record: the probe's nominal
  figures (configuration or defaults) with the lobing and Z/XY terms of an uncompensated probe.
- machine: the geometry calibration record (ball bar) in force: the standard uncertainty of its scale and
  squareness (half the record's k = 2 values), else the configured length-measuring MPE ``A + L / K``.
- thermal: the part temperature of the session (the report header's, typed on the page) or the configuration,
  the configured allowance, expansion coefficient and its uncertainty, and the scales' temperature and CTE.

The configuration's ``[uncertainty]`` table (the machine TOML; keys are the fields of ``Sources``) holds the
configured values; ``config_table`` reads and checks it.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

from .uncertainty import Sources

NUMBER_KEYS = ("u_tip", "lobing", "z_xy", "repeatability", "mpe_a_um", "mpe_k", "scale_u", "squareness_u",
               "temperature", "temperature_allowance", "cte", "cte_u", "form_prior", "scale_temperature", "scale_cte")


class UncertaintyConfigError(ValueError):
    """A wrong ``[uncertainty]`` table, in an operator's words."""


def check_table(table: Any, source: str = "<config>") -> dict[str, float]:
    """The ``[uncertainty]`` table checked: known keys, finite numbers, no negative uncertainties."""
    if table is None:
        return {}
    if not isinstance(table, dict):
        raise UncertaintyConfigError(f"{source}: [uncertainty] must be a table of numbers")
    out: dict[str, float] = {}
    for k, v in table.items():
        if k not in NUMBER_KEYS:
            raise UncertaintyConfigError(f"{source}: [uncertainty.{k}] is not a known setting; known: "
                                         f"{', '.join(NUMBER_KEYS)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise UncertaintyConfigError(f"{source}: [uncertainty.{k}] must be a number, got {v!r}")
        if k not in ("temperature", "scale_temperature") and v < 0:
            raise UncertaintyConfigError(f"{source}: [uncertainty.{k}] must not be negative, got {v!r}")
        if k == "mpe_k" and v <= 0:
            raise UncertaintyConfigError(f"{source}: [uncertainty.mpe_k] must be greater than 0, got {v!r}")
        out[k] = float(v)
    return out


def config_table(config: Any) -> dict[str, float]:
    """The ``[uncertainty]`` table of the machine configuration file ``config.source`` ({} when it has none or the
    configuration is the shipped default); a wrong table gives {} here (the configuration's load refuses it)."""
    source = getattr(config, "source", None)
    if not source or not Path(str(source)).is_file():
        return {}
    try:
        return check_table(tomllib.loads(Path(str(source)).read_text()).get("uncertainty"), str(source))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError, UncertaintyConfigError):
        return {}


def probe_sources(record: Any, base: Sources | None = None, probing_test: dict | None = None,
                  **overrides: Any) -> Sources:
    """``base`` with the probe terms of a qualification record (cmm.calibration.records.ProbeRecord)."""
    src = base or Sources()
    origin = dict(src.origin or {})
    if record is None:
        return replace(src, **overrides) if overrides else src
    when = f"probe record {str(getattr(record, 'date', ''))[:10]}".strip()
    u_tip = float(record.uncertainty_um) / 2 / 1000 if record.uncertainty_um > 0 else src.u_tip
    note = when
    if probing_test:  # P_Size of the calibrated probe on the test sphere: a radius error of P_Size / 2
        size = float(probing_test.get("size_um", 0.0)) / 1000
        u_tip = math.sqrt(u_tip ** 2 + (size / 2) ** 2 / 3)
        note += f", ISO 10360-5 P_Size {size * 1000:+.2f} um"
    origin["probe qualification"] = note
    changes: dict[str, Any] = {"u_tip": u_tip}
    coef_u = {k: float(v) / 1000 for k, v in (record.pretravel_u_um or {}).items() if k != "const"}
    directional = {k for k, v in record.pretravel.items() if k != "const" and v}
    if coef_u or directional:  # a directional model is applied: its coefficients' uncertainties are what is left
        changes["pretravel_u"] = {k: coef_u.get(k, 0.0) for k in sorted(set(coef_u) | directional)}
        changes["pretravel_mean"] = {k: float(v) for k, v in (record.pretravel_mean or {}).items()}
        origin["probe direction"] = when
    else:  # an isotropic qualification: the lobing and Z/XY difference stay as the nominal figures say
        origin.setdefault("probe lobing", "nominal probe figures (not modelled by the qualification)")
        origin.setdefault("probe Z/XY", "nominal probe figures (not modelled by the qualification)")
    if record.hit_sigma_um > 0:
        changes["repeatability"] = float(record.hit_sigma_um) / 1000
        origin["scatter"] = f"{when}, single-hit scatter about the model"
    changes["origin"] = origin
    return replace(src, **changes, **overrides)


def machine_sources(record: Any, base: Sources) -> Sources:
    """``base`` with the machine terms of a geometry calibration record (cmm.calibration.records.MachineRecord)."""
    origin = dict(base.origin or {})
    if record is None:
        return base
    when = f"geometry record {str(getattr(record, 'date', ''))[:10]}"
    changes: dict[str, Any] = {}
    if record.uncertainty_scale_ppm > 0:
        changes["scale_u"] = record.uncertainty_scale_ppm / 2 * 1e-6
        origin["machine scale"] = when
    if record.uncertainty_squareness_urad > 0:
        changes["squareness_u"] = record.uncertainty_squareness_urad / 2 * 1e-6
        origin["machine squareness"] = when
    return replace(base, **changes, origin=origin)


def station_sources(config: Any = None, *, probe_record: Any = None, machine_record: Any = None,
                    probing_test: dict | None = None, temperature: Any = None,
                    reference: Any = None) -> Sources:
    """The budget's inputs for a station: defaults, then the configuration's ``[uncertainty]`` table, then the
    calibration records in force, then the session's part ``temperature`` (C, the report header's)."""
    table = config_table(config)
    known = {f.name for f in fields(Sources)}
    src = Sources(**{k: v for k, v in table.items() if k in known})
    cfg = f"configuration {Path(str(getattr(config, 'source', ''))).name}"
    origin: dict[str, str] = {}
    for term, keys in (("probe qualification", ("u_tip",)), ("probe lobing", ("lobing",)), ("probe Z/XY", ("z_xy",)),
                       ("scatter", ("repeatability",)), ("sampling", ("form_prior",))):
        if any(k in table for k in keys):
            origin[term] = cfg
    if any(k in table for k in ("mpe_a_um", "mpe_k")):
        origin["machine scale"] = origin["machine squareness"] = \
            f"{cfg}: MPE {src.mpe_a_um:g} + L/{src.mpe_k:g} um"
    else:
        origin["machine scale"] = origin["machine squareness"] = f"default MPE {src.mpe_a_um:g} + L/{src.mpe_k:g} um"
    for k in ("scale_u", "squareness_u"):
        if k in table:
            origin["machine " + k.split("_")[0]] = cfg
    thermal = []
    if temperature not in (None, ""):
        src = replace(src, temperature=float(temperature))
        thermal.append(f"session temperature {float(temperature):g} C")
    elif "temperature" in table:
        thermal.append(f"{cfg}: {src.temperature:g} C")
    else:
        thermal.append("default 20 C")
    if any(k in table for k in ("temperature_allowance", "cte", "cte_u", "scale_temperature", "scale_cte")):
        thermal.append(f"{cfg}: CTE, allowance")
    origin["thermal"] = "; ".join(thermal)
    src = replace(src, origin=origin,
                  reference=None if reference is None else tuple(float(v) for v in reference))
    src = probe_sources(probe_record, src, probing_test)
    return machine_sources(machine_record, src)


def model_sources(model: Any, reference: Any = None) -> Sources:
    """The inputs for a measurement model (cmm.measurement.model.MeasurementModel): its machine's configuration,
    the probe record of its prober's settings, the geometry record and probing test its machine carries (set when
    the calibration is applied) and the session's temperature."""
    settings = getattr(getattr(model, "prober", None), "settings", None)
    machine = getattr(model, "machine", None)
    info = getattr(model, "info", None) or {}
    try:
        temperature = info.get("temperature")
    except AttributeError:
        temperature = None
    return station_sources(getattr(model, "config", None), probe_record=getattr(settings, "record", None),
                           machine_record=getattr(machine, "geometry_record", None),
                           probing_test=getattr(machine, "probing_test", None), temperature=temperature,
                           reference=reference)

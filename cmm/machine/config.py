"""Machine configuration: a TOML file the user can read, copy and edit.

Every value is checked on load and a problem is reported as a sentence that
names the file, the key and what is allowed.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any

from ..nmc.codec import BAUD_DIVISORS, Gains

AXES = ("x", "y", "z")


class ConfigError(ValueError):
    """A machine configuration that cannot be used, in an operator's words."""


@dataclass(frozen=True)
class AxisConfig:
    name: str
    address: int
    counts_per_mm: float = 500.0
    direction: int = 1
    min: float = 0.0
    max: float = 500.0
    home: float = 0.0
    gains: Gains = field(default_factory=Gains)

    def to_counts(self, mm: float) -> int:
        return round((mm - self.home) * self.counts_per_mm * self.direction)

    def to_mm(self, counts: float) -> float:
        return self.home + counts / (self.counts_per_mm * self.direction)


@dataclass(frozen=True)
class Speeds:
    positioning: float = 50.0
    probing: float = 2.0
    jog_fast: float = 40.0
    jog_slow: float = 10.0
    jog_fine: float = 1.0


@dataclass(frozen=True)
class Accelerations:
    positioning: float = 400.0
    probing: float = 400.0
    jog: float = 400.0
    stop: float = 1000.0


@dataclass(frozen=True)
class ProbeConfig:
    input: str = "limit1"
    active_level: str = "high"
    tip_radius: float = 1.0
    pretravel: float = 0.0
    approach_distance: float = 2.0
    search_distance: float = 3.0
    retract_distance: float = 1.0


@dataclass(frozen=True)
class LinkConfig:
    port: str = "sim"
    baud: int = 115200
    firmware: str = "pic-servo"
    read_following_error: bool = True  # status item 0x40 (SC firmware and the simulator); false on original PIC-SERVOs


@dataclass(frozen=True)
class MachineConfig:
    link: LinkConfig
    axes: tuple[AxisConfig, AxisConfig, AxisConfig]
    speeds: Speeds
    accelerations: Accelerations
    probe: ProbeConfig
    deadman_timeout: float = 0.15
    source: str = "<defaults>"

    def axis(self, name: str) -> AxisConfig:
        return self.axes[AXES.index(name)]

    def with_link(self, **changes: Any) -> "MachineConfig":
        return replace(self, link=replace(self.link, **changes))


def _fail(source: str, key: str, message: str) -> ConfigError:
    return ConfigError(f"{source}: [{key}] {message}")


def _number(source: str, key: str, value: Any, *, positive: bool = False, integer: bool = False) -> Any:
    ok_type = int if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, ok_type) or not math.isfinite(value):
        raise _fail(source, key, f"must be {'an integer' if integer else 'a number'}, got {value!r}")
    if positive and value <= 0:
        raise _fail(source, key, f"must be greater than 0, got {value!r}")
    return value if integer else float(value)


def _section(source: str, name: str, data: dict, cls: type, *, positive: bool = True) -> Any:
    known = {f.name: f for f in fields(cls)}
    values = {}
    for key, value in data.items():
        if key not in known:
            raise _fail(source, f"{name}.{key}", f"is not a known setting; known: {', '.join(known)}")
        if isinstance(known[key].default, (int, float)) and not isinstance(known[key].default, bool):
            value = _number(source, f"{name}.{key}", value, positive=positive)
        values[key] = value
    return cls(**values)


def _gains(source: str, key: str, data: dict, base: Gains) -> Gains:
    known = {f.name for f in fields(Gains)}
    values = {}
    for k, v in data.items():
        if k not in known:
            raise _fail(source, f"{key}.{k}", f"is not a servo gain; known: {', '.join(sorted(known))}")
        values[k] = _number(source, f"{key}.{k}", v, integer=True)
    gains = replace(base, **values)
    try:
        gains.to_bytes()
    except ValueError as exc:
        raise _fail(source, key, str(exc)) from None
    return gains


def parse(data: dict, source: str = "<config>") -> MachineConfig:
    """Build a validated configuration from parsed TOML."""
    unknown = set(data) - {"link", "axes", "speeds", "accelerations", "jog", "gains", "probe"}
    if unknown:
        raise _fail(source, sorted(unknown)[0], "is not a known section")
    link = LinkConfig(**{k: v for k, v in data.get("link", {}).items()})
    if link.firmware not in BAUD_DIVISORS:
        raise _fail(source, "link.firmware", f"must be one of {', '.join(BAUD_DIVISORS)}, got {link.firmware!r}")
    if link.baud not in BAUD_DIVISORS[link.firmware]:
        raise _fail(source, "link.baud", f"{link.baud} is not available on {link.firmware}; "
                    f"choose one of {sorted(BAUD_DIVISORS[link.firmware])}")
    gains = _gains(source, "gains", data.get("gains", {}), Gains())
    axes_data = data.get("axes", {})
    axes = []
    for name in AXES:
        if name not in axes_data:
            raise _fail(source, f"axes.{name}", "is missing: the station needs X, Y and Z axes")
        a = dict(axes_data[name])
        axis_gains = _gains(source, f"axes.{name}.gains", a.pop("gains", {}), gains)
        for k in ("min", "max", "home"):
            if k in a:
                a[k] = _number(source, f"axes.{name}.{k}", a[k])
        if "address" not in a:
            raise _fail(source, f"axes.{name}.address", "is missing")
        address = _number(source, f"axes.{name}.address", a["address"], integer=True)
        if not 1 <= address <= 0x7F:
            raise _fail(source, f"axes.{name}.address", f"must be a module address 1..127, got {address}")
        if "counts_per_mm" in a:
            a["counts_per_mm"] = _number(source, f"axes.{name}.counts_per_mm", a["counts_per_mm"], positive=True)
        if a.get("direction", 1) not in (1, -1):
            raise _fail(source, f"axes.{name}.direction", f"must be 1 or -1, got {a['direction']!r}")
        try:
            axis = AxisConfig(name=name, gains=axis_gains, **a)
        except TypeError as exc:
            raise _fail(source, f"axes.{name}", f"has an unknown setting ({exc})") from None
        if axis.min >= axis.max:
            raise _fail(source, f"axes.{name}", f"travel min {axis.min} must be below max {axis.max}")
        axes.append(axis)
    if len({a.address for a in axes}) != 3:
        raise _fail(source, "axes", "each axis needs its own module address")
    speeds = _section(source, "speeds", data.get("speeds", {}), Speeds)
    acc = _section(source, "accelerations", data.get("accelerations", {}), Accelerations)
    probe_data = dict(data.get("probe", {}))
    probe = _section(source, "probe", {k: v for k, v in probe_data.items()}, ProbeConfig, positive=False)
    if probe.input not in ("limit1", "limit2"):
        raise _fail(source, "probe.input", f"must be limit1 or limit2, got {probe.input!r}")
    if probe.active_level not in ("high", "low"):
        raise _fail(source, "probe.active_level", f"must be high or low, got {probe.active_level!r}")
    for k in ("tip_radius", "approach_distance", "search_distance", "retract_distance"):
        if getattr(probe, k) <= 0:
            raise _fail(source, f"probe.{k}", f"must be greater than 0, got {getattr(probe, k)}")
    deadman = _number(source, "jog.deadman_timeout", data.get("jog", {}).get("deadman_timeout", 0.15), positive=True)
    if deadman + speeds.jog_fast / acc.stop > 0.2 + 1e-9:
        raise _fail(source, "jog", f"a released jog must stop within 0.2 s: deadman_timeout {deadman} s plus "
                    f"jog_fast / accelerations.stop = {speeds.jog_fast / acc.stop:.3f} s is longer")
    return MachineConfig(link, tuple(axes), speeds, acc, probe, deadman, source)  # type: ignore[arg-type]


def default_text() -> str:
    return resources.files("cmm.data").joinpath("machine.toml").read_text()


def load(path: str | Path | None = None) -> MachineConfig:
    """Load a configuration file (the shipped default when ``path`` is None)."""
    if path is None:
        return parse(tomllib.loads(default_text()), "default machine.toml")
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read machine configuration {p}: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    return parse(data, str(p))

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
from typing import Any, Sequence

import numpy as np

from ..nmc.codec import BAUD_DIVISORS, Gains
from .geometry import GeometryCorrection

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

    def to_mm(self, counts: Any) -> Any:
        """Counts (a number or an array) -> the axis reading in mm."""
        return self.home + counts / (self.counts_per_mm * self.direction)

    def rate_to_mm(self, counts_per_s: float) -> float:
        """A rate in counts per second -> mm/s along the axis."""
        return counts_per_s / (self.counts_per_mm * self.direction)

    def snapshot(self) -> dict:
        """The fields that convert its counts, as a session's ``start`` event records them."""
        return {"name": self.name, "counts_per_mm": self.counts_per_mm, "direction": self.direction,
                "home": self.home, "min": self.min, "max": self.max}

    @classmethod
    def from_snapshot(cls, d: dict) -> "AxisConfig":
        """The axis as a session recorded it (:meth:`snapshot`): its conversion and travel; address and gains are
        not recorded and do not convert."""
        return cls(str(d["name"]), int(d.get("address", 0)), float(d["counts_per_mm"]), int(d["direction"]),
                   float(d.get("min", 0.0)), float(d.get("max", 500.0)), float(d["home"]))


def counts_to_mm(counts: Any, axes: Sequence[AxisConfig], correction: GeometryCorrection | None = None) -> np.ndarray:
    """Raw axis counts (one count per axis, or n rows of them) -> machine coordinates in mm: each axis's home,
    scale and direction, then the geometry correction. The one conversion: the machine's positions and hits, and
    a session's hits in re-evaluation (with the axes and correction it recorded), go through it."""
    c = np.asarray(counts, dtype=np.float64)
    if c.shape == (len(axes),):  # one reading (every sample): the same float64 arithmetic on plain floats
        readings = np.array([a.to_mm(v) for a, v in zip(axes, c.tolist())])
    else:
        readings = np.stack([a.to_mm(c[..., i]) for i, a in enumerate(axes)], axis=-1)
    if correction is None or correction.is_identity:
        return readings
    return readings @ correction.matrix.T


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
    process: str = "auto"  # link process (cmm/nmc/link_process.py): "auto" = own process for real ports, "same"


@dataclass(frozen=True)
class JogConfig:
    """How jogs are commanded.

    ``horizon``: a chain of position-mode moves whose goal is at most ``horizon``
    seconds of travel ahead (clamped to the travel), re-targeted by the machine
    loop on every sample; if the station stops refreshing or dies, the modules
    themselves stop at the last goal. Needs firmware that accepts a new
    trapezoidal goal while moving (the simulator does). ``velocity``: velocity
    mode (legal on every PIC-SERVO firmware); only the loop's dead-man stops it.
    """

    mode: str = "horizon"
    horizon: float = 0.12  # s of travel; must exceed the stopping time v / (2 a) of jog_fast
    deadman_timeout: float = 0.15


@dataclass(frozen=True)
class HomingConfig:
    """The homing cycle the station runs before it measures.

    ``switch``: each axis seeks a home switch on ``input`` (LIMIT2 by default)
    at its home end, backs off, approaches it again slowly with home capture
    armed, and the captured position becomes the axis's ``home`` coordinate.
    ``none``: the counters are trusted as they are at start-up (a machine
    without switches; the operator can still Zero with confirmation).
    """

    method: str = "switch"
    input: str = "limit2"
    active_level: str = "high"
    order: tuple[str, ...] = ("z", "xy")  # groups of axes homed together, in turn
    speed: float = 20.0  # seek speed, mm/s
    latch_speed: float = 2.0  # final approach, mm/s
    backoff: float = 1.0  # mm off the switch before the slow approach
    search: float = 0.0  # mm to search for the switch; 0 = the whole travel + 10 mm


@dataclass(frozen=True)
class MachineConfig:
    link: LinkConfig
    axes: tuple[AxisConfig, AxisConfig, AxisConfig]
    speeds: Speeds
    accelerations: Accelerations
    probe: ProbeConfig
    deadman_timeout: float = 0.15
    source: str = "<defaults>"
    jog: JogConfig = field(default_factory=JogConfig)
    homing: HomingConfig = field(default_factory=HomingConfig)

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
    # [notify]: the station's notifications, read by cmm.session.notify from the same file
    # [uncertainty]: the measurement uncertainty budget's inputs, read by cmm.metrology.uncertainty_inputs
    unknown = set(data) - {"link", "axes", "speeds", "accelerations", "jog", "gains", "probe", "homing", "notify",
                           "uncertainty"}
    if unknown:
        raise _fail(source, sorted(unknown)[0], "is not a known section")
    if "uncertainty" in data:
        from ..metrology.uncertainty_inputs import UncertaintyConfigError, check_table

        try:
            check_table(data["uncertainty"], source)
        except UncertaintyConfigError as exc:
            raise ConfigError(str(exc)) from None
    link = LinkConfig(**{k: v for k, v in data.get("link", {}).items()})
    if link.process not in ("auto", "same"):
        raise _fail(source, "link.process", f"must be \"auto\" or \"same\", got {link.process!r}")
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
    jog = _section(source, "jog", data.get("jog", {}), JogConfig)
    if jog.mode not in ("horizon", "velocity"):
        raise _fail(source, "jog.mode", f"must be horizon or velocity, got {jog.mode!r}")
    if jog.horizon <= speeds.jog_fast / (2 * acc.jog):
        raise _fail(source, "jog.horizon", f"{jog.horizon} s is shorter than the jog's stopping time "
                    f"jog_fast / (2 accelerations.jog) = {speeds.jog_fast / (2 * acc.jog):.3f} s")
    deadman = jog.deadman_timeout
    homing = _homing(source, dict(data.get("homing", {})))
    if homing.method == "switch" and homing.input == probe.input:
        raise _fail(source, "homing.input", f"the home switches need their own input; {probe.input} is the probe's")
    if deadman + speeds.jog_fast / acc.stop > 0.2 + 1e-9:
        raise _fail(source, "jog", f"a released jog must stop within 0.2 s: deadman_timeout {deadman} s plus "
                    f"jog_fast / accelerations.stop = {speeds.jog_fast / acc.stop:.3f} s is longer")
    return MachineConfig(link, tuple(axes), speeds, acc, probe, deadman, source, jog, homing)  # type: ignore[arg-type]


def _homing(source: str, data: dict) -> HomingConfig:
    order = data.pop("order", None)
    homing = _section(source, "homing", data, HomingConfig, positive=False)
    for k in ("speed", "latch_speed", "backoff"):
        if getattr(homing, k) <= 0:
            raise _fail(source, f"homing.{k}", f"must be greater than 0, got {getattr(homing, k)}")
    if homing.search < 0:
        raise _fail(source, "homing.search", f"must be 0 (whole travel) or more, got {homing.search}")
    if homing.method not in ("switch", "none"):
        raise _fail(source, "homing.method", f"must be switch or none, got {homing.method!r}")
    if homing.input not in ("limit1", "limit2"):
        raise _fail(source, "homing.input", f"must be limit1 or limit2, got {homing.input!r}")
    if homing.active_level not in ("high", "low"):
        raise _fail(source, "homing.active_level", f"must be high or low, got {homing.active_level!r}")
    if order is not None:
        if not isinstance(order, list) or not all(isinstance(g, str) and g and set(g) <= set(AXES) for g in order) \
                or sorted("".join(order)) != sorted(AXES):
            raise _fail(source, "homing.order", f"must list groups of axes covering x, y and z once, e.g. "
                        f'["z", "xy"]; got {order!r}')
        homing = replace(homing, order=tuple(order))
    return homing


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

"""``sim://`` URLs: an in-process simulated NMC network opened like any serial port.

    sim://[NAME][?cmm=1][&modules=N][&firmware=pic-servo|pic-servo-sc][&module_version=V]
               [&clock=virtual|realtime][&pace=X][&wire=1|0][&config=PATH]

- ``cmm=1``: the whole simulated CMM (three axes, part, reference sphere, probe on
  the LIMIT inputs; ``config`` is its machine configuration, default the shipped
  one, whose firmware it runs unless ``firmware`` says otherwise); otherwise
  ``modules`` bare modules (default 3, firmware pic-servo).
- ``clock=virtual`` (default): simulated time advances only while the host waits
  (reads, ``sleep``), as fast as the CPU allows, or at most ``pace`` simulated
  seconds per wall second (pace=1: a background poll thread keeps step with
  callers acting in wall time). ``clock=realtime``: the wall clock.
- ``wire=1`` (default): every byte takes 10 bits at its line rate each way.
- The port's ``baudrate`` is the host's line rate: after SET_BAUD the host must
  switch, as on a real port.

A named world (``sim://bench?...``) is kept in a registry: every port opened on
that name reaches the same modules (closing and reopening the port is a cable
reconnect, not a power cycle), and the composition root can get at its world
(:func:`open_world`, :func:`get`) to place parts and artifacts. An unnamed URL
opened as a port makes a private world each time.

pyserial finds the port class (:mod:`cmm.sim.protocol_sim`) through
``serial.protocol_handler_packages``; :mod:`cmm.nmc.transport` registers this
package there by name, so hosts never import the simulator themselves.
"""

from __future__ import annotations

import itertools
import threading
from dataclasses import dataclass, replace
from typing import Any
from urllib.parse import parse_qsl, urlsplit, urlunsplit

from cmm.nmc import codec as c
from cmm.sim.network import SimNetwork

CLOCKS = ("virtual", "realtime")
_OPTIONS = ("cmm", "modules", "firmware", "module_version", "clock", "pace", "wire", "config")
FORM = ("sim://[NAME]?cmm=1&modules=N&firmware=pic-servo|pic-servo-sc&module_version=V"
        "&clock=virtual|realtime&pace=X&wire=1|0&config=PATH")


class SimUrlError(ValueError):
    """A sim:// URL that cannot be understood, in an operator's words."""


@dataclass(frozen=True)
class SimOptions:
    name: str = ""
    cmm: bool = False
    modules: int = 3
    firmware: str | None = None  # None: the machine configuration's (cmm) or pic-servo
    module_version: int | None = None
    clock: str = "virtual"
    pace: float | None = None  # virtual clock: at most this many simulated s per wall s
    wire_time: bool = True
    config: str | None = None

    @property
    def realtime(self) -> bool:
        return self.clock == "realtime"

    def url(self) -> str:
        """The canonical URL of these options."""
        query = []
        if self.cmm:
            query.append("cmm=1")
        if not self.cmm or self.modules != 3:
            query.append(f"modules={self.modules}")
        if self.firmware:
            query.append(f"firmware={self.firmware}")
        if self.module_version is not None:
            query.append(f"module_version={self.module_version}")
        query.append(f"clock={self.clock}")
        if self.pace:
            query.append(f"pace={self.pace:g}")
        if not self.wire_time:
            query.append("wire=0")
        if self.config:
            query.append(f"config={self.config}")
        return urlunsplit(("sim", self.name, "", "&".join(query), ""))


def _flag(key: str, value: str) -> bool:
    if value.lower() in ("1", "true", "yes", "on"):
        return True
    if value.lower() in ("0", "false", "no", "off"):
        return False
    raise SimUrlError(f"sim:// option {key}={value!r} must be 1 or 0")


def _int(key: str, value: str) -> int:
    try:
        return int(value)
    except ValueError:
        raise SimUrlError(f"sim:// option {key}={value!r} must be a whole number") from None


def parse(url: str) -> SimOptions:
    """The options of a sim:// URL; unknown options are refused (a typo must not go unnoticed)."""
    parts = urlsplit(url)
    if parts.scheme.lower() != "sim":
        raise SimUrlError(f"not a simulator URL: {url!r} (expected {FORM})")
    opts: dict[str, Any] = {"name": parts.netloc}
    for key, value in parse_qsl(parts.query, keep_blank_values=True):
        if key == "version":
            key = "module_version"
        if key not in _OPTIONS:
            raise SimUrlError(f"unknown sim:// option {key!r}; known: {', '.join(_OPTIONS)}")
        if key in ("cmm", "wire"):
            opts["wire_time" if key == "wire" else key] = _flag(key, value)
        elif key in ("modules", "module_version"):
            opts[key] = _int(key, value)
        elif key == "firmware":
            if value not in c.BAUD_DIVISORS:
                raise SimUrlError(f"unknown firmware {value!r} in sim:// URL; known: {', '.join(c.BAUD_DIVISORS)}")
            opts[key] = value
        elif key == "pace":
            try:
                opts[key] = float(value)
            except ValueError:
                opts[key] = 0.0
            if not opts[key] > 0:
                raise SimUrlError(f"sim:// option pace={value!r} must be a positive number "
                                  f"(simulated seconds per wall second)")
        elif key == "clock":
            if value not in CLOCKS:
                raise SimUrlError(f"sim:// clock must be one of {', '.join(CLOCKS)}, not {value!r}")
            opts[key] = value
        else:
            opts[key] = value
    options = SimOptions(**opts)
    if not 1 <= options.modules <= 32:
        raise SimUrlError(f"an NMC network holds 1 to 32 modules, not {options.modules}")
    if options.cmm and options.modules < 3:
        raise SimUrlError(f"the simulated CMM needs 3 modules (one per axis), not {options.modules}")
    return options


@dataclass
class SimWorld:
    """What a sim:// URL opened: the network, and the simulated CMM around it (cmm=1)."""

    options: SimOptions
    network: SimNetwork
    cmm: Any = None  # cmm.sim.cmm_sim.SimulatedCMM when cmm=1

    @property
    def url(self) -> str:
        return self.options.url()


def build(options: SimOptions, *, config: Any = None, settings: Any = None) -> SimWorld:
    """A new world as ``options`` describe (``config`` / ``settings`` for cmm=1 override the URL's)."""
    if options.cmm:
        from cmm.machine.config import load
        from cmm.sim.cmm_sim import SimulatedCMM

        config = config if config is not None else load(options.config)
        sim = SimulatedCMM(config, settings, wire_time=options.wire_time, realtime=options.realtime,
                           n_modules=options.modules, firmware=options.firmware,
                           version=options.module_version)
        sim.network.pace = options.pace
        return SimWorld(options, sim.network, sim)
    network = SimNetwork(options.modules, version=options.module_version, wire_time=options.wire_time,
                         realtime=options.realtime, firmware=options.firmware or "pic-servo")
    network.pace = options.pace
    return SimWorld(options, network)


_registry: dict[str, SimWorld] = {}
_registry_lock = threading.Lock()
_names = itertools.count(1)


def open_world(url: str, *, config: Any = None, settings: Any = None) -> SimWorld:
    """The world of a named URL (created on first use), or a new world under a fresh name.

    The returned world's ``url`` names it: ports opened on that URL reach it.
    ``config`` and ``settings`` apply only when the world is created here.
    """
    options = parse(url)
    with _registry_lock:
        if options.name and options.name in _registry:
            return _registry[options.name]
        if not options.name:
            while True:
                name = f"world{next(_names)}"
                if name not in _registry:
                    break
            options = replace(options, name=name)
        world = build(options, config=config, settings=settings)
        _registry[options.name] = world
        return world


def attach(url: str) -> SimWorld:
    """What a port opened on ``url`` reaches: the named world, or a private new one."""
    options = parse(url)
    if options.name:
        return open_world(url)
    return build(options)


def get(url_or_name: str) -> SimWorld | None:
    """The registered world of a name or named URL, if any."""
    name = parse(url_or_name).name if "://" in url_or_name else url_or_name
    with _registry_lock:
        return _registry.get(name)


def release(url_or_name: str) -> None:
    """Forget a named world (ports still open on it keep working)."""
    name = parse(url_or_name).name if "://" in url_or_name else url_or_name
    with _registry_lock:
        _registry.pop(name, None)

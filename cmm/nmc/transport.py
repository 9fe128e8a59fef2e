"""Byte transports for the NMC bus: any pyserial URL, or an in-process object.

A transport is anything with pyserial's byte interface (``write``, ``read``
honouring ``timeout``, ``baudrate``, ``reset_input_buffer``, ``close``).
Objects that also provide ``now()`` and ``sleep(seconds)`` bring their own
clock (the simulator's virtual clock); everything else runs on wall time.

``sim://`` URLs open the in-process simulator (cmm/sim/url.py): its pyserial
handler package is registered here by name, and pyserial imports it only when
such a URL is opened, so the host never imports the simulator itself.
"""

from __future__ import annotations

import time
from typing import Any, Protocol

import serial


SIM_HANDLER_PACKAGE = "cmm.sim"  # holds protocol_sim.py, pyserial's handler for sim:// URLs
if SIM_HANDLER_PACKAGE not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append(SIM_HANDLER_PACKAGE)


class Clock(Protocol):
    def now(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...

    # optional: ``virtual`` True for a simulated clock that only runs while the host waits; ``rest(seconds)`` a
    # sleep of a host with nothing to do (see :func:`rest`)


def rest(clock: object, seconds: float) -> None:
    """Sleep ``seconds`` of machine time with nothing moving and no job waiting on the machine. On the simulator's
    uncapped virtual clock this also waits that long in wall time: an idle loop that only slept in machine time
    would race the simulated clock ahead at full CPU (a core spent on nothing, starving a browser or a test beside
    it). Other clocks just sleep."""
    getattr(clock, "rest", clock.sleep)(seconds)  # type: ignore[attr-defined]


def is_virtual(clock: object) -> bool:
    """True for the simulator's virtual clock (time passes only when the host waits)."""
    return bool(getattr(clock, "virtual", False))


class WallClock:
    """Real time, for real ports and served simulators."""

    virtual = False

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class TransportError(OSError):
    """A port that cannot be opened or used, in words an operator understands."""


URL_FORMS = ("a device path (/dev/ttyUSB0), COMn, socket://host:port, rfc2217://host:port, loop://, spy://... "
             "or sim://?cmm=1 (the in-process simulator)")


def open_port(port: Any, baudrate: int, timeout: float) -> tuple[Any, Clock]:
    """Open ``port`` (a pyserial URL / device name, or a transport object) at 8N1."""
    if not isinstance(port, str):
        port.baudrate = baudrate
        port.timeout = timeout
        return port, _clock_of(port)
    if not port:
        raise TransportError(f"no serial port given; use {URL_FORMS}")
    options: dict[str, Any] = {"write_timeout": 1.0}
    if port.lower().startswith("rfc2217://"):
        options = {}  # pyserial's RFC 2217 client refuses a write time-out
    try:
        ser = serial.serial_for_url(
            port, baudrate=baudrate, bytesize=8, parity="N", stopbits=1, timeout=timeout, **options
        )
    except (serial.SerialException, ValueError, OSError) as exc:
        raise TransportError(f"cannot open serial port {port!r}: {exc}. Expected {URL_FORMS}") from exc
    return ser, _clock_of(ser)


def _clock_of(port: Any) -> Clock:
    """The port's own clock if it has one (sim://), else the wall clock."""
    return port if hasattr(port, "sleep") and hasattr(port, "now") else WallClock()

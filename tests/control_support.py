"""A control core on the simulated CMM (in-process, virtual clock), with home switches and a breakable link."""

from __future__ import annotations

import time

import serial

from cmm.control import Controller
from cmm.machine.config import load
from cmm.machine.motion import Machine
from cmm.sim.cmm_sim import SimulatedCMM
from cmm.sim.home_switches import HomeSwitches


class BreakablePort:
    """The simulator's in-process port with a plug to pull: ``broken = True`` fails every write and read
    the way a dropped USB adapter or TCP link does in pyserial."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.broken = False

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def __setattr__(self, name, value):
        if name in ("inner", "broken"):
            object.__setattr__(self, name, value)
        else:
            setattr(self.inner, name, value)

    def write(self, data):
        if self.broken:
            raise serial.SerialException("write failed: [Errno 5] Input/output error (device disconnected?)")
        return self.inner.write(data)

    def read(self, size=1):
        if self.broken:
            raise serial.SerialException("device reports readiness to read but returned no data")
        return self.inner.read(size)


def make_controller(config=None, *, start_at=None):
    """(sim, controller, port): connected, not homed, not threaded (statuses drive the loop)."""
    config = config or load()
    sim = SimulatedCMM(config)
    HomeSwitches(sim)
    if start_at is not None:  # where the carriages stand at power-up (machine mm)
        for i, (axis, mm) in enumerate(zip(config.axes, start_at)):
            sim.network.plants[sim._axis_module[i]].move_to((mm - axis.home) * axis.counts_per_mm * axis.direction)
    port = BreakablePort(sim.transport())
    ctl = Controller(Machine(config, port))
    ctl.connect()
    return sim, ctl, port


def wait_idle(station, timeout: float = 60.0) -> None:
    """Until the station's machine stands idle (no move, jog, probe or homing left, by the control core too)."""
    end = time.monotonic() + timeout
    while station.machine.busy or station.controller.state.mode.value in ("moving", "jogging", "probing", "homing"):
        if time.monotonic() > end:
            raise AssertionError("the machine is still busy")
        time.sleep(0.01)

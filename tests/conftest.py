"""Shared fixtures: a simulated CMM reached through real NMC bytes (in-process, virtual clock)."""

from __future__ import annotations

import pytest

from cmm.machine.config import load
from cmm.machine.motion import Machine
from cmm.machine.probing import Prober
from cmm.sim.cmm_sim import SimulatedCMM


@pytest.fixture
def sim_machine():
    """(simulator, connected machine, prober); the machine polls only when a test waits."""
    config = load()
    sim = SimulatedCMM(config)
    machine = Machine(config, sim.transport())
    machine.connect()
    yield sim, machine, Prober(machine)
    machine.close()

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


def pytest_collection_modifyitems(config, items):
    """Two xdist workers (``--dist loadgroup``): a test file stays in one worker (its module fixtures are built once),
    and all browser tests share one worker, so two software-rendered WebGL browsers never compete for the two
    cores while their wall-time-paced jogs are timed."""
    for item in items:
        group = "browser" if item.get_closest_marker("browser") else item.nodeid.split("::", 1)[0]
        item.add_marker(pytest.mark.xdist_group(group))

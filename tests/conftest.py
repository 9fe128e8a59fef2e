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


REAL_TIME_FILES = {"test_link_process.py", "test_kill9.py", "test_calibrate_tcp.py", "test_sim_process.py"}


def pytest_collection_modifyitems(config, items):
    """The groups for ``--dist loadgroup``, which does not group with pytest 9.2 and xdist 3.8 (pyproject.toml runs
    ``--dist loadfile``: a test file stays in one worker, but browser files may run beside each other). The intent:
    two xdist workers, a test file stays in one worker (its module fixtures are built once),
    and all browser tests share one worker, so two software-rendered WebGL browsers never compete for the two
    cores while their wall-time-paced jogs are timed. The real-time tests on a served simulator join that worker:
    their simulator and link processes run at raised priority and starved a browser beside them of CPU (its hold
    events came over 1 s apart)."""
    for item in items:
        path = item.nodeid.split("::", 1)[0]
        timed = item.get_closest_marker("browser") or path.rsplit("/", 1)[-1] in REAL_TIME_FILES
        item.add_marker(pytest.mark.xdist_group("browser" if timed else path))

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


# Test files in the order the two xdist workers should start them, the longest first (wall seconds of a quiet
# 2-core run, most to least), so that no long file starts last and keeps one worker busy alone at the end
# (longest-processing-time-first: pyproject.toml runs --dist loadfile --no-loadscope-reorder, which keeps this
# order instead of xdist's "most tests first"). Files not listed follow in collection order. Scheduling only:
# every file runs alone as well.
LONGEST_FIRST = (
    "test_browser_walk.py", "test_browser_station.py", "test_browser_routine.py", "test_browser_viser.py",
    "test_browser_colour_map.py", "test_routine.py", "test_browser_view_keys.py", "test_browser.py",
    "test_calibration_geometry.py", "test_browser_probes.py", "test_dmis_routine_export.py", "test_dmis.py", "test_qif.py",
    "test_session_postgres.py",
    "test_path_preview.py", "test_link_process.py", "test_calibrate_tcp.py", "test_calibration_probe.py",
    "test_ippdme_nist.py", "test_session_station.py", "test_program.py", "test_control.py",
    "test_calibration_probes.py", "test_dmis_statements.py",
)


def pytest_collection_modifyitems(config, items):
    """Longest files first (see LONGEST_FIRST); a file's tests stay together and in their order (a stable sort)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::", 1)[0].rsplit("/", 1)[-1], len(rank)))

"""Shared fixtures: a simulated CMM reached through real NMC bytes (in-process, virtual clock)."""

from __future__ import annotations

import time
from collections import defaultdict

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
    "test_short_cylinder.py", "test_auto_measure_cone.py", "test_dmis_nominals.py", "test_one_hit.py",
    "test_session_postgres.py",
    "test_path_preview.py", "test_link_process.py", "test_calibrate_tcp.py", "test_calibration_probe.py",
    "test_ippdme_nist.py", "test_session_station.py", "test_program.py", "test_control.py",
    "test_calibration_probes.py", "test_dmis_statements.py", "test_command_api.py", "test_trends_dmis.py",
    "test_ui_feedback.py", "test_dmis_part_pose.py",
)


def pytest_collection_modifyitems(config, items):
    """Longest files first (see LONGEST_FIRST); a file's tests stay together and in their order (a stable sort)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::", 1)[0].rsplit("/", 1)[-1], len(rank)))


# Where the time goes, file by file: each test phase's wall seconds and the CPU seconds its test process spent in it
# (every thread: the stations, their simulators, viser; not chromium nor other subprocesses), summed per file on the
# controller and printed after pytest's slowest tests. A file's module fixtures count in its first test's setup.
_CPU_MARK = pytest.StashKey[float]()
_FILES: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0])
SLOWEST_FILES = 15


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    item.stash[_CPU_MARK] = time.process_time()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    now = time.process_time()
    report.user_properties.append(("cpu_s", round(now - item.stash.get(_CPU_MARK, now), 3)))
    item.stash[_CPU_MARK] = now


def pytest_runtest_logreport(report):
    entry = _FILES[report.nodeid.split("::", 1)[0]]
    entry[0] += report.duration
    entry[1] += dict(report.user_properties).get("cpu_s", 0.0)
    entry[2] += report.when == "call"


@pytest.hookimpl(trylast=True)
def pytest_terminal_summary(terminalreporter):
    if not _FILES or not terminalreporter.config.getoption("durations"):
        return
    wall = sum(e[0] for e in _FILES.values())
    cpu = sum(e[1] for e in _FILES.values())
    tr = terminalreporter
    tr.write_sep("=", f"slowest {SLOWEST_FILES} files (wall s of their tests, CPU s of the test process)")
    for name, (w, c, n) in sorted(_FILES.items(), key=lambda kv: -kv[1][0])[:SLOWEST_FILES]:
        tr.write_line(f"{w:8.1f}s wall {c:8.1f}s CPU  {n:4d} tests  {name}")
    tr.write_line(f"all files: {wall:.0f} s of test time, {cpu:.0f} CPU s in the test processes")

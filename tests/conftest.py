"""Shared fixtures: a simulated CMM reached through real NMC bytes (in-process, virtual clock)."""

from __future__ import annotations

import resource
import time
from collections import defaultdict
from pathlib import Path

import pytest

from stations import Stations


@pytest.fixture
def stations(tmp_path):
    """Builds the test's stations (tests/stations.py: the kinds), their sessions in ``tmp_path``; closed after it."""
    with Stations(lambda: tmp_path) as built:
        yield built


@pytest.fixture(scope="module")
def module_stations(tmp_path_factory):
    """Builds stations shared by a module's tests, each with a fresh session folder; closed after the module."""
    with Stations(lambda: tmp_path_factory.mktemp("sessions")) as built:
        yield built


@pytest.fixture
def sim_machine(stations):
    """(simulator, connected machine, prober); the machine polls only when a test waits."""
    return stations.machine()


# Test files in the order the xdist workers should start them, the longest first (wall seconds of a quiet 2-core
# run), so that no long file starts last and keeps one worker busy alone at the end (longest-processing-time-first:
# pyproject.toml runs --dist loadfile --no-loadscope-reorder, which keeps this order instead of xdist's "most tests
# first"). Browser files alternate with simulator ones: a browser test spends much of its time waiting on the
# page (and a held jog runs at a hand's pace), which a simulator test beside it fills, whereas three pages at once
# overload two cores. Files not listed follow in collection order. Scheduling only: every file runs alone as well.
LONGEST_FIRST = (
    "test_browser_walk.py", "test_routine.py", "test_browser_viser.py", "test_link_tolerance.py", "test_browser.py",
    "test_link_process.py", "test_browser_station.py", "test_calibration_geometry.py", "test_browser_routine.py",
    "test_dmis.py", "test_browser_stop.py", "test_dmis_routine_export.py", "test_browser_hands.py",
    "test_calibrate_tcp.py", "test_browser_users.py", "test_qif_reevaluate.py", "test_browser_align_layout.py",
    "test_ippdme_nist.py", "test_browser_probes.py", "test_program.py", "test_browser_view_keys.py", "test_qif.py",
    "test_browser_colour_map.py", "test_kill9.py", "test_dmis_nominals.py", "test_stop_ends_runs.py",
    "test_notify.py", "test_session_station.py", "test_cmm_sim.py", "test_auto_measure_cone.py",
    "test_session_postgres.py", "test_calibration_probe.py", "test_pendant.py", "test_control.py",
    "test_dmis_nist_part.py", "test_short_cylinder.py", "test_machine_motion.py", "test_dmis_vendor.py",
    "test_dmis_statements.py", "test_ippdme_server.py", "test_path_preview.py", "test_link_faults.py",
    "test_machine_probing.py", "test_calibration_probes.py", "test_calibration_records.py",
)


def pytest_collection_modifyitems(config, items):
    """Longest files first (see LONGEST_FIRST); a file's tests stay together and in their order (a stable sort)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::", 1)[0].rsplit("/", 1)[-1], len(rank)))


# Where the time goes, file by file: each test phase's wall seconds and the CPU seconds its test process spent in it
# (every thread: the stations, their simulators, viser), and the CPU seconds of its finished subprocesses as the
# kernel accounts them to it (Playwright's driver when the browser closes; most of chromium's renderer and GPU
# processes escape that account: a page's own cost is read from /proc, see tests/README.md), summed per file on the
# controller and printed after pytest's slowest tests. A file's module fixtures count in its first test's setup.
_CPU_MARK = pytest.StashKey[tuple[float, float]]()
_FILES: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0, 0.0])


def _cpu_now() -> tuple[float, float]:
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time(), children.ru_utime + children.ru_stime
SLOWEST_FILES = 15


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    item.stash[_CPU_MARK] = _cpu_now()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    now = _cpu_now()
    then = item.stash.get(_CPU_MARK, now)
    report.user_properties.append(("cpu_s", round(now[0] - then[0], 3)))
    report.user_properties.append(("child_cpu_s", round(now[1] - then[1], 3)))
    item.stash[_CPU_MARK] = now


def pytest_runtest_logreport(report):
    entry = _FILES[report.nodeid.split("::", 1)[0]]
    entry[0] += report.duration
    props = dict(report.user_properties)
    entry[1] += props.get("cpu_s", 0.0)
    entry[2] += report.when == "call"
    entry[3] += props.get("child_cpu_s", 0.0)


@pytest.hookimpl(trylast=True)
def pytest_terminal_summary(terminalreporter):
    if not _FILES or not terminalreporter.config.getoption("durations"):
        return
    wall = sum(e[0] for e in _FILES.values())
    cpu = sum(e[1] for e in _FILES.values())
    child = sum(e[3] for e in _FILES.values())
    tr = terminalreporter
    tr.write_sep("=", f"slowest {SLOWEST_FILES} files (wall s of their tests, CPU s of the test process and of its "
                      f"subprocesses: chromium)")
    for name, (w, c, n, k) in sorted(_FILES.items(), key=lambda kv: -kv[1][0])[:SLOWEST_FILES]:
        tr.write_line(f"{w:8.1f}s wall {c:8.1f}s CPU {k:8.1f}s child CPU  {n:4d} tests  {name}")
    tr.write_line(f"all files: {wall:.0f} s of test time, {cpu:.0f} CPU s in the test processes, {child:.0f} CPU s "
                  f"in their subprocesses")
    table = Path(__file__).resolve().parents[1] / "test-artifacts" / "file-times.csv"  # every file, for tuning
    table.parent.mkdir(exist_ok=True)
    table.write_text("file,wall_s,cpu_s,child_cpu_s,tests\n" + "".join(
        f"{name},{w:.1f},{c:.1f},{k:.1f},{n}\n" for name, (w, c, n, k) in sorted(_FILES.items(), key=lambda kv: -kv[1][0])))

"""The station's built-in simulator runs in a process of its own and ends with the station."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cmm.nmc.link_process import RemoteBus
from cmm.sim.sim_process import SimProcess

pytestmark = pytest.mark.timeout(120)


def _gone(pid: int, within: float) -> bool:
    """The process ended (no such pid, or a zombie its new parent has not reaped yet) within ``within`` s."""
    end = time.monotonic() + within
    while time.monotonic() < end:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError):
            return True
        if state in ("Z", "X"):
            return True
        time.sleep(0.05)
    return False


def test_default_station_simulator_runs_in_its_own_process(tmp_path):
    from cmm.station import Station

    station = Station(session_dir=tmp_path)
    try:
        sim = station.sim
        assert isinstance(sim, SimProcess) and sim.alive and sim.pid != os.getpid()
        assert station.port == sim.url and sim.url.startswith("socket://127.0.0.1:")
        assert isinstance(station.machine.bus, RemoteBus) and station.machine.bus.pid != sim.pid
        # at least the station's priority (raised when the system allows it)
        assert os.getpriority(os.PRIO_PROCESS, sim.pid) <= os.getpriority(os.PRIO_PROCESS, 0)
        assert station.measurement.part is not None and len(station.measurement.part.mesh.faces) > 100
        station.start()
        station.place_sim_artifacts([((300.0, 300.0, 50.0), 20.0)])  # reaches the child (an error otherwise)
        assert sim.triggers == 0
    finally:
        station.close()
    assert _gone(sim.pid, 5.0)


def test_simulator_process_ends_when_its_station_is_killed():
    code = ("from cmm.machine.config import load; from cmm.sim.cmm_sim import CmmSimSettings;"
            "from cmm.sim.sim_process import SimProcess; import time;"
            "p = SimProcess(load(), CmmSimSettings()); print(p.pid, flush=True); time.sleep(120)")
    station = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        child = int(station.stdout.readline())
        assert not _gone(child, 0.5)
        station.send_signal(signal.SIGKILL)
        station.wait(10)
        assert _gone(child, 5.0), "the simulator process outlived its station"
    finally:
        if station.poll() is None:
            station.kill()
            station.wait()

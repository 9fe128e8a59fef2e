"""kill -9 of a jogging station: what the machine does with nobody left to stop it.

The simulator runs as its own process (`cmm sim --cmm --tcp`) in real time; a
station process connects over TCP, jogs +X at 40 mm/s and is killed with
SIGKILL mid-jog. Then a fresh bus reads the modules directly: the axis stood
still at most one jog horizon (0.12 s of travel) past where the station last saw
it, because the modules only ever hold a goal that close ahead, and never past
the travel.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cmm.machine.config import default_text, load
from cmm.nmc import codec
from cmm.nmc.bus import Bus
from cmm.nmc.module import Module

pytestmark = pytest.mark.timeout(90)
HERE = Path(__file__).parent


def _config(tmp_path: Path) -> Path:
    text = default_text().replace('method = "switch"', 'method = "none"')  # the served sim has no home switches
    path = tmp_path / "machine.toml"
    path.write_text(text)
    load(path)
    return path


def _start_sim(config: Path) -> tuple[subprocess.Popen, str]:
    cli = "import sys; from cmm.cli import main; sys.exit(main(sys.argv[1:]))"
    sim = subprocess.Popen([sys.executable, "-u", "-c", cli, "sim", "--cmm", "--tcp", "127.0.0.1:0", "--config", str(config)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    end = time.monotonic() + 30
    while time.monotonic() < end:
        line = sim.stdout.readline()
        m = re.search(r"(socket://127\.0\.0\.1:\d+)", line)
        if m:
            return sim, m.group(1)
    sim.kill()
    raise AssertionError("the simulator did not print its URL")


def _read(url: str, axis) -> list[tuple[float, int]]:  # noqa: ANN001 - AxisConfig
    """An axis's position (mm) and velocity read straight from its module by a fresh bus, twice 0.3 s apart."""
    bus = Bus(url)
    bus._set_host_baud(115200)  # the modules stay at the station's rate (TCP carries none)
    mod = Module(bus, axis.address)
    out = []
    for _ in range(2):
        st = mod.read_status(codec.SEND_POS | codec.SEND_VEL)
        out.append((axis.to_mm(st.position), st.velocity))
        time.sleep(0.3)
    bus.close()
    return out


@pytest.mark.parametrize("axis,start", [(0, (40.0, 0.0, 300.0)),  # mid-travel: stops one horizon on
                                        (2, (0.0, 0.0, 294.0))])  # towards the top of Z: stops at the travel end
def test_kill_9_during_a_jog_leaves_the_axis_stopped_within_the_horizon(tmp_path, axis, start):
    config = _config(tmp_path)
    cfg = load(config)
    sim, url = _start_sim(config)
    station = None
    try:
        station = subprocess.Popen([sys.executable, str(HERE / "station_kill_helper.py"), url, str(config), str(axis),
                                    *map(str, start)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert station.stdout.readline().split()[0] == "ready"
        seen = []
        end = time.monotonic() + 0.6
        while time.monotonic() < end:
            line = station.stdout.readline()
            if line.startswith("pos"):
                seen.append([float(v) for v in line.split()[1:]])
        xs = np.array(seen)[:, 1 + axis]
        assert xs[-1] > xs[0] + 5 or xs[-1] > cfg.axes[axis].max - 1, xs  # it was jogging
        os.kill(station.pid, signal.SIGKILL)
        station.wait(10)
        for line in station.stdout:  # positions printed before the kill landed
            if line.startswith("pos"):
                xs = np.append(xs, float(line.split()[2 + axis]))
        last_seen = xs[-1]
        time.sleep(0.7)  # nobody talks to the modules now
        (x1, v1), (x2, v2) = _read(url, cfg.axes[axis])
        assert v1 == 0 and v2 == 0 and x1 == x2  # standing still, servo holding
        assert x1 <= cfg.axes[axis].max + 0.004  # never beyond the travel
        assert x1 - last_seen <= 40.0 * (cfg.jog.horizon + 0.06) + 0.05, (last_seen, x1)  # + a refresh's lag
        print(f"axis {'XYZ'[axis]}: last seen {last_seen:.3f} mm, stopped at {x1:.3f} mm "
              f"({x1 - last_seen:.3f} mm later)")
    finally:
        if station is not None and station.poll() is None:
            station.kill()
        sim.send_signal(signal.SIGINT)
        try:
            sim.wait(5)
        except subprocess.TimeoutExpired:
            sim.kill()

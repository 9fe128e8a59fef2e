"""kill -9 of a jogging station: what the machine does with nobody left to stop it.

The simulator runs as its own process (`cmm sim --cmm --tcp`) in real time; a
station process connects over TCP, jogs +X at 40 mm/s and is killed with
SIGKILL mid-jog. Then a fresh bus reads the modules directly: the axis stands
still, never past the travel, and no further than the jog could run from where the
station last saw it until the kill, plus the dead-man and the braking: the link
process stops the axes when the station's pipe closes, its dead-man at the latest.
All times are the machine's clock (monotonic, shared by the processes): a loaded
host that runs the station late moves the bound with it, never the verdict.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cmm.machine.config import default_text, load
from cmm.machine.jogging import STOP_MARGIN_S
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


def read_ready(station: subprocess.Popen) -> int:
    """The helper's lines up to its ``ready <pid>`` (a link warning may be logged first); the link process's pid."""
    seen = []
    for line in station.stdout:
        if line.startswith("ready"):
            return int(line.split()[1])
        seen.append(line.rstrip())
    raise AssertionError(f"the station ended before it was ready: {seen[-20:]}")


def jog_until_moved(station: subprocess.Popen, axis: int, top: float, timeout: float = 60.0) -> list[str]:
    """The helper's lines until its ``pos`` lines show ``axis`` jogged 5 mm on, or to 1 mm short of ``top``."""
    lines, first = [], None
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = station.stdout.readline()
        if not line:
            break
        lines.append(line.rstrip())
        if line.startswith("pos"):
            x = float(line.split()[2 + axis])
            first = x if first is None else first
            if x > first + 5 or x > top - 1:
                return lines
    raise AssertionError(f"the station did not jog axis {axis}: {lines[-20:]}")


def last_seen(lines: list[str], axis: int) -> tuple[float, float]:
    """(sample time, position of ``axis``) of the last ``pos`` line."""
    words = [line.split() for line in lines if line.startswith("pos")][-1]
    return float(words[1]), float(words[2 + axis])


def stopping_bound(cfg, seen_at: float, killed_at: float) -> float:  # noqa: ANN001 - MachineConfig
    """mm a 40 mm/s jog may go on past the station's last sample (taken at ``seen_at``): up to the kill (it was
    still jogging), then the dead-man at the latest (the link process stops at once when it sees the station's
    pipe close), then the braking at the stop deceleration and the stop's latency margin; +0.05 mm for the
    quantised readings. Times on the machine's clock."""
    v = cfg.speeds.jog_fast
    return (v * (killed_at - seen_at + cfg.deadman_timeout) + v * v / (2 * cfg.accelerations.stop)
            + v * STOP_MARGIN_S + 0.05)


def standing(url: str, axis, timeout: float = 20.0) -> float:  # noqa: ANN001 - AxisConfig
    """Where the axis stands once a fresh bus reads it still (velocity 0, the same position 0.3 s apart): mm."""
    bus = Bus(url)
    bus._set_host_baud(115200)  # the modules stay at the station's rate (TCP carries none)
    mod = Module(bus, axis.address)
    end = time.monotonic() + timeout
    try:
        before = None
        while time.monotonic() < end:
            st = mod.read_status(codec.SEND_POS | codec.SEND_VEL)
            if st.velocity == 0 and before is not None and st.position == before:
                return axis.to_mm(st.position)
            before = st.position if st.velocity == 0 else None
            time.sleep(0.3)
    finally:
        bus.close()
    raise AssertionError(f"axis {axis.name} did not stand still within {timeout} s of the kill")


@pytest.mark.parametrize("axis,start", [(0, (40.0, 0.0, 300.0)),  # mid-travel
                                        (2, (0.0, 0.0, 294.0))])  # towards the top of Z: stops at the travel end
def test_kill_9_during_a_jog_leaves_the_axis_stopped_within_the_dead_man_and_braking(tmp_path, axis, start):
    config = _config(tmp_path)
    cfg = load(config)
    sim, url = _start_sim(config)
    station = None
    try:
        station = subprocess.Popen([sys.executable, str(HERE / "station_kill_helper.py"), url, str(config), str(axis),
                                    *map(str, start)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        read_ready(station)
        lines = jog_until_moved(station, axis, cfg.axes[axis].max)  # it is jogging
        os.kill(station.pid, signal.SIGKILL)
        killed_at = time.monotonic()  # at or after the kill: the bound below is never too tight
        station.wait(10)
        lines += [line.rstrip() for line in station.stdout]  # positions printed before the kill landed
        seen_at, seen = last_seen(lines, axis)
        x = standing(url, cfg.axes[axis])  # nobody talks to the modules now: standing still, servo holding
        assert x <= cfg.axes[axis].max + 0.004  # never beyond the travel
        bound = stopping_bound(cfg, seen_at, killed_at)
        assert x - seen <= bound, (seen, x, bound)
        print(f"axis {'XYZ'[axis]}: last seen {seen:.3f} mm {killed_at - seen_at:.3f} s before the kill, stopped at "
              f"{x:.3f} mm ({x - seen:.3f} mm later, bound {bound:.3f} mm)")
    finally:
        if station is not None and station.poll() is None:
            station.kill()
        sim.send_signal(signal.SIGINT)
        try:
            sim.wait(5)
        except subprocess.TimeoutExpired:
            sim.kill()

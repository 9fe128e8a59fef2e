"""The simulated CMM served by `cmm sim --cmm`, and its injected geometry errors."""

import re
import subprocess
import sys

import numpy as np
import pytest

from cmm.machine.config import load
from cmm.machine.motion import Machine
from cmm.machine.probing import Prober
from cmm.sim.cmm_sim import CmmSimSettings
from cmm.sim.probe_world import GeometryErrors


def test_cmm_sim_over_tcp_serves_a_machine_that_probes_the_part():
    proc = subprocess.Popen([sys.executable, "-m", "cmm.cli", "sim", "--cmm", "--tcp", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        url = None
        for _ in range(20):
            line = proc.stdout.readline()
            m = re.search(r"socket://\S+", line)
            if m:
                url = m.group(0)
                break
        assert url, "cmm sim printed no driver URL"
        machine = Machine(load(), url)
        try:
            machine.connect()
            pose = CmmSimSettings().part_pose
            top = (pose @ np.array([20.0, 60.0, 40.0, 1.0]))[:3]
            hit = Prober(machine).probe(top, [0, 0, -1], clearance_z=60).wait(60)
            assert abs(hit.point[2] - 40.0) < 0.006  # nominal (zero) pre-travel: within 3 counts
        finally:
            machine.close()
    finally:
        proc.terminate()
        proc.wait(10)


def test_injected_scale_and_squareness_move_the_real_tip(stations):
    errors = GeometryErrors(scale_ppm=(50.0, 0.0, 0.0), squareness_urad=(30.0, 0.0, 0.0))
    sim, m, _ = stations.machine(settings=CmmSimSettings(errors=errors))
    m.move_to([400.0, 300.0, 300.0]).wait()
    tip = sim.tip_position()
    reading = np.array(sim.axis_readings())
    assert tip[0] - reading[0] == pytest.approx(400.0 * 50e-6 + 300.0 * 30e-6, abs=1e-6)
    assert tip[1] == pytest.approx(reading[1], abs=1e-9)


def test_geometry_correction_cancels_the_injected_errors(stations):
    from cmm.machine.geometry import GeometryCorrection

    errors = GeometryErrors(scale_ppm=(50.0, -20.0, 10.0), squareness_urad=(30.0, -15.0, 25.0))
    sim, m, _ = stations.machine(settings=CmmSimSettings(errors=errors))
    m.correction = GeometryCorrection(errors.scale_ppm, errors.squareness_urad)
    target = np.array([450.0, 350.0, 50.0])
    m.move_to(target).wait()
    m.run_for(0.05)
    assert np.abs(sim.tip_position() - target).max() < 0.003  # the true tip, within the count grid
    assert np.abs(m.position - target).max() < 0.003
    m.step("x", 0.002).wait()
    assert m.sample().axes[0].counts == m.mm_to_counts(target)[0] + 1


def test_pure_z_move_with_squareness_correction_arrives(stations):
    """With squareness corrected, a Z move also moves X and Y by a few counts: they must get a rate."""
    from cmm.machine.geometry import GeometryCorrection

    sim, m, _ = stations.machine()
    m.correction = GeometryCorrection((0.0, 0.0, 0.0), (30.0, 40.0, -25.0))
    start = m.position
    m.move_to(start - [0.0, 0.0, 250.0]).wait(30)
    assert np.abs(m.position - (start - [0.0, 0.0, 250.0])).max() < 0.003


def test_cmm_sim_honours_firmware_modules_and_version_and_says_so():
    """`cmm sim --cmm --firmware pic-servo-sc --module-version 12 --modules 4`: the banner
    says so, and the modules report it over the wire (READ_STAT item 0x20: type 0, version)."""
    import serial

    proc = subprocess.Popen([sys.executable, "-m", "cmm.cli", "sim", "--cmm", "--firmware", "pic-servo-sc",
                             "--module-version", "12", "--modules", "4", "--tcp", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        for _ in range(20):
            lines.append(proc.stdout.readline())
            if "socket://" in lines[-1]:
                break
        text = "".join(lines)
        assert "4 simulated PIC-SERVO modules (firmware pic-servo-sc, version 12)" in text, text
        url = re.search(r"socket://\S+", text).group(0)
        port = serial.serial_for_url(url, timeout=0.5)
        try:
            port.write(bytes(20))
            versions = []
            for a in range(1, 6):
                body = bytes((0, 0x21, a, 0xFF))
                port.reset_input_buffer()
                port.write(b"\xaa" + body + bytes((sum(body) & 0xFF,)))
                if len(port.read(2)) < 2:
                    break
                body = bytes((a, 0x13, 0x20))  # READ_STAT item 0x20
                port.write(b"\xaa" + body + bytes((sum(body) & 0xFF,)))
                reply = port.read(4)
                versions.append((reply[1], reply[2]))
            assert versions == [(0, 12)] * 4  # four modules answer, each a PIC-SERVO of version 12
        finally:
            port.close()
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_standing_machine_skips_its_idle_servo_ticks_and_still_feels_a_part_put_on_the_probe(stations):
    """The probe and the home switches read only the axes: while every module is idle the network skips the
    servo ticks between host packets (they would change nothing), and the probe check runs again at the end of
    each skipped stretch, so a ball put on the standing stylus still trips it."""
    sim, m, _ = stations.machine(home_switches=True)
    net = sim.network
    try:
        m.move_to([300.0, 200.0, 250.0]).wait()
        watched, every = [], []
        net.add_tick_hook(lambda n, tick: watched.append(tick), reads_axes_only=True)
        for _ in range(200):  # 10 s of a host sampling every 50 ms
            m.poll()
            m.clock.sleep(0.05)
        assert 150 <= len(watched) < 2000  # about one check per host packet, not 20 000 ticks
        trips = sim.triggers
        sim.place_artifacts([(sim.tip_position() + [0.0, 0.0, -12.0], 25.0)])  # a 25 mm ball pushed onto the tip
        m.poll()
        m.clock.sleep(0.05)
        assert sim.triggers == trips + 1
        net.add_tick_hook(lambda n, tick: every.append(tick))  # a hook that must see every tick stops the skip
        for _ in range(20):
            m.poll()
            m.clock.sleep(0.05)
        assert len(every) >= 0.99 * 2000
    finally:
        m.close()

"""sim:// URLs: any part of the host opens an in-process simulated network like a serial port."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import serial

from cmm.machine.config import load
from cmm.machine.motion import Machine
from cmm.nmc import codec
from cmm.nmc.bus import Bus
from cmm.nmc.transport import TransportError, open_port
from cmm.sim import url as sim_url
from cmm.station import Station, StationError


def test_serial_for_url_opens_a_virtual_network_with_its_own_clock():
    port, clock = open_port("sim://?modules=2&firmware=pic-servo-sc", 19200, 0.05)
    assert isinstance(port, serial.SerialBase) and clock is port
    t0 = clock.now()
    port.write(bytes.fromhex("AA 00 21 01 FF 21"))  # SET_ADDR 1: the furthest module answers
    reply = port.read(2)
    assert reply[1] == reply[0]  # status byte + checksum
    assert 0 < clock.now() - t0 < 0.01  # a transaction costs simulated time, not wall time
    clock.sleep(5.0)  # five simulated seconds pass at once
    assert clock.now() - t0 >= 5.0
    assert port.world.network.firmware == "pic-servo-sc" and len(port.world.network.modules) == 2
    port.close()


def test_the_driver_initialises_and_switches_baud_through_a_url():
    bus = Bus("sim://?modules=3&module_version=7")
    infos = bus.initialize(115200, expected_modules=3)
    assert [(i.address, i.version) for i in infos] == [(1, 7), (2, 7), (3, 7)]
    net = bus.port.world.network
    assert net.host_baud == 115200 and all(m.baud == 115200 for m in net.modules)
    bus.close()


def test_a_host_that_does_not_switch_its_rate_fails_as_on_a_real_port():
    bus = Bus("sim://?modules=1")
    bus.initialize(None)
    bus.transact(codec.set_baud(1, 10))  # the module answers at 19200, then moves to 115200
    assert bus._attempt(codec.nop(1), 0) is None  # the host still talks at 19200: nothing comes back
    bus.close()


def test_named_worlds_are_shared_and_reopening_is_a_reconnect():
    world = sim_url.open_world("sim://bench-a?modules=1")
    try:
        assert sim_url.get("bench-a") is world and world.url.startswith("sim://bench-a?")
        bus = Bus("sim://bench-a?modules=1")
        bus.initialize(115200)
        bus.close()
        assert world.network.modules[0].address == 1  # the same modules, still addressed
        again = Bus(world.url)
        again._set_host_baud(115200)
        assert again._attempt(codec.nop(1), 0) is not None  # still at 115200: no power cycle
        again.close()
    finally:
        sim_url.release("bench-a")
    assert sim_url.get("bench-a") is None


@pytest.mark.parametrize("url, message", [
    ("sim://?cmm=1&clock=fast", "clock must be one of"),
    ("sim://?modul=3", "unknown sim:// option 'modul'"),
    ("sim://?modules=40", "1 to 32 modules"),
    ("sim://?firmware=pic-stepper", "unknown firmware"),
])
def test_bad_urls_are_refused_in_plain_words(url, message):
    with pytest.raises(TransportError, match=message):
        Bus(url)


def test_realtime_clock_follows_the_wall():
    port, clock = open_port("sim://?modules=1&clock=realtime", 19200, 0.05)
    w0, t0 = time.perf_counter(), clock.now()
    port.write(bytes.fromhex("AA 00 21 01 FF 21"))
    assert len(port.read(2)) == 2
    elapsed_sim, elapsed_wall = clock.now() - t0, time.perf_counter() - w0
    assert elapsed_sim <= elapsed_wall + 0.01  # never ahead of the wall clock
    port.close()


def test_machine_poll_thread_runs_on_the_virtual_clock_with_other_threads_waiting():
    """A background poll thread drives the virtual clock; callers in other threads
    waiting on wall time see moves finish and do not deadlock."""
    config = load()
    machine = Machine(config, "sim://?cmm=1")
    machine.connect()
    machine.start_polling()
    try:
        start = machine.clock.now()
        results = []

        def mover(target):
            results.append(machine.move_to(target).wait(20.0))  # a wall-clock wait: the poll thread works

        threads = [threading.Thread(target=mover, args=([100.0, 120.0, 250.0],))]
        for t in threads:
            t.start()
        for t in threads:
            t.join(30.0)
        assert not any(t.is_alive() for t in threads)
        assert results and np.allclose(machine.state.position, [100.0, 120.0, 250.0], atol=0.01)
        assert machine.clock.now() - start > 1.0  # simulated seconds went by (a move of ~100 mm)
    finally:
        machine.close()


def test_station_runs_in_process_on_the_virtual_clock(stations):
    st = stations.station("virtual")
    try:
        assert st.port.startswith("sim://world") and st.sim is not None
        assert sim_url.get(st.port).cmm is st.sim  # the composition root reaches the world it opened
        top = (st.measurement.part.pose @ np.array([20.0, 15.0, 40.0, 1.0]))[:3]
        hit = st.measurement.probe(top, [0, 0, -1], clearance_z=70.0).wait(30)
        assert abs(hit.point[2] - top[2]) < 0.5  # the simulated part is where the set-up says, give or take
        assert st.sim.triggers >= 1
    finally:
        st.close()
    assert sim_url.get(st.port) is None  # the station's own world goes with it


def test_station_refuses_a_bare_network_url(tmp_path):
    with pytest.raises(StationError, match="cmm=1"):
        Station(port="sim://?modules=3", session_dir=tmp_path)


def test_a_paced_virtual_clock_does_not_run_ahead_of_the_wall():
    """pace=2: a poll loop may not take more than two simulated seconds per wall second
    (only the safe direction is asserted: a loaded machine makes wall time longer)."""
    port, clock = open_port("sim://?modules=1&pace=2", 19200, 0.05)
    assert port.world.url.endswith("pace=2")
    w0, t0 = time.perf_counter(), clock.now()
    for _ in range(20):
        clock.sleep(0.01)
    assert clock.now() - t0 == pytest.approx(0.2)
    assert time.perf_counter() - w0 >= (0.2 - 0.05) / 2  # 50 ms of forgiven lag at most
    port.close()
    with pytest.raises(TransportError, match="pace"):
        Bus("sim://?pace=0")

"""NMC link and machine-layer throughput, and trigger-to-hit latency.

Prints:
  (issue 2b) 3-axis status sample rate with wire emulation at 115200 baud,
             in-process (virtual clock) and over TCP (real time), as a
             fraction of the wire limit;
  (issue 3)  position samples per second the machine layer publishes for
             3 axes over the served simulator, and the time from the probe
             trigger to the compensated hit.

The wire limit counts only bytes on the wire (10 bits per byte). The
protocol adds an unavoidable wait: a command executes at the end of the
servo tick in which it arrived (0.256 ms on average), so the protocol limit
is also printed.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from cmm.nmc import codec
from cmm.nmc.bus import Bus
from cmm.nmc.module import Module
from cmm.sim.network import SimNetwork
from cmm.sim.serve import serve_tcp

BAUD = 115200
ITEMS = codec.SEND_POS | codec.SEND_AUX


def limits(items: int, axes: int = 3) -> tuple[float, float]:
    bits = (4 + codec.status_length(items)) * 10
    per_axis = bits / BAUD
    return 1.0 / (axes * per_axis), 1.0 / (axes * (per_axis + codec.TICK_SECONDS / 2))


def sample_rate(bus: Bus, seconds: float, use_clock: bool) -> float:
    mods = [Module(bus, m.address) for m in bus.modules]
    for m in mods:
        m.define_status(ITEMS)
    clock = bus.clock if use_clock else None
    now = clock.now if clock else time.perf_counter
    t0, n = now(), 0
    while now() - t0 < seconds:
        for m in mods:
            m.nop()
        n += 1
    return n / (now() - t0)


def report(name: str, rate: float, items: int) -> None:
    wire, protocol = limits(items)
    print(f"  {name:<38} {rate:8.1f} /s   {rate / wire:6.1%} of wire limit {wire:.0f}/s, "
          f"{rate / protocol:6.1%} of protocol limit {protocol:.0f}/s")


def main() -> None:
    print(f"3-axis status sampling at {BAUD} baud, items position + aux ({codec.status_length(ITEMS)}-byte replies)")
    net = SimNetwork(3, wire_time=True)
    bus = Bus(net.transport())
    bus.initialize(BAUD)
    report("in-process, virtual clock", sample_rate(bus, 2.0, use_clock=True), ITEMS)
    net = SimNetwork(3, wire_time=True)
    with serve_tcp(net) as served:
        bus = Bus(served.url)
        bus.initialize(BAUD)
        report("TCP, real time", sample_rate(bus, 3.0, use_clock=False), ITEMS)
        bus.close()

    from cmm.machine.config import load
    from cmm.machine.motion import Machine
    from cmm.sim.cmm_sim import SimulatedCMM
    from cmm.station import Station

    sim = SimulatedCMM(load(), wire_time=True)
    machine = Machine(sim.config, sim.transport())
    machine.connect()
    print(f"machine layer publishing (items {machine.items:#04x}, {codec.status_length(machine.items)}-byte replies)")
    n0, t0 = machine.samples, machine.clock.now()
    machine.run_for(2.0)
    report("machine.poll in-process, virtual clock", (machine.samples - n0) / (machine.clock.now() - t0), machine.items)

    with tempfile.TemporaryDirectory() as tmp:
        station = Station(session_dir=tmp).start(home=True)
        try:
            m = station.machine
            n0, t0 = m.samples, time.perf_counter()
            time.sleep(3.0)
            rate = (m.samples - n0) / (time.perf_counter() - t0)
            report("machine.poll over TCP, real time", rate, m.items)
            latencies = []
            got = []
            station.prober.listeners.append(lambda hit: got.append(time.perf_counter()))
            for xy in [(230, 180), (240, 180), (250, 185), (260, 190), (270, 195)]:
                st = station.probe([*xy, 40.0], [0, 0, -1], clearance_z=60.0)
                st.wait(60)
                latencies.append((got[-1] - station.sim.last_trigger_wall) * 1e3)
            print(f"trigger -> compensated hit: median {np.median(latencies):.1f} ms, max {max(latencies):.1f} ms "
                  f"over {len(latencies)} hits")
        finally:
            station.close()


if __name__ == "__main__":
    main()

"""NMC link and machine-layer throughput, and trigger-to-hit latency.

Prints:
  - 3-axis status sample rate with wire emulation at 115200 baud,
    in-process (virtual clock) and over TCP (real time), as a
    fraction of the wire limit;
  - position samples per second the machine layer publishes for
    3 axes over the served simulator, and the time from the probe
    trigger to the compensated hit;
  - the real-time reply latency distribution (p50, p99, max, and
    how many replies a host with a 20 ms / 50 ms time-out would
    have missed) over TCP (served by a thread of this process and
    by a separate `cmm sim` process) and over a pty, against the
    protocol's own minimum. ``--latency-only`` runs just that;
    ``--load N`` adds N busy processes (a loaded machine).

The wire limit counts only bytes on the wire (10 bits per byte). The
protocol adds an unavoidable wait: a command executes at the end of the
servo tick in which it arrived (0.256 ms on average), so the protocol limit
is also printed.
"""

from __future__ import annotations

import argparse
import multiprocessing
import re
import subprocess
import sys
import tempfile
import threading
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


def _busy(stop) -> None:
    while not stop.is_set():
        sum(range(10000))


def _nop_latencies(port, n: int, address: int = 1) -> np.ndarray:
    """Wall seconds from writing a NOP to holding its whole reply (items position + aux: 7 bytes)."""
    packet = codec.nop(address)
    size = codec.status_length(ITEMS)
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        port.write(packet)
        got = port.read(size)
        out[i] = time.perf_counter() - t0
        if len(got) != size:
            out[i] = np.inf  # no reply within the port's 1 s time-out
        time.sleep(0.0005)  # a host doing a little work between transactions
    return out


def _prepare(port) -> None:
    """Address one module, status items position + aux, switch to 115200 (raw bytes)."""
    port.write(bytes(20))
    time.sleep(0.05)
    port.reset_input_buffer()
    for a in (1, 2, 3):
        port.write(codec.set_addr(0, a))
        port.read(2)
        port.write(codec.def_stat(a, ITEMS))
        port.read(codec.status_length(ITEMS))
    port.write(codec.set_baud(0xFF, codec.baud_divisor(BAUD)))
    time.sleep(0.1)
    port.baudrate = BAUD
    port.reset_input_buffer()


def report_latency(name: str, lat: np.ndarray) -> None:
    ms = lat * 1e3
    minimum = ((4 + codec.status_length(ITEMS)) * 10 / BAUD + codec.TICK_SECONDS / 2) * 1e3
    print(f"  {name:<31} p50 {np.percentile(ms, 50):6.2f} ms  p99 {np.percentile(ms, 99):6.2f} ms  "
          f"max {ms.max():7.2f} ms   > 20 ms: {int((ms > 20).sum())}, > 50 ms: {int((ms > 50).sum())} "
          f"of {len(ms)}   (protocol minimum {minimum:.2f} ms on average)")


def latency(n: int, load: int) -> None:
    import serial

    from cmm.sim.serve import serve_pty

    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=_busy, args=(stop,), daemon=True) for _ in range(load)]
    for h in hogs:
        h.start()
    try:
        print(f"real-time NOP reply latency, 3 modules at {BAUD} baud with wire emulation, {n} transactions"
              + (f", {load} busy processes" if load else ""))
        with serve_tcp(SimNetwork(3, wire_time=True)) as served:
            port = serial.serial_for_url(served.url, timeout=1.0)
            _prepare(port)
            report_latency("TCP, server thread in-process", _nop_latencies(port, n))
            busy = threading.Event()
            worker = threading.Thread(target=_busy, args=(busy,), daemon=True)  # like `cmm serve`'s UI threads
            worker.start()
            tight = sys.getswitchinterval()  # what serving set (cmm.sim.serve.SWITCH_INTERVAL_S)
            for interval in (0.005, tight):  # Python's default GIL switch interval, then the served one
                sys.setswitchinterval(interval)
                report_latency(f"  + a busy thread, GIL {interval * 1e3:g} ms", _nop_latencies(port, n))
            busy.set()
            worker.join()
            port.close()
        proc = subprocess.Popen([sys.executable, "-m", "cmm.cli", "sim", "--tcp", "127.0.0.1:0"],
                                stdout=subprocess.PIPE, text=True)
        try:
            url = None
            for _ in range(20):
                m = re.search(r"socket://\S+", proc.stdout.readline())
                if m:
                    url = m.group(0)
                    break
            port = serial.serial_for_url(url, timeout=1.0)
            _prepare(port)
            report_latency("TCP, `cmm sim` process", _nop_latencies(port, n))
            port.close()
        finally:
            proc.terminate()
            proc.wait(10)
        if sys.platform != "win32":
            with serve_pty(SimNetwork(3, wire_time=True)) as served:
                port = serial.Serial(served.url, 19200, timeout=1.0)
                _prepare(port)
                report_latency("pty, server thread in-process", _nop_latencies(port, n))
                port.close()
    finally:
        stop.set()
        for h in hogs:
            h.join(5)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latency-only", action="store_true", help="only the real-time reply latency")
    parser.add_argument("--transactions", type=int, default=3000, help="NOPs per latency run (default 3000)")
    parser.add_argument("--load", type=int, default=0, metavar="N", help="busy processes during the latency runs")
    args = parser.parse_args()
    latency(args.transactions, args.load)
    if args.latency_only:
        return
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
                st = station.measurement.probe([*xy, 40.0], [0, 0, -1], clearance_z=60.0)
                st.wait(60)
                latencies.append((got[-1] - station.sim.last_trigger_wall) * 1e3)
            print(f"trigger -> compensated hit: median {np.median(latencies):.1f} ms, max {max(latencies):.1f} ms "
                  f"over {len(latencies)} hits")
        finally:
            station.close()


if __name__ == "__main__":
    main()

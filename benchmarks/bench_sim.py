"""Simulator throughput figures (pure Python, one core).

(a) raw in-process NOP transactions per second, position + aux status,
    virtual clock, wire emulation off;
(b) simulated seconds per wall second for 3 axes at 1953.125 Hz, idle and
    while all three axes move (velocity mode, so they never stop).

Run: python benchmarks/bench_sim.py
"""

from __future__ import annotations

import time

from cmm.nmc import codec as c
from cmm.sim.network import SimNetwork
from cmm.sim.plant import DEFAULT_GAINS

ITEMS = c.SEND_POS | c.SEND_AUX


def init(net: SimNetwork, baud: int = 19200):
    """Address the chain and enable the servos, through bytes only."""
    t = net.transport(baudrate=baud)
    t.write(bytes(16))
    t.read(64)
    status_len = c.status_length(ITEMS)
    for addr in range(1, len(net.modules) + 1):
        t.write(c.set_addr(0, addr))
        assert len(t.read(2)) == 2
        for packet in (c.def_stat(addr, ITEMS), c.set_gain(addr, DEFAULT_GAINS),
                       c.stop_motor(addr, c.AMP_ENABLE | c.STOP_ABRUPT), c.clear_bits(addr)):
            t.write(packet)
            reply = t.read(status_len)
            assert len(reply) == status_len
    return t


def bench_nop(seconds: float = 2.0) -> float:
    net = SimNetwork(3)
    t = init(net)
    packets = [c.nop(a) for a in (1, 2, 3)]
    n = c.status_length(ITEMS)
    count = 0
    write, read = t.write, t.read
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end:
        for p in packets:
            write(p)
            if len(read(n)) != n:
                raise RuntimeError("a NOP went unanswered")
        count += 3
    return count / seconds


def bench_ticks(moving: bool, seconds: float = 2.0, hook: str = "") -> float:
    net = SimNetwork(3)
    if hook:  # a hook that must see every tick disables the exact idle skip; one that reads the axes only
        # (the CMM's probe and home switches) does not
        net.add_tick_hook(lambda network, tick: None, reads_axes_only=hook == "axes")
    t = init(net)
    n = c.status_length(ITEMS)
    if moving:
        vel = c.velocity_to_fixed(40, 500)
        acc = c.acceleration_to_fixed(1000, 500)
        for a in (1, 2, 3):
            t.write(c.load_traj(a, velocity=vel, acceleration=acc, velocity_mode=True))
            t.read(n)
    sim0 = net.now_ns
    w0 = time.perf_counter()
    while time.perf_counter() - w0 < seconds:
        t.sleep(0.1)
    wall = time.perf_counter() - w0
    if moving:
        t.write(c.nop(1))
        assert c.parse_status(t.read(n), ITEMS).position > 0
    return (net.now_ns - sim0) * 1e-9 / wall


def main() -> None:
    print(f"(a) in-process NOP transactions/s (position+aux, wire off): {bench_nop():,.0f}")
    idle = bench_ticks(False)
    moving = bench_ticks(True)
    hooked_idle = bench_ticks(False, hook="every")
    hooked = bench_ticks(True, hook="every")
    probe_idle = bench_ticks(False, hook="axes")
    for label, x in (("idle", idle), ("moving", moving), ("idle, tick hook", hooked_idle),
                     ("moving, tick hook", hooked), ("idle, probe hook", probe_idle)):
        print(f"(b) 3 axes at 1953 Hz, {label + ':':18s} {x:12,.1f} simulated s per wall s "
              f"({x * 3 * 1953.125:,.0f} module-ticks/s)")


if __name__ == "__main__":
    main()

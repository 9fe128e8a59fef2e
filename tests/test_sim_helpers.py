"""A minimal byte-level host for the simulator tests (no driver, codec only).

Imported by the other tests/test_sim_*.py files; holds no tests itself.
"""

from __future__ import annotations

from cmm.nmc import codec as c
from cmm.sim.network import SimNetwork
from cmm.sim.plant import DEFAULT_GAINS

ITEMS = c.SEND_POS | c.SEND_AUX


class Host:
    """Talks to a SimNetwork through its in-process transport, bytes only."""

    def __init__(self, net: SimNetwork, timeout: float = 0.05) -> None:
        self.net = net
        self.port = net.transport(timeout=timeout)
        self.items: dict[int, int] = {}

    def raw(self, packet: bytes, n: int) -> bytes:
        """Send a packet, read up to ``n`` reply bytes."""
        self.port.write(packet)
        return self.port.read(n)

    def cmd(self, packet: bytes, items: int | None = None) -> c.Status | None:
        """Send a packet to one module and parse its status reply (None: no reply)."""
        addr = packet[1]
        if items is None:
            items = self.items.get(addr, 0)
        n = c.status_length(items)
        reply = self.raw(packet, n)
        if not reply:
            return None
        assert len(reply) == n, reply.hex(" ")
        return c.parse_status(reply, items)

    def init(self, n: int | None = None, gains: c.Gains = DEFAULT_GAINS, items: int = ITEMS) -> None:
        """Address the chain 1..n, define status, send gains, enable the servos."""
        self.port.write(bytes(16))
        self.port.read(100)
        self.port.reset_input_buffer()
        for addr in range(1, (n or len(self.net.modules)) + 1):
            assert self.cmd(c.set_addr(0, addr)) is not None
            self.cmd(c.def_stat(addr, items), items)
            self.items[addr] = items
            self.cmd(c.set_gain(addr, gains))
            self.cmd(c.stop_motor(addr, c.AMP_ENABLE | c.STOP_ABRUPT))
            self.cmd(c.clear_bits(addr))

    def nop(self, addr: int) -> c.Status:
        s = self.cmd(c.nop(addr))
        assert s is not None
        return s

    def wait_done(self, addr: int, limit_s: float = 20.0) -> c.Status:
        t_end = self.port.now() + limit_s
        while self.port.now() < t_end:
            s = self.nop(addr)
            if s.move_done:
                return s
        raise AssertionError("move did not finish")

    def settle(self, seconds: float = 0.05) -> None:
        self.port.sleep(seconds)

"""In-process transport: the pyserial subset the NMC driver uses, over a SimNetwork.

With a virtual clock (the default) simulated time advances only while the
host waits (``read`` blocking, ``sleep``), as fast as the CPU allows: a
transaction costs exactly the rest of the current servo tick (plus the wire
time when emulated). With ``SimNetwork(realtime=True)`` the clock is the wall
clock and reads really wait.

Several host threads may share one transport (a poll thread plus callers):
every step holds the network's lock. On the virtual clock ``sleep`` is a
deadline: the caller's time has come once the shared clock reaches call time
+ seconds, whoever advanced it, so two threads sleeping at once do not add up.
``network.pace`` caps how fast the virtual clock runs (simulated s per wall s):
a poll thread then cannot race ahead of callers acting in wall time (a jog
pendant's refreshes against the machine's dead-man time-out).
"""

from __future__ import annotations

import threading
import time
from typing import Any

# A blocking read (timeout None) on a virtual clock still gives up after this
# much simulated time, so a host waiting for a reply that never comes ends.
VIRTUAL_BLOCK_LIMIT_S = 10.0


class SimTransport:
    """``serial.Serial``-like byte pipe to a simulated NMC network (the :class:`cmm.sim.network.SimNetwork` that
    made it: its lock, clock and host byte queues)."""

    def __init__(self, network: Any, baudrate: int = 19200, timeout: float | None = 0.1) -> None:
        self.network = network
        self.timeout = timeout
        self.write_timeout: float | None = None
        self.port = "sim://"
        self.is_open = True
        self.baudrate = baudrate

    # pyserial attributes -------------------------------------------------------
    @property
    def baudrate(self) -> int:
        return self._baudrate

    @baudrate.setter
    def baudrate(self, value: int) -> None:
        self._baudrate = int(value)
        self.network.host_baud = self._baudrate

    @property
    def in_waiting(self) -> int:
        with self.network.lock:
            self.network.sync()
            return len(self.network.host_in)

    @property
    def out_waiting(self) -> int:
        return 0

    def _check_open(self) -> None:
        if not self.is_open:
            raise OSError("the simulated port is closed")

    # byte I/O ----------------------------------------------------------------------
    def write(self, data: bytes | bytearray | memoryview) -> int:
        self._check_open()
        data = bytes(data)
        with self.network.lock:
            self.network.host_write(data)
        return len(data)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes; waits up to ``timeout`` seconds of simulated time."""
        self._check_open()
        net = self.network
        buf = net.host_in
        wait = VIRTUAL_BLOCK_LIMIT_S if self.timeout is None else self.timeout
        if net.realtime:
            deadline = time.perf_counter() + wait
            while True:
                with net.lock:
                    net.sync()
                    if len(buf) >= size or time.perf_counter() >= deadline:
                        return net.host_read(size)
                time.sleep(0.0002)
        with net.lock:
            deadline = net.now_ns + round(wait * 1e9)
            while len(buf) < size and net.now_ns < deadline:
                if net.busy():
                    net.advance_to(min(deadline, net.next_event_ns()))
                else:
                    net.advance_to(deadline)  # nothing can arrive: the whole time-out passes
            data = net.host_read(size)
        net.hold_pace()
        return data

    def quiet_for(self) -> float | None:
        """Simulated seconds during which no byte can reach the host (None: none until the host writes), for a
        wrapper that polls without blocking (:class:`cmm.nmc.faults.FaultyTransport`) to sleep through."""
        net = self.network
        with net.lock:
            if net.realtime:
                return 0.0
            if net.host_in:
                return 0.0
            if not net.busy():
                return None
            return max(0.0, (net.next_event_ns() - net.now_ns) * 1e-9)

    def read_all(self) -> bytes:
        with self.network.lock:
            self.network.sync()
            return self.network.host_read()

    def reset_input_buffer(self) -> None:
        with self.network.lock:
            self.network.sync()
            self.network.host_in.clear()

    def reset_output_buffer(self) -> None:
        pass  # bytes are on the wire as soon as written

    def flush(self) -> None:
        """Wait until written bytes have left (only takes time with wire emulation)."""
        net = self.network
        with net.lock:
            if net.wire_time and not net.realtime and net._host_tx_free > net.now_ns:
                net.advance_to(net._host_tx_free)

    def close(self) -> None:
        self.is_open = False

    def open(self) -> None:
        self.is_open = True

    def __enter__(self) -> "SimTransport":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # clock ------------------------------------------------------------------------
    @property
    def virtual(self) -> bool:
        """Simulated time that runs only while the host waits (not the wall clock)."""
        return not self.network.realtime

    def now(self) -> float:
        """Simulated seconds since power-up (wall time when real time)."""
        net = self.network
        if net.realtime:
            with net.lock:
                net.sync()
        return net.now_ns * 1e-9

    def rest(self, seconds: float) -> None:
        """A sleep of a host with nothing to do (:func:`cmm.nmc.transport.rest`): uncapped, also in wall time."""
        self.sleep(seconds)
        if not self.network.realtime and not self.network.pace and seconds > 0:
            time.sleep(seconds)

    def sleep(self, seconds: float) -> None:
        net = self.network
        if seconds <= 0:
            return
        if net.realtime:
            time.sleep(seconds)
            with net.lock:
                net.sync()
            return
        wake = net.now_ns + round(seconds * 1e9)  # the deadline counts from the call
        with net.lock:
            net.advance_to(wake)
        if net.pace:
            net.hold_pace()
        elif threading.active_count() > 1:
            time.sleep(0)  # let other threads in (the clock stands still while nobody waits)

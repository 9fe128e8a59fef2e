"""Fault injection on the NMC byte stream: for tests and benchmarks of link robustness.

Two ways in, one fault model:
- :class:`FaultyTransport` wraps any transport in-process (the simulator's on
  its virtual clock, or a pyserial port); the bus opens it like a port.
- :class:`FaultProxy` is a TCP proxy in front of ``cmm sim --tcp`` (or any
  ``socket://`` NMC link); the bus opens ``proxy.url``.

A fault is armed with ``inject(Fault(...))`` and hits the next byte that
passes in its direction ("rx": module -> host replies, "tx": host -> module
commands, "both"):
- ``drop``: the next ``count`` bytes are lost;
- ``flip``: one random bit flips in each of the next ``count`` bytes;
- ``garbage``: ``count`` random bytes are inserted before the next byte;
- ``stall``: from the next byte on, bytes are held for ``duration`` s and then
  delivered in order (a stalled device, a busy host, a USB adapter hiccup);
- ``blackout``: from the next byte on, every byte is lost for ``duration`` s;
  (with direction "both", a stall or blackout starts at once on both lines)
- ``disconnect``: the connection drops now; the in-process transport then
  raises the exception pyserial raises (``error``: "serial" for
  SerialException, "write_timeout" for SerialTimeoutException, "oserror" for
  OSError) until :meth:`FaultyTransport.restore` (a write time-out leaves
  reads working but silent).

:class:`FaultyTransport` can also play a *descheduled host* (``deschedule`` s): after each piece of a reply
its read has taken, the host is off the CPU that long before it looks again; once its time-out has passed
meanwhile the read returns what it had (as pyserial's reads do), though the rest of the reply has arrived.
No byte is lost: the rest waits in the port's buffer. With ``oversleep`` s, a read whose time-out passes
without its bytes comes back that much late (the host was off the CPU at its deadline) with what arrived
meanwhile.

Run ``python -m cmm.nmc.faults --target 127.0.0.1:7777`` to put a proxy in
front of a served simulator and inject faults by hand.
"""

from __future__ import annotations

import argparse
import math
import random
import selectors
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import serial

FAULT_KINDS = ("drop", "flip", "garbage", "stall", "blackout", "disconnect")
DIRECTIONS = ("rx", "tx", "both")
ERRORS = ("serial", "write_timeout", "oserror")


@dataclass(frozen=True)
class Fault:
    kind: str
    direction: str = "rx"
    duration: float = 0.0  # stall / blackout, seconds
    count: int = 1  # bytes dropped, flipped or inserted
    error: str = "serial"  # what a disconnected in-process port raises

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault {self.kind!r}; use one of {', '.join(FAULT_KINDS)}")
        if self.direction not in DIRECTIONS:
            raise ValueError(f"unknown direction {self.direction!r}; use one of {', '.join(DIRECTIONS)}")
        if self.error not in ERRORS:
            raise ValueError(f"unknown error {self.error!r}; use one of {', '.join(ERRORS)}")
        if self.count < 1 or self.duration < 0 or not math.isfinite(self.duration):
            raise ValueError("a fault needs count >= 1 and a finite duration >= 0")

    def describe(self) -> str:
        extra = f" {self.duration * 1000:.0f} ms" if self.kind in ("stall", "blackout") else (
            f" x{self.count}" if self.kind in ("drop", "flip", "garbage") else "")
        return f"{self.kind}{extra} ({self.direction})"


def link_error(kind: str, where: str) -> Exception:
    """The exception pyserial raises for a dropped connection of this kind."""
    if kind == "write_timeout":
        return serial.SerialTimeoutException("Write timeout")
    if kind == "oserror":
        return OSError(5, f"Input/output error ({where} disconnected)")
    return serial.SerialException(f"{where} disconnected")


class FaultLine:
    """One direction of the link: bytes in with their arrival time, out when due, faults applied."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self.queue: deque[tuple[float, int]] = deque()
        self.armed: deque[list] = deque()  # [fault, bytes still to affect]
        self.stall_until = -math.inf
        self.blackout_until = -math.inf
        self.dropped = 0
        self.flipped = 0
        self.inserted = 0
        self.passed = 0

    def arm(self, fault: Fault) -> None:
        self.armed.append([fault, fault.count])

    def pending(self) -> bool:
        return bool(self.armed)

    def push(self, data: bytes, now: float) -> None:
        for b in data:
            if now < self.blackout_until:
                self.dropped += 1
                continue
            if self.armed:
                entry = self.armed[0]
                fault: Fault = entry[0]
                if fault.kind == "stall":
                    self.stall_until = max(self.stall_until, now + fault.duration)
                    self.armed.popleft()
                elif fault.kind == "blackout":
                    self.blackout_until = now + fault.duration
                    self.armed.popleft()
                    self.dropped += 1
                    continue
                elif fault.kind == "drop":
                    entry[1] -= 1
                    if entry[1] <= 0:
                        self.armed.popleft()
                    self.dropped += 1
                    continue
                elif fault.kind == "flip":
                    b ^= 1 << self.rng.randrange(8)
                    self.flipped += 1
                    entry[1] -= 1
                    if entry[1] <= 0:
                        self.armed.popleft()
                elif fault.kind == "garbage":
                    for _ in range(fault.count):
                        self._queue(self.rng.randrange(256), now)
                    self.inserted += fault.count
                    self.armed.popleft()
            self._queue(b, now)

    def _queue(self, b: int, now: float) -> None:
        due = max(now, self.stall_until, self.queue[-1][0] if self.queue else -math.inf)
        self.queue.append((due, b))
        self.passed += 1

    def pop_due(self, now: float) -> bytes:
        out = bytearray()
        q = self.queue
        while q and q[0][0] <= now:
            out.append(q.popleft()[1])
        return bytes(out)

    def next_due(self) -> float | None:
        return self.queue[0][0] if self.queue else None

    def clear(self) -> None:
        self.queue.clear()


class _Lines:
    """The two lines and the arming of faults on them."""

    def __init__(self, seed: int | None) -> None:
        self.rng = random.Random(seed)
        self.rx = FaultLine(self.rng)
        self.tx = FaultLine(self.rng)
        self.injected: list[Fault] = []

    def arm(self, fault: Fault, now: float) -> None:
        self.injected.append(fault)
        if fault.direction == "both" and fault.kind in ("stall", "blackout"):  # the whole link, from now
            for line in (self.rx, self.tx):
                if fault.kind == "stall":
                    line.stall_until = max(line.stall_until, now + fault.duration)
                else:
                    line.blackout_until = now + fault.duration
            return
        if fault.direction in ("rx", "both"):
            self.rx.arm(fault)
        if fault.direction in ("tx", "both"):
            self.tx.arm(fault)


class FaultyTransport:
    """A pyserial-like port that passes bytes through an inner one, with faults injected.

    The inner port is polled without blocking; time passes through the inner
    port's clock if it has one (the simulator's virtual clock), else the
    wall clock.
    """

    STEP = 0.0005  # s between polls of the inner port while a read waits (about a servo tick)

    def __init__(self, inner: Any, *, seed: int | None = None) -> None:
        self._inner = inner
        self._lines = _Lines(seed)
        self._ready = bytearray()
        self._error: str | None = None  # set while disconnected
        self.timeout: float | None = 0.1
        self.write_timeout: float | None = None
        self.port = f"faulty:{getattr(inner, 'port', 'port')}"
        self.is_open = True
        inner.timeout = 0
        self._virtual = hasattr(inner, "now") and hasattr(inner, "sleep")
        self.deschedule = 0.0  # s the host is off the CPU after each piece a read takes (see the module doc)
        self.oversleep = 0.0  # s a read that times out comes back late

    # --- faults ---------------------------------------------------------------------
    def inject(self, fault: Fault) -> None:
        if fault.kind == "disconnect":
            self._error = fault.error
            self._lines.rx.clear()
            self._lines.tx.clear()
            self._ready.clear()
            return
        self._lines.arm(fault, self.now())

    def restore(self) -> None:
        """Reconnect after a ``disconnect`` fault."""
        self._error = None

    @property
    def lines(self) -> _Lines:
        return self._lines

    def pending(self) -> bool:
        """A fault is armed and has not hit a byte yet."""
        return self._lines.rx.pending() or self._lines.tx.pending()

    # --- clock ----------------------------------------------------------------------
    def now(self) -> float:
        return self._inner.now() if self._virtual else time.monotonic()

    def sleep(self, seconds: float) -> None:
        end = self.now() + seconds
        while True:
            self._pump()
            left = end - self.now()
            if left <= 1e-7:  # the virtual clock counts whole nanoseconds
                return
            self._advance(self._until_due(left))

    def _until_due(self, cap: float) -> float:
        now = self.now()
        nxt = [t - now for t in (self._lines.tx.next_due(), self._lines.rx.next_due()) if t is not None]
        # a simulator that says when its next byte can come is slept through to then, not polled every STEP
        quiet = getattr(self._inner, "quiet_for", None) if self._virtual else None
        step = self.STEP
        if quiet is not None:
            q = quiet()
            step = cap if q is None else max(q, 1e-6)
        return max(min([cap, step, *nxt]), 1e-6) if cap > 1e-6 else cap

    def _advance(self, seconds: float) -> None:
        if self._virtual:
            self._inner.sleep(seconds)
        else:
            time.sleep(seconds)

    # --- pyserial interface -------------------------------------------------------
    @property
    def baudrate(self) -> int:
        return self._inner.baudrate

    @baudrate.setter
    def baudrate(self, value: int) -> None:
        self._inner.baudrate = value

    def _check(self, writing: bool = False) -> None:
        if not self.is_open:
            raise serial.PortNotOpenError()
        if self._error is not None and (writing or self._error != "write_timeout"):
            raise link_error(self._error, self.port)  # a stuck write: reads just see nothing

    def _pump(self) -> None:
        if self._error is not None:
            return
        now = self.now()
        out = self._lines.tx.pop_due(now)
        if out:
            self._inner.write(out)
        n = self._inner.in_waiting
        if n:
            self._lines.rx.push(self._inner.read(n), now)
        self._ready += self._lines.rx.pop_due(now)

    def write(self, data: bytes | bytearray | memoryview) -> int:
        self._check(writing=True)
        data = bytes(data)
        self._lines.tx.push(data, self.now())
        self._pump()
        return len(data)

    def read(self, size: int = 1) -> bytes:
        self._check()
        wait = 10.0 if self.timeout is None else self.timeout
        end = self.now() + wait
        while True:
            self._pump()
            self._check()
            left = end - self.now()
            if left <= 1e-7 and len(self._ready) < size and self.oversleep and end > 0:
                self.sleep(self.oversleep)  # off the CPU at the deadline: back late, with what came meanwhile
                end = 0.0
                continue
            if len(self._ready) >= size or left <= 1e-7:
                break
            if self.deschedule and self._ready:  # a piece came; the host is descheduled before it looks again
                got = len(self._ready)
                self.sleep(self.deschedule)
                if end - self.now() <= 1e-7:  # its time-out passed meanwhile: it returns what it had
                    size = got
                    break
                continue
            self._advance(self._until_due(left))
        out = bytes(self._ready[:size])
        del self._ready[:size]
        return out

    @property
    def in_waiting(self) -> int:
        self._check()
        self._pump()
        return len(self._ready)

    def read_all(self) -> bytes:
        n = self.in_waiting
        return self.read(n) if n else b""

    def reset_input_buffer(self) -> None:
        self._check()
        self._pump()
        self._ready.clear()

    def reset_output_buffer(self) -> None:
        pass

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.is_open = False
        self._inner.close()


class FaultProxy:
    """A TCP proxy in front of an NMC link served over TCP, with faults injected.

    One client at a time (the bus); a ``disconnect`` fault closes both sides,
    and the next client connection reaches the target again.
    """

    def __init__(self, target: str | tuple[str, int], *, seed: int | None = None, host: str = "127.0.0.1") -> None:
        if isinstance(target, str):
            target = target.removeprefix("socket://")
            h, _, p = target.rpartition(":")
            target = (h or "127.0.0.1", int(p))
        self.target = target
        self._lines = _Lines(seed)
        self._lock = threading.Lock()
        self._listener = socket.create_server((host, 0))
        self._listener.setblocking(False)
        self.url = "socket://{}:{}".format(*self._listener.getsockname()[:2])
        self._stop = threading.Event()
        self._drop = threading.Event()
        self.connections = 0
        self.disconnects = 0
        self._thread = threading.Thread(target=self._loop, name="nmc-fault-proxy", daemon=True)
        self._thread.start()

    def inject(self, fault: Fault) -> None:
        with self._lock:
            if fault.kind == "disconnect":
                self._lines.injected.append(fault)
                self._drop.set()
            else:
                self._lines.arm(fault, time.monotonic())

    def pending(self) -> bool:
        with self._lock:
            return self._lines.rx.pending() or self._lines.tx.pending()

    @property
    def lines(self) -> _Lines:
        return self._lines

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._listener.close()

    def __enter__(self) -> "FaultProxy":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _loop(self) -> None:
        sel = selectors.SelectSelector()  # microsecond time-outs (epoll rounds up to 1 ms)
        sel.register(self._listener, selectors.EVENT_READ, "listen")
        client: socket.socket | None = None
        server: socket.socket | None = None

        def drop() -> None:
            nonlocal client, server
            for s in (client, server):
                if s is not None:
                    try:
                        sel.unregister(s)
                    except (KeyError, ValueError):
                        pass
                    s.close()
            client = server = None
            with self._lock:
                self._lines.rx.clear()
                self._lines.tx.clear()

        try:
            while not self._stop.is_set():
                if self._drop.is_set():
                    self._drop.clear()
                    if client is not None:
                        self.disconnects += 1
                    drop()
                with self._lock:
                    nxt = [t for t in (self._lines.rx.next_due(), self._lines.tx.next_due()) if t is not None]
                wait = 0.001 if not nxt else min(0.001, max(0.0, min(nxt) - time.monotonic()))
                for key, _ in sel.select(wait):
                    if key.data == "listen":
                        try:
                            conn, _ = self._listener.accept()
                        except OSError:
                            continue
                        drop()
                        try:
                            server = socket.create_connection(self.target, timeout=2.0)
                        except OSError:
                            conn.close()
                            continue
                        client = conn
                        for s, tag in ((client, "client"), (server, "server")):
                            s.setblocking(False)
                            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                            sel.register(s, selectors.EVENT_READ, tag)
                        self.connections += 1
                        continue
                    try:
                        chunk = key.fileobj.recv(4096)
                    except OSError:
                        chunk = b""
                    if not chunk:
                        drop()
                        break
                    with self._lock:
                        line = self._lines.tx if key.data == "client" else self._lines.rx
                        line.push(chunk, time.monotonic())
                now = time.monotonic()
                with self._lock:
                    to_server = self._lines.tx.pop_due(now)
                    to_client = self._lines.rx.pop_due(now)
                try:
                    if to_server and server is not None:
                        server.sendall(to_server)
                    if to_client and client is not None:
                        client.sendall(to_client)
                except OSError:
                    drop()
        finally:
            drop()
            sel.close()


def main(argv: list[str] | None = None) -> None:
    """A proxy on the command line: faults typed on stdin, e.g. ``stall rx 0.3`` or ``disconnect``."""
    ap = argparse.ArgumentParser(prog="python -m cmm.nmc.faults", description=main.__doc__)
    ap.add_argument("--target", default="127.0.0.1:7777", help="the served link (cmm sim --tcp HOST:PORT)")
    args = ap.parse_args(argv)
    with FaultProxy(args.target) as proxy:
        print(f"proxy for {args.target}: open {proxy.url}; type KIND [rx|tx|both] [SECONDS|COUNT], empty line quits",
              flush=True)
        while True:
            line = input().split()
            if not line:
                return
            kind, direction = line[0], line[1] if len(line) > 1 else "rx"
            value = float(line[2]) if len(line) > 2 else 0.3
            try:
                fault = Fault(kind, direction, duration=value if kind in ("stall", "blackout") else 0.0,
                              count=int(value) if kind in ("drop", "flip", "garbage") and value >= 1 else 1)
            except ValueError as exc:
                print(exc)
                continue
            proxy.inject(fault)
            print(f"armed {fault.describe()}", flush=True)


if __name__ == "__main__":
    main()

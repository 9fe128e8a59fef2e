"""Serve a SimNetwork in real time over TCP or a pseudo-terminal.

One background thread owns the network: it feeds the bytes a client sends
(timestamped on arrival, serialised at the line rate when wire-time
emulation is on), runs the servo ticks to catch up with the wall clock in a
batch, and sends back the status bytes whose time has come. Hold
``handle.lock`` to touch the network (inputs, power) from another thread.

- TCP: one client at a time; a new connection replaces the old one; a client
  disconnecting leaves the modules as they are. A plain TCP link carries no
  line rate, so the host is assumed to follow the modules' baud rate (a host
  that never switches passes). With ``rfc2217=True`` the server speaks RFC 2217
  (Telnet COM-PORT-OPTION, pyserial's ``rfc2217://`` URLs): the client
  announces its line rate in the byte stream, in order with its data, and the
  modules judge every byte by it, as on a real port; a client that announces
  nothing stays at 19200.
- PTY: the device path works with any serial program. The line rate the
  client sets with termios is the host's baud rate: after SET_BAUD the client
  must switch, as on a real port. This is the faithful path for a host's baud
  handling. The rate is read before the bytes, and bytes are judged by the
  rate they were sent with. ``tcdrain`` returns at once on a pty, so a host
  may switch right after writing; when the serving thread sees new bytes and a
  new rate in the same look (it was late), it cannot tell which came first and
  takes the rate the modules listen at, new before old.
"""

from __future__ import annotations

import os
import selectors
import socket
import sys
import termios
import threading
import tty
from dataclasses import dataclass, field

from cmm.nmc import codec as c
from cmm.sim.network import SimNetwork, rates_match

_POLL_S = 0.002  # loop period when idle (new bytes wake it at once; this bounds the catch-up work)
# A server thread woken by the OS must then take the GIL from any busy Python thread of the host
# (the UI, the poll loop): it waits up to the interpreter's switch interval (5 ms by default).
SWITCH_INTERVAL_S = 0.001
# The serving thread keeps wire time like a real module: it asks for the priority the link process has (nice -10,
# where permitted), so on a busy computer the bytes a host wrote before and after switching its rate are not
# read together, late, and judged at one rate (a pty carries no rate per byte).
SERVE_NICE = -10


def _raise_serving_priority() -> None:
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), SERVE_NICE)
    except (AttributeError, OSError):
        pass  # not permitted: the thread keeps the process's priority


def _tighten_gil() -> None:
    """Process-wide: busy threads hand over the GIL every 1 ms instead of 5 (costs them a little)."""
    if sys.getswitchinterval() > SWITCH_INTERVAL_S:
        sys.setswitchinterval(SWITCH_INTERVAL_S)


_SPEEDS = {getattr(termios, f"B{r}"): r for r in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)
           if hasattr(termios, f"B{r}")}


@dataclass
class ServedSim:
    """A simulator served by a background thread; ``close()`` stops it."""

    network: SimNetwork
    url: str  # what the driver opens: socket://host:port or the pty device path
    _thread: threading.Thread | None = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _closers: list = field(default_factory=list)

    @property
    def lock(self) -> threading.RLock:
        return self.network.lock

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for closer in self._closers:
            try:
                closer()
            except OSError:
                pass

    def __enter__(self) -> "ServedSim":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_SAME = object()


def _pump(network: SimNetwork, data: bytes | None, sent_at: object = _SAME, rate_now: object = _SAME) -> bytes:
    """One step of the real-time loop: catch up with the wall clock, take host bytes (sent at
    host rate ``sent_at``; the host's rate is ``rate_now`` from then on), return reply bytes.

    Bytes are taken to arrive now, after the catch-up, also when the thread was
    held up: a reply computed at an earlier simulated time would report
    positions a catch-up later jumps past, which a host's continuity check
    rightly rejects."""
    with network.lock:
        network.sync()
        if data:
            if sent_at is not _SAME:
                network.host_baud = sent_at  # type: ignore[assignment]
            network.host_write(data)
        if rate_now is not _SAME:
            network.host_baud = rate_now  # type: ignore[assignment]
        return network.host_read()


def _sent_rate(network: SimNetwork, *rates: int) -> int:
    """Bytes that came with a rate change (``rates``: the host's rates seen, oldest first): the rate they were
    sent at.

    A host switches either right after its SET_BAUD command (modules still at the
    old rate) or before talking to modules that have switched: take the rate
    some module listens at, the newest first."""
    for rate in reversed(rates):
        if any(m.comms_enabled and rates_match(m.line_rate, rate) for m in network.modules):
            return rate
    return rates[-1]


def _wait_s(network: SimNetwork) -> float:
    """Sleep until something the host will see is due, at most one poll period."""
    with network.lock:
        if not network.busy():
            return _POLL_S
        # a reply is handed over whole when its last byte is due: the host acts only on
        # complete packets, and one wake-up per reply instead of per byte keeps up with the wire
        due = network._tx[-1][1] if network._tx else network.next_event_ns()
        if network._rx:  # wire emulation: a command byte still on its way in
            due = min(due, max(network._rx[0][0], (network._rx[0][0] // 512_000 + 1) * 512_000))
    return min(_POLL_S, max(0.0, (due - network.wall_ns()) * 1e-9))


class _AnnouncedLine:
    """The serial settings an RFC 2217 client sets, seen as a port by pyserial's PortManager.

    A rate change first hands the bytes the client sent before it to the
    network (``flush``), so every byte is judged at the rate it was sent with."""

    def __init__(self, network: SimNetwork, flush) -> None:
        self.network = network
        self.flush = flush
        self.bytesize, self.parity, self.stopbits = 8, "N", 1
        self.xonxoff = self.rtscts = self.break_condition = False
        self.dtr = self.rts = True
        self.cts = self.dsr = self.cd = True  # modem lines are not wired on an NMC network
        self.ri = False

    @property
    def baudrate(self) -> int:
        return self.network.host_baud or c.POWER_UP_BAUD

    @baudrate.setter
    def baudrate(self, rate: int) -> None:
        self.flush()
        with self.network.lock:
            self.network.host_baud = int(rate)

    def reset_input_buffer(self) -> None:  # PURGE receive buffer: replies not yet sent
        with self.network.lock:
            self.network.host_in.clear()

    def reset_output_buffer(self) -> None:
        pass


def serve_tcp(network: SimNetwork, host: str = "127.0.0.1", port: int = 0, *, rfc2217: bool = False) -> ServedSim:
    """Serve on ``host:port`` (port 0: an ephemeral port, see ``.url``); ``rfc2217``: the
    client announces its line rate by RFC 2217 and it is enforced (``.url`` is rfc2217://...)."""
    listener = socket.create_server((host, port))
    listener.setblocking(False)
    bound_host, bound_port = listener.getsockname()[:2]
    handle = ServedSim(network, f"{'rfc2217' if rfc2217 else 'socket'}://{bound_host}:{bound_port}")
    network.host_baud = c.POWER_UP_BAUD if rfc2217 else None  # plain TCP carries no line rate
    network.start_realtime()
    _tighten_gil()
    sel = selectors.SelectSelector()  # microsecond time-outs: epoll and poll round up to whole milliseconds
    sel.register(listener, selectors.EVENT_READ)
    client: list[socket.socket] = []
    telnet: list = []  # the client's RFC 2217 PortManager
    pending = bytearray()  # client data not yet handed to the network
    out = bytearray()  # replies not yet sent

    def drop_client() -> None:
        for s in client:
            sel.unregister(s)
            s.close()
        client.clear()
        telnet.clear()

    def send(data: bytes) -> None:
        if data and client:
            try:
                client[0].sendall(b"".join(telnet[0].escape(data)) if telnet else data)
            except OSError:
                drop_client()

    def flush() -> None:
        out.extend(_pump(network, bytes(pending)))
        pending.clear()

    def accept(conn: socket.socket) -> None:
        drop_client()  # a new connection replaces the old one
        conn.setblocking(False)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sel.register(conn, selectors.EVENT_READ)
        client.append(conn)
        with network.lock:
            network.host_in.clear()
            if rfc2217:
                network.host_baud = c.POWER_UP_BAUD  # until the client announces its rate
        if rfc2217:
            from serial.rfc2217 import PortManager

            class _Conn:
                def write(self, data: bytes) -> None:
                    try:
                        conn.sendall(data)
                    except OSError:
                        pass

            telnet.append(PortManager(_AnnouncedLine(network, flush), _Conn()))

    def loop() -> None:
        _raise_serving_priority()
        while not handle._stop.is_set():
            for key, _ in sel.select(_wait_s(network)):
                if key.fileobj is listener:
                    try:
                        conn, _ = listener.accept()
                    except OSError:
                        continue
                    accept(conn)
                else:
                    try:
                        chunk = key.fileobj.recv(4096)
                    except OSError:
                        chunk = b""
                    if not chunk:
                        drop_client()
                    elif telnet:  # Telnet commands out, rate changes applied in order with the data
                        for byte in telnet[0].filter(chunk):  # one by one: a rate change flushes what came before
                            pending.extend(byte)
                    else:
                        pending.extend(chunk)
            flush()
            send(bytes(out))
            out.clear()
        drop_client()

    handle._closers += [sel.close, listener.close]
    handle._thread = threading.Thread(target=loop, name="cmm-sim-tcp", daemon=True)
    handle._thread.start()
    return handle


def serve_pty(network: SimNetwork) -> ServedSim:
    """Serve on a new pseudo-terminal; ``.url`` is the device path (e.g. /dev/pts/4)."""
    master, slave = os.openpty()
    tty.setraw(slave)  # no echo, no line discipline: a byte-clean line
    attrs = termios.tcgetattr(slave)
    attrs[4] = attrs[5] = termios.B19200  # the modules' power-up rate
    termios.tcsetattr(slave, termios.TCSANOW, attrs)
    os.set_blocking(master, False)
    handle = ServedSim(network, os.ttyname(slave))
    network.start_realtime()
    _tighten_gil()
    sel = selectors.SelectSelector()  # microsecond time-outs: epoll and poll round up to whole milliseconds
    sel.register(master, selectors.EVENT_READ)

    def speed(last: int) -> int:
        try:  # the client's termios speed is the host's line rate
            return _SPEEDS.get(termios.tcgetattr(slave)[5], 0)
        except termios.error:
            return last

    def loop() -> None:
        _raise_serving_priority()
        last = c.POWER_UP_BAUD
        while not handle._stop.is_set():
            data = None
            ready = sel.select(_wait_s(network))
            before = speed(last)
            if ready:
                try:
                    data = os.read(master, 4096)
                except (BlockingIOError, OSError):
                    data = None
            # a second look after the bytes: a host that switched and wrote while this thread was held up
            # between the first look and the read sent them at the rate seen after, not before
            now = speed(before) if data else before
            sent = _sent_rate(network, last, before, now) if data and now != last else now
            last = now
            out = _pump(network, data, sent, now)
            if out:
                try:
                    os.write(master, out)
                except OSError:
                    pass

    # the slave stays open here so a client closing the port does not hang up the master
    handle._closers += [sel.close, lambda: os.close(master), lambda: os.close(slave)]
    handle._thread = threading.Thread(target=loop, name="cmm-sim-pty", daemon=True)
    handle._thread.start()
    return handle
